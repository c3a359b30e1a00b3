"""The stair gait (paper 004): the tripod gait whose step length and step height adapt to the
stairs, the same gait on level ground and on stairs.

Every half cycle one tripod (group A: MF, RB, LB; group B: MB, RF, LF, by the estimator's layout
rule) swings while the other stands; it opens with both down (``transfer``), marked ``unload``,
while the controller passes the weight feed-forward to the tripod that landed. At the start of each
half cycle the planner (plugins/gaits/stair_plan.py) computes this step's length and height and the
next step's length from the ``StairMap`` (odometry frame) and the footholds; the body advances
half the step along its heading from this lift-off to the next (its half step lags the half cycle by
the transfer, so a tripod lifts with the body where the plan put it), its height and pitch following
the terrain under it, with its speed at each lift-off the mean of the two planned half steps (two
steps ahead keeps it smooth). Feet are held in the odometry frame: stance feet stay on their
footholds, a swing foot rises to its step height above lift-off, crosses, and descends onto its
foothold (quintic segments, at rest at both ends). The plan frame is anchored on the estimated body
pose at start, so the first targets equal the measured feet; the measured-vs-planned height and tilt
fade out over the first half cycle. While a foot swings over the stairs it is placed from the
estimated body pose instead (faded in as it rises and out as it descends), so the body's sag under
load does not bring it down onto an edge. Stance footholds follow the estimated body's horizontal
lead over the planned one (an integral action, time constant ``1 / DRIFT_GAIN``): feet roll on their
spheres and slip, so the body runs ahead of the plan by about a centimetre a step, which would
otherwise accumulate into the swing feet's landings the planner keeps clear of edges. The operator's
``vx`` sets the direction (forward or backward) and caps the step (``|vx|`` × cycle time); without a
command, or when no step is feasible, the feet stay down. Without stairs the terrain is level at the
feet."""

from __future__ import annotations

import logging
import math
from collections import deque
from typing import ClassVar, NamedTuple

import msgspec
import numpy as np

from climbd.daemon.algorithms.estimation import tripod_groups
from climbd.daemon.algorithms.feature_maps import flight
from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.messages import (
    BodyState,
    FootTargets,
    Message,
    MotionCommand,
    StairMap,
    Stairs,
    StairStep,
)
from climbd.daemon.contract.plugins import GaitPlugin, PluginError
from climbd.daemon.contract.units import NonNegative, Positive
from climbd.plugins.gaits.stair_plan import (
    StairGeometry,
    StairModel,
    StepPlan,
    StepPlanner,
)
from climbd.plugins.gaits.swing import progress

log = logging.getLogger("climbd.gait.stairs")

CROSSING = 0.5
"""Share of the swing a foot spends crossing at its apex; its rise and descent share the rest."""
DRIFT_GAIN = 5.0
"""Rate (1/s) at which stance footholds absorb the body's horizontal drift from the plan: slow
beside the stance legs' stiffness (body mode about 20 rad/s at kp 300), fast beside rolling
(about 1.3 cm/s, so 2.6 mm stay)."""
REPORTS = 8
"""StairStep reports kept for the next telemetry call (the control role takes them every
few ticks; a gait run without one keeps only the latest)."""


class HalfStep(NamedTuple):
    """The body's progress along its heading from one lift-off (``start``, s) to the next: from
    ``s0`` to ``s1`` (m), at speed ``v0`` then ``v1`` (m/s), a cubic Hermite over a half cycle."""

    start: float
    s0: float
    s1: float
    v0: float
    v1: float


class StairGaitConfig(StairGeometry, kw_only=True):
    """Stair gait parameters (SI): the plan's geometry (StairGeometry) plus ``cycle_time`` (s,
    one transfer and swing of each tripod), the longest ``step_length`` (m) and the tripods by
    leg name (``groups``; empty: the layout rule). ``landing_margin`` defaults to 1 cm here: in
    the twin (kp 300, feed-forward) feet land up to 4 mm off their planned place beside the
    estimate's frame, and a foothold planned at exactly 5 cm landed 4.7 cm from the riser.
    ``roll_margin`` 1.5 cm: in stance the sphere feet roll 1.5-1.8 cm along the walking
    direction (150 × 300 mm, descending: landed 6.4 cm from the drop edge, lifted off 4.95 cm
    from it; at 1 cm, 100 × 250 mm with stair ICP: landed 6.0 cm from the riser, lifted off 4.7
    cm from it). ``shin_margin`` 1 cm: the shins' clearance lost to that roll and the body's
    lead (180 × 280 mm: planned 3.2 cm from the riser's edge axis at lift-off, 1.9 cm in the
    twin: a contact). ``transfer`` (s) opens each half cycle with both tripods down while the
    weight passes to the one that landed: swapping the feed-forward at once dropped the body
    onto it (support 0-50 N of 245 N, then 460 N) and the rebound slid the feet by up to 15 mm.
    The swing has the rest of the half cycle, 0.8 s."""

    landing_margin: NonNegative = 0.01
    roll_margin: NonNegative = 0.015
    shin_margin: NonNegative = 0.01
    cycle_time: Positive = 2.0
    transfer: NonNegative = 0.2
    step_length: Positive = 0.30
    groups: list[list[str]] = []


def hermite(tau: float, s0: float, s1: float, v0: float, v1: float, span: float) -> float:
    """Cubic Hermite position at ``tau`` in [0, 1] between (s0, v0) and (s1, v1) over ``span`` s."""
    t2, t3 = tau * tau, tau * tau * tau
    return (
        (2 * t3 - 3 * t2 + 1) * s0
        + (t3 - 2 * t2 + tau) * span * v0
        + (-2 * t3 + 3 * t2) * s1
        + (t3 - t2) * span * v1
    )


def swing_phases(
    lift_off: np.ndarray, landing: np.ndarray, top: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per foot (n,), the swing phases at which it has risen to ``top`` and has crossed: rise and
    descent share the time outside the crossing by the square roots of their heights, so both
    peak at the same vertical acceleration (a quarter each drove Qingzhui's front thighs past
    their 12 rad/s stepping down 130 mm stairs; the foot lagged 17 cm at touch-down; shares by
    the heights themselves made a step up's short descent land hard)."""
    rise = np.sqrt(np.maximum(top - lift_off[:, 2], 1e-6))
    drop = np.sqrt(np.maximum(top - landing[:, 2], 1e-6))
    up = (1.0 - CROSSING) * rise / (rise + drop)
    return up, up + CROSSING


def swing_point(
    tau: float,
    lift_off: np.ndarray,
    landing: np.ndarray,
    top: np.ndarray,
    phases: tuple[np.ndarray, np.ndarray],
    crossed: np.ndarray | float = 1.0,
) -> np.ndarray:
    """Swing feet (n, 3, global) at ``tau``: up to ``top`` (n,) over lift-off, across the share
    ``crossed`` (n,) of the travel, down over the rest, at the ``phases`` of ``swing_phases``
    (a foot stepping down descends from past the drop's edge, not straight down over its
    landing: there, the apex of a step down a 180 mm riser lay above the leg's hip)."""
    up, across = phases
    down = progress(np.clip((tau - across) / (1.0 - across), 0.0, 1.0))
    a = crossed * progress(np.clip((tau - up) / CROSSING, 0.0, 1.0)) + (1.0 - crossed) * down
    out = lift_off + a[:, None] * (landing - lift_off)
    rising = lift_off[:, 2] + (top - lift_off[:, 2]) * progress(np.clip(tau / up, 0.0, 1.0))
    out[:, 2] = np.where(
        tau < up, rising, np.where(tau < across, top, top + (landing[:, 2] - top) * down)
    )
    return out


class StairGait(GaitPlugin):
    """Tripod gait with step length and height from the stair interference model."""

    name: ClassVar[str] = "stairs"
    Config: ClassVar[type[msgspec.Struct]] = StairGaitConfig

    def __init__(self, config: StairGaitConfig | None = None, profile=None) -> None:
        super().__init__(config, profile)
        c: StairGaitConfig = self.config
        kin = Kinematics(profile)
        if kin.n_legs != 6:
            raise PluginError(f"gait {self.name}: needs 6 legs, profile has {kin.n_legs}")
        try:
            group = tripod_groups(profile, c.groups)
        except ValueError as e:
            raise PluginError(f"gait {self.name}: groups: {e}") from None
        self.groups = [np.flatnonzero(group == 0), np.flatnonzero(group == 1)]
        self.half = 0.5 * c.cycle_time
        if c.transfer >= self.half:
            raise PluginError(
                f"gait {self.name}: transfer {c.transfer} s leaves no swing in the half cycle "
                f"{self.half} s (cycle_time / 2)"
            )
        self.planner = StepPlanner(kin, c, c.transfer / self.half)
        self.geometry = self.planner.geometry
        self.plans: list[StepPlan] = []
        self.footholds: list[np.ndarray] = []
        self.reports: deque[StairStep] = deque(maxlen=REPORTS)
        # this tick's swing phase, swinging legs and their planned feet (odometry frame)
        self.swing: tuple[float, np.ndarray, np.ndarray] | None = None

    def start(self, body: BodyState, feet: np.ndarray) -> None:
        """Anchor the plan on the estimated pose; the first targets equal the measured feet."""
        feet = np.asarray(feet, float)
        if feet.shape != (6, 3):
            raise PluginError(f"gait {self.name}: start feet shape {feet.shape}, expected (6, 3)")
        rot = rotation(np.asarray(body.orientation, float))
        pos = np.asarray(body.position, float)
        self.feet = pos + feet @ rot.T
        self.estimated = bool(np.any(pos != 0.0)) or body.orientation != [1.0, 0.0, 0.0, 0.0]
        self.yaw = math.atan2(rot[1, 0], rot[0, 0])
        self.origin = pos
        self.start_rot = rot
        self.start_z = float(pos[2])
        self.model: StairModel | None = None
        self.refused_maps = 0
        """Stair maps that made no flight (treads overlapping along the walking line, an edge
        along it) while one did before: the gait plans on the last that made one."""
        self._map: StairMap | None = None
        self._stairs: Stairs | None = None
        self.body_s, self.t0 = 0.0, None
        self.half_steps: list[HalfStep] = []  # the last two
        self.step_plan: StepPlan | None = None
        self.direction = 1.0
        self.top = np.zeros(3)
        self.phases = (np.zeros(0), np.zeros(0))
        self.lift_off = self.feet[:0]
        self.next_group = 0
        self.offset = None
        self.plans.clear()
        self.footholds.clear()
        self.reports.clear()
        self.done = False

    # --- the model ------------------------------------------------------------------------

    def _update_model(self, world: dict[str, Message]) -> None:
        stairs = world.get(StairMap.TOPIC)
        if not isinstance(stairs, StairMap):
            stairs = None
        if self.model is not None and (stairs is None or stairs is self._map):
            return
        seen = self._stairs if stairs is None else flight(stairs)
        if stairs is not None:
            self._map = stairs
        left = np.array([-math.sin(self.yaw), math.cos(self.yaw), 0.0])
        lanes = (self.feet - self.origin) @ left
        ground = float(self.feet[:, 2].mean()) - self.geometry.foot_radius
        try:
            model = StairModel(seen, self.origin, self.yaw, lanes, ground)
        except ValueError as e:
            if self.model is None:
                raise PluginError(f"gait {self.name}: {e}") from None
            self.refused_maps += 1
            if self.refused_maps == 1 or self.refused_maps % 100 == 0:
                log.warning(
                    "gait %s: stair map of %.3f s not used (%s, %d so far): planning on the "
                    "last one that made a flight",
                    self.name,
                    stairs.frame_stamp,
                    e,
                    self.refused_maps,
                )
            return
        self.model, self._stairs = model, seen
        if self.offset is None:
            z, pitch = self.model.body_pose(np.array([0.0]), self.geometry)
            r = self.start_rot
            measured_pitch = math.asin(-min(max(r[2, 0], -1.0), 1.0))
            measured_roll = math.atan2(r[2, 1], r[2, 2])
            self.offset = np.array(
                [self.start_z - z[0], measured_roll, measured_pitch - pitch[0]], float
            )

    # --- half cycles ----------------------------------------------------------------------

    def _begin(self, t: float, command: MotionCommand | None) -> None:
        """Start a half cycle: finish the last swing, plan this step and the next."""
        if self.step_plan is not None and self.step_plan.length > 0.0:
            self.feet[self.step_plan.group] = self.step_plan.landing
            self.footholds.append(self.step_plan.landing.copy())
        if self.half_steps:
            self.body_s = self.half_steps[-1].s1
        vx = float(command.vx) if command is not None and math.isfinite(command.vx) else 0.0
        if vx != 0.0:
            self.direction = math.copysign(1.0, vx)
        limit = min(self.config.step_length, abs(vx) * self.config.cycle_time)
        group = self.groups[self.next_group]
        plan = self.planner.plan(self.model, self.feet, self.body_s, group, self.direction, limit)
        self.plans.append(plan)
        self.reports.append(
            StairStep(
                stamp=t,
                body=self.body_s,
                legs=group.tolist(),
                length=plan.length,
                height=plan.height,
                next_length=plan.next_length,
                limit=limit,
                feasible=plan.sections.tolist(),
                blocked=plan.blocked,
            )
        )
        self.step_plan = plan
        self.t0 = t
        v0 = self.half_steps[-1].v1 if self.half_steps else 0.0
        v1 = self.direction * 0.25 * (plan.length + plan.next_length) / self.half
        s1 = self.body_s + self.direction * 0.5 * plan.length
        lift = HalfStep(t + self.config.transfer, self.body_s, s1, v0, v1)
        self.half_steps = [*self.half_steps[-1:], lift]
        if plan.length > 0.0:
            self.lift_off = self.feet[group].copy()
            self.top = plan.apex
            self.phases = swing_phases(self.lift_off, plan.landing, self.top)
        self.next_group = 1 - self.next_group

    def telemetry(self) -> list[Message]:
        """The StairStep of every half cycle begun since the last call, for the control role
        to publish: the paper's step parameters, and why the robot waits when it does."""
        reports = list(self.reports)
        self.reports.clear()
        return reports

    def _body_at(self, t: float) -> float:
        """The body's progress (m along the heading) at ``t``: on the half step begun at the
        latest lift-off, still before the first."""
        begun = [h for h in self.half_steps if h.start <= t + 1e-9]
        if not begun:
            return self.body_s
        h = begun[-1]
        return hermite(min((t - h.start) / self.half, 1.0), h.s0, h.s1, h.v0, h.v1, self.half)

    def step(
        self,
        t: float,
        dt: float,
        body: BodyState,
        world: dict[str, Message],
        command: MotionCommand | None,
    ) -> FootTargets:
        """Foot targets (body frame) of this tick."""
        self._update_model(world)
        if self.t0 is None or t - self.t0 >= self.half - 1e-9:
            self._begin(t, command)
        tau = min(max((t - self.t0) / self.half, 0.0), 1.0)
        s = self._body_at(t)
        offset = None
        if self.offset is not None and len(self.plans) == 1:
            offset = (1.0 - float(progress(tau))) * self.offset
        pos, rot = self.model.body_frames(np.array([s]), self.geometry, offset)
        stance = np.ones(6, bool)
        unload = np.zeros(6, bool)
        plan = self.step_plan
        transfer = self.config.transfer
        swinging = plan.length > 0.0 and t - self.t0 >= transfer
        if plan.length > 0.0:
            stance[plan.group] = not swinging
            unload[plan.group] = not swinging
        if self.estimated:
            lead = np.asarray(body.position[:2], float) - pos[0, :2]
            self.feet[stance & ~unload, :2] += min(DRIFT_GAIN * dt, 1.0) * lead
        feet = self.feet.copy()
        targets = (feet - pos[0]) @ rot[0]
        self.swing = None
        if swinging:
            phase = min((t - self.t0 - transfer) / (self.half - transfer), 1.0)
            up, across = self.phases
            swing = swing_point(
                phase, self.lift_off, plan.landing, self.top, self.phases, plan.crossed
            )
            self.swing = (phase, plan.group, swing)
            targets[plan.group] = (swing - pos[0]) @ rot[0]
            w = progress(np.minimum(phase / up, 1.0)) * (
                1.0 - progress(np.maximum(phase - across, 0.0) / (1.0 - across))
            )
            if w.any() and self.estimated:
                est_rot = rotation(np.asarray(body.orientation, float))
                measured = (swing - np.asarray(body.position, float)) @ est_rot
                targets[plan.group] += w[:, None] * (measured - targets[plan.group])
        return FootTargets(
            stamp=t, positions=targets.tolist(), stance=stance.tolist(), unload=unload.tolist()
        )
