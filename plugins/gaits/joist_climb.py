"""Climb-or-sidestep behaviour of paper 000: walk, then climb a low joist or go round a high one.

The robot walks forward with the tripod gait until the nearest joist across its path is
closer than ``approach_distance`` (0.55 m), or any joist comes within the circle its feet sweep
turning in place. Under ``climb_max_height`` (14 cm) it turns square to the joist when oblique
(the tripod's turn, closed on the measured yaw; first walking straight away from the joist's
face while that is inside the turn's circle of feet), walks up to it,
stops, re-measures, squares up to within ``square_tolerance_deg`` with small turns in place
(leg by leg, five feet standing), and crosses it with the free gait of
plugins/gaits/joist_crossing.py: body raised to the climb height, legs stepped one at a time
over the joist (front, then middle, then back, as in Figure 8) while five feet stand, the
body moved on six. Joists parallel to it in view (an attic row, 16 in apart, closer than the
robot is long) are crossed in the same plan, which is extended when another comes into view
and replanned only when the measured body has drifted out of the plan's tolerance (feet slip,
servo lag): past ``replan_drift`` the rest of the plan is checked against the joists where the
body now finds them, and kept when it still keeps its margins, so perception's noise of a few
millimetres does not restart the crossing at every phase; when it does not, the rest is moved
onto the joists (``CrossingPlan.reanchored``), and planned anew only when that breaks a margin.
At or above the threshold, it walks sideways until no high joist blocks its path, then walks
on; a joist for which the planner finds no safe motion (legs clear of it, feet reachable, body
over its support) is gone round the same way. The crossing is planned standing still, in the
tick that ends the settle (about 0.2–2 s of computation). The joist is tracked on the ground
by dead reckoning of the behaviour's own motion from the moment it is chosen, so it stays
known once it is under the body and out of view; at each settle the measured pose takes over
and the tracked joist keeps its place relative to the body. Every decision reads the world
model's joist map (``features/joist_map``, odometry frame), seen from the body's pose of the
tick (``feature_maps.joists_seen_from``); without a map the robot holds.
"""

from __future__ import annotations

import enum
import logging
import math
from typing import ClassVar

import msgspec
import numpy as np

from climbd.daemon.algorithms.feature_maps import joists_seen_from
from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.algorithms.planning import Outcome, PlanWorker
from climbd.daemon.contract import geometry
from climbd.daemon.contract.messages import (
    BodyState,
    FootTargets,
    Joist,
    JoistMap,
    Message,
    MotionCommand,
)
from climbd.daemon.contract.plugins import GaitPlugin, PluginError
from climbd.plugins.gaits.joist_crossing import (
    Bar,
    CrossingError,
    CrossingGeometry,
    CrossingParams,
    CrossingPlan,
)
from climbd.plugins.gaits.periodic import HOME_TOLERANCE, Tripod, TripodConfig, layout_offsets
from climbd.plugins.gaits.swing import lift, progress

log = logging.getLogger("climbd.gait.joist_climb")


class JoistClimbConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Thresholds (paper 000 defaults), clearances (m), speeds (m/s, rad/s) and times (s)."""

    approach_distance: float = 0.55
    climb_max_height: float = 0.14
    min_height: float = 0.05
    min_confidence: float = 0.3
    corridor: float = 0.25
    walk_speed: float = 0.08
    side_speed: float = 0.05
    turn_rate: float = 0.3
    align_tolerance_deg: float = 3.0
    turn_clearance: float = 0.04
    square_tolerance_deg: float = 1.0
    fine_turn_max_deg: float = 6.0
    side_direction: int = 1
    side_margin: float = 0.10
    crossing_start: float = 0.10
    joist_width: float = 0.04
    foot_margin: float = 0.035
    clearance: float = 0.03
    leg_radius: float = 0.013
    support_margin: float = 0.01
    body_clearance: float = 0.015
    body_half_height: float = 0.02
    climb_heights: list[float] = msgspec.field(default_factory=lambda: [0.135, 0.145, 0.155])
    step_height: float = 0.03
    reach: float = 0.15
    lead: float = 0.03
    body_speed: float = 0.05
    foot_speed: float = 0.1
    swing_time: float = 0.5
    shift_time: float = 0.3
    touchdown_time: float = 0.4
    exit_distance: float = 0.06
    landing_height: float = 0.0
    slip_recovery: bool = False
    plan_tolerance: float = 0.006
    """How far (m) each margin of a crossing plan stays inside its limit where it can."""
    landmark_gate: float = 0.05
    """How near (m) a joist of the map must be to the tracked one to be taken for it."""
    landmark_min_distance: float = 0.25
    """Nearest (m) a joist may be ahead for its map estimate to fix the body's pose. Nearer,
    the stock WidowX camera (12 cm above the body, tilted 30° down) loses the joist's near
    edge (at about 0.21 m at the climb height) and the map's estimate wanders: through the
    driver on Table 2 test 1 it turned up to 5.8° while the leg odometry's heading stayed
    within 0.07° of the twin's (bench/joist_heading.py). There the odometry carries on alone."""
    replan_drift: float = 0.006
    replan_yaw_deg: float = 0.5
    """Drift (m, deg) from the planned pose past which the rest of the plan is checked."""
    row_angle_deg: float = 10.0
    row_min_spacing: float = 0.2
    """Least distance (m) between joists of one row: a parallel joist nearer one in the row is
    that joist's far edge or top seen again (through the driver the map put one 11 cm past
    the face being crossed); attic joists stand 12-24 in (0.3-0.6 m) apart."""
    goal_distance: float | None = None
    tripod: TripodConfig = msgspec.field(default_factory=TripodConfig)

    def __post_init__(self) -> None:
        if self.side_direction not in (1, -1):
            raise ValueError(
                f"joist_climb: side_direction must be 1 or -1, got {self.side_direction}"
            )
        for name in ("approach_distance", "climb_max_height", "walk_speed", "side_speed"):
            if not getattr(self, name) > 0:
                raise ValueError(f"joist_climb: {name} must be > 0, got {getattr(self, name)}")
        if not self.touchdown_time >= 0:
            raise ValueError(f"joist_climb: touchdown_time must be >= 0, got {self.touchdown_time}")

    def crossing_params(self) -> CrossingParams:
        """The crossing planner's clearances, body heights, steps and timing."""
        return CrossingParams(
            foot_margin=self.foot_margin,
            clearance=self.clearance,
            leg_radius=self.leg_radius,
            support_margin=self.support_margin,
            body_clearance=self.body_clearance,
            body_half_height=self.body_half_height,
            climb_heights=tuple(self.climb_heights),
            step_height=self.step_height,
            reach=self.reach,
            lead=self.lead,
            body_speed=self.body_speed,
            foot_speed=self.foot_speed,
            swing_time=self.swing_time,
            shift_time=self.shift_time,
            touchdown_time=self.touchdown_time,
            exit_distance=self.exit_distance,
            landing_height=self.landing_height,
            slip_recovery=self.slip_recovery,
            tolerance=self.plan_tolerance,
        )


BACK_OFF = 0.03
"""How much closer (m) than ``crossing_start`` the front feet may be before backing off."""


SQUARINGS = 4
"""Turns at most, after the first, to square up to a joist within ``square_tolerance_deg``."""


class Phase(str, enum.Enum):
    """What the behaviour is doing."""

    WALK = "walk"
    SIDESTEP = "sidestep"
    CLEAR = "clear"
    ALIGN = "align"
    SQUARE = "square"
    APPROACH = "approach"
    SETTLE = "settle"
    PLAN = "plan"
    CROSS = "cross"
    DONE = "done"


class TrackedJoist(msgspec.Struct, kw_only=True):
    """A joist on the dead-reckoned ground: a point on its near face, unit normal, height."""

    point: list[float]
    normal: list[float]
    height: float


class InPlaceTurn:
    """A small turn in place as a free gait: the body yaws by ``angle`` (rad, left positive) on
    six feet, then each leg steps back home while five stand, and all hold still. The tripod's
    turn over- and undershoots by degrees (feet slip, its stop filter); this lands within a
    fraction of one, which a crossing of an oblique joist needs."""

    def __init__(
        self,
        feet: np.ndarray,
        angle: float,
        body_speed: float,
        foot_speed: float,
        swing_time: float,
        shift_time: float,
        step_height: float,
    ) -> None:
        """Plan from the feet at home (body frame, n×3); speeds in m/s at the farthest foot."""
        self.home = np.asarray(feet, float)
        self.swung = self._rotated(-angle)
        self.angle = angle
        self.step_height = step_height
        arc = float(np.hypot(*self.home[:, :2].T).max()) * abs(angle)
        self.body_time = max(shift_time, arc / body_speed)
        self.swing = max(swing_time, (arc + 2.0 * step_height) / foot_speed)
        self.hold = shift_time
        self.duration = self.body_time + len(self.home) * self.swing + self.hold

    def _rotated(self, yaw: float) -> np.ndarray:
        """The home feet turned by ``yaw`` (rad) about the body's z axis."""
        feet = self.home.copy()
        feet[:, :2] = self.home[:, :2] @ _rot(yaw).T
        return feet

    def turned(self, t: float) -> float:
        """How far (rad) the body has turned ``t`` s into the turn."""
        return self.angle * float(progress(min(t / self.body_time, 1.0)))

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Feet (body frame, n×3) and stance flags ``t`` s into the turn."""
        stance = np.ones(len(self.home), bool)
        if t < self.body_time:
            return self._rotated(-self.turned(t)), stance
        leg, rest = divmod(t - self.body_time, self.swing)
        leg = int(leg)
        feet = self.swung.copy()
        feet[:leg] = self.home[:leg]
        if leg < len(self.home):
            tau = rest / self.swing
            feet[leg] = self.swung[leg] + float(progress(tau)) * (self.home[leg] - self.swung[leg])
            feet[leg, 2] += self.step_height * float(lift(tau))
            stance[leg] = False
        return feet, stance


class Replans(msgspec.Struct):
    """Replans of the crossings since the walk started: requested, of which a new plan came,
    and drift checks after which the plan still kept its margins (no replan)."""

    attempts: int = 0
    succeeded: int = 0
    kept: int = 0

    def __str__(self) -> str:
        return (
            f"{self.succeeded} of {self.attempts} replans succeeded; "
            f"the plan kept its margins after {self.kept} drifts"
        )


class Repeats(msgspec.Struct):
    """The journal's run of alike events: their kind, how many followed the first (logged)
    without being logged, and the last of them."""

    kind: str = ""
    more: int = 0
    t: float = 0.0
    what: str = ""


def _refit(
    plan: CrossingPlan, bars: tuple[Bar, ...], phase: int, geometry: CrossingGeometry, *args
) -> CrossingPlan | None:
    """None when the rest of ``plan`` from ``phase`` keeps its margins with the joists at
    ``bars`` (its frame); else its rest moved onto the joists where they are, when that keeps
    them; else a new plan from ``geometry`` and ``args`` (CrossingPlan's)."""
    if plan.margin(bars, phase) >= 0.0:
        return None
    anchored = plan.reanchored(bars, phase, geometry)
    return anchored if anchored is not None else CrossingPlan(geometry, *args)


def _rot(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s], [s, c]])


def _reach(joist: Joist) -> float:
    """Distance (m) from the body's centre to the joist's seen segment, on the floor."""
    a, b = (np.array(p[:2], float) for p in joist.endpoints)
    ab = b - a
    s = float(np.clip(-(a @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0))
    return float(np.hypot(*(a + s * ab)))


def _planar(body: BodyState) -> np.ndarray:
    """The measured body pose on the floor: x, y (m) and yaw (rad)."""
    return np.array([body.position[0], body.position[1], geometry.yaw(body.orientation)])


class JoistClimb(GaitPlugin):
    """Walk, climb joists under 14 cm, sidestep higher ones (paper 000, Figure 8)."""

    name: ClassVar[str] = "joist_climb"
    Config: ClassVar[type[msgspec.Struct]] = JoistClimbConfig
    needs: ClassVar[tuple[str, ...]] = (JoistMap.TOPIC,)

    def __init__(self, config: JoistClimbConfig | None = None, profile=None) -> None:
        super().__init__(config, profile)
        self.kin = Kinematics(profile)
        if self.kin.n_legs < 4:
            raise PluginError("gait joist_climb: needs at least 4 legs")
        self.tripod = Tripod(self.config.tripod, profile)
        self.height0 = self.tripod.height0
        mounts = self.kin.mount
        order = np.argsort(-mounts[:, 0], kind="stable")
        self.pairs = tuple(tuple(int(i) for i in order[k : k + 2]) for k in range(0, len(order), 2))
        offsets = layout_offsets(mounts, "tripod")
        self.groups = (
            tuple(int(i) for i in np.flatnonzero(offsets == 0.0)),
            tuple(int(i) for i in np.flatnonzero(offsets != 0.0)),
        )
        self.pose = np.zeros(3)
        self.mode = Phase.WALK
        self.target: TrackedJoist | None = None
        self.row: list[TrackedJoist] = []
        self._phase = 0
        self.plan: CrossingPlan | None = None
        self.events: list[tuple[float, str]] = []
        self._repeats = Repeats()
        self.impassable: list[TrackedJoist] = []
        self.travelled = 0.0
        self._t_mode = 0.0
        self._turn_left = 0.0
        self._squarings = 0
        self._clear_since: float | None = None
        self._rest_since: float | None = None
        self.turn: InPlaceTurn | None = None
        self._align_from: tuple[float, float, float] | None = None
        self._square_from = 0.0
        self.planner: PlanWorker[CrossingPlan | None] = PlanWorker("joist-plan")
        self.replans = Replans()
        self._held: tuple[float, FootTargets, np.ndarray, np.ndarray] | None = None
        self._holding: FootTargets | None = None
        self._planned: tuple[tuple[Bar, ...], np.ndarray, float] | None = None

    # --- frames and perception ------------------------------------------------------------

    def start(self, body: BodyState, feet: np.ndarray) -> None:
        """Begin walking from the measured feet (body frame)."""
        self.tripod.start(body, feet)
        self.pose = np.zeros(3)
        self._odometry0 = _planar(body)
        self.mode = Phase.WALK
        self.target = None
        self.plan = None
        self.done = False
        self.travelled = 0.0
        self._held = None
        self.replans = Replans()
        self.planner.close()
        self.planner = PlanWorker("joist-plan", wait=self.stepped)

    def stop(self) -> None:
        """Stop the planning worker (the robot left ACTIVE or the daemon stops)."""
        self.planner.close()

    def _to_ground(self, p: np.ndarray) -> np.ndarray:
        return self.pose[:2] + _rot(self.pose[2]) @ p

    def track(self, joist: Joist) -> TrackedJoist:
        """A joist of the current perception message, placed on the dead-reckoned ground."""
        ends = np.array(joist.endpoints, float)[:, :2]
        normal = _rot(self.pose[2]) @ np.array([math.cos(joist.yaw), math.sin(joist.yaw)])
        return TrackedJoist(
            point=self._to_ground(ends.mean(axis=0)).tolist(),
            normal=normal.tolist(),
            height=joist.height,
        )

    def ahead(self, joist: TrackedJoist) -> tuple[float, float]:
        """Distance to the joist's near face along the heading, and its yaw in the body frame."""
        heading = np.array([math.cos(self.pose[2]), math.sin(self.pose[2])])
        n = np.array(joist.normal)
        along = float(n @ heading)
        gap = float(n @ (np.array(joist.point) - self.pose[:2]))
        distance = gap / along if abs(along) > 1e-6 else math.inf
        yaw = math.atan2(n[1], n[0]) - self.pose[2]
        return distance, math.atan2(math.sin(yaw), math.cos(yaw))

    def _relevant(self, sightings: list[Joist]) -> list[Joist]:
        """Joists of the map that are real (height, confidence) and cross the path."""
        c = self.config
        out = []
        for j in sightings:
            if j.height < c.min_height or j.confidence < c.min_confidence:
                continue
            ys = [p[1] for p in j.endpoints]
            if min(ys) <= c.corridor and max(ys) >= -c.corridor:
                out.append(j)
        return sorted(out, key=lambda j: j.distance)

    def _blocks(self, joist: Joist) -> bool:
        """Too high to climb, or one this robot already found it cannot cross safely."""
        if joist.height >= self.config.climb_max_height:
            return True
        here = self.track(joist)
        return any(
            abs(np.dot(here.normal, np.subtract(here.point, j.point))) < 0.1
            and np.dot(here.normal, j.normal) > math.cos(math.radians(10.0))
            for j in self.impassable
        )

    def _sighting(self, joist: TrackedJoist, sightings: list[Joist]) -> Joist | None:
        """The joist of the map that is ``joist``: the nearest in distance within
        ``landmark_gate`` and 10°. Seen from above, a joist's far edge can enter the map as a
        second joist a width or two beyond its face; the nearest is the one tracked."""
        distance, yaw = self.ahead(joist)
        near = [
            j
            for j in self._relevant(sightings)
            if abs(j.distance - distance) < self.config.landmark_gate
            and abs(j.yaw - yaw) < math.radians(10.0)
        ]
        return min(near, key=lambda j: abs(j.distance - distance), default=None)

    def _refresh(self, sightings: list[Joist]) -> None:
        """Replace the tracked joist by a fresh detection of the same joist, when there is one."""
        if self.target is None:
            return
        seen = self._sighting(self.target, sightings)
        if seen is not None:
            self.target = self.track(seen)

    # --- the tick -------------------------------------------------------------------------

    def _walk(self, t: float, dt: float, body: BodyState, vx: float, vy: float, wz: float):
        """A tripod tick under (vx, vy, yaw rate) or, with all zero, settling to the stand."""
        moving = vx != 0.0 or vy != 0.0 or wz != 0.0
        command = MotionCommand(vx=vx, vy=vy, yaw_rate=wz) if moving else None
        out = self.tripod.step(t, dt, body, {}, command)
        v = self.tripod.velocity
        self.pose[:2] += _rot(self.pose[2]) @ v * dt
        self.pose[2] += self.tripod.yaw_rate * dt
        self.travelled += float(v[0]) * dt
        return out

    def _switch(self, t: float, mode: Phase, why: str) -> None:
        self.mode = mode
        self._t_mode = t
        self._event(t, f"{mode.value}: {why}")

    def _event(self, t: float, what: str, kind: str = "") -> None:
        """Keep ``what`` in ``events`` and log it: the journal says what the behaviour decided.
        Events of one ``kind`` in a row are logged once, then summarised (how many more, and the
        last) when the next event of another kind is logged."""
        self.events.append((t, what))
        if kind and kind == self._repeats.kind:
            self._repeats = Repeats(kind, self._repeats.more + 1, t, what)
            return
        last = self._repeats
        if last.more:
            log.info(
                "%.2f s %s (%d more like it since the first; this the last)",
                last.t,
                last.what,
                last.more,
            )
        self._repeats = Repeats(kind, 0, t, what)
        log.info("%.2f s %s", t, what)

    def _settled(self) -> bool:
        tri = self.tripod
        still = not tri.moving and not any(tri.stepping)
        feet = np.asarray(tri.feet, float)
        home = np.hypot(*(feet[:, :2] - tri.home).T).max() < HOME_TOLERANCE
        return bool(still and home and abs(tri.height - tri.height0) < 1e-4)

    def _at_rest(self, t: float) -> bool:
        """Settled for ``touchdown_time``: the feet land after their targets (smoothing, servo
        lag), so the walk is done only once they have had that long to come down."""
        if not self._settled():
            self._rest_since = None
            return False
        if self._rest_since is None:
            self._rest_since = t
        return t - self._rest_since >= self.config.touchdown_time

    def step(
        self,
        t: float,
        dt: float,
        body: BodyState,
        world: dict[str, Message],
        command: MotionCommand | None,
    ) -> FootTargets:
        """Foot targets (body frame) of this tick, deciding from the joist map."""
        c = self.config
        joists = world.get(JoistMap.TOPIC)
        sightings = joists_seen_from(joists, body) if isinstance(joists, JoistMap) else []
        if self.mode == Phase.WALK:
            return self._step_walk(t, dt, body, sightings)
        if self.mode == Phase.SIDESTEP:
            return self._step_sidestep(t, dt, body, sightings)
        if self.mode == Phase.CLEAR:
            return self._step_clear(t, dt, body)
        if self.mode == Phase.ALIGN:
            return self._step_align(t, dt, body)
        if self.mode == Phase.APPROACH:
            self._refresh(sightings)
            distance, _ = self.ahead(self.target)
            front = max(h[0] for h in self.tripod.home)
            # Where the walk would stop; an oblique joist may be under the feet once squared.
            gap = distance - front - self._stopping_distance()
            if gap < c.crossing_start - BACK_OFF:
                return self._walk(t, dt, body, -c.walk_speed, 0.0, 0.0)
            if gap <= c.crossing_start:
                self._switch(t, Phase.SETTLE, f"front feet {distance - front:.3f} m from it")
                return self._walk(t, dt, body, 0.0, 0.0, 0.0)
            return self._walk(t, dt, body, c.walk_speed, 0.0, 0.0)
        if self.mode == Phase.SETTLE:
            out = self._walk(t, dt, body, 0.0, 0.0, 0.0)
            if self._settled():
                # From here on the measured pose is the frame: the joist is tracked in it.
                self._rebase(self._measured(body))
                self._refresh(sightings)
                _, yaw = self.ahead(self.target)
                if abs(yaw) > math.radians(c.square_tolerance_deg) and self._squarings < SQUARINGS:
                    self._squarings += 1
                    self._square(t, yaw)
                else:
                    self._begin_crossing(t, sightings, out)
            return out
        if self.mode == Phase.SQUARE:
            return self._step_square(t, body)
        if self.mode == Phase.PLAN:
            self._refresh(sightings)  # a fresh sighting may show the plan's joist has moved
            self.row[0] = self.target
            self._take_crossing(t)
            return msgspec.structs.replace(self._holding, stamp=t)
        if self.mode == Phase.CROSS:
            return self._step_cross(t, dt, body, sightings)
        return self._walk(t, dt, body, 0.0, 0.0, 0.0)

    def _turn_radius(self) -> float:
        """How near (m) a joist's face may come to the body's centre before a turn in place
        sweeps a foot or a leg into it: the farthest foot, the leg's radius and
        ``turn_clearance``."""
        c = self.config
        return float(np.hypot(*self.tripod.home[:, :2].T).max()) + c.leg_radius + c.turn_clearance

    def _face_gap(self, joist: TrackedJoist) -> float:
        """Distance (m) from the body's centre to the joist's near face (its whole line)."""
        return float(np.dot(joist.normal, np.subtract(joist.point, self.pose[:2])))

    def _step_clear(self, t: float, dt: float, body: BodyState) -> FootTargets:
        """A tick of walking straight away from an oblique joist whose face is inside the circle
        the feet sweep turning in place (at 75° its near end is beside the legs from the start),
        until the turn to square up clears it."""
        c = self.config
        if self._face_gap(self.target) >= self._turn_radius():
            self._switch(t, Phase.ALIGN, f"{math.degrees(self._turn_left):.1f} deg to square")
            return self._walk(t, dt, body, 0.0, 0.0, 0.0)
        away = -(_rot(-self.pose[2]) @ np.array(self.target.normal)) * c.walk_speed
        return self._walk(t, dt, body, float(away[0]), float(away[1]), 0.0)

    def _step_align(self, t: float, dt: float, body: BodyState) -> FootTargets:
        """A tick of the tripod's turn by ``_turn_left``, closed on the measured yaw: over a
        large turn the tripod's own (commanded) yaw is off by degrees (feet slip)."""
        c = self.config
        yaw = self._measured(body)[2]
        if self._align_from is None:
            self._align_from = (yaw, float(self.pose[2]), self._turn_left)
        yaw0, pose0, goal = self._align_from
        turned = math.remainder(yaw - yaw0, math.tau)
        left = goal - turned
        before = self.pose[2]
        out = self._walk(t, dt, body, 0.0, 0.0, c.turn_rate if left > 0 else -c.turn_rate)
        # The measured turn so far, and this tick's commanded turn it does not show yet.
        self.pose[2] = pose0 + turned + (self.pose[2] - before)
        braking = abs(self.tripod.yaw_rate) * self._ramp()
        if abs(left) <= braking + math.radians(c.align_tolerance_deg) / 4:
            self._align_from = None
            self._switch(t, Phase.APPROACH, "square to the joist")
        return out

    def _square(self, t: float, yaw: float) -> None:
        """Turn ``yaw`` (rad) left to square up: in place, leg by leg, when it is small; else
        with the tripod, then approach again."""
        c = self.config
        why = f"{math.degrees(yaw):.1f} deg left to square"
        if abs(yaw) > math.radians(c.fine_turn_max_deg):
            self._turn_left = yaw
            self._switch(t, Phase.ALIGN, why)
            return
        self.turn = InPlaceTurn(
            self.tripod.feet,
            yaw,
            c.body_speed,
            c.foot_speed,
            c.swing_time,
            c.shift_time,
            c.step_height,
        )
        self._square_from = float(self.pose[2])
        self._switch(t, Phase.SQUARE, why)

    def _step_square(self, t: float, body: BodyState) -> FootTargets:
        """A tick of the in-place turn; at its end the tripod stands and the settle re-measures."""
        turn = self.turn
        elapsed = t - self._t_mode
        feet, stance = turn.sample(elapsed)
        self.pose[2] = self._square_from + turn.turned(elapsed)
        if elapsed >= turn.duration:
            self.tripod.start(body, feet)
            self._switch(t, Phase.SETTLE, "turned in place")
        return FootTargets(stamp=t, positions=feet.tolist(), stance=stance.tolist())

    def _ramp(self) -> float:
        """How far (s × speed) the tripod's critically damped command filter runs on a stop."""
        return 3.0 * self.tripod.config.ramp_time

    def _stopping_distance(self) -> float:
        return float(self.tripod.velocity[0]) * self._ramp()

    def _step_walk(self, t, dt, body, sightings) -> FootTargets:
        c = self.config
        if c.goal_distance is not None and self.travelled >= c.goal_distance:
            out = self._walk(t, dt, body, 0.0, 0.0, 0.0)
            if self._at_rest(t):
                self._switch(t, Phase.DONE, f"walked {self.travelled:.2f} m")
                self.done = True
            return out
        # A joist behind (one just crossed, kept by the map while out of view) is not in the way.
        joists = [j for j in self._relevant(sightings) if j.distance > 0.0]
        near = [j for j in joists if _reach(j) < self._turn_radius()]
        if near or (joists and joists[0].distance < c.approach_distance):
            nearest = near[0] if near else joists[0]
            self.target = self.track(nearest)
            if self._blocks(nearest):
                self._switch(t, Phase.SIDESTEP, f"joist {nearest.height:.3f} m high: too high")
                return self._step_sidestep(t, dt, body, sightings)
            self._turn_left = nearest.yaw
            if abs(nearest.yaw) > math.radians(c.align_tolerance_deg):
                what = f"joist {nearest.height:.3f} m, yaw {nearest.yaw:.3f}"
                if self._face_gap(self.target) < self._turn_radius():
                    self._switch(t, Phase.CLEAR, f"{what}: too near to turn")
                    return self._step_clear(t, dt, body)
                self._switch(t, Phase.ALIGN, what)
            else:
                self._switch(t, Phase.APPROACH, f"joist {nearest.height:.3f} m high: climb")
            return self._walk(t, dt, body, c.walk_speed, 0.0, 0.0)
        return self._walk(t, dt, body, c.walk_speed, 0.0, 0.0)

    def _step_sidestep(self, t, dt, body, sightings) -> FootTargets:
        c = self.config
        blocking = [j for j in self._relevant(sightings) if self._blocks(j)]
        if blocking:
            self._clear_since = None
        elif self._clear_since is None:
            self._clear_since = self.pose[1]
        elif abs(self.pose[1] - self._clear_since) >= c.side_margin:
            self._clear_since = None
            self.target = None
            self._switch(t, Phase.WALK, "no high joist in the way")
            return self._walk(t, dt, body, c.walk_speed, 0.0, 0.0)
        return self._walk(t, dt, body, 0.0, c.side_direction * c.side_speed, 0.0)

    def _grow_row(self, sightings: list[Joist]) -> bool:
        """Add to the row being crossed every newly seen climbable joist parallel to it (an
        attic's joists come in rows 16 in apart, closer than the robot is long)."""
        c = self.config
        _, yaw = self.ahead(self.target)
        grown = False
        for j in self._relevant(sightings):
            if j.height >= c.climb_max_height:
                continue
            seen = self.track(j)
            d, y = self.ahead(seen)
            parallel = abs(y - yaw) < math.radians(c.row_angle_deg)
            new = all(abs(d - self.ahead(r)[0]) > c.row_min_spacing for r in self.row)
            if parallel and new:
                self.row.append(seen)
                grown = True
        return grown

    def _bars(self) -> tuple[Bar, ...]:
        """The row's joists as bars of the crossing frame (x along the heading from here); what
        is left of the turn skews a face across the feet, so each is widened by it."""
        c = self.config
        half_width = float(np.abs(self.tripod.home[:, 1]).max()) + c.reach
        bars = []
        for joist in self.row:
            distance, yaw = self.ahead(joist)
            skew = abs(math.tan(yaw)) * half_width
            bars.append(Bar(distance - skew, c.joist_width + 2.0 * skew, joist.height))
        return tuple(sorted(bars, key=lambda bar: bar.face))

    def _request_plan(
        self, feet: np.ndarray, height: float, fit: tuple[CrossingPlan, float, int] | None = None
    ) -> None:
        """Plan a crossing of the row from here on the worker: ``feet`` on the ground (n×3: x, y
        relative to the body, z above the floor). With ``fit`` (the plan, the body's x in it,
        the phase) the plan is kept (the outcome is None) when its rest still keeps its
        margins with the joists where the body finds them. Inputs are taken now, on the tick."""
        geometry = CrossingGeometry(
            bars=self._bars(),
            half_length=float(np.abs(self.kin.mount[:, 0]).max()),
        )
        params = self.config.crossing_params()
        self._planned = (geometry.bars, feet.copy(), height)
        args = (geometry, params, self.kin, feet.copy(), self.tripod.height0, height)
        if fit is None:
            self.planner.request(CrossingPlan, *args)
        else:
            plan, x, phase = fit
            shifted = tuple(Bar(bar.face + x, bar.width, bar.height) for bar in geometry.bars)
            self.planner.request(_refit, plan, shifted, phase, *args)

    def _outcome(self) -> Outcome[CrossingPlan | None] | None:
        """The requested plan's outcome; a planner bug (not a CrossingError) is raised, so the
        runtime isolates the behaviour and holds."""
        outcome = self.planner.take()
        error = outcome.error if outcome is not None else None
        if error is not None and not isinstance(error, CrossingError):
            raise error
        return outcome

    def _still(self, bars: tuple[Bar, ...]) -> bool:
        """Whether the row's joists are where they were when the plan was asked for (within the
        replanning drift): a plan that took its time is re-checked before it is used."""
        now = self._bars()
        drift = self.config.replan_drift
        return len(now) == len(bars) and all(
            abs(a.face - b.face) <= drift and abs(a.height - b.height) <= drift
            for a, b in zip(now, bars, strict=True)
        )

    def _begin_crossing(self, t: float, sightings: list[Joist], holding: FootTargets) -> None:
        """Plan the crossing from here (the joist and its row square ahead, the feet at home),
        holding ``holding`` until the plan arrives."""
        self._squarings = 0
        self.row = [self.target]
        self._grow_row(sightings)
        feet = np.column_stack([self.tripod.feet[:, :2], np.zeros(len(self.tripod.feet))])
        self._request_plan(feet, self.tripod.height)
        self._plan_from = self.pose.copy()
        self._holding = holding
        if not self._take_crossing(t):
            self._switch(
                t,
                Phase.PLAN,
                f"holding while the {self.target.height:.3f} m joist's crossing is planned",
            )

    def _take_crossing(self, t: float) -> bool:
        """Cross on the plan once it arrives, or go round when none is safe; whether it came."""
        outcome = self._outcome()
        if outcome is None:
            return False
        bars, feet, height = self._planned
        if not self._still(bars):
            self._event(t, "plan: the joist moved while its crossing was planned; planning again")
            self._request_plan(feet, height)
            return False
        if outcome.error is not None:
            self.impassable.append(self.target)
            self._switch(t, Phase.SIDESTEP, f"cannot cross safely ({outcome.error})")
            return True
        self.plan = outcome.plan
        self._plan_origin = self._plan_from
        self._phase = 0
        distance, _ = self.ahead(self.target)
        self._switch(
            t, Phase.CROSS, f"crossing a {self.target.height:.3f} m joist at {distance:.3f} m"
        )
        return True

    def _measured(self, body: BodyState) -> np.ndarray:
        """The estimator's body pose (x, y, yaw) in this behaviour's frame."""
        p0 = self._odometry0
        now = _planar(body)
        xy = _rot(-p0[2]) @ (now[:2] - p0[:2])
        return np.array([xy[0], xy[1], now[2] - p0[2]])

    def _rebase(self, pose: np.ndarray) -> None:
        """Make ``pose`` the behaviour's pose; the tracked joists keep their place relative to
        the body (dead reckoning drifts by degrees in yaw over a walk, the body-relative view
        it tracked them with does not)."""
        turn = _rot(pose[2] - self.pose[2])
        tracked = {id(j): j for j in (self.target, *self.row, *self.impassable) if j is not None}
        for joist in tracked.values():
            joist.point = (pose[:2] + turn @ (np.array(joist.point) - self.pose[:2])).tolist()
            joist.normal = (turn @ np.array(joist.normal)).tolist()
        self.pose = pose

    def _localised(self, body: BodyState, sightings: list[Joist]) -> np.ndarray:
        """The measured pose, its heading and its distance across the row fixed by a joist of
        the row in view: dead reckoning drifts by centimetres and degrees over a crossing (feet
        slip, servos lag), the joist being crossed is a landmark that does not, while the camera
        sees it whole (``landmark_min_distance``). Later odometry counts on from the fixed
        pose."""
        measured = self._measured(body)
        for joist in self.row:
            seen = self._sighting(joist, sightings)
            if seen is None or seen.distance < self.config.landmark_min_distance:
                continue
            n, point = np.array(joist.normal), np.array(joist.point)
            gap = seen.distance * math.cos(seen.yaw)
            xy = measured[:2] + n * (float(n @ (point - measured[:2])) - gap)
            pose = np.array([xy[0], xy[1], math.atan2(n[1], n[0]) - seen.yaw])
            now = _planar(body)
            turn = now[2] - pose[2]
            self._odometry0 = np.array([*(now[:2] - _rot(turn) @ pose[:2]), turn])
            return pose
        return measured

    def _drifted(self, body: BodyState, sightings: list[Joist]) -> bool:
        """Whether the body has drifted from the planned pose (feet slip, servo lag): then the
        pose becomes the measured one and the rest of the crossing is replanned."""
        c = self.config
        measured = self._localised(body, sightings)
        turn = math.remainder(measured[2] - self.pose[2], math.tau)
        off = np.hypot(*(measured[:2] - self.pose[:2]))
        if off <= c.replan_drift and abs(turn) <= math.radians(c.replan_yaw_deg):
            return False
        self.pose = measured
        return True

    def _replan(
        self, t: float, targets: FootTargets, body: np.ndarray, feet: np.ndarray, fit: bool
    ) -> None:
        """Plan on from this phase boundary (a joist of the row came into view, or, with
        ``fit``, the body drifted and the plan no longer keeps its margins), holding
        ``targets`` until the outcome arrives: the feet stay where they stand relative to the
        body."""
        check = (self.plan, float(body[0]), self._phase) if fit else None
        self._request_plan(feet - np.array([body[0], body[1], 0.0]), float(body[2]), check)
        self._plan_from = self.pose.copy()
        self._held = (t, targets, body, feet)
        self._take_replan(t)

    def _take_replan(self, t: float) -> None:
        """Go on from the held boundary on the new plan, or on the old one when it still fits
        or none does."""
        outcome = self._outcome()
        if outcome is None or self._held is None:
            return
        since, _, body, _ = self._held
        self._held = None
        if outcome.error is None and outcome.plan is None:
            self.replans.kept += 1
            self._t_mode += t - since  # the old plan resumes at the boundary it held at
            return
        self.replans.attempts += 1
        if outcome.error is not None:
            self._t_mode += t - since
            self._event(
                t, f"cross: no new plan from here ({outcome.error}); on as planned", "unplanned"
            )
            return
        self.replans.succeeded += 1
        plan = outcome.plan
        self.travelled += float(body[0])
        self.plan = plan
        self._plan_origin = self._plan_from
        self._t_mode = t
        self._phase = 0
        backed = f", the body shifted {plan.recovery:+.3f} m first" if plan.recovery else ""
        self._event(t, f"cross: replanned ({len(self.row)} joists in the row{backed})")

    def _step_cross(
        self, t: float, dt: float, body: BodyState, sightings: list[Joist]
    ) -> FootTargets:
        if self._held is not None:
            held = self._held[1]
            self._take_replan(t)
            return msgspec.structs.replace(held, stamp=t)
        plan = self.plan
        elapsed = t - self._t_mode
        b, feet, stance = plan.sample(elapsed)
        origin = self._plan_origin
        self.pose[:2] = origin[:2] + _rot(origin[2]) @ b[:2]
        local = feet.copy()
        local[:, 0] -= b[0]
        local[:, 1] -= b[1]
        local[:, 2] -= b[2]
        out = FootTargets(stamp=t, positions=local.tolist(), stance=stance.tolist())
        phase = plan.phase(elapsed)
        if phase != self._phase:
            self._phase = phase
            if stance.all() and self._grow_row(sightings):
                self._replan(t, out, b, feet, fit=False)
            elif stance.all() and self._drifted(body, sightings):
                self._replan(t, out, b, feet, fit=True)
        if elapsed >= plan.duration:
            self.travelled += float(b[0])
            self.target = None
            self.tripod.start(body, local)
            self._switch(t, Phase.WALK, f"joist crossed ({self.replans})")
        return out
