"""Rights per identity and replay defences over real Zenoh (issue #33, item 2).

One control role on the fake driver with user/password authentication and a rights table; each
attack runs as its own process on plain Zenoh (tests/support/zenoh_attack.py), and each must be
refused: by Zenoh's ACL where the right rides on the key, else by the control role, which
counts it in Health and logs it.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from conftest import free_port
from support.auth_roles import auth_profile, control_health
from support.zenoh_roles import ROOT, Observer, Proc

from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import Health, Mode, ModeState
from climbd.daemon.contract.profile import AuthConfig, ProfileError
from climbd.daemon.runtime.access import command_acl, identity_rights
from climbd.daemon.runtime.safety import Safety

ATTACK = Path(__file__).resolve().parent / "support" / "zenoh_attack.py"
ROBOT = "widowx"
USERS = {
    "control": "rolepw",
    "alice": "apw",  # drives and engages e-stops
    "bob": "bpw",  # a commander without reset or override
    "carol": "cpw",  # may reset
    "dave": "dpw",  # may override
    "viewer": "vpw",  # read-only
    "lidar": "lpw",  # a perception source
}
RIGHTS = """[network.auth.rights]
alice = ["teleop", "estop"]
bob = ["teleop", "estop"]
carol = ["teleop", "reset"]
dave = ["teleop", "override"]
viewer = ["telemetry"]
lidar = ["features"]
"""


@dataclass
class Robot:
    """The control role under attack, its endpoints, and an anonymous telemetry observer."""

    proc: Proc
    listen: str
    telemetry: str
    obs: Observer
    window: float
    users: Path

    def health_after(self, t: float) -> Health:
        """The control role's first Health stamped after ``t`` + one publication period."""
        return control_health(self.obs, lambda h: h.stamp > t + 0.6)


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Robot]:
    tmp = tmp_path_factory.mktemp("rights")
    (tmp / "users.txt").write_text("".join(f"{u}:{p}\n" for u, p in USERS.items()))
    listen, telemetry = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    auth = 'user = "{role}"\npassword = "rolepw"\ncredentials_file = "users.txt"'
    profile = auth_profile(tmp, ROOT / "robots", auth, telemetry, RIGHTS)
    proc = Proc("run", "--profile", profile, "--driver", "fake", "--quiet", "--gait", "tripod",
                "--listen", listen)  # fmt: skip
    obs = Observer(ROBOT, [telemetry])
    try:
        obs.wait(ModeState, lambda m: m.mode == Mode.HOLD, 60)
        window = profiles.load(profile).safety.heartbeat_window
        yield Robot(proc, listen, telemetry, obs, window, tmp / "users.txt")
    finally:
        obs.close()
        proc.kill()


def attack(robot: Robot, spec: dict, user: str = "", wait: bool = True) -> subprocess.Popen:
    """Run one attack process (as ``user``, or without credentials) against the robot's
    authenticated endpoint unless ``spec`` names another; wait for it unless ``wait`` is off."""
    spec = {"robot": ROBOT, "connect": [robot.listen], **spec}
    if user:
        spec |= {"user": user, "password": USERS[user]}
    proc = subprocess.Popen(
        [sys.executable, str(ATTACK), json.dumps(spec)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    if wait:
        out, _ = proc.communicate(timeout=30)
        assert proc.returncode == 0, out
    return proc


def events(proc: subprocess.Popen) -> list[dict]:
    """The JSON events an attack process printed (it must have ended)."""
    out, _ = proc.communicate(timeout=30)
    return [json.loads(line) for line in out.splitlines() if line.startswith("{")]


def test_a_replayed_heartbeat_does_not_keep_the_session_alive(robot: Robot, tmp_path) -> None:
    thief = f"tcp/127.0.0.1:{free_port()}"
    replay = attack(robot, {"attack": "replay", "capture": [thief], "silence": 0.12,
                            "dictionary": str(robot.users),
                            "seconds": 2.0}, user="bob", wait=False)  # fmt: skip
    assert json.loads(replay.stdout.readline())["event"] == "listening"
    script = tmp_path / "drive.txt"
    script.write_text("0 claim\n0.2 mode ACTIVE\n120 release\n")
    teleop = Proc("teleop", "--robot", ROBOT, "--connect", robot.listen, "--connect", thief,
                  "--script", str(script), "--user", "alice", "--name", "laptop",
                  env={"CLIMBD_PASSWORD": USERS["alice"]})  # fmt: skip
    try:
        active = robot.obs.wait(ModeState, lambda m: m.mode == Mode.ACTIVE, 30)
        time.sleep(1.0)  # the thief captures heartbeats
        teleop.proc.send_signal(signal.SIGKILL)
        held = robot.obs.wait(
            ModeState, lambda m: m.mode == Mode.HOLD and m.stamp > active.stamp, 10
        )
        captured, replayed = events(replay)
        assert captured["count"] >= 10 and replayed["count"] >= 20
        assert "heartbeat of laptop lost" in held.reason
        assert held.stamp - captured["stamp"] <= robot.window + 0.1, "held at the window"
        after = robot.health_after(held.stamp + 1.5)
        assert after.refused_heartbeats >= 1, "replays within the window were refused"
        assert after.session == "", "once lapsed, replays are another session's: ignored"
        robot.proc.wait_for(f"refused heartbeat of session {captured['session']} \\(laptop\\)")
    finally:
        teleop.kill()
        replay.kill()


def test_b_a_viewer_cannot_feed_features_but_a_features_identity_can(robot: Robot) -> None:
    joists = {"key": "features/joists", "fields": {"joists": []}}
    attack(robot, {"attack": "puts", "messages": [joists], "repeat": 10}, user="viewer")
    after = robot.health_after(time.monotonic())
    assert "features/joists" not in after.features, "Zenoh's ACL dropped the viewer's joists"
    attack(robot, {"attack": "puts", "messages": [joists], "repeat": 10}, user="lidar")
    control_health(robot.obs, lambda h: "features/joists" in h.features, 10)


def test_c_only_an_identity_with_reset_resets_an_estop(robot: Robot) -> None:
    estop = {"key": "cmd/estop", "fields": {"engage": True, "source": "alice"}}
    attack(robot, {"attack": "puts", "messages": [estop], "repeat": 3}, user="alice")
    engaged = robot.obs.wait(ModeState, lambda m: m.mode == Mode.ESTOP)
    before = robot.health_after(time.monotonic()).refused_commands
    resets = [
        {"key": "cmd/mode", "fields": {"reset": True}},  # the old field: refused, counted
        {"key": "cmd/reset", "fields": {}},  # its own key: Zenoh's ACL drops it
    ]
    attack(robot, {"attack": "session", "messages": resets, "seconds": 1.0}, user="bob")
    after = robot.health_after(time.monotonic())
    assert after.mode == Mode.ESTOP, "bob has no reset right"
    assert after.refused_commands == before + 1
    robot.proc.wait_for("refused a reset on cmd/mode from session bob-session")
    reset = [{"key": "cmd/reset", "fields": {}}]
    attack(robot, {"attack": "session", "messages": reset, "seconds": 1.0}, user="carol")
    done = robot.obs.wait(ModeState, lambda m: m.mode != Mode.ESTOP and m.stamp > engaged.stamp)
    assert done.reset_by == "carol-session"


def test_d_an_override_claim_needs_the_override_right(robot: Robot) -> None:
    holder = attack(robot, {"attack": "session", "seconds": 6.0}, user="alice", wait=False)
    try:
        control_health(robot.obs, lambda h: h.session == "alice", 10)
        before = robot.health_after(time.monotonic()).refused_commands
        override = {"key": "cmd/override", "fields": {"session": "bob-2", "client": "bob"}}
        attack(robot, {"attack": "session", "claim": {"override": True}, "seconds": 0.6,
                       "messages": [override]}, user="bob")  # fmt: skip
        after = robot.health_after(time.monotonic())
        assert after.session == "alice", "neither override of bob's took the session"
        assert after.refused_commands >= before + 1
        robot.proc.wait_for("refused an override claim on cmd/session by bob")
        attack(robot, {"attack": "session", "claim_key": "cmd/override", "seconds": 0.6},
               user="dave")  # fmt: skip
        control_health(robot.obs, lambda h: h.session == "dave", 10)
    finally:
        holder.kill()


@pytest.mark.parametrize("mode", ["client", "peer"])
def test_e_the_telemetry_endpoint_is_read_only_for_every_session_mode(
    robot: Robot, mode: str
) -> None:
    truth = robot.health_after(time.monotonic())
    spoof = {"key": "state/mode", "fields": {"mode": "ACTIVE", "reason": "spoofed"}}
    command = {"key": "cmd/estop", "fields": {"engage": True, "source": "spoof"}}
    attack(robot, {"attack": "puts", "mode": mode, "connect": [robot.telemetry],
                   "messages": [spoof, command], "repeat": 10})  # fmt: skip
    after = robot.health_after(time.monotonic())
    assert after.mode == truth.mode != Mode.ESTOP
    assert after.unauthorised_commands >= truth.unauthorised_commands + 10
    assert not [m for m in robot.obs.messages(ModeState) if m.reason == "spoofed"]
    assert robot.obs.messages(ModeState)[-1].mode == truth.mode, "subscribers see the truth"
    robot.proc.wait_for("refused climbd/widowx/cmd/estop from a peer without credentials")


def test_heartbeats_must_advance_seq_and_stamp_even_across_a_new_claim(robots) -> None:
    safety = Safety(profiles.load(robots / "widowx.toml"))
    safety.claim("s1", "alice", 0.0)
    assert safety.heartbeat("s1", 0.1, seq=1, stamp=10.0)
    assert not safety.heartbeat("s1", 0.2, seq=1, stamp=10.0), "replayed"
    assert not safety.heartbeat("s1", 0.2, seq=2, stamp=9.0), "stamp went back"
    assert not safety.heartbeat("other", 0.2, seq=5, stamp=20.0), "another session: ignored"
    assert safety.refused_heartbeats == 2 and safety.refused == 0
    safety.check_heartbeat(1.0)
    assert safety.session is None
    safety.claim("s1", "alice", 1.1)  # claimed again: the watermark stays
    assert not safety.heartbeat("s1", 1.2, seq=1, stamp=10.0)
    assert safety.heartbeat("s1", 1.2, seq=2, stamp=11.0)


def test_rights_map_to_the_acl_and_commanders_keep_every_command_right() -> None:
    auth = AuthConfig(user="{role}", commanders=["op"], rights={"v": ["telemetry"]})
    rights = identity_rights(auth)
    assert rights["op"] == {"telemetry", "teleop", "override", "estop", "reset"}
    assert rights["v"] == {"telemetry"}
    acl = command_acl(ROBOT, auth)
    by_id = {s["id"]: s.get("usernames") for s in acl["subjects"]}
    assert by_id["reset-user"] == ["op"] and by_id["role-user"] == ["control", "perception"]
    assert "features-user" not in by_id and "peers" not in by_id


def test_an_unknown_right_names_the_field(tmp_path, robots) -> None:
    path = auth_profile(tmp_path, robots, 'user = "{role}"', "tcp/127.0.0.1:1",
                        'rights = { bob = ["fly"] }')  # fmt: skip
    with pytest.raises(ProfileError, match=r"network.auth.rights.*'fly'"):
        profiles.load(path)
