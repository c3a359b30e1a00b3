"""Free-climbing gaits of paper 001 (§3) over discrete graspable points, as pure planners.

Frames: the wall frame has x up the slope (towards the goal), y left, z out of the wall; the
body keeps the wall's orientation, so body-frame feet are wall-frame feet minus the base.
One limb swings at a time (quasi-static, no four-limb phase): its gripper opens only while the
three others hold, it swings along a cubic spline (0.02 m high, 4 s), and closes before the
limb takes load. During the swing the base moves so that the CoM's projection along gravity
lands on the intersection of the support diagonals (§3.3). The non-periodic gait swings the
limb with most graspable points ahead in its reach (§3.1); the periodic baseline [9] swings
limbs in a fixed order; both grip the point giving the longest stride (§3.2). A step whose
predicted Tumble Stability Margin is negative anywhere along the swing is not taken.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import msgspec
import numpy as np

from daemon.kinematics import Kinematics
from daemon.messages import BodyState, FootTargets, GraspablePoints, Message, MotionCommand
from daemon.plugins import GaitPlugin
from plugins.gaits.tsm import tumble_stability_margin

NORMAL = np.array([0.0, 0.0, 1.0])
PERIODIC_ORDER = (1, 0, 2, 3)  # rr, rf, lr, lf: the crawl order of [9]


class ClimbConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Paper 001 §4.1 conditions: swing height/period, base height, grip force, slope, gravity."""

    swing_height: float = 0.02
    swing_period: float = 4.0
    base_height: float = 0.06
    grip_force: float = 9.0
    mass: float = 2.3
    gravity: float = 9.80665 / 6
    slope_deg: float = 30.0
    min_stride: float = 0.005
    hold_spacing: float = 0.03


@dataclass(frozen=True)
class Step:
    """One planned swing: limb, foot start/target and base start/end (wall frame, m)."""

    limb: int
    start: np.ndarray
    target: np.ndarray
    base_start: np.ndarray
    base_end: np.ndarray


def smooth(s: float) -> float:
    """Cubic ease 3s² − 2s³: zero velocity at both ends."""
    return s * s * (3.0 - 2.0 * s)


def swing_lift(s: float, height: float) -> float:
    """Cubic-spline height of the swing foot over the wall: 0 → ``height`` at s = ½ → 0."""
    return height * (smooth(2 * s) if s < 0.5 else 1.0 - smooth(2 * s - 1.0))


def diagonal_crossing(feet: np.ndarray) -> np.ndarray | None:
    """Intersection (x, y) of the diagonals rf–lr and rr–lf, or None if they do not cross."""
    a, b = feet[0, :2], feet[2, :2]
    c, d = feet[1, :2], feet[3, :2]
    m = np.column_stack((b - a, c - d))
    if abs(np.linalg.det(m)) < 1e-12:
        return None
    u, v = np.linalg.solve(m, c - a)
    if not (0.0 < u < 1.0 and 0.0 < v < 1.0):
        return None
    return a + u * (b - a)


class ClimbPlanner:
    """Plans swings over a hold map; ``periodic`` picks limbs in a fixed order instead (§3.1)."""

    def __init__(self, kinematics: Kinematics, config: ClimbConfig, periodic: bool) -> None:
        self.kinematics = kinematics
        self.config = config
        self.periodic = periodic
        self.turn = 0
        slope = math.radians(config.slope_deg)
        self.down = np.array([-math.sin(slope), 0.0, -math.cos(slope)])
        self.force = config.mass * config.gravity * self.down

    def base_for(self, feet: np.ndarray) -> np.ndarray | None:
        """Base whose CoM projects along gravity onto the diagonals' crossing (§3.3)."""
        crossing = diagonal_crossing(feet)
        if crossing is None:
            return None
        h = self.config.base_height
        shift = -h * self.down[:2] / -self.down[2]
        return np.array([crossing[0] + shift[0], crossing[1] + shift[1], h])

    def reachable(self, feet: np.ndarray, base: np.ndarray) -> np.ndarray:
        """Per-leg reachability of wall-frame feet from a base position (IK within limits)."""
        return self.kinematics.ik(feet - base)[1]

    def tsm(self, com: np.ndarray, stance: np.ndarray) -> float:
        """Tumble Stability Margin (m) of the gripping ``stance`` feet with the CoM at ``com``."""
        return tumble_stability_margin(com, stance, self.force, self.config.grip_force, NORMAL)

    def pose(self, step: Step, s: float) -> tuple[np.ndarray, np.ndarray]:
        """Swing foot and base at phase s ∈ [0, 1] of ``step``."""
        k = smooth(s)
        foot = step.start + k * (step.target - step.start)
        foot = foot + NORMAL * swing_lift(s, self.config.swing_height)
        return foot, step.base_start + k * (step.base_end - step.base_start)

    def _feasible(self, feet: np.ndarray, base: np.ndarray, limb: int, target: np.ndarray):
        new = feet.copy()
        new[limb] = target
        base_end = self.base_for(new)
        if base_end is None or not self.reachable(new, base_end).all():
            return None
        step = Step(limb, feet[limb].copy(), target, base.copy(), base_end)
        stance = np.delete(feet, limb, axis=0)
        for s in (0.0, 0.25, 0.5, 0.75, 1.0):
            if self.tsm(self.pose(step, s)[1], stance) < 0.0:
                return None
        return step

    def _ahead(self, feet: np.ndarray, base: np.ndarray, limb: int, holds: np.ndarray):
        """Holds ahead of the limb's foot, free of other feet, reachable from the current base."""
        ahead = holds[holds[:, 0] > feet[limb, 0] + self.config.min_stride]
        others = np.delete(feet, limb, axis=0)
        free = np.linalg.norm(ahead[:, None, :2] - others[None, :, :2], axis=2).min(axis=1)
        ahead = ahead[free > self.config.hold_spacing]
        trial = feet - base
        ok = np.zeros(len(ahead), dtype=bool)
        for i, hold in enumerate(ahead):
            trial[limb] = hold - base
            ok[i] = self.kinematics.ik(trial)[1][limb]
        return ahead[ok]

    def _longest_stride(self, feet, base, limb, holds) -> Step | None:
        options = self._ahead(feet, base, limb, holds)
        for i in np.argsort(-options[:, 0], kind="stable"):
            step = self._feasible(feet, base, limb, options[i])
            if step is not None:
                return step
        return None

    def plan(self, feet: np.ndarray, base: np.ndarray, holds: np.ndarray) -> Step | None:
        """The next swing (§3.1-3.2), or None when no limb has a feasible grip ahead."""
        if self.periodic:
            order = [PERIODIC_ORDER[(self.turn + i) % 4] for i in range(4)]
        else:
            counts = [len(self._ahead(feet, base, limb, holds)) for limb in range(4)]
            order = sorted(range(4), key=lambda limb: (-counts[limb], feet[limb, 0]))
        for limb in order:
            step = self._longest_stride(feet, base, limb, holds)
            if step is not None:
                if self.periodic:
                    self.turn = (PERIODIC_ORDER.index(limb) + 1) % 4
                return step
        return None


@dataclass
class Tick:
    """Wall-frame state of one control tick: feet, base, swinging limb, grips, TSM (m)."""

    feet: np.ndarray
    base: np.ndarray
    swing: int | None
    grip: list[bool]
    tsm: float


class ClimbRunner:
    """Executes planned swings tick by tick: release, swing, grip; replans after each swing."""

    def __init__(self, planner: ClimbPlanner, feet: np.ndarray, base: np.ndarray) -> None:
        self.planner = planner
        self.feet = np.array(feet, float)
        self.base = np.array(base, float)
        self.step: Step | None = None
        self.phase = 0.0

    def tick(self, dt: float, holds: np.ndarray) -> Tick:
        """Advance by ``dt`` (s); a swing starts only when the three other grippers hold."""
        if self.step is None:
            self.step = self.planner.plan(self.feet, self.base, holds)
            self.phase = 0.0
        step = self.step
        if step is None:
            stance = self.feet
            return Tick(self.feet.copy(), self.base.copy(), None, [True] * 4, self._tsm(stance))
        self.phase = min(1.0, self.phase + dt / self.planner.config.swing_period)
        foot, base = self.planner.pose(step, self.phase)
        feet = self.feet.copy()
        feet[step.limb] = foot
        grip = [True] * 4
        grip[step.limb] = self.phase >= 1.0
        stance = np.delete(self.feet, step.limb, axis=0)
        margin = tumble_stability_margin(
            base, stance, self.planner.force, self.planner.config.grip_force, NORMAL
        )
        if self.phase >= 1.0:
            self.feet = feet
            self.base = base
            self.step = None
        return Tick(feet, base, step.limb, grip, margin)

    def _tsm(self, stance: np.ndarray) -> float:
        return self.planner.tsm(self.base, stance)


class FreeClimb(GaitPlugin):
    """Non-periodic free-climbing gait (paper 001) as a gait plugin over GraspablePoints."""

    name: ClassVar[str] = "free_climb"
    Config: ClassVar[type[msgspec.Struct]] = ClimbConfig
    periodic: ClassVar[bool] = False

    def __init__(self, config: ClimbConfig | None = None, profile: object = None) -> None:
        super().__init__(config, profile)
        if profile is None:
            raise ValueError(f"{self.name}: needs the robot profile for its kinematics")
        self.planner = ClimbPlanner(Kinematics(profile), self.config, self.periodic)
        self.runner: ClimbRunner | None = None
        self.holds = np.zeros((0, 3))
        self.last: Tick | None = None

    def start(self, body: BodyState, feet: np.ndarray) -> None:
        """Take the measured feet (body frame) as gripping; the wall frame starts at the base."""
        base = np.array([0.0, 0.0, self.config.base_height])
        wall_feet = np.asarray(feet, float) + base
        wall_feet[:, 2] = 0.0
        self.origin = np.asarray(body.position, float) - base
        self.runner = ClimbRunner(self.planner, wall_feet, base)

    def step(
        self,
        t: float,
        dt: float,
        body: BodyState,
        world: dict[str, Message],
        command: MotionCommand | None,
    ) -> FootTargets:
        """Foot targets (body frame) of this tick; holds come from ``features/graspable``."""
        seen = world.get(GraspablePoints.TOPIC)
        if isinstance(seen, GraspablePoints) and seen.points:
            points = np.asarray(seen.points, float) + np.asarray(body.position) - self.origin
            points[:, 2] = 0.0
            self.holds = points
        tick = self.runner.tick(dt, self.holds)
        self.last = tick
        return FootTargets(
            stamp=t,
            positions=(tick.feet - tick.base).tolist(),
            stance=[g for g in tick.grip],
            grip=tick.grip,
        )


class PeriodicClimb(FreeClimb):
    """The periodic baseline of paper 001 ([9]): fixed limb order, same foothold rule."""

    name: ClassVar[str] = "periodic_climb"
    periodic: ClassVar[bool] = True
