"""Reliability campaign: every fault the emulators and fakes inject, crossed with each robot.

Each cell runs the real driver against its emulator (dynamixel_sdk on the pty servo chain,
python-can MIT motors on a virtual bus, pyrealsense2 software device) under the real
controller, safety supervisor and control loop at the profile's rate, and checks: no exception
escapes, every command stays inside the profile's position limits, the profile's e-stop policy
is honoured when the fault latches, and the robot recovers (stands again) once the fault
clears. ``bench/soak.py --campaign`` turns the results into the table in BENCHMARKS.md; each
cell records a one-line outcome with ``record_property``.
"""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from support.still_body import StillBody

from climbd.daemon.contract import messages as m
from climbd.daemon.contract.messages import EstopPolicy, Mode
from climbd.daemon.contract.plugins import PerceptionPlugin
from climbd.daemon.contract.profile import Profile, load
from climbd.daemon.runtime.loader import Isolated, instantiate
from climbd.daemon.runtime.loop import MonotonicClock
from climbd.daemon.runtime.stack import control_stack

ROOT = Path(__file__).resolve().parent.parent
ROBOTS = ("widowx", "hubrobo", "qingzhui")
GAITS = {"widowx": "tripod", "hubrobo": "crawl", "qingzhui": "tripod"}
DYNAMIXEL = ("widowx", "hubrobo")
_channels = itertools.count()

FAULTS: dict[str, tuple[tuple[str, ...], str]] = {
    "servo lost": (ROBOTS, ""),
    "servo power-cycled": (DYNAMIXEL, "not injectable on the MIT emulator"),
    "overheat": (DYNAMIXEL, "MIT motors report no temperature"),
    "overload": (DYNAMIXEL, "MIT motors have no overload flag"),
    "corrupt packets": (ROBOTS, ""),
    "port gone": (DYNAMIXEL, "CAN: see CAN bus-off"),
    "CAN bus-off": (("qingzhui",), "Dynamixel robots have no CAN bus"),
    "camera unplugged": (ROBOTS, ""),
    "teleop heartbeat lost": (ROBOTS, ""),
    "clock jump": (ROBOTS, ""),
    "disk full while recording": (ROBOTS, ""),
    "perception plugin crash": (ROBOTS, ""),
}
"""Fault → (robots it applies to, why not to the others)."""

KNOWN_GAPS: dict[tuple[str, str], str] = {}
"""Cells that fail today for a reason outside this campaign: run as strict xfails, so a fix
turns them into failures that ask for this table to be updated."""


class JumpClock(MonotonicClock):
    """CLOCK_MONOTONIC plus an offset a test moves: a suspended process resuming, seen as a jump."""

    def __init__(self) -> None:
        super().__init__()
        self.offset = 0.0

    def now(self) -> float:
        return time.monotonic() + self.offset

    def sleep_until(self, deadline: float) -> None:
        super().sleep_until(deadline - self.offset)


class Rig:
    """One robot's real driver on its emulator, under the controller and loop, in real time."""

    def __init__(self, robot: str, gait: bool = True, publish=None) -> None:
        self.robot = robot
        self.profile: Profile = load(ROOT / "robots" / f"{robot}.toml")
        self.clock = JumpClock()
        self.errors: list[BaseException] = []
        self.commands: list[np.ndarray] = []
        self.published: list[m.Message] = []
        self._publish = publish
        self._open_driver()
        isolated = None
        if gait:
            name = GAITS[robot]
            plugin = instantiate("climbd.gaits", name, {}, self.profile, name)
            isolated = Isolated(name, plugin, lambda n, e: self.safety.hold(self.clock.now(), n))
        stack = control_stack(
            self.profile, self.bus, self.clock, isolated, publish=self._on_publish, tick=self._tick
        )
        self.safety, self.controller, self.loop = stack.safety, stack.controller, stack.loop
        self.thread = threading.Thread(target=self.loop.run, daemon=True)

    def _open_driver(self) -> None:
        from climbd.daemon.algorithms.kinematics import Kinematics

        stand = Kinematics(self.profile).stand_joints()
        if self.robot in DYNAMIXEL:
            from climbd.drivers.dynamixel.bus import DynamixelBus
            from climbd.drivers.sim.dynamixel import DynamixelEmulator, ServoChain

            self.chain = ServoChain.from_profile(self.profile)
            self.chain.set_joint_state(stand)
            self.emulator = DynamixelEmulator(self.chain).start()
            self.bus = DynamixelBus.from_profile(
                self.profile, port=self.emulator.port, timeout_margin_ms=10.0
            )
        else:
            from climbd.daemon.cli.sim_host import THREAD_REPLY_TIMEOUT
            from climbd.drivers.sim.mit_motors import MitMotorChain
            from climbd.drivers.torque.bus import MitJointBus, waiting_for_replies
            from climbd.drivers.torque.config import TorqueConfig

            channel = f"campaign-{os.getpid()}-{next(_channels)}"
            ids = [j.id for j in self.profile.joints]
            actuator = TorqueConfig.from_profile(self.profile).actuator
            self.chain = MitMotorChain(ids, actuator, channel).start()
            for ident, q in zip(ids, stand, strict=True):
                self.chain.set_state(ident, float(q), 0.0, 0.0)
            self.emulator = None
            waiting = waiting_for_replies(self.profile, THREAD_REPLY_TIMEOUT)
            self.bus = MitJointBus(waiting, [channel], interface="virtual")
        self.bus.open()
        write = self.bus.write

        def recorded(command: m.JointCommand) -> None:
            self.commands.append(np.array(command.position))
            write(command)

        self.bus.write = recorded

    def _on_publish(self, msg: m.Message) -> None:
        self.published.append(msg)
        if self._publish is not None:
            self._publish(msg)

    def _tick(self, t: float, dt: float) -> None:
        try:
            self.controller.tick(t, dt)
        except BaseException as e:  # the check: nothing may escape a tick
            self.errors.append(e)
            raise

    # --- driving --------------------------------------------------------------------------

    def start(self) -> Rig:
        self.thread.start()
        return self

    def wait(self, condition: Callable[[], bool], timeout: float = 5.0) -> float:
        """Seconds until ``condition`` held; fails with the mode history if it never did."""
        start = time.monotonic()
        while not condition():
            if time.monotonic() - start > timeout or not self.thread.is_alive():
                history = [(h.mode.value, h.reason) for h in self.safety.history]
                raise AssertionError(f"timed out; mode {self.safety.mode.value}, {history}")
            time.sleep(0.005)
        return time.monotonic() - start

    def stand(self) -> None:
        """STAND (after a reset if latched) until the stand completes and the robot holds."""
        now = self.clock.now()
        if self.safety.mode in (Mode.ESTOP, Mode.FAULT):
            assert self.safety.reset(now)
        assert self.safety.request(Mode.STAND, self.clock.now()), self.safety.mode
        self.wait(lambda: self.safety.mode == Mode.HOLD and self.safety.reason == "stand complete")

    def activate(self) -> None:
        """Stand, then run the robot's gait (ACTIVE, requested by the daemon itself)."""
        self.stand()
        assert self.safety.request(Mode.ACTIVE, self.clock.now())
        time.sleep(0.2)
        assert self.safety.mode == Mode.ACTIVE, self.safety.reason

    def measured(self) -> np.ndarray:
        return np.asarray(self.controller.measured.position)

    def stop(self) -> None:
        self.loop.stop()
        self.thread.join(5)
        self.bus.close()
        if self.emulator is not None:
            self.emulator.stop()
        else:
            self.chain.stop()

    # --- checks ---------------------------------------------------------------------------

    def check(self) -> None:
        """No exception escaped (nor was caught as a failed tick); commands inside the limits."""
        assert not self.errors, self.errors
        crashes = [h.reason for h in self.safety.history if "tick failed" in h.reason]
        assert not crashes, crashes
        lower = np.array([j.limits.lower for j in self.profile.joints])
        upper = np.array([j.limits.upper for j in self.profile.joints])
        if self.commands:
            cmds = np.array(self.commands)
            assert np.all(cmds >= lower - 1e-9) and np.all(cmds <= upper + 1e-9)

    def check_policy(self, at_fault: int) -> str:
        """The profile's e-stop policy after a latched fault: torque off, or hold the pose the
        joints had when it latched."""
        if self.safety.policy == EstopPolicy.TORQUE_OFF:
            assert not self.safety.torque_on
            assert len(self.commands) <= at_fault + 1, "no command after torque off"
            if self.robot in DYNAMIXEL and self.emulator is not None and not self._vanished:
                assert not any(s.torque_enabled for s in self.chain.servos.values())
            return "torque off"
        assert self.safety.torque_on, "hold/hold_grip keep the joints powered"
        pose = self.controller.target
        assert pose is not None and len(self.commands) > at_fault, "commands go on"
        assert np.max(np.abs(self.commands[-1] - pose)) < 0.02, "holds the pose it had"
        return "holding the pose"

    _vanished = False


@pytest.fixture()
def rig_factory():
    rigs: list[Rig] = []

    def make(robot: str, **options) -> Rig:
        rig = Rig(robot, **options)
        rigs.append(rig)
        return rig.start()

    yield make
    for rig in rigs:
        rig.stop()


def cells() -> list:
    return [
        pytest.param(
            fault,
            robot,
            id=f"{fault}-{robot}",
            marks=[pytest.mark.xfail(reason=KNOWN_GAPS[fault, robot], strict=True)]
            if (fault, robot) in KNOWN_GAPS
            else [],
        )
        for fault, (robots, _) in FAULTS.items()
        for robot in robots
    ]


@pytest.mark.parametrize("fault,robot", cells())
def test_campaign(fault: str, robot: str, rig_factory, record_property, tmp_path, endpoint) -> None:
    outcome = SCENARIOS[fault](robot, rig_factory, tmp_path, endpoint)
    record_property("outcome", outcome)


# --- scenarios: each returns a one-line outcome ------------------------------------------------


def _joint(rig: Rig, k: int = 4):
    return rig.profile.joints[k]


def servo_lost(robot, make, tmp_path, endpoint) -> str:
    rig = make(robot)
    j = _joint(rig)
    took = _hold_and_recover(
        rig,
        lambda: rig.chain.silence(j.id),
        lambda: rig.chain.silence(j.id, False),
        f"servo lost: {j.name}",
        lambda: not any(h.lost for h in rig.bus.health()),
    )
    return f"HOLD ({j.name} lost) in {took:.2f} s; stands again once it answers"


def _hold_and_recover(rig: Rig, inject, clear, reason: str, cleared) -> float:
    """Walking, ``inject`` must bring HOLD for ``reason``; once ``clear``ed and ``cleared()``,
    the robot stands and walks again. Seconds from injection to HOLD."""
    rig.activate()
    inject()
    took = rig.wait(lambda: rig.safety.mode == Mode.HOLD and reason in rig.safety.reason)
    clear()
    rig.wait(cleared)
    rig.activate()
    rig.check()
    return took


def servo_power_cycled(robot, make, tmp_path, endpoint) -> str:
    rig = make(robot)
    j = _joint(rig)
    servo = rig.chain.servo(j.id)

    def power_back() -> None:
        servo.set("torque_enable", 0)  # a power cycle: it wakes with torque off
        rig.chain.silence(j.id, False)

    took = _hold_and_recover(
        rig,
        lambda: rig.chain.silence(j.id),
        power_back,
        f"servo lost: {j.name}",
        lambda: not any(h.lost for h in rig.bus.health()),
    )
    assert servo.torque_enabled, f"{j.name} powers its horn again after the power cycle"
    return f"HOLD ({j.name} lost) in {took:.2f} s; torque back on once it answers; stands again"


def overheat(robot, make, tmp_path, endpoint) -> str:
    rig = make(robot)
    rig.activate()
    s = rig.profile.safety
    servo = rig.chain.servo(_joint(rig, 2).id)
    servo.set_present(temperature=s.derate_temperature + 1)
    rig.wait(lambda: rig.safety.speed_scale < 1.0)
    assert rig.safety.mode == Mode.ACTIVE, "derated, still walking"
    servo.set_present(temperature=s.max_temperature + 5)
    took = rig.wait(lambda: rig.safety.mode == Mode.FAULT)
    at_fault = len(rig.commands)
    time.sleep(0.3)
    policy = rig.check_policy(at_fault)
    servo.set_present(temperature=40.0)
    rig.wait(lambda: all(h.temperature < s.derate_temperature for h in rig.bus.health()))
    rig.activate()
    assert rig.safety.speed_scale == 1.0
    rig.check()
    return f"derate, then FAULT in {took:.2f} s, {policy}; reset and stand once cool"


def overload(robot, make, tmp_path, endpoint) -> str:
    """The servo switches its torque off (Shutdown); X series latch the error until a REBOOT.
    Nothing is rebooted or re-torqued until the operator resets (as ``climbd estop --reset``
    does: claim, reset, release)."""
    rig = make(robot)
    j = _joint(rig, 1)
    servo = rig.chain.servo(j.id)

    def cleared_by_operator() -> None:
        servo.inject_overload(False)
        time.sleep(0.3)
        assert not servo.torque_enabled, "no re-torque before the operator asks"
        now = rig.clock.now()
        assert rig.safety.claim("operator", "campaign", now)[0]
        rig.controller.on_reset(m.ResetRequest(stamp=now, session="operator"))
        rig.safety.release("operator", now)

    took = _hold_and_recover(
        rig,
        servo.inject_overload,
        cleared_by_operator,
        f"overload: {j.name}",
        lambda: servo.torque_enabled and not any(h.errors or h.lost for h in rig.bus.health()),
    )
    return f"HOLD (overload: {j.name}) in {took:.2f} s; operator reset re-torques it; walks again"


def corrupt_packets(robot, make, tmp_path, endpoint) -> str:
    rig = make(robot)
    rig.activate()
    j = _joint(rig, 0)
    if robot in DYNAMIXEL:
        rig.chain.corrupt(j.id, count=3)
        time.sleep(0.3)
        assert rig.safety.mode == Mode.ACTIVE, "a few bad replies are misses, not a fault"
        rig.chain.corrupt(j.id, count=None)
    else:
        rig.chain.corrupt(j.id)
    took = rig.wait(lambda: rig.safety.mode == Mode.HOLD)
    reason = rig.safety.reason
    if robot in DYNAMIXEL:
        rig.chain.corrupt(j.id, count=0)
    else:
        rig.chain.corrupt(j.id, False)
    rig.wait(lambda: not any(h.lost or h.errors for h in rig.bus.health()))
    rig.activate()
    rig.check()
    transient = "3 bad replies ignored; " if robot in DYNAMIXEL else ""
    return f"{transient}HOLD ({reason}) in {took:.2f} s; stands again once clean"


def port_gone(robot, make, tmp_path, endpoint) -> str:
    rig = make(robot)
    rig.activate()
    rig._vanished = True
    rig.emulator.vanish()
    took = rig.wait(lambda: rig.safety.mode == Mode.FAULT)
    time.sleep(0.3)
    assert rig.safety.mode == Mode.FAULT and rig.thread.is_alive()
    rig.check()
    return (
        f"FAULT (joint bus gone) in {took:.2f} s, loop keeps running; the servos keep their last "
        "goal (nothing can reach them); restart the role to recover"
    )


def can_bus_off(robot, make, tmp_path, endpoint) -> str:
    rig = make(robot)
    rig.activate()
    rig.chain.bus_off()
    took = rig.wait(lambda: rig.safety.mode == Mode.FAULT)
    at_fault = len(rig.commands)
    time.sleep(0.3)
    policy = rig.check_policy(at_fault)
    rig.activate()  # the controller recovers from bus-off by itself; reset is explicit
    rig.check()
    return f"FAULT (bus-off) in {took:.2f} s, {policy}; reset and stand after recovery"


def camera_unplugged(robot, make, tmp_path, endpoint) -> str:
    from climbd.daemon.contract.hardware import mount_extrinsics
    from climbd.daemon.runtime.capture import Capture
    from climbd.drivers.realsense.models import model
    from climbd.drivers.realsense.software import SoftwareDepthCamera

    profile = load(ROOT / "robots" / f"{robot}.toml")
    config = profile.cameras[0]
    intrinsics = model(config.model).intrinsics(config.width, config.height)
    camera = SoftwareDepthCamera(
        intrinsics, 0.001, mount_extrinsics(config), model=config.model, timeout=0.5
    )
    capture = Capture(camera, config.name)
    capture.start()
    image = np.full((intrinsics.height, intrinsics.width), 1500, np.uint16)
    rig = make(robot)
    try:
        rig.stand()
        frames = []

        def pump(n: int, t0: float) -> None:
            for k in range(n):
                camera.push(image, t0 + k / 30)
                frame = capture.latest(timeout=1.0)
                if frame is not None:
                    frames.append(frame.timestamp)

        pump(5, 0.0)
        camera.unplug()
        rig.wait(lambda: not camera.health().connected)
        assert capture.running, "the capture thread survives the unplug"
        camera.replug()
        rig.wait(lambda: camera.health().connected)
        before = len(frames)
        pump(5, 10.0)
        assert len(frames) > before and frames[-1] >= 10.0
        assert rig.safety.mode == Mode.HOLD and rig.safety.reason == "stand complete"
        rig.check()
    finally:
        capture.stop()
    return (
        f"{config.model}: frames stop, capture thread reconnects "
        f"({camera.health().reconnects}×), frames resume; control stays in HOLD"
    )


def heartbeat_lost(robot, make, tmp_path, endpoint) -> str:
    rig = make(robot, gait=True)
    rig.stand()
    c = rig.controller
    c.on_claim(m.SessionClaim(session="op", client="operator"))
    c.on_heartbeat(m.Heartbeat(session="op", seq=0, stamp=time.monotonic()))
    c.on_mode(m.ModeRequest(session="op", mode=Mode.ACTIVE))
    t_end = time.monotonic() + 0.6
    seq = 0
    while time.monotonic() < t_end:
        seq += 1
        c.on_heartbeat(m.Heartbeat(session="op", seq=seq, stamp=time.monotonic()))
        lost_at = time.monotonic()
        c.on_motion(m.MotionCommand(session="op", vx=0.02))
        time.sleep(0.05)
    assert rig.safety.mode == Mode.ACTIVE, rig.safety.reason
    rig.wait(lambda: rig.safety.mode == Mode.HOLD)
    took = time.monotonic() - lost_at
    assert "heartbeat of operator lost" in rig.safety.reason
    window = rig.profile.safety.heartbeat_window
    assert took >= window * 0.9, "not before the window"
    c.on_motion(m.MotionCommand(session="op", vx=0.05))
    assert rig.safety.refused >= 1, "commands of the lost session are refused"
    c.on_claim(m.SessionClaim(session="op2", client="operator"))
    c.on_heartbeat(m.Heartbeat(session="op2"))
    c.on_mode(m.ModeRequest(session="op2", mode=Mode.ACTIVE))
    rig.wait(lambda: rig.safety.mode == Mode.ACTIVE)
    c.on_mode(m.ModeRequest(session="op2", mode=Mode.HOLD))
    rig.check()
    return f"ACTIVE → HOLD {took:.2f} s after the last heartbeat (window {window} s); re-claim"


def clock_jump(robot, make, tmp_path, endpoint) -> str:
    rig = make(robot)
    rig.stand()
    c = rig.controller
    c.on_claim(m.SessionClaim(session="op", client="operator"))
    for stamp in (1e9, 1e9 - 3600.0):  # the operator's wall clock jumps back an hour
        c.on_heartbeat(m.Heartbeat(session="op", stamp=stamp))
        time.sleep(0.05)
    assert rig.safety.session is not None, "stamps do not decide liveness; arrival does"
    ticks, overruns = rig.loop.ticks, rig.loop.timing.overruns
    n_cmd = len(rig.commands)
    rig.clock.offset += 2.0  # this process was suspended for 2 s
    time.sleep(0.5)
    burst = rig.loop.ticks - ticks
    assert burst <= rig.profile.rate_hz * 0.5 * 1.5 + 5, "no burst of catch-up ticks"
    assert rig.loop.timing.overruns > overruns
    assert rig.safety.mode == Mode.HOLD and rig.safety.session is None
    cmds = np.array(rig.commands[n_cmd - 1 :])
    vmax = np.array([j.limits.velocity for j in rig.profile.joints])
    step = np.abs(np.diff(cmds, axis=0)).max(axis=0) if len(cmds) > 1 else 0.0
    assert np.all(step <= vmax / rig.profile.rate_hz * 1.01 + 1e-9), "no jump in the command"
    rig.stand()
    rig.check()
    return f"2 s forward jump: {burst} ticks in 0.5 s, overrun counted, session expired → HOLD"


def disk_full(robot, make, tmp_path, endpoint) -> str:
    import resource

    from climbd.daemon.runtime.network import Endpoints, Network, zenoh_config

    bus = Network(robot, zenoh_config(None, "control", Endpoints([endpoint], [])))
    pubs: dict[type, object] = {}
    out = tmp_path / "full.mcap"
    limit = 64 * 1024

    def small_files() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    live = threading.Event()
    live.set()

    def publish(msg: m.Message) -> None:
        if live.is_set():
            pub = pubs.get(type(msg))
            if pub is None:
                pub = pubs[type(msg)] = bus.publisher(type(msg))
            pub.put(msg)

    rig = make(robot, publish=publish)
    try:
        rig.stand()
        rec = subprocess.Popen(
            [sys.executable, "-m", "climbd.daemon.cli", "record", "--robot", robot]
            + ["--connect", endpoint, "-o", str(out)],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            preexec_fn=small_files,
        )
        try:
            stdout, stderr = rec.communicate(timeout=60)
        finally:
            if rec.poll() is None:
                rec.send_signal(signal.SIGKILL)
                rec.wait()
        ticks = rig.loop.ticks
        rig.wait(lambda: rig.loop.ticks > ticks + 10)
    finally:
        live.clear()
        time.sleep(0.05)
        bus.close()
    assert rec.returncode == 1 and "Traceback" not in stderr, stderr
    assert "recording stopped" in stderr and "file sealed and readable" in stderr, stderr
    from climbd.daemon.cli.replay import read

    kept = list(read(out))
    assert kept and out.stat().st_size <= limit
    assert rig.safety.mode == Mode.HOLD and rig.safety.reason == "stand complete"
    rig.check()
    return f"recorder stops with a clear message, {len(kept)} messages sealed; robot unaffected"


class Crashing(PerceptionPlugin):
    """A perception plugin that raises on its third frame."""

    name = "crashing"
    publishes = (m.Joists,)

    def __init__(self) -> None:
        super().__init__()
        self.calls = 0

    def process(self, frame, body):
        self.calls += 1
        if self.calls == 3:
            raise ZeroDivisionError("bad frame")
        return m.Joists(stamp=frame.timestamp)


def perception_crash(robot, make, tmp_path, endpoint) -> str:
    import argparse

    from climbd.daemon.cli.run import make_camera
    from climbd.daemon.runtime.capture import Capture
    from climbd.daemon.runtime.perception_role import PerceptionRole

    profile = load(ROOT / "robots" / f"{robot}.toml")
    role = PerceptionRole(profile, argparse.Namespace())
    camera = make_camera(profile, "floor", None, None)
    capture = Capture(camera, camera.config.name)
    crashing = Isolated("crashing", Crashing())
    elevation = Isolated(
        "elevation", instantiate("climbd.perception", "elevation", {}, profile, "")
    )
    published: list[m.Message] = []
    capture.start()
    worker = threading.Thread(
        target=role._work, args=(capture, [crashing, elevation], published.append), daemon=True
    )
    rig = make(robot)
    worker.start()
    still = StillBody(role)
    try:
        still.__enter__()
        rig.stand()
        grids = lambda: sum(isinstance(x, m.ElevationGrid) for x in published)  # noqa: E731
        rig.wait(lambda: crashing.failed and grids() >= 3, timeout=20.0)
        n = grids()
        rig.wait(lambda: grids() > n + 2, timeout=20.0)
        assert worker.is_alive(), "the worker goes on"
        assert crashing.status.startswith("failed: ZeroDivisionError")
        assert crashing.plugin.calls == 3, "a failed plugin is not called again"
        assert rig.safety.mode == Mode.HOLD and rig.safety.reason == "stand complete"
        rig.check()
    finally:
        still.__exit__()
        role._stop.set()
        capture.stop()
        worker.join(5)
    return "crashing plugin marked failed and skipped; elevation goes on; control unaffected"


SCENARIOS: dict[str, Callable[..., str]] = {
    "servo lost": servo_lost,
    "servo power-cycled": servo_power_cycled,
    "overheat": overheat,
    "overload": overload,
    "corrupt packets": corrupt_packets,
    "port gone": port_gone,
    "CAN bus-off": can_bus_off,
    "camera unplugged": camera_unplugged,
    "teleop heartbeat lost": heartbeat_lost,
    "clock jump": clock_jump,
    "disk full while recording": disk_full,
    "perception plugin crash": perception_crash,
}
