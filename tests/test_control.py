"""The control tick on a stepped clock with the fake bus: stand, hold, e-stop policy, faults."""

from __future__ import annotations

import numpy as np
import pytest

from climbd.daemon.algorithms.estimation import StateEstimator
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import (
    BodyState,
    EStop,
    FootTargets,
    Heartbeat,
    JointCommand,
    JointState,
    Mode,
    ModeRequest,
    SessionClaim,
    Stairs,
)
from climbd.daemon.contract.plugins import GaitPlugin
from climbd.daemon.runtime.control import LOAD_RAMP, current_joints
from climbd.daemon.runtime.loader import Isolated
from climbd.daemon.runtime.loop import SteppedClock
from climbd.daemon.runtime.stack import control_stack
from climbd.drivers.fake import FakeJointBus


class StillGait(GaitPlugin):
    """Keeps every foot where it started: the command must equal the measured state."""

    def start(self, body, feet):
        self.feet = np.array(feet)

    def step(self, t, dt, body, world, command):
        return FootTargets(stamp=t, positions=self.feet.tolist(), stance=[True] * len(self.feet))


class FailingGait(StillGait):
    def step(self, t, dt, body, world, command):
        raise RuntimeError("lost its footing")


class Rig:
    """A controller, fake bus, safety supervisor and loop on one stepped clock."""

    def __init__(self, profile, gait=None, tau: float = 0.01, compliant: bool = False) -> None:
        """``compliant`` marks the fake bus as position servos that sag (sag compensation)."""
        self.clock = SteppedClock()
        self.profile = profile
        self.bus = FakeJointBus(profile, tau=tau, clock=self.clock.now)
        self.bus.compliant = compliant
        self.bus.open()
        self.published: list = []
        isolated = Isolated("test", gait, lambda n, e: None) if gait else None
        stack = control_stack(
            profile, self.bus, self.clock, isolated, publish=self.published.append
        )
        self.safety, self.controller, self.loop = stack.safety, stack.controller, stack.loop
        self.commands: list[np.ndarray] = []
        write = self.bus.write

        def record(cmd):
            self.commands.append(np.array(cmd.position))
            write(cmd)

        self.bus.write = record

    def run(self, seconds: float) -> None:
        self.loop.run(max_ticks=self.loop.ticks + int(round(seconds * self.profile.rate_hz)))

    def stand(self) -> None:
        assert self.safety.request(Mode.STAND, self.clock.now())
        self.run(self.profile.safety.stand_time * 3)


@pytest.fixture()
def widowx(robots):
    return profiles.load(robots / "widowx.toml")


def test_stand_up_then_hold(widowx) -> None:
    rig = Rig(widowx)
    rig.stand()
    assert rig.safety.mode == Mode.HOLD and rig.safety.reason == "stand complete"
    stand_q = rig.controller.stand_q
    assert np.max(np.abs(rig.bus.position - stand_q)) < 0.01
    limits = np.array([[j.limits.lower, j.limits.upper] for j in widowx.joints])
    cmds = np.array(rig.commands)
    assert np.all(cmds >= limits[:, 0] - 1e-9) and np.all(cmds <= limits[:, 1] + 1e-9)
    vel = np.diff(cmds, axis=0) * widowx.rate_hz
    vmax = np.array([j.limits.velocity for j in widowx.joints])
    assert np.all(np.abs(vel) <= vmax * 1.001), "the rise respects velocity limits"


def test_entering_active_commands_the_measured_state(widowx) -> None:
    rig = Rig(widowx, StillGait(profile=widowx))
    rig.stand()
    measured = rig.bus.position.copy()
    n = len(rig.commands)
    assert rig.safety.request(Mode.ACTIVE, rig.clock.now())
    rig.run(0.5)
    assert rig.safety.mode == Mode.ACTIVE
    first = rig.commands[n]
    assert np.max(np.abs(first - measured)) < 1e-6, "no jump on entering ACTIVE"


def test_failed_gait_holds(widowx) -> None:
    rig = Rig(widowx, FailingGait(profile=widowx))
    rig.stand()
    rig.safety.request(Mode.ACTIVE, rig.clock.now())
    rig.run(0.2)
    assert rig.safety.mode == Mode.HOLD and "lost its footing" in rig.safety.reason
    assert rig.bus.torque_on


class OpenOneGripper(StillGait):
    """Keeps the feet, opens leg 0's gripper, and records the holds the control role reports."""

    def start(self, body, feet):
        super().start(body, feet)
        self.reported: list[list[bool] | None] = []

    def step(self, t, dt, body, world, command):
        self.reported.append(body.holding)
        targets = super().step(t, dt, body, world, command)
        targets.grip = [False, True, True, True]
        return targets


def test_grips_ride_the_command_and_a_hold_or_estop_never_opens_one(robots) -> None:
    """HubRobo's grippers close at start, open only as the gait says, stay as the gait left
    them through a HOLD, and close again at an e-stop (``hold_grip``); the gait sees what the
    bus reports they hold (a gripper closed on nothing holds nothing)."""
    profile = profiles.load(robots / "hubrobo.toml")
    gait = OpenOneGripper(profile=profile)
    rig = Rig(profile, gait)
    rig.bus.empty_grips = {3}
    rig.stand()
    assert rig.bus.grip == [True] * 4, "a climber's grippers close from the first command"
    rig.safety.request(Mode.ACTIVE, rig.clock.now())
    rig.run(0.2)
    assert rig.bus.grip == [False, True, True, True]
    assert gait.reported[-1] == [False, True, True, False]
    rig.safety.hold(rig.clock.now(), "operator")
    rig.run(0.2)
    assert rig.safety.mode == Mode.HOLD and rig.bus.grip == [False, True, True, True]
    rig.controller.on_estop(EStop(engage=True, source="pendant"))
    rig.run(0.1)
    assert rig.safety.mode == Mode.ESTOP and rig.bus.grip == [True] * 4


@pytest.mark.parametrize(
    "robot,torque_after",
    [("widowx", False), ("hubrobo", True), ("qingzhui", True)],
)
def test_estop_follows_the_profile_policy(robots, robot: str, torque_after: bool) -> None:
    profile = profiles.load(robots / f"{robot}.toml")
    rig = Rig(profile)
    rig.stand()
    rig.controller.on_estop(EStop(engage=True, source="pendant"))
    before = rig.bus.position.copy()
    n = len(rig.commands)
    rig.run(0.3)
    assert rig.safety.mode == Mode.ESTOP
    assert rig.bus.torque_on == torque_after
    if torque_after:
        held = np.array(rig.commands[n:])
        assert held.size and np.max(np.abs(held - before)) < 1e-3, "holds the commanded pose"
    else:
        assert len(rig.commands) == n, "no command is written with torque off"
    rig.controller.on_mode(ModeRequest(mode=Mode.STAND))
    rig.run(0.1)
    assert rig.safety.mode == Mode.ESTOP, "only an explicit reset leaves ESTOP"


def test_estop_acts_within_one_tick(widowx) -> None:
    rig = Rig(widowx)
    rig.stand()
    rig.controller.on_estop(EStop(engage=True, source="pendant"))
    rig.run(1.0 / widowx.rate_hz)
    assert not rig.bus.torque_on


def test_port_failure_faults_without_raising(widowx) -> None:
    rig = Rig(widowx)
    rig.stand()
    rig.bus.fail_reads = 3
    rig.run(0.1)
    assert rig.safety.mode == Mode.FAULT and "injected read error" in rig.safety.reason
    assert not rig.bus.torque_on, "FAULT applies the torque_off policy"


def test_lost_heartbeat_holds_and_foreign_commands_are_refused(widowx) -> None:
    rig = Rig(widowx, StillGait(profile=widowx))
    rig.stand()
    c = rig.controller
    c.on_claim(SessionClaim(session="s1", client="alice"))
    c.on_mode(ModeRequest(session="s2", mode=Mode.ACTIVE))
    assert rig.safety.refused == 1 and rig.safety.mode == Mode.HOLD
    c.on_mode(ModeRequest(session="s1", mode=Mode.ACTIVE))
    rig.run(0.05)
    assert rig.safety.mode == Mode.ACTIVE
    for k in range(1, 11):
        c.on_heartbeat(Heartbeat(session="s1", seq=k, stamp=float(k)))
        rig.run(0.1)
    assert rig.safety.mode == Mode.ACTIVE
    last = rig.clock.now()
    rig.run(1.0)
    assert rig.safety.mode == Mode.HOLD
    entered = rig.safety.history[-1].at
    assert entered - last <= widowx.safety.heartbeat_window + 1.0 / widowx.rate_hz + 1e-9


@pytest.mark.parametrize("robot", ["widowx", "qingzhui"])
def test_shutdown_reaches_the_safe_pose(robots, robot: str) -> None:
    profile = profiles.load(robots / f"{robot}.toml")
    rig = Rig(profile)
    rig.stand()
    rig.controller.begin_shutdown(rig.clock.now())
    rig.run(profile.safety.stand_time * 3)
    assert rig.controller.shutdown_done
    if robot == "widowx":
        assert not rig.bus.torque_on, "torque_off: sat down, then switched off"
        assert np.max(np.abs(rig.bus.position - rig.controller.sit_q)) < 0.01
    else:
        assert rig.bus.torque_on and rig.safety.mode == Mode.HOLD


def test_overheat_derates_then_faults(widowx) -> None:
    rig = Rig(widowx)
    rig.stand()
    rig.bus.temperature[4] = widowx.safety.derate_temperature + 1
    rig.run(0.5)
    assert rig.safety.speed_scale < 1.0 and rig.safety.mode == Mode.HOLD
    rig.bus.temperature[4] = widowx.safety.max_temperature + 1
    rig.run(0.5)
    assert rig.safety.mode == Mode.FAULT and "overheat" in rig.safety.reason


def test_stair_alignment_reaches_the_estimator(robots) -> None:
    """A Stairs feature's ICP alignment is fused by filter 2 on the next tick along the
    directions it is constrained in: the height moves toward it, the horizontal (unconstrained)
    stays the legs'; a Stairs without one, or a malformed one (directions not unit 3-vectors,
    a NaN shift), changes nothing."""
    profile = profiles.load(robots / "qingzhui.toml")
    rigs = [Rig(profile) for _ in range(4)]
    for rig in rigs:
        rig.controller.estimator = StateEstimator(profile)
        rig.stand()
    alignment = [0.01, 0.0, -0.02]
    rigs[1].controller.on_feature(Stairs(alignment=alignment, constrained=[[0.0, 0.0, 1.0]]))
    rigs[2].controller.on_feature(Stairs())
    rigs[3].controller.on_feature(Stairs(alignment=alignment, constrained=[[0.0, 1.0]]))
    rigs[3].controller.on_feature(Stairs(alignment=alignment, constrained=[[0.0, 0.0, 2.0]]))
    rigs[3].controller.on_feature(
        Stairs(alignment=[0.0, 0.0, float("nan")], constrained=[[0.0, 0.0, 1.0]])
    )
    for rig in rigs:
        rig.run(1.0 / profile.rate_hz)
    plain, aligned, empty, malformed = (np.array(rig.controller.body.position) for rig in rigs)
    assert -0.02 < aligned[2] - plain[2] < -0.01
    np.testing.assert_allclose(aligned[:2], plain[:2], atol=1e-12)
    np.testing.assert_allclose(empty, plain, atol=1e-12)
    np.testing.assert_allclose(malformed, plain, atol=1e-12)
    assert rigs[3].safety.mode == rigs[0].safety.mode


class SwingGait(StillGait):
    """Keeps every foot where it started, with the first leg in swing."""

    def step(self, t, dt, body, world, command):
        targets = super().step(t, dt, body, world, command)
        targets.stance[0] = False
        return targets


def test_compliant_servos_get_stance_goals_offset_by_their_sag(widowx) -> None:
    """On a bus of compliant position servos each stance foot's goal reaches below its target
    by the sag its share of the weight would cause (torque / stiffness); the swing foot's goal
    is its target. A stiff bus (the fake) gets its targets as they are."""
    rig = Rig(widowx, SwingGait(profile=widowx), compliant=True)
    rig.stand()
    assert rig.safety.request(Mode.ACTIVE, rig.clock.now())
    rig.run(0.5)
    assert rig.safety.mode == Mode.ACTIVE, rig.safety.reason
    kin = rig.controller.kinematics
    target = kin.fk(np.asarray(rig.controller.motion.command))
    goal = kin.fk(rig.commands[-1])
    drop = target[:, 2] - goal[:, 2]
    assert drop[0] == pytest.approx(0.0, abs=1e-9)
    assert np.all((drop[1:] > 0.0005) & (drop[1:] < 0.01)), drop


class TransferGait(StillGait):
    """Feet where they started: all six stand, then the second tripod unloads for ``UNLOAD`` s
    and lifts (stance off) from ``LIFT`` s on."""

    UNLOAD, LIFT = 0.3, 0.5

    def start(self, body, feet):
        super().start(body, feet)
        self.t0 = None

    def step(self, t, dt, body, world, command):
        targets = super().step(t, dt, body, world, command)
        self.t0 = t if self.t0 is None else self.t0
        since = t - self.t0
        lifting = since >= self.LIFT
        targets.stance = [not (lifting and leg % 2) for leg in range(len(self.feet))]
        unloading = self.UNLOAD <= since < self.LIFT
        targets.unload = [unloading and bool(leg % 2) for leg in range(len(self.feet))]
        return targets


def test_unloading_feet_pass_their_share_on_before_they_lift(widowx) -> None:
    """A tripod marked ``unload`` gives its feed-forward share to the feet that stay, over
    LOAD_RAMP: the shares add up to the weight on every tick and no foot's changes faster
    than a full share per LOAD_RAMP, so nothing steps when the tripod lifts."""
    rig = Rig(widowx, TransferGait(profile=widowx), compliant=True)
    rig.stand()
    assert rig.safety.request(Mode.ACTIVE, rig.clock.now())
    shares = []
    write = rig.bus.write

    def record(cmd):
        shares.append(rig.controller.support.shares(rig.controller.load))
        write(cmd)

    rig.bus.write = record
    rig.run(0.8)
    assert rig.safety.mode == Mode.ACTIVE, rig.safety.reason
    shares = np.array(shares)
    weight = rig.controller.support.weight
    np.testing.assert_allclose(shares.sum(axis=1), weight, rtol=1e-9)
    full = weight / 3
    step = np.abs(np.diff(shares, axis=0)).max()
    assert step <= full / (LOAD_RAMP * widowx.rate_hz) * 1.001, (step, full)
    np.testing.assert_allclose(shares[-1], [full, 0.0] * 3, atol=1e-9)


def test_feed_forward_beyond_the_effort_limit_is_clipped_before_the_driver(robots) -> None:
    """The guard is the last thing that touches a command: a feed-forward stage that asks each
    of Qingzhui's joints for three times its effort limit (and a NaN-free velocity) reaches the
    driver clipped to ±limit, with the positions still inside their limits."""
    profile = profiles.load(robots / "qingzhui.toml")
    rig = Rig(profile)
    written: list[JointCommand] = []
    write = rig.bus.write

    def record(command: JointCommand) -> None:
        written.append(command)
        write(command)

    rig.bus.write = record
    limit = np.array([j.limits.effort for j in profile.joints])
    signs = np.where(np.arange(len(limit)) % 2 == 0, 1.0, -1.0)

    def greedy(command: JointCommand) -> None:
        command.effort = (3.0 * signs * limit).tolist()

    rig.controller.feed_forward = True
    rig.controller._feed_forward = greedy
    rig.stand()
    assert written, "nothing reached the driver"
    efforts = np.array([c.effort for c in written])
    assert np.allclose(efforts, signs * limit), efforts[-1]
    lower = np.array([j.limits.lower for j in profile.joints])
    upper = np.array([j.limits.upper for j in profile.joints])
    positions = np.array([c.position for c in written])
    assert np.all((positions >= lower) & (positions <= upper))


def test_joints_read_ticks_ago_reach_the_estimator_moved_on_by_their_velocity() -> None:
    """A joint read 20 ms ago at 1 rad/s is 20 mrad further now; beyond its velocity limit
    the extrapolation is clipped; a lost joint (age NaN) and a bus without ages are as read."""
    state = JointState(names=["a", "b", "c"], position=[0.0, 1.0, 2.0], velocity=[1.0, 50.0, 3.0])
    limits = np.array([5.0, 5.0, 5.0])
    assert current_joints(state, limits).tolist() == [0.0, 1.0, 2.0]
    state.age = [0.02, 0.02, float("nan")]
    assert np.allclose(current_joints(state, limits), [0.02, 1.1, 2.0])


def test_published_joints_carry_the_tick_time_the_body_state_does(widowx) -> None:
    """The driver stamps its reading on its own clock (here 100 s off the control clock; the
    Dynamixel driver does not stamp at all): the control role publishes the joints with its
    tick's time, as the body state, so the perception role's self filter finds the joints of
    each frame's time."""
    rig = Rig(widowx)
    rig.bus.clock = lambda: rig.clock.now() + 100.0
    rig.stand()
    joints = [m for m in rig.published if isinstance(m, JointState)]
    bodies = [m for m in rig.published if isinstance(m, BodyState)]
    assert len(joints) == len(bodies) > 10
    assert [j.stamp for j in joints] == [b.stamp for b in bodies]
    assert joints[-1].stamp == pytest.approx(rig.clock.now(), abs=1.0 / widowx.rate_hz)


class SlidingFoot(StillGait):
    """Keeps three feet; drags leg 3's foot 3 cm sideways over a second, still in stance, as a
    foot on rock its gripper does not hold slides under the body."""

    def start(self, body, feet):
        super().start(body, feet)
        self.t0: float | None = None

    def step(self, t, dt, body, world, command):
        targets = super().step(t, dt, body, world, command)
        self.t0 = t if self.t0 is None else self.t0
        feet = np.array(targets.positions)
        feet[3, 1] += 0.03 * min(1.0, (t - self.t0) / 1.0)
        targets.positions = feet.tolist()
        return targets


def test_a_foot_whose_gripper_holds_nothing_does_not_carry_the_pose(robots) -> None:
    """HubRobo stands still on three grips while leg 3's gripper, closed on nothing, lets its
    foot slide 3 cm: the odometry leaves that foot out of its stance fit, so the body's
    estimate stays where the three holding feet keep it (the pose of all four feet's fit
    would move and turn with the slide)."""
    profile = profiles.load(robots / "hubrobo.toml")
    rig = Rig(profile, SlidingFoot(profile=profile))
    rig.bus.empty_grips = {3}
    rig.stand()
    before = rig.controller.body
    rig.safety.request(Mode.ACTIVE, rig.clock.now())
    rig.run(1.5)
    after = rig.controller.body
    assert rig.safety.mode == Mode.ACTIVE and after.holding == [True, True, True, False]
    moved = np.linalg.norm(np.subtract(after.position, before.position))
    turned = 2 * np.degrees(np.arccos(min(1.0, abs(np.dot(after.orientation, before.orientation)))))
    assert moved < 0.001 and turned < 0.1
