"""A confirmed e-stop: ``climbd estop`` (and ``--reset``) exits 0 only when the robot's mode
shows the e-stop latched by this command (or the reset done by its session), and otherwise
exits non-zero naming what happened: no robot, refused, not confirmed. The same for
``TeleopClient.estop``/``reset``. Real subprocesses against a control role on the fake driver,
over loopback Zenoh; one robot serves the whole module.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass

import pytest
from conftest import ROOT, free_port
from support.zenoh_roles import Observer, Proc

from climbd.daemon.cli.confirm import NoRobot, Refused
from climbd.daemon.cli.teleop import TeleopClient
from climbd.daemon.contract.messages import Health, Mode, ModeState
from climbd.daemon.runtime.network import Endpoints, Network, zenoh_config


@dataclass
class Run:
    """One finished ``climbd`` command: exit code, output, its pid (its e-stop source) and time."""

    code: int
    out: str
    err: str
    pid: int
    took: float

    @property
    def source(self) -> str:
        """The e-stop source ``climbd estop`` names itself by: ``host:pid``."""
        return f"{socket.gethostname()}:{self.pid}"


def climbd(*args: str) -> Run:
    """Run ``climbd ARGS`` to completion as a real subprocess."""
    start = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-m", "climbd.daemon.cli", *args],
        cwd=ROOT,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    out, err = proc.communicate(timeout=30)
    return Run(proc.returncode, out, err, proc.pid, time.monotonic() - start)


@dataclass
class Robot:
    """The module's control role and an observer of its mode and health."""

    endpoint: str
    proc: Proc
    obs: Observer

    def estop(self, *args: str) -> Run:
        return climbd("estop", "--robot", "widowx", "--connect", self.endpoint, *args)

    def engage(self) -> Run:
        """Engage the e-stop (confirmed), the start of each reset test."""
        run = self.estop("--reason", "test")
        assert run.code == 0, run.err
        return run


@pytest.fixture(scope="module")
def robot() -> Iterator[Robot]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = Proc("run", "--profile", "robots/widowx.toml", "--driver", "fake", "--quiet",
                "--listen", endpoint)  # fmt: skip
    obs = Observer("widowx", [endpoint])
    try:
        obs.wait(ModeState, lambda m: m.mode == Mode.HOLD, 60)
        yield Robot(endpoint, proc, obs)
    finally:
        obs.close()
        proc.kill()


def test_nothing_listening_fails_fast_naming_robot_and_endpoint() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    run = climbd("estop", "--robot", "widowx", "--connect", endpoint, "--timeout", "30")
    print(f"failed in {run.took:.2f} s")
    assert run.code == 1 and run.out == ""
    assert f"no robot widowx answered on {endpoint}: no connection" in run.err
    assert run.took < 10.0, "no connection: it fails at once, not at the timeout"


def test_estop_exits_0_once_the_robot_shows_it_latched(robot: Robot) -> None:
    run = robot.estop("--reason", "confirm test")
    print(f"confirmed in {run.took:.2f} s")
    assert run.code == 0, run.err
    assert run.out.startswith("e-stop engaged on widowx: ESTOP")
    latched = robot.obs.wait(ModeState, lambda m: run.source in m.estop_by)
    assert latched.mode == Mode.ESTOP
    assert robot.obs.latest_health(after=latched.stamp).mode == Mode.ESTOP


def test_a_misspelt_robot_fails_naming_the_robots_that_answer(robot: Robot) -> None:
    run = climbd("estop", "--robot", "widowy", "--connect", robot.endpoint, "--timeout", "1")
    assert run.code == 1 and run.out == ""
    assert f"no robot widowy answered on {robot.endpoint} within 1 s" in run.err
    assert "robots there: widowx" in run.err


def test_reset_refused_while_a_teleop_client_holds_the_session(robot: Robot, tmp_path) -> None:
    robot.engage()
    script = tmp_path / "hold.txt"
    script.write_text("0 claim\n60 release\n")
    alice = Proc("teleop", "--robot", "widowx", "--connect", robot.endpoint,
                 "--script", str(script), "--name", "alice")  # fmt: skip
    try:
        robot.obs.wait(Health, lambda h: h.session == "alice")
        run = robot.estop("--reset", "--timeout", "1")
        assert run.code == 1, run.out
        assert "refused: reset: widowx stays in ESTOP (e-stop by" in run.err
        assert "session held by alice" in run.err
    finally:
        alice.stop()
    stopped = time.monotonic()  # the daemon stamps on this machine's monotonic clock
    done = robot.obs.wait(Health, lambda h: h.stamp > stopped and h.session == "")
    run = robot.estop("--reset")
    assert run.code == 0, run.err
    assert run.out.startswith("reset on widowx: OFF (reset by ")
    reset = robot.obs.wait(ModeState, lambda m: m.stamp > done.stamp and m.reset_by != "")
    assert reset.mode == Mode.OFF, "torque_off: a reset robot is off"


def test_reset_with_nothing_latched_is_refused(robot: Robot) -> None:
    robot.engage()
    assert robot.estop("--reset").code == 0
    run = robot.estop("--reset")
    assert run.code == 1 and "refused: nothing to reset: widowx is in OFF" in run.err


def test_teleop_client_confirms_its_estop_and_reset(robot: Robot) -> None:
    net = Network("widowx", zenoh_config(None, "test", Endpoints([], [robot.endpoint])))
    client = TeleopClient(net, "api", endpoints=[robot.endpoint], timeout=1.0)
    client.start()
    try:
        engaged = client.estop("api test")
        assert engaged.mode == Mode.ESTOP and "api" in engaged.estop_by
        with pytest.raises(
            Refused, match="refused: reset: api holds no session of widowx: claim first"
        ):
            client.reset()  # only the session's holder may reset
        client.claim()
        reset = client.reset()
        assert reset.mode == Mode.OFF and reset.reset_by == client.session
    finally:
        client.close()
        net.close()


def test_teleop_client_of_a_robot_nobody_runs_raises_no_robot(robot: Robot) -> None:
    net = Network("widowy", zenoh_config(None, "test", Endpoints([], [robot.endpoint])))
    client = TeleopClient(net, "api", endpoints=[robot.endpoint], timeout=1.0)
    try:
        with pytest.raises(NoRobot, match=f"no robot widowy answered on {robot.endpoint}"):
            client.estop()
    finally:
        client.close()
        net.close()
