"""Hardware in the loop: the daemon's own code paths against the twin's emulated devices.

The WidowX's real Dynamixel driver (dynamixel_sdk on the twin's pty), the real controller,
safety supervisor and tripod gait run on a stepped clock that advances the physics.
"""

from __future__ import annotations

import itertools
import signal
import subprocess
import sys

import msgspec
import numpy as np
import pytest
from conftest import ROOT

from climbd.daemon.contract.hardware import DriverError
from climbd.daemon.contract.messages import (
    Heartbeat,
    JointCommand,
    Mode,
    ModeRequest,
    MotionCommand,
    SessionClaim,
)
from climbd.daemon.contract.profile import load, with_bus_options
from climbd.daemon.runtime.loader import Isolated
from climbd.daemon.runtime.loop import SteppedClock
from climbd.daemon.runtime.stack import control_stack
from climbd.drivers.dynamixel.bus import DynamixelBus
from climbd.drivers.sim.twin import Twin
from climbd.drivers.torque.bus import MitJointBus
from climbd.plugins.gaits.periodic import Tripod, TripodConfig

STEPPED_MARGIN_MS = 100.0
DETERMINISM_MARGIN_MS = 2000.0
"""Reply timeout margin of the driver in lock-step runs: on a shared machine a thread can be
descheduled for longer than a real bus's few milliseconds, and a miss would change the log."""


class Hil:
    """Twin + real driver + controller + loop on one stepped clock."""

    def __init__(
        self,
        robot: str = "widowx",
        world: str = "attic",
        gait: TripodConfig | None = None,
        margin_ms: float = STEPPED_MARGIN_MS,
        stiffness: float | None = None,
    ) -> None:
        """``stiffness`` overrides the profile's bus.stiffness (the sag compensation's)."""
        profile = load(ROOT / "robots" / f"{robot}.toml")
        if stiffness is not None:
            bus = msgspec.structs.replace(profile.bus, stiffness=stiffness)
            profile = msgspec.structs.replace(profile, bus=bus)
        self.profile = profile
        self.twin = Twin(self.profile, world, stepped=True).start()
        self.clock = SteppedClock(on_advance=self.twin.advance_to)
        self.bus = DynamixelBus.from_profile(
            self.profile, port=self.twin.port, timeout_margin_ms=margin_ms
        )
        self.bus.open()
        self.twin.driver_sent = lambda: self.bus.sent
        isolated = Isolated("tripod", Tripod(gait, self.profile)) if gait else None
        stack = control_stack(self.profile, self.bus, self.clock, isolated)
        self.safety, self.controller, self.loop = stack.safety, stack.controller, stack.loop
        self.log: list[np.ndarray] = []

    def run(self, seconds: float, every=None) -> None:
        """Run the loop for ``seconds`` of simulated time, calling ``every()`` each 0.1 s."""
        per = round(0.1 * self.profile.rate_hz)
        for _ in range(round(seconds * self.profile.rate_hz / per)):
            if every is not None:
                every()
            self.loop.run(max_ticks=self.loop.ticks + per)
            self.log.append(self.twin.joint_positions())

    def stand(self) -> None:
        """Request STAND and run until the rise completes (HOLD), at most 3 stand times."""
        assert self.safety.request(Mode.STAND, self.clock.now())
        for _ in range(round(self.profile.safety.stand_time * 30)):
            self.run(0.1)
            if self.safety.mode != Mode.STAND:
                break

    def walk(self, vx: float, heights: list[float]):
        """Claim a session and go ACTIVE; the returned ``run`` callback keeps the robot walking
        at ``vx`` (heartbeat and motion command), noting the body height, checking no fall."""
        c = self.controller
        c.on_claim(SessionClaim(session="t", client="test"))
        c.on_mode(ModeRequest(session="t", mode=Mode.ACTIVE))

        beats = itertools.count(1)

        def drive():
            n = next(beats)
            c.on_heartbeat(Heartbeat(session="t", seq=n, stamp=float(n)))
            c.on_motion(MotionCommand(session="t", vx=vx))
            heights.append(self.twin.body_pose()[0][2])
            assert not self.twin.fallen(self.profile.stand.body_height)

        return drive

    def close(self) -> None:
        self.bus.close()
        self.twin.stop()


FAST_TRIPOD = TripodConfig(cycle_time=1.2, step_length=0.06)
"""The tripod gait at 0.1 m/s (WidowX strides of 6 cm, a cycle every 1.2 s)."""


@pytest.fixture()
def hil():
    rig = Hil(gait=FAST_TRIPOD)
    yield rig
    rig.close()


def test_widowx_stands_and_walks_one_metre_through_the_real_driver(hil):
    """Stand through the pty, then tripod-walk forward ≥ 1 m: body height held within 1 cm
    of the standing height, never a fall, the heading kept."""
    hil.stand()
    assert hil.safety.mode == Mode.HOLD, hil.safety.reason
    z_stand = hil.twin.body_pose()[0][2]
    target = hil.profile.stand.body_height + hil.twin.robot.foot_radius
    assert abs(z_stand - target) < 0.01
    heights = []
    drive = hil.walk(0.1, heights)
    start = hil.twin.body_pose()[0]
    for _ in range(20):
        hil.run(1.0, drive)
        if hil.twin.body_pose()[0][0] - start[0] >= 1.0:
            break
    pos, quat = hil.twin.body_pose()
    assert hil.safety.mode == Mode.ACTIVE, hil.safety.reason
    assert pos[0] - start[0] >= 1.0
    assert abs(pos[1] - start[1]) < 0.1
    assert np.max(np.abs(np.array(heights[5:]) - target)) < 0.01
    assert not hil.twin.base_contacts()


def walking_sag(rig: Hil, seconds: float = 6.0) -> float:
    """Mean body height (m) below the standing target over a tripod walk at 0.1 m/s."""
    rig.stand()
    assert rig.safety.mode == Mode.HOLD, rig.safety.reason
    heights = []
    rig.run(seconds, rig.walk(0.1, heights))
    assert rig.safety.mode == Mode.ACTIVE, rig.safety.reason
    target = rig.profile.stand.body_height + rig.twin.robot.foot_radius
    return target - float(np.mean(heights[10:]))


@pytest.mark.parametrize("stiffness", [None, 0.0])
def test_sag_compensation_holds_the_walking_height(stiffness):
    """The AX-18As sag under the tripod's load (about 2 mm of body height in the twin without
    compensation); the profile's stiffness offsets the stance goals so the walk holds its
    standing height within 1 mm."""
    rig = Hil(gait=FAST_TRIPOD, stiffness=stiffness)
    try:
        sag = walking_sag(rig)
    finally:
        rig.close()
    if stiffness is None:
        assert rig.profile.bus.stiffness > 0
        assert abs(sag) < 0.001
    else:
        assert sag > 0.0015


def test_stepped_hil_is_deterministic():
    """Two stepped stand-ups through driver and pty give identical joint logs."""
    logs = []
    for _ in range(2):
        # no servo is silenced here, so a long packet timeout costs nothing; it keeps a reply
        # delayed by a loaded CI machine from counting as a miss, which would change the log
        rig = Hil(margin_ms=DETERMINISM_MARGIN_MS)
        try:
            assert rig.safety.request(Mode.STAND, rig.clock.now())
            rig.run(1.0)
            logs.append(np.array(rig.log))
        finally:
            rig.close()
    assert np.array_equal(logs[0], logs[1])
    assert np.ptp(logs[0]) > 0.5


def test_twin_injects_every_emulator_fault(hil):
    """Overheat, brown-out, overload, a silent servo, corrupt replies and an unplugged adapter
    each reach the daemon's driver as its health or a DriverError."""
    hil.run(0.2)
    twin, bus = hil.twin, hil.bus
    k = hil.profile.joint_names.index("rf_femur")
    twin.overheat("rf_femur", 80.0)
    twin.brownout(8.0)
    twin.overload("lf_tibia")
    hil.run(0.5)
    health = {h.name: h for h in bus.health()}
    assert health["rf_femur"].temperature == pytest.approx(80.0, abs=1.0)
    assert "overheat" in " ".join(health["rf_femur"].errors).lower()
    assert health["rm_coxa"].voltage == pytest.approx(8.0)
    assert "overload" in " ".join(health["lf_tibia"].errors).lower()
    assert twin.thermal.temperature[k] < 80.0  # it cools by the thermal model
    twin.silence("rm_tibia")
    hil.run(0.3)
    assert {h.name: h for h in bus.health()}["rm_tibia"].lost
    twin.silence("rm_tibia", False)
    twin.corrupt("lr_coxa", 3)
    hil.run(0.3)
    assert not {h.name: h for h in bus.health()}["lr_coxa"].lost
    twin.unplug()
    with pytest.raises(DriverError):
        bus.read()


def test_qingzhui_torque_legs_answer_mit_frames_from_the_physics():
    """The torque robot's real CAN driver on the twin's virtual channel: impedance commands
    move the simulated joints, replies carry the simulated state, a silent motor is lost."""
    profile = load(ROOT / "robots" / "qingzhui.toml")
    profile = with_bus_options(profile, reply_timeout=0.05)
    profile = msgspec.structs.replace(
        profile, bus=msgspec.structs.replace(profile.bus, lost_after=3)
    )
    twin = Twin(profile, "attic", stepped=True).start()
    bus = MitJointBus.from_profile(profile, port=twin.port, interface="virtual")
    try:
        bus.open()
        rest = np.array(bus.read().position)
        np.testing.assert_allclose(rest, twin.joint_positions(), atol=1e-3)
        bus.torque(True)
        target = rest.copy()
        target[0::3] += 0.1  # every abduction joint out by 0.1 rad
        n = len(target)
        command = JointCommand(position=target.tolist(), kp=[150.0] * n, kd=[3.0] * n)
        for k in range(1, 201):
            bus.write(command)
            twin.advance_to(k * 0.001)
            state = bus.read()
        q = twin.joint_positions()
        assert np.all(np.abs(q[0::3] - target[0::3]) < 0.02)
        np.testing.assert_allclose(state.position, q, atol=2e-3)
        # The impedance command arrived through the CAN codec (16/12-bit quantised).
        np.testing.assert_allclose(twin.goal, target, atol=1e-3)
        np.testing.assert_allclose(twin.mit_kp, 150.0, atol=0.2)
        np.testing.assert_allclose(twin.mit_kd, 3.0, atol=0.01)
        twin.silence("rf_thigh")
        for k in range(201, 206):
            bus.write(command)
            twin.advance_to(k * 0.001)
            bus.read()
        assert {h.name: h for h in bus.health()}["rf_thigh"].lost
    finally:
        bus.close()
        twin.stop()


def test_twin_in_its_own_process_serves_the_driver():
    """``python -m climbd.drivers.sim`` prints its pty; the driver in this process reads the resting
    robot from it; SIGTERM ends it with a summary of simulated and wall time."""
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "climbd.drivers.sim",
            "--profile",
            str(ROOT / "robots" / "widowx.toml"),
        ]
        + ["--world", "attic", "--no-cameras"],
        stdout=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    try:
        port = proc.stdout.readline().strip()
        assert port.startswith("/dev/")
        profile = load(ROOT / "robots" / "widowx.toml")
        bus = DynamixelBus.from_profile(profile, port=port, timeout_margin_ms=STEPPED_MARGIN_MS)
        bus.open()
        try:
            state = bus.read()
        finally:
            bus.close()
        femur = np.array(state.position)[1::3]
        assert np.all(femur > 0.5), "resting belly-down: femurs raised"
    finally:
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=10)
    assert proc.returncode == 0 and "simulated" in out
