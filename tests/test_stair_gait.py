"""Paper 004's gait parameters over constructed stair models: the interference model (eqs. 11-12)
against hand-built geometry, and planned walks up and down flights of 130 × 300, 100, 150 and
180 mm rise with 250-320 mm treads, where every foothold lands in a middle area and no shin ever
meets an edge cylinder (checked independently of the planner); knee b only where it can climb at
all (below 180 mm its front leg has no foothold for longer than a swing, shown constructively)."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest
from conftest import ROOT

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import (
    BodyState,
    MappedStair,
    MotionCommand,
    Stair,
    StairMap,
    Stairs,
)
from climbd.daemon.contract.plugins import PluginError
from climbd.daemon.runtime.loader import load_class
from climbd.plugins.gaits.stair_gait import StairGait, StairGaitConfig, swing_phases, swing_point
from climbd.plugins.gaits.stair_plan import (
    StairGeometry,
    StairModel,
    StepPlanner,
    axis_distance,
    batched,
    edge_frames,
    in_edge_frames,
    interferes,
    knees,
    leg_checks,
)

AREA = 0.05
FLIGHTS = [(0.13, 0.30), (0.10, 0.25), (0.15, 0.32), (0.18, 0.28)]


def qingzhui(knee: str = "a"):
    """The stock Qingzhui, or its knee-"b" variant: the knee below the hip-foot line needs the
    thigh past vertical at the stand (1.79 rad), so that variant's thigh range is ±2.2 rad."""
    profile = profiles.load(ROOT / "robots" / "qingzhui.toml")

    def thigh(joint):
        limits = msgspec.structs.replace(joint.limits, lower=-2.2, upper=2.2)
        return msgspec.structs.replace(joint, limits=limits)

    legs = [
        msgspec.structs.replace(
            leg,
            knee=knee,
            joints=[thigh(j) if knee == "b" and k == 1 else j for k, j in enumerate(leg.joints)],
        )
        for leg in profile.legs
    ]
    return msgspec.structs.replace(profile, legs=legs)


def flight(rise, tread, count=3, start=0.8, landing=1.6, width=1.2) -> Stairs:
    steps = []
    for k in range(count):
        x, top = start + k * tread, (k + 1) * rise
        edge = [[x, width / 2, top], [x, -width / 2, top]]
        depth = tread if k < count - 1 else landing
        steps.append(Stair(height=top, rise=rise, depth=depth, edge=edge))
    return Stairs(steps=steps)


# --- eqs. 11-12 -------------------------------------------------------------------------------


def test_axis_distance_is_eq_11_between_skew_lines() -> None:
    """Shin along z through (0, 0), edge along y at height 0.1, 0.3 m away in x: d = 0.3."""
    knee, foot = np.array([[0.0, 0.0, 0.5]]), np.array([[0.0, 0.0, -0.2]])

    def distance(point: list[float]) -> tuple[float, float]:
        edge = edge_frames(np.array([point]), np.array([[0, 1.0, 0]]))
        d, along = axis_distance(in_edge_frames(knee, *edge), in_edge_frames(foot, *edge))
        return d[0, 0], along[0, 0]

    assert distance([0.3, 2.0, 0.1]) == pytest.approx((0.3, -2.0))
    # the perpendicular's foot beyond the shin (the edge passes below the foot): end distance
    assert distance([0.0, 0.0, -0.5])[0] == pytest.approx(0.3)


def test_interference_is_eq_12_sum_of_radii() -> None:
    model = StairModel(flight(0.13, 0.30), np.zeros(3), 0.0, np.zeros(1), 0.0)
    g = StairGeometry(shin_radius=0.02, edge_radius=0.01, foot_radius=0.0)
    edge = np.array([0.8, 0.0, 0.13])
    # a shin slanting past the first edge at axis distances 0.029 and 0.031 m
    direction = np.array([0.6, 0.0, 0.8])
    normal = np.array([0.8, 0.0, -0.6])
    for gap, hit in ((0.029, True), (0.031, False)):
        mid = edge + gap * normal
        knee, foot = mid + 0.2 * direction, mid - 0.2 * direction
        assert interferes(knee[None], foot[None], model, g)[0] == hit
    # shin_margin widens the shin: 3.9 cm from the edge axis interferes with 1 cm, 4.1 does not
    wide = msgspec.structs.replace(g, shin_margin=0.01)
    for gap, hit in ((0.039, True), (0.041, False)):
        mid = edge + gap * normal
        knee, foot = mid + 0.2 * direction, mid - 0.2 * direction
        assert interferes(knee[None], foot[None], model, wide)[0] == hit


# --- the plan ---------------------------------------------------------------------------------


def shin_clear(kin, planner, model, feet, body_s, legs) -> bool:
    """Independent check: IK of each stance leg from the planned body pose, shin against every
    edge by sampling points along the shin (no use of eq. 11's closed form)."""
    g = planner.geometry
    pos, rot = model.body_frames(np.full(len(legs), body_s), g)
    b = batched(kin, legs)
    body = np.einsum("nji,nj->ni", rot, feet[legs] - pos)
    theta, ok = b.ik_leg(b.to_leg(body))
    if not ok.all():
        return False
    knee = pos + np.einsum("nij,nj->ni", rot, knees(b, theta))
    t = np.linspace(0.0, 1.0, 200)[:, None, None]
    pts = knee[None] + t * (feet[legs] - knee)[None]
    for p, e in zip(model.edge_point, model.edge_dir, strict=True):
        rel = pts - p
        off = rel - (rel @ e)[..., None] * e
        if np.linalg.norm(off, axis=-1).min() < g.shin_radius + g.edge_radius:
            return False
    return True


def walk(
    knee: str,
    rise: float,
    tread: float,
    direction: float,
    steps: int = 40,
    transfer: float = 0.0,
    landing: float | None = None,
    **geometry,
):
    """Plan a walk up (direction +1) or, starting on the landing, backward down (-1); the gait
    stands both tripods for ``transfer`` of each half cycle, the planner told ``landing``
    (default: the same). Shins are checked with the body where each tripod has landed as well."""
    profile = qingzhui(knee)
    kin = Kinematics(profile)
    landing = transfer if landing is None else landing
    planner = StepPlanner(kin, StairGeometry(foot_radius=0.025, **geometry), landing)
    g = planner.geometry
    stairs = flight(rise, tread)
    top = 0.8 + 2 * tread + 0.6 if direction < 0 else 0.0
    feet = kin.stand_feet(g.body_height) + [top, 0.0, 0.0]
    ground = 3 * rise if direction < 0 else 0.0
    feet[:, 2] = ground + g.foot_radius
    model = StairModel(stairs, np.zeros(3), 0.0, feet[:, 1], 0.0)
    groups = [np.array([0, 2, 4]), np.array([1, 3, 5])]
    body, footholds, clear = top, [], True
    for k in range(steps):
        group = groups[k % 2]
        plan = planner.plan(model, feet, body, group, direction, 0.30)
        assert not plan.blocked
        if plan.length > 0:
            feet[group] = plan.landing
            footholds.append(plan.landing.copy())
            landed = body + direction * (1.0 - transfer) * plan.length / 2
            clear &= shin_clear(kin, planner, model, feet, landed, group)
        body += direction * plan.length / 2
        clear &= shin_clear(kin, planner, model, feet, body, np.arange(6))
    return body, np.array(footholds).reshape(-1, 3), stairs, clear


def test_a_tripod_standing_past_reach_still_steps_back() -> None:
    """Stance feet follow the estimated body's lead, so a tripod can stand millimetres past
    ``reach`` (the twin's 150 × 300 mm run stood 2 mm past it on the top landing): it must still
    lift off and step back, or no step of either tripod is feasible and the walk stalls."""
    kin = Kinematics(qingzhui())
    planner = StepPlanner(kin, StairGeometry(foot_radius=0.025))
    g = planner.geometry
    feet = kin.stand_feet(g.body_height)
    feet[:, 2] = g.foot_radius
    tripod = np.array([1, 3, 5])
    feet[tripod, 0] += g.reach + 0.002
    model = StairModel(flight(0.13, 0.30), np.zeros(3), 0.0, feet[:, 1], 0.0)
    plan = planner.plan(model, feet, 0.0, tripod, -1.0, 0.30)
    assert plan.length > 0.0


def margins(stairs: Stairs, footholds: np.ndarray) -> np.ndarray:
    """Distance of each foothold to the nearer end of its tread (true geometry)."""
    model = StairModel(stairs, np.zeros(3), 0.0, footholds[:, 1], 0.0)
    return model.margin(np.arange(len(footholds)), model.to_plane(footholds)[0])


STEEP = (
    "no step sequence passes the last riser: with the front feet on the landing and the rear"
    " ones two rises below, the body pitches 26 deg and the rear legs stand at 0.76 rad of"
    " abduction (limit 0.785 rad), lifting needs more; a depth-first search over every"
    " feasible step length (the planner's sections, tripods waiting in turn) ends at 1.30 m"
    " on 180 x 280 mm, 1.35 m on 180 x 300, 1.33 m on 180 x 320"
)
KNEE_B_180 = (
    "the two-step plan reaches a state where no step of either tripod is feasible (every leg"
    " has a usable foothold at every body position on this flight, unlike the lower rises:"
    " test_knee_b_front_leg_has_no_foothold_for_longer_than_a_swing)"
)
KNEE_B_GAP = [(0.10, 0.25), (0.13, 0.30), (0.15, 0.32)]
"""Flights where the knee-b front leg has no foothold for longer than a swing: no climb."""


def _climb_marks(knee: str, rise: float) -> list:
    if knee == "b":
        return [pytest.mark.xfail(strict=True, reason=KNEE_B_180)]
    if rise >= 0.18:
        return [pytest.mark.xfail(strict=True, reason=STEEP)]
    return []


CLIMBS = [
    pytest.param(knee, rise, tread, marks=_climb_marks(knee, rise))
    for rise, tread in FLIGHTS
    for knee in ("a", "b")
    if knee == "a" or (rise, tread) not in KNEE_B_GAP
]


@pytest.mark.parametrize("knee,rise,tread", CLIMBS)
def test_planned_climb_lands_in_middle_areas_without_shin_interference(knee, rise, tread):
    body, footholds, stairs, clear = walk(knee, rise, tread, +1.0)
    m = margins(stairs, footholds)
    assert (m >= AREA - 1e-9).all(), m.min()
    assert clear
    top = 0.8 + 2 * tread
    assert body > top, f"the body reached the top tread ({body:.2f} m)"
    on_top = footholds[-6:]
    assert (on_top[:, 2] > rise).all()


@pytest.mark.parametrize("rise,tread", [(0.13, 0.30), (0.18, 0.28), (0.18, 0.32)])
def test_planned_descent_backward(rise, tread):
    """Knee a; knee b cannot pass this flight's body positions (the test below). 180 mm rises
    descend only with swings leaving the apex past the drop's edge (``clear_of_drop``)."""
    body, footholds, stairs, clear = walk("a", rise, tread, -1.0)
    m = margins(stairs, footholds)
    assert (m >= AREA - 1e-9).all(), m.min()
    assert clear
    assert body < 0.8, f"the body came down to the floor ({body:.2f} m)"


def test_a_swing_lands_clear_with_the_body_short_of_the_half_step():
    """With a transfer the body is a transfer's share short of the half step when a swing
    lands: the planner checks the landing there (150 x 300 mm backward down: told nothing, one
    landing shin meets an edge)."""
    *_, clear = walk("a", 0.15, 0.30, -1.0, transfer=0.2)
    assert clear
    *_, unaware = walk("a", 0.15, 0.30, -1.0, transfer=0.2, landing=0.0)
    assert not unaware


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_roll_margin_keeps_footholds_off_the_far_end(direction):
    """The sphere feet roll along the walking direction in stance: with ``roll_margin`` every
    planned foothold keeps that much more from its tread's far end (the riser ahead going up,
    the drop edge behind going down backward) than the near end's 5 cm + landing margin."""
    body, footholds, stairs, clear = walk(
        "a", 0.13, 0.30, direction, landing_margin=0.01, roll_margin=0.02
    )
    assert clear and (body > 0.8 + 2 * 0.30 if direction > 0 else body < 0.8)
    model = StairModel(stairs, np.zeros(3), 0.0, footholds[:, 1], 0.0)
    s = model.to_plane(footholds)[0]
    lanes = np.arange(len(footholds))
    seg = model.segment(lanes, s)
    bounds = np.pad(model.bounds, ((0, 0), (1, 1)), constant_values=(-np.inf, np.inf))
    lo, hi = bounds[lanes, seg], bounds[lanes, seg + 1]
    far, near = (hi - s, s - lo) if direction > 0 else (s - lo, hi - s)
    assert far.min() >= AREA + 0.01 + 0.02 - 1e-9, far.min()
    assert near.min() >= AREA + 0.01 - 1e-9, near.min()


def footless_stretch(knee: str, rise: float, tread: float, leg: int = 0) -> float:
    """Longest stretch (m) of body positions along a flight where ``leg`` has no foothold: none
    in a tread's middle area (or the floor's) that it reaches within its joint limits and
    ``reach`` with the body at the gait's pose there (eq. 12 clear). Sampled: body every 5 mm,
    footholds every 5 mm (the feasible footholds found are bands >= 1 cm wide)."""
    kin = Kinematics(qingzhui(knee))
    planner = StepPlanner(kin, StairGeometry(foot_radius=0.025))
    g = planner.geometry
    lane = kin.stand_feet(g.body_height)[leg, 1]
    model = StairModel(flight(rise, tread), np.zeros(3), 0.0, np.array([lane]), 0.0)
    body = np.arange(-0.2, 1.6, 0.005)
    x = np.arange(-0.2, 2.2, 0.005)
    ss, xx = (a.ravel() for a in np.meshgrid(body, x, indexing="ij"))
    zeros = np.zeros(len(xx), int)
    foot = np.column_stack([xx, np.full_like(xx, lane), model.height(zeros, xx) + g.foot_radius])
    pos, rot = model.body_frames(ss, g)
    legs = np.full(len(ss), leg)
    ok = leg_checks(batched(kin, legs), planner.home[legs], foot, pos, rot, model, g)
    ok &= model.margin(zeros, xx) >= g.area
    held = ok.reshape(len(body), len(x)).any(1)
    longest, start = 0.0, None
    for s, h in zip(body, held, strict=True):
        if not h and start is None:
            start = s
        elif h and start is not None:
            longest, start = max(longest, s - start), None
    assert start is None, "the sampled stretch ends without a foothold"
    return longest


@pytest.mark.parametrize("rise,tread", KNEE_B_GAP)
def test_knee_b_front_leg_has_no_foothold_for_longer_than_a_swing(rise, tread):
    """Why knee b cannot climb (or descend) these flights: with the body at the gait's pose
    (stand height over the terrain fit, pitched with it), the front leg's knee hangs below
    the tread ahead, and over a stretch of body positions longer than the body moves during
    one swing (half the longest step, 0.15 m) every foothold it reaches puts its shin or foot
    through an edge, so the leg would have to stay in the air longer than a swing. Knee a has
    a foothold at every body position on the same flights."""
    half_step = 0.5 * StairGaitConfig().step_length
    assert footless_stretch("b", rise, tread) > half_step + 0.02
    assert footless_stretch("a", rise, tread) == 0.0


def test_two_steps_ahead_and_step_height_clear_the_edges() -> None:
    kin = Kinematics(qingzhui())
    planner = StepPlanner(kin, StairGeometry(foot_radius=0.025))
    feet = kin.stand_feet(0.30)
    feet[:, 2] = 0.025
    stairs = flight(0.13, 0.30, start=0.62)
    model = StairModel(stairs, np.zeros(3), 0.0, feet[:, 1], 0.0)
    plan = planner.plan(model, feet, 0.0, np.array([0, 2, 4]), 1.0, 0.30)
    assert plan.next_length > 0 and plan.length > 0
    # the front foot crosses the first edge: its apex clears it by the step height
    s_land = model.to_plane(plan.landing)[0][0]
    assert s_land > 0.62 + AREA
    assert plan.apex[0] >= 0.13 + 0.025 + planner.geometry.min_step_height - 1e-9
    assert plan.length in plan.sections


def test_a_swing_descends_a_riser_no_faster_than_it_rises() -> None:
    """Rise and descent share the time outside the crossing by the square roots of their
    heights: stepping down a 130 mm riser (apex 50 mm over lift-off) the foot's peak vertical
    acceleration down equals its peak up; level steps keep a quarter each. The path is
    continuous, crossing at the apex."""
    lift_off = np.array([[0.0, 0.0, 0.415], [0.0, 0.3, 0.025]])
    landing = np.array([[-0.3, 0.0, 0.285], [0.3, 0.3, 0.025]])
    top = np.array([0.465, 0.075])
    up, across = swing_phases(lift_off, landing, top)
    np.testing.assert_allclose(up[1], 0.25)
    np.testing.assert_allclose(across[1], 0.75)
    tau = np.linspace(0.0, 1.0, 20001)
    path = np.array([swing_point(t, lift_off, landing, top, (up, across)) for t in tau])
    assert np.abs(np.diff(path, axis=0)).max() < 1e-3
    np.testing.assert_allclose(path[0], lift_off, atol=1e-12)
    np.testing.assert_allclose(path[-1], landing, atol=1e-12)
    az = np.diff(path[:, 0, 2], 2) / np.diff(tau)[1:] ** 2
    rising, falling = tau[1:-1] < up[0], tau[1:-1] > across[0]
    assert np.abs(az[falling]).max() == pytest.approx(np.abs(az[rising]).max(), rel=1e-2)
    crossing = (tau > up[0] + 1e-9) & (tau < across[0] - 1e-9)
    np.testing.assert_allclose(path[crossing, 0, 2], top[0])


def test_a_swing_stepping_down_may_descend_from_past_the_edge_it_leaves() -> None:
    """Treads [0.8, 1.1) at 0.13 m and [1.1, 1.4) at 0.26 m: a step down may leave the apex once
    past the last edge above its landing by the clearance (at most at the landing), backward
    and forward; steps up and along a tread cross over their landing."""
    stairs = flight(0.13, 0.30)
    c = 0.055
    lane = np.zeros(1)
    back = StairModel(stairs, np.zeros(3), 0.0, lane, 0.0)
    s0 = np.array([0.9, 1.15, 0.9, 0.5, 0.85])
    s1 = np.array([0.6, 0.7, 0.77, 0.95, 1.0])
    np.testing.assert_allclose(back.clear_of_drop(0, s0, s1, c), [0.745, 0.745, 0.77, 0.95, 1.0])
    ahead = StairModel(stairs, np.array([2.5, 0.0, 0.0]), np.pi, lane, 0.0)
    s0, s1 = 2.5 - np.array([0.9, 1.15]), 2.5 - np.array([0.6, 0.6])
    np.testing.assert_allclose(ahead.clear_of_drop(0, s0, s1, c), 2.5 - np.array([0.745] * 2))


def test_a_swing_crosses_its_share_at_the_apex_then_descends_to_the_landing() -> None:
    """Stepping down a 180 mm riser with 40 % of the travel crossed at the apex: the foot holds
    the apex height until then, descends while it covers the rest, touches down at rest, and its
    sphere never comes within the edge cylinder of the riser it leaves."""
    lift_off = np.array([[1.0, 0.0, 0.205]])
    landing = np.array([[0.7, 0.0, 0.025]])
    top = np.array([0.265])
    edge = np.array([0.9, 0.18])  # (x, z) of the riser's edge axis
    phases = swing_phases(lift_off, landing, top)
    up, across = phases
    tau = np.linspace(0.0, 1.0, 20001)
    path = np.array([swing_point(t, lift_off, landing, top, phases, 0.4)[0] for t in tau])
    np.testing.assert_allclose(path[0], lift_off[0], atol=1e-12)
    np.testing.assert_allclose(path[-1], landing[0], atol=1e-12)
    assert np.abs(np.diff(path, axis=0)).max() < 1e-3
    crossing = (tau >= up[0]) & (tau <= across[0])
    np.testing.assert_allclose(path[crossing, 2], top[0])
    at_end = path[np.searchsorted(tau, across[0])]
    assert at_end[0] == pytest.approx(1.0 - 0.4 * 0.3, abs=1e-4)
    falling = tau > across[0]
    assert (np.diff(path[falling, 0]) <= 1e-12).all() and (np.diff(path[falling, 2]) <= 1e-12).all()
    gap = np.hypot(path[:, 0] - edge[0], path[:, 2] - edge[1])
    assert gap.min() >= 0.025 + 0.01, gap.min()


def test_gait_first_targets_equal_measured_feet_and_walks_on_level_ground() -> None:
    profile = qingzhui()
    kin = Kinematics(profile)
    gait = StairGait(StairGaitConfig(), profile)
    feet = kin.stand_feet(0.29)
    body = BodyState()  # no estimator: the odometry frame is the body's start
    gait.start(body, feet)
    first = np.array(gait.step(0.0, 1e-3, body, {}, MotionCommand(vx=0.1)).positions)
    np.testing.assert_allclose(first, feet, atol=1e-9)
    prev = first
    for k in range(1, 6000):
        out = np.array(gait.step(k * 1e-3, 1e-3, body, {}, MotionCommand(vx=0.1)).positions)
        assert np.abs(out - prev).max() < 2e-3
        prev = out
    assert gait.body_s >= 0.5  # 0.1 m/s for 6 s, after a start from rest


def test_each_half_cycle_opens_with_both_tripods_down_the_lifting_one_unloading() -> None:
    """For ``transfer`` s after each half cycle's start all six feet stand, the tripod about to
    swing marked ``unload`` and held at its footholds; then it swings, the other alone in
    stance, having lifted with the body where its plan put it (the body's half step runs from
    lift-off to lift-off). A transfer that leaves no swing is refused, naming the field."""
    profile = qingzhui()
    kin = Kinematics(profile)
    config = StairGaitConfig(transfer=0.2)
    gait = StairGait(config, profile)
    feet = kin.stand_feet(0.29)
    body = BodyState()
    gait.start(body, feet)
    half, dt = 0.5 * config.cycle_time, 1e-3
    seen, lifts = [], 0
    for k in range(int(3 * half / dt)):
        t = k * dt
        out = gait.step(t, dt, body, {}, MotionCommand(vx=0.1))
        stance, unload = np.array(out.stance), np.array(out.unload)
        lifting = gait.step_plan.group
        positions = np.array(out.positions)
        if k % int(half / dt) == 0:
            opened = positions
        if (t % half) < config.transfer - dt:
            assert stance.all() and unload[lifting].all() and unload.sum() == 3, t
            moved = positions - opened  # the body's motion under feet fixed on the ground
            np.testing.assert_allclose(moved, np.broadcast_to(moved[0], moved.shape), atol=1e-9)
        elif (t % half) > config.transfer + dt:
            assert not stance[lifting].any() and stance.sum() == 3 and not unload.any(), t
        if abs(t % half - config.transfer) < 0.5 * dt:
            standing = np.flatnonzero(stance)[0]  # level ground: the body is at foot x - target x
            body_s = gait.feet[standing, 0] - positions[standing, 0]
            assert abs(body_s - gait.body_s) < 1e-9, (t, body_s, gait.body_s)
            lifts += 1
        seen.append(unload.any())
    assert any(seen) and not all(seen) and lifts == 3
    with pytest.raises(PluginError, match="transfer"):
        StairGait(StairGaitConfig(transfer=half), profile)


def test_each_half_cycle_reports_its_step_and_a_wall_the_wait() -> None:
    """Every half cycle's plan goes out as a StairStep (the control role publishes the gait's
    telemetry): paper 004's step length and height, the tripods in turn, the command's limit.
    Before a 0.6 m riser, which no leg reaches over, the steps shorten to nothing under that
    limit: the reports say the robot waits, and where."""
    profile = qingzhui()
    gait = StairGait(StairGaitConfig(), profile)
    gait.start(BodyState(), Kinematics(profile).stand_feet(0.29))
    top = 0.6 - 0.29 - gait.geometry.foot_radius  # the floor under the feet, 0.6 m down
    edge = [[0.8, 0.6, top], [0.8, -0.6, top]]
    riser = MappedStair(
        id=1, confidence=1.0, seen=1, age=0.0, height=top, rise=0.6, depth=1.0, edge=edge
    )
    world = {StairMap.TOPIC: StairMap(steps=[riser])}
    reports, dt = [], 1e-3
    for k in range(int(14.0 / dt)):
        gait.step(k * dt, dt, BodyState(), world, MotionCommand(vx=0.1))
        if k % 10 == 0:
            reports += gait.telemetry()
    assert len(reports) == len(gait.plans) == 14
    for report, plan in zip(reports, gait.plans, strict=True):
        assert report.legs == plan.group.tolist()
        assert (report.length, report.height) == (plan.length, plan.height)
        assert report.length in report.feasible
    assert [r.legs for r in reports[:2]] == [g.tolist() for g in gait.groups]
    assert all(r.limit == pytest.approx(0.2) for r in reports)  # 0.1 m/s over a 2 s cycle
    assert reports[0].length > 0 and reports[1].length > 0
    # a tripod may wait a half cycle for the other; the robot waits once both do in turn
    lengths = [r.length for r in reports]
    both = [k for k in range(1, len(reports)) if lengths[k] == lengths[k - 1] == 0.0]
    assert both == list(range(both[0], len(reports))) and len(both) >= 4, lengths
    assert {r.body for r in reports[both[0] :]} == {gait.body_s}
    assert not any(r.blocked for r in reports)
    front = gait.feet[:, 0].max() + gait.geometry.foot_radius
    assert 0.8 - 0.1 < front < 0.8, front


def test_entry_point_is_registered() -> None:
    assert load_class("climbd.gaits", "stairs") is StairGait


def mapped(stairs: Stairs) -> StairMap:
    """``stairs`` as the world model's stair map."""
    return StairMap(
        steps=[
            MappedStair(id=k, confidence=1.0, seen=3, age=0.0, **msgspec.structs.asdict(s))
            for k, s in enumerate(stairs.steps)
        ]
    )


def test_a_stair_map_that_makes_no_flight_leaves_the_last_one_in_use(caplog) -> None:
    """At the top of the flight the camera sees the floor beyond the landing, and the stair map
    once gained a phantom step on the first riser's line, 3.9 m deep: its treads overlap. The
    gait plans on the last map that made a flight and warns, naming why; a first map that
    makes none fails the gait with the reason (the robot holds)."""
    profile = qingzhui()
    good = mapped(flight(0.13, 0.30))
    phantom = Stair(
        height=0.035, rise=0.047, depth=3.86, edge=[[0.8, 2.4, 0.035], [0.8, -2.4, 0.035]]
    )
    bad = mapped(Stairs(steps=[phantom, *flight(0.13, 0.30).steps]))
    gait = StairGait(StairGaitConfig(), profile)
    gait.start(BodyState(), Kinematics(profile).stand_feet(0.29))
    dt = 1e-3
    gait.step(0.0, dt, BodyState(), {StairMap.TOPIC: good}, MotionCommand(vx=0.1))
    model = gait.model
    with caplog.at_level("WARNING", logger="climbd.gait.stairs"):
        for k in range(1, 2000):
            gait.step(k * dt, dt, BodyState(), {StairMap.TOPIC: bad}, MotionCommand(vx=0.1))
    assert gait.model is model and gait.refused_maps == 1
    assert "treads overlap" in caplog.text and "last one that made a flight" in caplog.text
    fresh = StairGait(StairGaitConfig(), profile)
    fresh.start(BodyState(), Kinematics(profile).stand_feet(0.29))
    with pytest.raises(PluginError, match="treads overlap"):
        fresh.step(0.0, dt, BodyState(), {StairMap.TOPIC: bad}, MotionCommand(vx=0.1))
