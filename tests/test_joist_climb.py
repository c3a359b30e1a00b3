"""Climb-or-sidestep behaviour (paper 000): decisions, alignment, crossing, clearance, safety.

The robot walks in a kinematic world (tests/support/joist_world.py): its pose is the behaviour's own
dead reckoning, joists are seen through a perception oracle with the crop box, and every tick
is checked against the profile's kinematics: reachability, the legs' clearance from the joist
box (femur, tibia and foot), and static support.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field

import numpy as np
import pytest
from support.joist_scenes import JoistSpec
from support.joist_world import (
    body_state,
    joist_distance,
    knees,
    mapped,
    oracle_map,
    perceive,
    world_feet,
)

from climbd.daemon.algorithms.feature_maps import JoistTracks
from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.algorithms.motion import MotionPipeline
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import Joist, JoistMap
from climbd.daemon.contract.plugins import PluginError
from climbd.daemon.contract.profile import stock_profiles
from climbd.daemon.runtime.loader import instantiate
from climbd.daemon.runtime.loop import SteppedClock
from climbd.drivers.fake import FakeJointBus
from climbd.drivers.sim.worlds import INCH
from climbd.plugins.gaits.joist_climb import InPlaceTurn, JoistClimb, JoistClimbConfig, Phase
from climbd.plugins.gaits.joist_crossing import (
    Bar,
    CrossingError,
    CrossingGeometry,
    CrossingPlan,
    support_margin,
)

WIDOWX = profiles.load(stock_profiles()["widowx"])
DT = 0.01


@dataclass
class Run:
    """What happened: events, poses at events, worst clearances, support, final state."""

    behaviour: JoistClimb
    events: list[tuple[float, str]]
    poses: dict[str, np.ndarray] = field(default_factory=dict)
    clearance: float = math.inf
    foot_clearance: float = math.inf
    unreachable: int = 0
    min_support: float = math.inf
    final_feet: np.ndarray | None = None
    final_stance: np.ndarray | None = None
    final_height: float = 0.0


def run(joists: list[JoistSpec], goal: float | None, seconds: float = 120.0, **config) -> Run:
    """Run the behaviour until done (or ``seconds``), checking every tick."""
    b = JoistClimb(JoistClimbConfig(goal_distance=goal, **config), WIDOWX)
    b.stepped = True  # simulated time: plans are waited for
    kin = b.kin
    b.start(body_state(b.pose), kin.stand_feet())
    out = Run(b, b.events)
    world: dict = {}
    tracks = JoistTracks()
    seen_events = 0
    for k in range(int(seconds / DT)):
        t = k * DT
        if k % 10 == 0:
            world = {JoistMap.TOPIC: oracle_map(tracks, joists, b.pose, t)}
        targets = b.step(t, DT, body_state(b.pose, t), world, None)
        while seen_events < len(b.events):
            out.poses[b.events[seen_events][1].split(":")[0]] = b.pose.copy()
            seen_events += 1
        feet = np.array(targets.positions)
        stance = np.array(targets.stance)
        height = -float(feet[stance, 2].mean()) if stance.any() else b.tripod.height
        if b.mode == Phase.CROSS:
            height = float(b.plan.sample(t - b._t_mode)[0][2])
        _, ok = kin.ik(feet)
        out.unreachable += int((~ok).sum())
        ground = world_feet(b.pose, height, feet)
        knee = world_feet(b.pose, height, knees(kin, feet))
        femur = world_feet(b.pose, height, kin.mount.copy())
        links = np.concatenate(
            [femur + (knee - femur) * a for a in np.linspace(0, 1, 6)]
            + [knee + (ground - knee) * a for a in np.linspace(0, 1, 8)]
        )
        for spec in joists:
            out.foot_clearance = min(out.foot_clearance, joist_distance(spec, ground).min())
            out.clearance = min(out.clearance, joist_distance(spec, links).min())
        down = stance | (feet[:, 2] <= -height + 0.01)
        if not down.all():
            margin = support_margin(ground[down, :2][None], b.pose[None, :2])[0]
            out.min_support = min(out.min_support, float(margin))
        if b.done:
            break
    out.final_feet = ground
    out.final_stance = stance
    out.final_height = height
    return out


def test_decides_at_the_approach_distance():
    """Paper: walk with the tripod until the nearest joist is closer than 0.55 m."""
    joist = JoistSpec(1.0, 0.0, 0.18, length=1.0)
    r = run([joist], goal=None, seconds=10.0)
    assert "sidestep" in r.poses
    distance = joist.distance - r.poses["sidestep"][0]
    assert 0.50 <= distance < 0.55


def test_low_joist_is_crossed_legs_clear_and_all_six_feet_down_on_the_far_side():
    """Paper 000 climbs its 10 cm joist: a free gait of checked, statically stable phases."""
    joist = JoistSpec(1.0, 0.0, 0.10)
    r = run([joist], goal=1.6, seconds=240.0)
    modes = [e.split(":")[0] for _, e in r.events]
    assert modes == ["approach", "settle", "cross", "walk", "done"]
    assert r.unreachable == 0
    radius = r.behaviour.config.leg_radius
    assert r.clearance >= radius, "femur, tibia and foot keep a leg radius off the joist"
    assert r.foot_clearance >= radius
    assert r.min_support >= -1e-3, "the body stays over its support while feet are up"
    assert r.final_stance.all()
    assert (r.final_feet[:, 0] > joist.distance + joist.width).all()
    assert np.allclose(r.final_feet[:, 2], 0.0, atol=1e-9)
    assert r.final_height == pytest.approx(WIDOWX.stand.body_height, abs=1e-3)


def test_oblique_joist_is_squared_up_to_before_crossing():
    joist = JoistSpec(1.0, math.radians(45.0), 0.06)
    r = run([joist], goal=1.2, seconds=240.0)
    assert [e.split(":")[0] for _, e in r.events][:2] == ["align", "approach"]
    yaw = r.poses["cross"][2]
    assert math.degrees(yaw) == pytest.approx(45.0, abs=3.0)
    assert "walk" in r.poses and r.unreachable == 0
    assert r.clearance >= r.behaviour.config.leg_radius


def test_in_place_turn_keeps_standing_feet_on_the_ground_and_ends_at_home():
    """The fine turn: body yaws on six feet, then one leg at a time steps home while five
    stand; no standing foot moves on the ground and the body ends turned by the angle."""
    home = Kinematics(WIDOWX).stand_feet()
    angle = math.radians(-4.0)
    turn = InPlaceTurn(home, angle, 0.05, 0.1, 0.5, 0.3, 0.03)
    ts = np.arange(0.0, turn.duration + DT, DT)
    prev_ground, prev_stance = None, None
    for t in ts:
        feet, stance = turn.sample(t)
        assert (~stance).sum() <= 1, "five feet stand while one swings"
        psi = turn.turned(t)
        c, s = math.cos(psi), math.sin(psi)
        ground = feet[:, :2] @ np.array([[c, s], [-s, c]])
        if prev_ground is not None:
            still = stance & prev_stance
            assert np.allclose(ground[still], prev_ground[still], atol=1e-9)
        prev_ground, prev_stance = ground, stance
    feet, stance = turn.sample(turn.duration)
    assert stance.all() and np.allclose(feet, home, atol=1e-12)
    assert turn.turned(turn.duration) == pytest.approx(angle, abs=1e-12)


def test_a_small_yaw_is_squared_in_place_leg_by_leg_before_crossing():
    """Under the 3 deg alignment tolerance but over the 1 deg the crossing needs: squared by
    the fine turn (not the tripod), then crossed with the legs clear."""
    joist = JoistSpec(1.0, math.radians(2.0), 0.10)
    r = run([joist], goal=1.6, seconds=240.0)
    modes = [e.split(":")[0] for _, e in r.events]
    assert modes == ["approach", "settle", "square", "settle", "cross", "walk", "done"]
    assert math.degrees(r.poses["cross"][2]) == pytest.approx(2.0, abs=0.05)
    assert r.unreachable == 0
    assert r.clearance >= r.behaviour.config.leg_radius
    assert r.min_support >= -1e-3
    assert r.final_stance.all()


def test_high_joist_is_sidestepped_until_clear_then_passed():
    joist = JoistSpec(1.0, 0.0, 0.18, length=1.0)
    r = run([joist], goal=1.6)
    modes = [e.split(":")[0] for _, e in r.events]
    assert modes == ["sidestep", "walk", "done"]
    final = r.behaviour.pose
    assert final[0] > joist.distance + joist.width + 0.3, "walked on past the joist"
    assert abs(final[1]) > joist.length / 2 + 0.2, "went round its end"
    assert r.foot_clearance > 0.05 and r.clearance > 0.05
    assert r.unreachable == 0


def test_a_joist_the_legs_cannot_cross_safely_is_gone_round_instead():
    """Under the paper's 14 cm threshold but beyond the stock WidowX legs: at 13 cm no checked
    crossing exists (the body would have to stand 16.5 cm high to clear it); the robot must
    then treat it as a wall, never climb into it."""
    joist = JoistSpec(1.0, 0.0, 0.13, length=1.0)
    r = run([joist], goal=1.6)
    causes = [e for _, e in r.events if e.startswith("sidestep")]
    assert causes and "cannot cross safely" in causes[0]
    assert r.clearance > 0.05
    assert r.behaviour.pose[0] > joist.distance + 0.3


def offset(pose: np.ndarray, by: np.ndarray) -> np.ndarray:
    """``pose`` (x, y, yaw) seen in a frame turned by ``by[2]`` and moved by ``by[:2]``."""
    c, s = math.cos(by[2]), math.sin(by[2])
    x, y = pose[:2]
    return np.array([c * x - s * y + by[0], s * x + c * y + by[1], pose[2] + by[2]])


SLIP_TIME = 4.0
"""Seconds over which the crossing's odometry drift builds up (feet slipping step by step)."""


def crossing_poses(joist: JoistSpec, odometry_bias: np.ndarray) -> tuple[list, np.ndarray]:
    """Events and final pose of a crossing whose odometry drifts to ``odometry_bias`` (x, y m,
    yaw rad) over the first ``SLIP_TIME`` s of the crossing, as slipping feet would leave it;
    the world model places what the camera sees by that odometry."""
    b = JoistClimb(JoistClimbConfig(goal_distance=1.6), WIDOWX)
    b.stepped = True  # simulated time: plans are waited for
    b.start(body_state(b.pose), b.kin.stand_feet())
    world: dict = {}
    tracks = JoistTracks()
    crossing_since = None
    for k in range(int(240 / DT)):
        t = k * DT
        if b.mode == Phase.CROSS and crossing_since is None:
            crossing_since = t
        slip = 0.0 if crossing_since is None else min(1.0, (t - crossing_since) / SLIP_TIME)
        body = body_state(offset(b.pose, slip * odometry_bias), t)
        if k % 10 == 0:
            world = {JoistMap.TOPIC: mapped(tracks, perceive([joist], b.pose, t), body)}
        b.step(t, DT, body, world, None)
        if b.done:
            break
    return [e for _, e in b.events], b.pose.copy()


def test_odometry_drift_in_a_crossing_is_undone_by_the_joist_in_view():
    """Dead reckoning drifts over a crossing (feet slip, servos lag: 2-5 cm and degrees through
    the twin's driver path). The joist being crossed is the landmark: while it is in view the
    joist map places it relative to the body, so an odometry drifting 3 cm and 2 deg changes no
    decision, and the crossing ends within 5 mm and 0.3 deg of the undrifted one; blind to it,
    the crossing would replan on the false drift."""
    joist = JoistSpec(1.0, 0.0, 0.10)
    events, pose = crossing_poses(joist, np.zeros(3))
    drifted, drifted_pose = crossing_poses(joist, np.array([0.03, -0.02, math.radians(2.0)]))
    assert drifted == events
    assert np.hypot(*(drifted_pose - pose)[:2]) <= 0.005
    assert abs(math.degrees(drifted_pose[2] - pose[2])) <= 0.3


def test_crossing_runs_through_ik_ruckig_and_the_guard_without_an_unreachable_tick():
    joist = JoistSpec(0.7, 0.0, 0.06)
    b = JoistClimb(JoistClimbConfig(goal_distance=1.1), WIDOWX)
    b.stepped = True  # simulated time: plans are waited for
    clock = SteppedClock()
    bus = FakeJointBus(WIDOWX, tau=0.005, clock=clock.now)
    pipeline = MotionPipeline(WIDOWX, DT)
    bus.position[:] = pipeline.kinematics.stand_joints()
    bus.open()
    bus.torque(True)
    pipeline.start(np.array(bus.read().position))
    b.start(body_state(b.pose), pipeline.kinematics.fk(np.array(bus.read().position)))
    world: dict = {}
    tracks = JoistTracks()
    crossed = False
    for k in range(int(240 / DT)):
        t = k * DT
        if k % 10 == 0:
            world = {JoistMap.TOPIC: oracle_map(tracks, [joist], b.pose, t)}
        bus.write(pipeline.feet_step(b.step(t, DT, body_state(b.pose, t), world, None)))
        clock.advance(DT)
        crossed |= b.mode == Phase.CROSS
        if b.done:
            break
    assert crossed and b.done
    assert pipeline.unreachable_ticks == 0


def test_config_is_validated_and_the_plugin_loads_by_name():
    plugin = instantiate("climbd.gaits", "joist_climb", {"walk_speed": 0.05}, WIDOWX, "test")
    assert isinstance(plugin, JoistClimb) and plugin.config.walk_speed == 0.05
    assert plugin.config.approach_distance == 0.55 and plugin.config.climb_max_height == 0.14
    with pytest.raises(PluginError, match="side_direction"):
        instantiate("climbd.gaits", "joist_climb", {"side_direction": 2}, WIDOWX, "test")
    with pytest.raises(PluginError, match="profile"):
        JoistClimb(JoistClimbConfig(), None)


def test_a_joist_beside_the_legs_is_walked_away_from_before_the_turn_to_square_up():
    """Table 2 test 6 (75°, 1.8 m long): the joist's near end is beside the left legs from the
    start. Walking on, or turning 75° in place there, sweeps a leg into it; the behaviour first
    walks straight away from its face until the turn's circle of feet clears it."""
    psi = math.radians(75.0)
    joist = JoistSpec(1.0 - 0.02 / math.cos(psi), psi, 0.10, length=1.8)
    r = run([joist], goal=None, seconds=25.0)
    modes = [e.split(":")[0] for _, e in r.events]
    assert modes[:4] == ["clear", "align", "approach", "settle"], modes
    c = r.behaviour.config
    assert r.clearance >= c.leg_radius + c.turn_clearance / 2, r.clearance


def test_a_replan_from_a_slip_into_a_margin_backs_the_body_out_first():
    """Through the driver the robot slips (a foot lands off its mark and shoves the body): on a
    row of two, 16 mm forward (more than the foot margin's slack) leaves a link inside its
    margin of a joist, where every move of the plan fails at its first instant. The replan
    backs the body along x out of the margin first; every later move keeps every margin."""
    config = JoistClimbConfig(slip_recovery=True)
    kin = Kinematics(WIDOWX)
    feet = kin.stand_feet()
    stand = -float(feet[0, 2])
    ground = np.column_stack([feet[:, :2], np.zeros(len(feet))])
    half_length = float(np.abs(kin.mount[:, 0]).max())
    faces = (0.31, 0.31 + 16 * INCH)

    def plan(slip: float, feet: np.ndarray, height: float, x: float = 0.0) -> CrossingPlan:
        bars = tuple(Bar(face - x - slip, config.joist_width, 0.10) for face in faces)
        geometry = CrossingGeometry(bars=bars, half_length=half_length)
        return CrossingPlan(geometry, config.crossing_params(), kin, feet, stand, height)

    row = plan(0.0, ground, stand)
    stance = np.ones(kin.n_legs, bool)
    slipped = []
    slip = np.array([0.016, 0.0, 0.0])
    for move in row.moves:
        body, on = move.body0, move.feet0
        start = row.check((body + slip)[None, None], (on + slip)[None, None], stance)[0]
        if move.paths or not -np.inf < start < 0.0:
            continue
        local = on - np.array([body[0], body[1], 0.0])
        slipped.append(plan(slip[0], local, float(body[2]), float(body[0])))
    assert slipped, "no phase of the row where the slip breaks a margin"
    for replan in slipped:
        assert replan.recovery < 0.0, "backs away from the joist ahead"
        first = replan.moves[0]
        assert not first.paths and first.body1[0] == pytest.approx(replan.recovery)
        for move in replan.moves[1:]:
            for tau in np.linspace(0.0, 1.0, 9):
                body, at, down = move.sample(tau)
                margin = replan.check(body[None, None], at[None, None], down)[0]
                assert margin >= -1e-9, f"a move after the recovery breaks a margin ({margin})"


def test_the_walk_is_done_only_after_the_feet_have_had_touchdown_time_to_land():
    """Smoothing and servo lag put the real feet behind their targets: ``done`` (and with it
    the daemon's HOLD) waits ``touchdown_time`` after the last foot target stopped moving
    (the stop filter's µm/tick tail counts as still)."""
    b = JoistClimb(JoistClimbConfig(goal_distance=0.3), WIDOWX)
    b.stepped = True  # simulated time: plans are waited for
    b.start(body_state(b.pose), b.kin.stand_feet())
    last_move, previous = 0.0, None
    for k in range(int(30.0 / DT)):
        t = k * DT
        feet = np.array(b.step(t, DT, body_state(b.pose, t), {}, None).positions)
        if previous is not None and np.abs(feet - previous).max() > 1e-5:  # 1 mm/s
            last_move = t
        previous = feet
        if b.done:
            break
    assert b.done and b.travelled >= 0.3
    assert t - last_move >= b.config.touchdown_time - DT
    assert t - last_move < b.config.touchdown_time + 2 * DT


def _plan_on(bars: tuple[Bar, ...], feet: np.ndarray, height: float, **config) -> CrossingPlan:
    """A crossing plan of the default config (``config`` over it) from ``feet`` (ground)."""
    kin = Kinematics(WIDOWX)
    stand = -float(kin.stand_feet()[0, 2])
    geometry = CrossingGeometry(bars=bars, half_length=float(np.abs(kin.mount[:, 0]).max()))
    params = JoistClimbConfig(**config).crossing_params()
    return CrossingPlan(geometry, params, kin, feet, stand, height)


def test_a_plan_keeps_its_tolerance_so_a_drift_inside_it_needs_no_replan():
    """Every margin of the plan keeps ``plan_tolerance`` beyond its limit, so the joist found
    that far off along x (perception's noise, servo lag) still fits the rest of the plan; one
    found 3 cm nearer does not, and the behaviour replans."""
    kin = Kinematics(WIDOWX)
    feet = kin.stand_feet()
    ground = np.column_stack([feet[:, :2], np.zeros(len(feet))])
    bar = Bar(0.31, 0.04, 0.10)
    tolerance = JoistClimbConfig().plan_tolerance
    plan = _plan_on((bar,), ground, -float(feet[0, 2]))
    assert plan.margin((bar,), 0) >= tolerance - 1e-9
    for phase in (0, len(plan.moves) // 3, 2 * len(plan.moves) // 3):
        for shift in (-tolerance, tolerance):
            moved = Bar(bar.face + shift, bar.width, bar.height)
            assert plan.margin((moved,), phase) >= -1e-9, (phase, shift)
    nearer = Bar(bar.face - 0.03, bar.width, bar.height)
    assert plan.margin((nearer,), 0) < 0.0


def test_a_refused_crossing_says_which_leg_and_by_how_much():
    """A 12 cm joist from the stand: no body height gives a plan, and the planner's reason names
    the front leg waiting to cross with how much of its margins its best foothold keeps (0.7 of
    6 mm at a 0.155 m body, bench/joist_heights.py), so the go-round has its numbers."""
    kin = Kinematics(WIDOWX)
    feet = kin.stand_feet()
    ground = np.column_stack([feet[:, :2], np.zeros(len(feet))])
    with pytest.raises(CrossingError) as refused:
        _plan_on((Bar(0.31, 0.04, 0.12),), ground, -float(feet[0, 2]))
    reason = str(refused.value)
    assert "0.155 m: stuck at body x 0.175 m (leg rf cannot step: its best foothold keeps" in reason
    kept, need = (
        float(x) for x in re.findall(r"keeps (-?[\d.]+) mm of the ([\d.]+) mm", reason)[0]
    )
    assert need == pytest.approx(1000 * JoistClimbConfig().plan_tolerance)
    assert 0.0 < kept < need


def test_a_plan_moved_onto_a_joist_found_nearer_keeps_its_feet_and_crosses():
    """Mid-crossing, the joist is found 2 cm nearer than planned (past the plan's 6 mm
    tolerance). From most phases that this breaks (every fifth checked), the rest of the plan
    moved onto it starts with the feet where they stand and the body where it is, shifts the
    body back by the 2 cm, lifts each foot from where it stands, lands none on the joist, and
    ends with every foot beyond it."""
    kin = Kinematics(WIDOWX)
    feet = kin.stand_feet()
    ground = np.column_stack([feet[:, :2], np.zeros(len(feet))])
    bar = Bar(0.31, 0.04, 0.10)
    plan = _plan_on((bar,), ground, -float(feet[0, 2]))
    shift = -0.02
    moved = (Bar(bar.face + shift, bar.width, bar.height),)
    broken = [k for k in range(0, len(plan.moves), 5) if plan.margin(moved, k) < 0.0]
    assert broken, "a 2 cm shift breaks the plan somewhere"
    anchored = 0
    for k in broken:
        start = plan.moves[k]
        origin = np.array([start.body0[0], start.body0[1], 0.0])
        seen = Bar(moved[0].face - origin[0], bar.width, bar.height)
        geometry = CrossingGeometry(bars=(seen,), half_length=plan.g.half_length)
        again = plan.reanchored(moved, k, geometry)
        if again is None:
            continue
        anchored += 1
        first = again.moves[0]
        np.testing.assert_allclose(first.feet0, start.feet0 - origin, atol=1e-12)
        np.testing.assert_allclose(first.body0, start.body0 - origin, atol=1e-12)
        assert first.body1[0] - first.body0[0] == pytest.approx(shift)
        for a, b in zip(again.moves, again.moves[1:], strict=False):
            body, at_end, _ = a.sample(1.0)
            np.testing.assert_allclose(at_end, b.feet0, atol=1e-9)
            np.testing.assert_allclose(body, b.body0, atol=1e-9)
            on_joist = (b.feet0[:, 0] > seen.face) & (b.feet0[:, 0] < seen.face + seen.width)
            assert not on_joist.any(), "no foot stands on the joist"
        assert (again.moves[-1].feet0[:, 0] > seen.face + seen.width).all()
    assert anchored >= len(broken) // 2, (anchored, len(broken))


def test_a_replan_from_a_pose_inside_a_margin_crosses_without_going_deeper():
    """A replan from the twin on its perceived joist: a drift left the left front foot 1.4 cm
    before the joist's face, its tibia 2 mm inside its clearance. Every margin could not keep
    the tolerance from there, so the plan keeps each no worse than the start's: the crossing
    goes on, every foot ends beyond the joist."""
    feet = np.array(
        [
            [0.131, -0.166, 0.0],
            [0.0, -0.25, 0.0],
            [-0.226, -0.166, 0.0],
            [0.136, 0.166, 0.0],
            [0.0, 0.25, 0.0],
            [-0.256, 0.166, 0.0],
        ]
    )
    bar = Bar(0.150, 0.044, 0.098)
    plan = _plan_on((bar,), feet, 0.145)
    start = plan.check(np.array([[[0.0, 0.0, 0.145]]]), feet[None, None], np.ones(6, bool))[0]
    assert -0.005 < start < 0.0, "the start breaks a margin"
    assert plan.margin((bar,), 0) >= start - 1e-9
    final = plan.moves[-1].feet0
    assert (final[:, 0] > bar.face + bar.width).all(), "every foot beyond the joist"


def test_a_joist_just_crossed_behind_the_body_is_not_taken_for_one_ahead():
    """The world model keeps a joist it no longer sees (out of view is not gone), so after a
    crossing the joist just crossed is in the map, behind the body and inside the circle its
    feet sweep turning: the walk goes on instead of turning to it (make demo did)."""
    b = JoistClimb(JoistClimbConfig(goal_distance=0.3), WIDOWX)
    b.stepped = True
    b.start(body_state(b.pose), b.kin.stand_feet())
    crossed = JoistSpec(-0.15, math.radians(-9.0), 0.10)
    seen_before = np.array([-0.75, 0.0, 0.0])  # where the robot saw it, 0.6 m ahead
    world = {JoistMap.TOPIC: oracle_map(JoistTracks(), [crossed], seen_before, 0.0)}
    assert world[JoistMap.TOPIC].joists, "the map holds the crossed joist"
    assert b._turn_radius() > 0.15, "it is inside the circle the feet sweep turning"
    for k in range(int(10.0 / DT)):
        b.step(k * DT, DT, body_state(b.pose, k * DT), world, None)
        if b.done:
            break
    assert [e.split(":")[0] for _, e in b.events] == ["done"], b.events


def _joist_ahead(distance: float, height: float = 0.10) -> Joist:
    """A joist square ahead of the body at ``distance`` (m), its near top edge 0.8 m long."""
    edge = [[distance, -0.4, height], [distance, 0.4, height]]
    return Joist(distance=distance, yaw=0.0, height=height, endpoints=edge)


def test_a_joist_just_past_the_one_crossed_is_its_far_edge_not_a_row():
    """Through the driver the map put a second joist 11 cm past the face being crossed (the
    far edge seen again): taken into the row, it made a 15 cm bar no plan crosses, and 0 of
    65 replans succeeded. A parallel joist 16 in on (an attic row) joins the row."""
    b = JoistClimb(JoistClimbConfig(), WIDOWX)
    b.start(body_state(b.pose), b.kin.stand_feet())
    b.target = b.track(_joist_ahead(0.30))
    b.row = [b.target]
    assert not b._grow_row([_joist_ahead(0.30), _joist_ahead(0.41, 0.08)])
    assert len(b.row) == 1
    assert b._grow_row([_joist_ahead(0.30), _joist_ahead(0.30 + 16 * INCH)])
    assert [round(b.ahead(j)[0], 3) for j in b.row] == [0.3, round(0.30 + 16 * INCH, 3)]


def test_alike_decisions_in_a_row_are_logged_once_then_summarised(caplog) -> None:
    """make demo logged 'no new plan from here' 69 times in one crossing: a run of one kind of
    event is logged at its first and summarised (how many more, the last) before the next
    event of another kind; the journal (``events``) keeps every one."""
    b = JoistClimb(JoistClimbConfig(), WIDOWX)
    unplanned = [f"cross: no new plan from here (leg {leg} cannot step)" for leg in "abcde"]
    with caplog.at_level(logging.INFO, logger="climbd.gait.joist_climb"):
        b._event(1.0, "cross: crossing a 0.100 m joist at 0.300 m")
        for k, what in enumerate(unplanned):
            b._event(2.0 + k, what, "unplanned")
        b._event(9.0, "walk: joist crossed")
    assert [r.getMessage() for r in caplog.records] == [
        "1.00 s cross: crossing a 0.100 m joist at 0.300 m",
        f"2.00 s {unplanned[0]}",
        f"6.00 s {unplanned[-1]} (4 more like it since the first; this the last)",
        "9.00 s walk: joist crossed",
    ]
    assert [what for _, what in b.events][1:6] == unplanned
