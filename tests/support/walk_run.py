"""A straight walk on flat ground in the twin through the robot's own driver, for odometry drift.

Dynamixel robots (WidowX, HubRobo): the DynamixelBus on the twin's emulated servos (pty), the
control stack and a periodic gait under a teleop session, on a stepped clock; their odometry is
LegOdometry with the twin's IMU. Qingzhui: the MIT-mode torque driver and paper 004's estimator
(tests/support/qingzhui_twin.py). The twin's true pose scores the estimate; the baseline is dead
reckoning of the commanded velocity along the start heading.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
from conftest import ROOT

from climbd.daemon.algorithms.estimation import log_so3
from climbd.daemon.algorithms.odometry import LegOdometry
from climbd.daemon.cli.sim_host import STEPPED_TIMEOUT_MARGIN_MS
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.geometry import yaw
from climbd.daemon.contract.messages import Heartbeat, Mode, MotionCommand
from climbd.daemon.runtime.loader import instantiate
from climbd.daemon.runtime.loop import SteppedClock
from climbd.daemon.runtime.stack import control_stack
from climbd.drivers.dynamixel.bus import DynamixelBus
from climbd.drivers.sim.twin import Twin
from climbd.drivers.sim.worlds import Floor, World
from support.qingzhui_twin import QingzhuiRig, flat_world

SESSION = "walk"
CHUNK = 0.1
"""Seconds of loop between teleop messages (heartbeat and motion, 10 Hz)."""


@dataclass
class OdometryInput:
    """What leg odometry was given at one update: joints, stance flags, time, IMU."""

    q: np.ndarray
    stance: np.ndarray
    t: float
    gyro: np.ndarray | None
    accel: np.ndarray | None


def recording(odometry: LegOdometry, inputs: list[OdometryInput]) -> None:
    """Append every input ``odometry`` is given to ``inputs``, to replay into variants of it."""
    update = odometry.update

    def recorded(q, stance, t, gyro=None, accel=None):
        imu = [None if v is None else np.array(v, float) for v in (gyro, accel)]
        inputs.append(OdometryInput(np.array(q, float), np.array(stance), t, *imu))
        return update(q, stance, t, gyro, accel)

    odometry.update = recorded


@dataclass
class Walk:
    """Where the robot truly went and where its odometry says it went (odometry frame = the
    start pose), over ``seconds`` of walking."""

    robot: str
    seconds: float
    true_start: np.ndarray
    true_end: np.ndarray
    true_yaw: float
    estimated_end: np.ndarray
    estimated_yaw: float
    commanded: float
    sigma_xy: float
    """m: the standard deviation of the horizontal position the odometry published at the end
    of the walk (from its covariance's diagonal)."""
    sigma_yaw_deg: float
    started: float = 0.0
    """Clock time (s) at which the walk began: the estimate's origin is its pose then."""
    slide: float = 0.0
    """m: how far the stance slid over the ground in truth: per pair of samples CHUNK apart,
    the median over the feet the gait had down and touching at both of each foot ball's slip
    (its centre's displacement less the roll r·(dθ × up)), summed over the walk as a vector.
    Leg odometry assumes it is nil; what the stance feet do together it cannot see."""

    @property
    def distance(self) -> float:
        return float(np.linalg.norm(self.true_end[:2] - self.true_start[:2]))

    @property
    def position_error(self) -> float:
        return float(np.linalg.norm(self.estimated_end[:2] - self.true_end[:2]))

    @property
    def yaw_error_deg(self) -> float:
        d = self.estimated_yaw - self.true_yaw
        return abs(math.degrees(math.atan2(math.sin(d), math.cos(d))))

    @property
    def baseline_error(self) -> float:
        """Position error (m) of dead reckoning the command: ``commanded`` m straight ahead."""
        return float(np.linalg.norm(self.true_end[:2] - [self.commanded, 0.0]))


EARTH = 9.80665
GRAVITY = {"hubrobo": EARTH / 6}
"""m/s²: where a robot walks. HubRobo is built for the Moon (paper 001's experiments are at
G/6); at 1 g its X-series servos sag 0.11 rad off the stand pose, past the 0.05 rad tolerance."""


def in_start_frame(xy, start_xy, start_heading: float) -> np.ndarray:
    """Horizontal position ``xy`` in the frame of a start pose (its position and heading)."""
    c, s = math.cos(-start_heading), math.sin(-start_heading)
    d = np.asarray(xy[:2], float) - np.asarray(start_xy[:2], float)
    return np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]])


def _relative(twin: Twin, start: tuple[np.ndarray, float]) -> tuple[np.ndarray, float]:
    """The twin's pose in the start pose's frame (the odometry frame's origin)."""
    pos, quat = twin.body_pose()
    return in_start_frame(pos, *start), yaw(quat) - start[1]


@contextmanager
def dynamixel_stack(robot: str, gait: str, config: dict | None = None) -> Iterator[tuple]:
    """The twin of ``robot`` on a flat floor (under its design gravity), DynamixelBus on its
    emulated servos and the control stack running ``gait``, on a stepped clock: yields
    (twin, stack, clock, profile)."""
    profile = profiles.load(ROOT / "robots" / f"{robot}.toml")
    world = World(name="flat", floor=Floor(size=12.0), gravity=GRAVITY.get(robot, EARTH))
    twin = Twin(profile, world, stepped=True, bus=True)
    twin.start()
    bus = DynamixelBus.from_profile(
        profile, port=twin.port, timeout_margin_ms=STEPPED_TIMEOUT_MARGIN_MS
    )
    bus.open()
    try:
        twin.driver_sent = lambda: bus.sent
        clock = SteppedClock(on_advance=lambda t0, t1: twin.advance_to(t1))
        plugin = instantiate("climbd.gaits", gait, config or {}, profile, f"walk {gait}")
        stack = control_stack(
            profile, bus, clock, plugin, imu=SimpleNamespace(read=twin.imu_sample)
        )
        yield twin, stack, clock, profile
    finally:
        bus.close()
        twin.stop()


def dynamixel_walk(
    robot: str,
    gait: str,
    vx: float,
    seconds: float,
    config: dict | None = None,
    inputs: list[OdometryInput] | None = None,
) -> Walk:
    """``robot`` walks ``gait`` (its ``config``) at ``vx`` for ``seconds`` through
    DynamixelBus on the twin; the odometry's inputs are appended to ``inputs`` if given."""
    with dynamixel_stack(robot, gait, config) as (twin, stack, clock, profile):
        if inputs is not None:
            recording(stack.controller.odometry, inputs)
        return _walk(robot, twin, stack, clock, profile.rate_hz, vx, seconds)


def qingzhui_walk(vx: float, seconds: float) -> Walk:
    """Qingzhui's tripod at ``vx`` for ``seconds`` through MitJointBus, with its estimator."""
    gait = instantiate(
        "climbd.gaits", "tripod", {}, profiles.load(ROOT / "robots" / "qingzhui.toml"), "walk"
    )
    rig = QingzhuiRig(world=flat_world(), gait=gait)
    try:
        rig.stand()
        rig.start_estimator()
        stack = SimpleNamespace(safety=rig.safety, controller=rig.controller, loop=rig.loop)
        return _walk("qingzhui", rig.twin, stack, rig.clock, rig.profile.rate_hz, vx, seconds)
    finally:
        rig.close()


def _slip(moved: np.ndarray, turn: np.ndarray, twin: Twin) -> np.ndarray:
    """How far (x, y) a foot ball slid: its centre moved ``moved`` while it turned by ``turn``
    (world frame); rolling without slip moves the centre by r·(dθ × up)."""
    wx, wy, _ = log_so3(turn)
    return moved[:2] - twin.robot.foot_radius * np.array([wy, -wx])


def _walk(
    robot: str, twin: Twin, stack, clock: SteppedClock, rate: float, vx: float, seconds: float
) -> Walk:
    safety, controller, loop = stack.safety, stack.controller, stack.loop
    if safety.mode != Mode.HOLD:
        assert safety.request(Mode.STAND, clock.now(), reason="start-up")
        while safety.mode == Mode.STAND and clock.now() < 30.0:
            loop.run(max_ticks=loop.ticks + round(CHUNK * rate))
        assert safety.mode == Mode.HOLD, safety.reason
    pos, quat = twin.body_pose()
    start = (pos.copy(), yaw(quat))
    body0 = controller.body
    est0 = (np.asarray(body0.position[:2], float), yaw(body0.orientation))
    started = clock.now()
    safety.claim(SESSION, "walk", started)
    seq = 0

    def teleop() -> None:
        nonlocal seq
        seq += 1
        controller.on_heartbeat(Heartbeat(stamp=clock.now(), session=SESSION, seq=seq))
        controller.on_motion(MotionCommand(stamp=clock.now(), session=SESSION, vx=vx))

    teleop()
    assert safety.request(Mode.ACTIVE, clock.now(), SESSION), safety.reason
    end = clock.now() + seconds
    slide = np.zeros(2)
    feet, turns = twin.foot_positions(), twin.foot_orientations()
    down = np.zeros(len(feet), bool)
    while clock.now() < end and safety.mode == Mode.ACTIVE:
        loop.run(max_ticks=loop.ticks + round(CHUNK * rate))
        teleop()
        now, held = twin.foot_positions(), twin.foot_contacts() & np.asarray(controller.stance)
        now_turns = twin.foot_orientations()
        both = np.flatnonzero(held & down)
        if both.size:
            slips = [_slip(now[k] - feet[k], now_turns[k] @ turns[k].T, twin) for k in both]
            slide += np.median(slips, axis=0)
        feet, turns, down = now, now_turns, held
    assert safety.mode == Mode.ACTIVE, safety.reason
    true_xy, true_yaw = _relative(twin, start)
    body = controller.body
    est_xy = in_start_frame(body.position, *est0)
    var = body.pose_variance
    return Walk(
        robot=robot,
        seconds=seconds,
        true_start=np.zeros(2),
        true_end=true_xy,
        true_yaw=true_yaw,
        estimated_end=est_xy,
        estimated_yaw=yaw(body.orientation) - est0[1],
        commanded=vx * seconds,
        sigma_xy=math.sqrt(var[0] + var[1]),
        sigma_yaw_deg=math.degrees(math.sqrt(var[5])),
        started=started,
        slide=float(np.linalg.norm(slide)),
    )
