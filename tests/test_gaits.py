"""Periodic gaits in the loop: gait -> IK -> ruckig -> guard -> fake joint bus, stepped clock.

Ground truth is built from what the bus reports: the body's motion over the ground is the
rigid motion that keeps the stance feet (forward kinematics of the measured joints) still,
integrated tick by tick (leg odometry with a 2-D Kabsch fit).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from climbd.daemon.algorithms.motion import MotionPipeline
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import BodyState, Heartbeat, Mode, MotionCommand, SessionClaim
from climbd.daemon.contract.plugins import PluginError
from climbd.daemon.contract.profile import stock_profiles
from climbd.daemon.runtime.loader import Isolated, instantiate
from climbd.daemon.runtime.loop import SteppedClock
from climbd.daemon.runtime.stack import control_stack
from climbd.drivers.fake import FakeJointBus
from climbd.plugins.gaits.periodic import layout_offsets
from climbd.plugins.gaits.swing import lift, progress

PROFILES = {name: profiles.load(path) for name, path in stock_profiles().items()}
BEATS = itertools.count(1)
"""Heartbeat sequence numbers (and stamps): the robot refuses one that does not advance."""


def rigid_step(prev: np.ndarray, cur: np.ndarray) -> tuple[np.ndarray, float]:
    """Body displacement (in the previous body frame) and yaw that keep ground points still."""
    c0, c1 = prev.mean(0), cur.mean(0)
    h = (prev - c0).T @ (cur - c1)
    ang = np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    return -rot.T @ (c1 - rot @ c0), -ang


@dataclass
class Walk:
    """The record of one run: commands, stance flags, support margins and odometry."""

    commands: np.ndarray
    stance: np.ndarray
    margins: np.ndarray
    position: np.ndarray
    yaw: float
    first_command: np.ndarray
    measured_at_start: np.ndarray
    final_feet: np.ndarray
    stand_feet: np.ndarray
    unreachable_ticks: int


def support_margin(points: np.ndarray) -> float:
    """Signed distance (m) of the body origin inside the convex hull of ``points``."""
    if len(points) < 3:
        return -np.inf
    return float(-ConvexHull(points).equations[:, 2].max())


def walk(robot: str, gait: str, command: MotionCommand, seconds: float, settle: float, **config):
    """Walk under ``command`` for ``seconds``, then without a command for ``settle``."""
    profile = PROFILES[robot]
    dt = 1.0 / profile.rate_hz
    clock = SteppedClock()
    bus = FakeJointBus(profile, tau=0.005, clock=clock.now)
    pipeline = MotionPipeline(profile, dt)
    kin = pipeline.kinematics
    bus.position[:] = kin.stand_joints()
    bus.open()
    bus.torque(True)
    plugin = instantiate("climbd.gaits", gait, config, profile, f"test {gait}")
    measured = np.array(bus.read().position)
    pipeline.start(measured)
    plugin.start(BodyState(), kin.fk(measured))
    commands, stances, margins = [], [], []
    position, yaw = np.zeros(2), 0.0
    prev_feet = prev_stance = None
    unreachable = 0
    for k in range(int(round((seconds + settle) / dt))):
        t = k * dt
        targets = plugin.step(t, dt, BodyState(), {}, command if t < seconds else None)
        cmd = pipeline.feet_step(targets)
        bus.write(cmd)
        clock.advance(dt)
        q = np.array(bus.read().position)
        stance = np.array(targets.stance)
        feet = kin.fk(q)[:, :2]
        commands.append(cmd.position)
        stances.append(stance)
        margins.append(support_margin(kin.fk(np.array(cmd.position))[stance, :2]))
        unreachable += any(pipeline.unreachable)
        if prev_feet is not None:
            ground = stance | prev_stance
            step, turn = rigid_step(prev_feet[ground], feet[ground])
            c, s = np.cos(yaw), np.sin(yaw)
            position += [c * step[0] - s * step[1], s * step[0] + c * step[1]]
            yaw += turn
        prev_feet, prev_stance = feet, stance
    return Walk(
        np.array(commands),
        np.array(stances),
        np.array(margins),
        position,
        yaw,
        np.array(commands[0]),
        measured,
        kin.fk(np.array(commands[-1])),
        kin.stand_feet(),
        unreachable,
    )


def assert_joint_limits(run: Walk, robot: str) -> None:
    """Velocity, acceleration and jerk of the commanded samples, and positions, at every tick."""
    profile = PROFILES[robot]
    dt = 1.0 / profile.rate_hz
    lim = [
        np.array([getattr(j.limits, f) for j in profile.joints])
        for f in ("lower", "upper", "velocity", "acceleration", "jerk")
    ]
    q = np.vstack([run.measured_at_start, run.commands])
    assert np.all((q >= lim[0]) & (q <= lim[1]))
    for n, bound in ((1, lim[2]), (2, lim[3]), (3, lim[4])):
        diff = np.abs(np.diff(q, n, axis=0)) / dt**n
        assert np.all(diff <= bound * (1 + 1e-6) + 1e-9), (n, (diff / bound).max())


def assert_start_and_stop_are_smooth(run: Walk, robot: str) -> None:
    """Start from the measured pose (first tick moves by at most jerk*dt^3/6) and end at stand."""
    profile = PROFILES[robot]
    dt = 1.0 / profile.rate_hz
    jerk = np.array([j.limits.jerk for j in profile.joints])
    assert np.all(np.abs(run.first_command - run.measured_at_start) <= jerk * dt**3 / 6 + 1e-12)
    np.testing.assert_allclose(run.final_feet, run.stand_feet, atol=2e-3)
    assert run.stance[-1].all(), "stopped: every foot on the ground"


def test_tripod_walks_widowx_one_metre_in_the_commanded_time() -> None:
    run = walk("widowx", "tripod", MotionCommand(vx=0.05), seconds=20.0, settle=6.0)
    assert run.position[0] == pytest.approx(1.0, rel=0.05)
    assert abs(run.position[1]) <= 0.02 * run.position[0], "sideways drift ≤ 2 cm per metre"
    assert abs(run.yaw) < 0.02
    assert run.stance.sum(1).min() >= 3, "at least three feet in stance at every tick"
    assert run.unreachable_ticks == 0
    assert_joint_limits(run, "widowx")
    assert_start_and_stop_are_smooth(run, "widowx")


@pytest.mark.parametrize("gait,speed", [("ripple", 0.03), ("wave", 0.012)])
def test_ripple_and_wave_keep_four_feet_down(gait: str, speed: float) -> None:
    seconds = 0.4 / speed
    run = walk("widowx", gait, MotionCommand(vx=speed), seconds=seconds, settle=10.0)
    assert run.position[0] == pytest.approx(0.4, rel=0.05)
    assert abs(run.position[1]) <= 0.02 * run.position[0]
    need = 4 if gait == "ripple" else 5
    assert run.stance.sum(1).min() >= need
    assert_joint_limits(run, "widowx")
    assert_start_and_stop_are_smooth(run, "widowx")


def test_tripod_sidesteps_and_turns_as_commanded() -> None:
    run = walk("widowx", "tripod", MotionCommand(vy=-0.04), seconds=10.0, settle=3.0)
    assert run.position[1] == pytest.approx(-0.4, rel=0.05)
    assert abs(run.position[0]) <= 0.02 * 0.4
    run = walk("widowx", "tripod", MotionCommand(yaw_rate=0.2), seconds=10.0, settle=3.0)
    assert run.yaw == pytest.approx(2.0, rel=0.05)
    assert np.linalg.norm(run.position) < 0.01
    assert_joint_limits(run, "widowx")


def test_hubrobo_crawl_keeps_the_centre_of_mass_over_the_support() -> None:
    """Flat ground, CoM at the body origin: inside the stance feet's polygon at every tick."""
    run = walk("hubrobo", "crawl", MotionCommand(vx=0.015), seconds=20.0, settle=12.0)
    assert run.position[0] == pytest.approx(0.3, rel=0.05)
    assert abs(run.position[1]) <= 0.02 * run.position[0]
    assert run.stance.sum(1).min() >= 3
    assert run.margins.min() > 0.005, "support margin stays above 5 mm"
    assert_joint_limits(run, "hubrobo")
    assert_start_and_stop_are_smooth(run, "hubrobo")


def test_qingzhui_tripod_at_one_kilohertz() -> None:
    run = walk("qingzhui", "tripod", MotionCommand(vx=0.15), seconds=20.0 / 3.0, settle=5.0)
    assert run.position[0] == pytest.approx(1.0, rel=0.05)
    assert abs(run.position[1]) <= 0.02 * run.position[0]
    assert run.stance.sum(1).min() >= 3
    assert_joint_limits(run, "qingzhui")
    assert_start_and_stop_are_smooth(run, "qingzhui")


def test_layout_offsets_give_the_classic_patterns() -> None:
    widowx = np.array([leg.mount for leg in PROFILES["widowx"].legs])
    names = [leg.name for leg in PROFILES["widowx"].legs]
    tripod = dict(zip(names, layout_offsets(widowx, "tripod"), strict=True))
    assert {n for n, o in tripod.items() if o == 0.0} == {"lr", "lf", "rm"}
    wave = dict(zip(names, layout_offsets(widowx, "wave") * 6, strict=True))
    assert [n for n, _ in sorted(wave.items(), key=lambda kv: kv[1])] == [
        "lr",
        "lm",
        "lf",
        "rr",
        "rm",
        "rf",
    ]
    qingzhui = PROFILES["qingzhui"]
    mounts = np.array([leg.mount for leg in qingzhui.legs])
    offsets = dict(
        zip([leg.name for leg in qingzhui.legs], layout_offsets(mounts, "tripod"), strict=True)
    )
    group_a = {n for n, o in offsets.items() if o == offsets["mf"]}
    assert group_a == {"mf", "rb", "lb"}, "paper 004: group A is MF, RB, LB"


def test_swing_profile_starts_and_ends_at_rest() -> None:
    tau = np.array([0.0, 1.0])
    h = 1e-6
    np.testing.assert_allclose(progress(tau), [0.0, 1.0])
    np.testing.assert_allclose(lift(tau), [0.0, 0.0])
    assert lift(np.array(0.5)) == pytest.approx(1.0)
    for f in (progress, lift):
        vel = (f(np.array([h, 1.0])) - f(np.array([0.0, 1.0 - h]))) / h
        np.testing.assert_allclose(vel, 0.0, atol=1e-6)


def test_gait_config_errors_name_the_field() -> None:
    profile = PROFILES["hubrobo"]
    with pytest.raises(PluginError, match="duty_factor"):
        instantiate("climbd.gaits", "crawl", {"duty_factor": 0.7}, profile, "$.plugins.gaits[0]")
    with pytest.raises(PluginError, match=r"\$.plugins.gaits\[0\].*cycle_time"):
        instantiate("climbd.gaits", "tripod", {"cycle_time": -1}, profile, "$.plugins.gaits[0]")
    with pytest.raises(PluginError, match="phase_offsets: expected 4 values"):
        instantiate("climbd.gaits", "wave", {"phase_offsets": [0.0]}, profile, "x")


class Teleop:
    """The lead's controller on a stepped clock with a teleop session sending commands."""

    def __init__(self, robot: str, gait: str) -> None:
        self.profile = PROFILES[robot]
        self.clock = SteppedClock()
        self.bus = FakeJointBus(self.profile, tau=0.005, clock=self.clock.now)
        self.bus.open()
        plugin = instantiate("climbd.gaits", gait, {}, self.profile, gait)
        stack = control_stack(
            self.profile, self.bus, self.clock, Isolated(gait, plugin, lambda n, e: None)
        )
        self.safety, self.controller, self.loop = stack.safety, stack.controller, stack.loop
        self.controller.on_claim(SessionClaim(session="op", client="test"))

    def run(self, seconds: float, command: MotionCommand | None = None) -> None:
        """Run, with heartbeats (and the command, if any) every 50 ms."""
        end = self.clock.now() + seconds
        while self.clock.now() < end:
            beat = next(BEATS)
            self.controller.on_heartbeat(Heartbeat(session="op", seq=beat, stamp=float(beat)))
            if command is not None:
                self.controller.on_motion(command)
            self.loop.run(max_ticks=self.loop.ticks + round(0.05 * self.profile.rate_hz))


def test_teleop_command_walks_and_its_absence_stops_and_stands() -> None:
    rig = Teleop("widowx", "tripod")
    kin = rig.controller.kinematics
    assert rig.safety.request(Mode.STAND, rig.clock.now(), "op")
    rig.run(3 * rig.profile.safety.stand_time)
    assert rig.safety.mode == Mode.HOLD
    assert rig.safety.request(Mode.ACTIVE, rig.clock.now(), "op")
    start = kin.fk(rig.bus.position.copy())
    rig.run(4.0, MotionCommand(session="op", vx=0.05))
    assert rig.safety.mode == Mode.ACTIVE
    moved = not np.allclose(kin.fk(rig.bus.position), start, atol=5e-3)
    assert moved, "the command makes the robot step"
    rig.run(rig.profile.safety.command_timeout + 6.0)
    assert rig.safety.mode == Mode.ACTIVE
    np.testing.assert_allclose(kin.fk(rig.bus.position), kin.stand_feet(), atol=3e-3)
    assert np.abs(rig.bus.velocity).max() < 1e-3, "stopped walking and standing still"
