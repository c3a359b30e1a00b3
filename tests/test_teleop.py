"""``climbd teleop`` and ``climbd estop`` against a running control role, over real Zenoh.

Times are compared on the daemon's own stamps (ModeState) and the teleop client's heartbeat
stamps: both are CLOCK_MONOTONIC of this machine.
"""

from __future__ import annotations

import signal
from collections.abc import Callable

import pytest
from support.zenoh_roles import Observer, Proc

from climbd.daemon.cli.teleop import ScriptError, parse_script
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import EStop, Heartbeat, Mode, ModeState

HOLD_SCRIPT = """\
0.0 claim
0.1 mode ACTIVE
0.2 motion vx=0.02 yaw_rate=0.05
120 release
"""


def test_script_parses_in_time_order() -> None:
    steps = parse_script(
        "1.5 release\n0 claim override  # take over\n\n0.5 motion vx=0.1\n2 release handoff\n"
    )
    assert [(s.at, s.verb, s.args) for s in steps] == [
        (0.0, "claim", ("override",)),
        (0.5, "motion", ("vx=0.1",)),
        (1.5, "release", ()),
        (2.0, "release", ("handoff",)),
    ]


@pytest.mark.parametrize(
    "line,error",
    [
        ("soon claim", "drive.txt:2: time 'soon'"),
        ("1 jump", "drive.txt:2: unknown verb 'jump'"),
        ("1 motion speed=2", "drive.txt:2: motion field 'speed' unknown"),
        ("1 motion vx=fast", "drive.txt:2: motion vx='fast' is not a number"),
        ("1 mode FLY", "drive.txt:2: mode takes one of"),
        ("1 release now", "drive.txt:2: release takes nothing or 'handoff'"),
    ],
)
def test_script_errors_name_file_and_line(line: str, error: str) -> None:
    with pytest.raises(ScriptError, match=error):
        parse_script(f"0 claim\n{line}\n", "drive.txt")


def control_role(endpoint: str, *extra: str) -> Proc:
    return Proc("run", "--profile", "robots/widowx.toml", "--driver", "fake", "--quiet",
                "--gait", "tripod", "--listen", endpoint, *extra)  # fmt: skip


def teleop(endpoint: str, obs: Observer, script, *extra: str) -> Proc:
    return Proc("teleop", "--robot", "widowx", "--connect", endpoint, "--connect", obs.endpoint,
                "--script", str(script), *extra)  # fmt: skip


def test_killed_teleop_client_puts_the_robot_in_hold_within_the_window(
    endpoint: str, tmp_path, robots
) -> None:
    profile = profiles.load(robots / "widowx.toml")
    window, tick = profile.safety.heartbeat_window, 1.0 / profile.rate_hz
    script = tmp_path / "drive.txt"
    script.write_text(HOLD_SCRIPT)
    robot = control_role(endpoint)
    obs = Observer("widowx", [endpoint])
    client = None
    try:
        obs.wait(ModeState, lambda m: m.mode == Mode.HOLD, 60)
        client = teleop(endpoint, obs, script, "--name", "laptop")
        active = obs.wait(ModeState, lambda m: m.mode == Mode.ACTIVE)
        obs.wait(Heartbeat, lambda h: h.stamp > active.stamp + 0.5)
        client.proc.send_signal(signal.SIGKILL)
        client.proc.wait(10)
        hold = obs.wait(ModeState, lambda m: m.mode == Mode.HOLD and m.stamp > active.stamp)
        assert "heartbeat of laptop lost" in hold.reason
        last_beat = max(h.stamp for h in obs.messages(Heartbeat))
        print(f"HOLD {1e3 * (hold.stamp - last_beat):.1f} ms after the last heartbeat")
        # Held after the window had passed, and no later than one tick (+ delivery) after it.
        assert window < hold.stamp - last_beat <= window + 2 * tick + 0.05
        assert robot.stop() == 0
    finally:
        obs.close()
        robot.kill()
        if client is not None:
            client.kill()


def test_second_client_is_refused_while_the_first_holds_the_session(
    endpoint: str, tmp_path
) -> None:
    first, second, override = (tmp_path / f"{n}.txt" for n in ("first", "second", "override"))
    first.write_text(HOLD_SCRIPT)
    second.write_text("0 claim\n0.2 mode HOLD\n0.3 motion vx=-0.05\n1.0 release\n")
    override.write_text("0 claim\n0.3 mode HOLD\n1.0 release\n")
    robot = control_role(endpoint)
    obs = Observer("widowx", [endpoint])
    clients = []
    try:
        obs.wait(ModeState, lambda m: m.mode == Mode.HOLD, 60)
        clients.append(teleop(endpoint, obs, first, "--name", "alice"))
        active = obs.wait(ModeState, lambda m: m.mode == Mode.ACTIVE)
        before = obs.latest_health(after=active.stamp).refused_commands

        clients.append(teleop(endpoint, obs, second, "--name", "bob"))
        assert clients[-1].proc.wait(30) == 0
        after = obs.latest_health(after=active.stamp + 1.5)
        assert after.mode == Mode.ACTIVE, "bob's HOLD request must be refused"
        assert after.refused_commands >= before + 3, "claim, mode and motion refused and counted"

        clients.append(teleop(endpoint, obs, override, "--name", "carol", "--override"))
        held = obs.wait(ModeState, lambda m: m.mode == Mode.HOLD and m.stamp > active.stamp)
        assert "requested by" in held.reason
        assert clients[-1].proc.wait(30) == 0
        robot.stop()
        assert "session of alice preempted by carol" in robot.text
    finally:
        obs.close()
        robot.kill()
        for c in clients:
            c.kill()


def test_estop_from_a_third_process_acts_within_one_tick_and_latches(endpoint: str, robots) -> None:
    tick = 1.0 / profiles.load(robots / "widowx.toml").rate_hz
    robot = control_role(endpoint)
    obs = Observer("widowx", [endpoint])
    obs.watch(EStop)
    try:
        obs.wait(ModeState, lambda m: m.mode == Mode.HOLD, 60)
        stop = Proc("estop", "--robot", "widowx", "--connect", endpoint,
                    "--connect", obs.endpoint, "--reason", "test")  # fmt: skip
        assert stop.proc.wait(30) == 0
        arrival = obs.seen[EStop][0][0]
        engaged = obs.wait(ModeState, lambda m: m.mode == Mode.ESTOP)
        print(f"ESTOP tick {1e3 * (engaged.stamp - arrival):.1f} ms after the e-stop arrived")
        assert "e-stop by" in engaged.reason and "test" in engaged.reason
        assert engaged.stamp - arrival <= tick + 0.01, "the first tick after arrival acts"
        assert engaged.estop_by == [obs.seen[EStop][0][1].source], "named by its source"
        stop.stop()
        assert "e-stop engaged on widowx: ESTOP" in stop.text
        assert 1 <= len(obs.seen[EStop]) < 10, "repeated only until the robot confirmed it"

        latched = obs.latest_health(after=engaged.stamp + 1.0)
        assert latched.mode == Mode.ESTOP, "an e-stop stays engaged until an explicit reset"
        assert latched.joints and robot.proc.poll() is None

        reset = Proc("estop", "--robot", "widowx", "--connect", endpoint, "--reset")
        assert reset.proc.wait(30) == 0
        off = obs.wait(ModeState, lambda m: m.mode == Mode.OFF and m.stamp > engaged.stamp)
        assert "reset" in off.reason
        assert robot.stop() == 0
    finally:
        obs.close()
        robot.kill()


def entered(mode: Mode, after: ModeState) -> Callable[[ModeState], bool]:
    """A ModeState in ``mode`` published after ``after``."""
    return lambda m: m.mode == mode and m.stamp > after.stamp


def test_release_holds_unless_handed_to_autonomy(endpoint: str, tmp_path) -> None:
    """Release means HOLD: an explicit release and a client exiting without one both hold the
    robot; only a handoff (``--handoff`` on exit) leaves it ACTIVE, logged and in the reason."""
    drive = "0 claim\n0.1 mode ACTIVE\n0.8 {end}\n"
    scripts = {}
    for name, end in (("alice", "release"), ("carol", "wait"), ("bob", "wait")):
        scripts[name] = tmp_path / f"{name}.txt"
        scripts[name].write_text(drive.format(end=end))
    robot = control_role(endpoint)
    obs = Observer("widowx", [endpoint])
    try:
        held = obs.wait(ModeState, lambda m: m.mode == Mode.HOLD, 60)
        for name in ("alice", "carol"):  # an explicit release; an exit without one
            client = teleop(endpoint, obs, scripts[name], "--name", name)
            assert client.proc.wait(30) == 0, client.text
            active = obs.wait(ModeState, entered(Mode.ACTIVE, after=held))
            held = obs.wait(ModeState, entered(Mode.HOLD, after=active))
            assert held.reason == f"session of {name} released"

        bob = teleop(endpoint, obs, scripts["bob"], "--name", "bob", "--handoff")
        assert bob.proc.wait(30) == 0, bob.text
        handed = obs.wait(ModeState, lambda m: m.reason == "handed to autonomy by bob")
        assert handed.mode == Mode.ACTIVE
        later = obs.latest_health(after=handed.stamp + 1.0)
        assert later.mode == Mode.ACTIVE and later.session == "", "autonomy, no session"
        assert robot.stop() == 0
        assert "session of bob released: robot handed to autonomy in ACTIVE" in robot.text
    finally:
        obs.close()
        robot.kill()


def test_teleop_without_terminal_or_with_bad_script_says_why(tmp_path) -> None:
    bad = tmp_path / "bad.txt"
    bad.write_text("0 claim\nx mode STAND\n")
    for args, message in (
        (("--script", str(bad)), f"{bad}:2: time 'x'"),
        (("--script", str(tmp_path / "missing.txt")), "missing.txt"),
        ((), "no terminal for the keyboard UI"),
    ):
        p = Proc("teleop", "--robot", "widowx", *args)
        assert p.proc.wait(30) == 2
        p.stop()
        assert message in p.text
