"""Periodic gaits: tripod, ripple and wave for hexapods, crawl for quadrupeds.

Every leg runs the same cycle of period ``cycle_time``, shifted by its phase offset: a swing
of ``(1 - duty_factor) * cycle_time`` then a stance for the rest. Feet are kept in a level
frame that moves with the body: a stance foot stays fixed on the ground (it moves against
the body's velocity and yaw rate), a swing foot travels from its lift-off point to a
touch-down point chosen so that the next stance is centred on the stand pose, both points
held fixed on the ground, along the quintic profile of plugins/gaits/swing.py: the foot
leaves and lands at rest relative to the ground. Velocity, yaw rate, body height, roll and
pitch follow the operator's command through a critically damped third-order filter, so
starting and stopping have no step in velocity or acceleration; without a command the robot
slows to a stop and its legs settle on the stand pose. A leg whose foot is already home when
the body is still does not lift at all. Crawl sways the body over the support of the other
three feet while a leg swings (a trigonometric series through the support centroids).

Phase offsets follow the legs' layout (overridable per leg): legs are split into a left and
a right side by the angle of their mount and ordered back to front; tripod alternates along
each side with the right side half a cycle behind, ripple runs each side back to front with
the sides half a cycle apart, wave (and crawl) swings one leg at a time, left side back to
front then right side back to front.
"""

from __future__ import annotations

import math
from typing import Annotated, ClassVar

import msgspec
import numpy as np

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.messages import BodyState, FootTargets, Message, MotionCommand
from climbd.daemon.contract.plugins import GaitPlugin, PluginError
from climbd.daemon.contract.units import NonNegative, Positive
from climbd.plugins.gaits.swing import lift, progress

Fraction = Annotated[float, msgspec.Meta(gt=0, lt=1)]

HOME_TOLERANCE = 1e-3
"""A foot within this distance (m) of its stand position needs no step when the body is still."""

MOVING_SPEED = 5e-4
"""Below this foot speed (m/s) over the ground, with no command, the body counts as still."""

SETTLED = 1e-9
"""Filter error (m, m/s, rad, rad/s) under which the body pose counts as converged."""

LATE_START = 0.5
"""A leg may lift off until this fraction of its swing window has passed (when the body starts
moving mid-window); its swing then takes the rest of the window."""


class PeriodicConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Parameters of a periodic gait (SI units); ``None`` derives a value from the profile.

    ``step_length``: longest stance stroke (m), default 0.4 x stand foot_reach; it caps the
    commanded speed. ``step_height``: swing height (m), default body_height / 3.
    ``body_height``: default stand body_height. ``ramp_time``: time constant (s) of the
    critically damped third-order filter through which velocity, yaw rate, height, roll and
    pitch follow the command (their first and second derivatives stay continuous).
    ``height_range``: allowed body height change as a fraction of the default.
    ``max_tilt``: roll/pitch bound (rad). ``sway``: fraction of the way the body shifts towards
    the centroid of the other feet while a leg swings (crawl); with sway the body starts
    moving, and legs lift, only once the sway is established. ``phase_offsets``: one cycle
    fraction per leg in profile order, replacing the layout rule.
    """

    cycle_time: Positive = 1.5
    duty_factor: Fraction = 0.5
    step_length: Positive | None = None
    step_height: Positive | None = None
    body_height: Positive | None = None
    ramp_time: Positive = 0.3
    height_range: Fraction = 0.3
    max_tilt: Positive = 0.3
    sway: NonNegative = 0.0
    phase_offsets: list[float] | None = None


class TripodConfig(PeriodicConfig, kw_only=True):
    """Tripod: duty factor 1/2, two alternating groups of three legs."""


class RippleConfig(PeriodicConfig, kw_only=True):
    """Ripple: duty factor 2/3, four legs in stance at every instant."""

    cycle_time: Positive = 2.4
    duty_factor: Fraction = 2.0 / 3.0


class WaveConfig(PeriodicConfig, kw_only=True):
    """Wave: duty factor 5/6, one leg in swing at a time."""

    cycle_time: Positive = 4.5
    duty_factor: Fraction = 5.0 / 6.0


class CrawlConfig(PeriodicConfig, kw_only=True):
    """Quadruped crawl: duty factor >= 3/4, one leg at a time, body swaying over the support."""

    cycle_time: Positive = 4.0
    duty_factor: Fraction = 0.8
    sway: NonNegative = 1.0


def layout_offsets(mounts: np.ndarray, pattern: str) -> np.ndarray:
    """Phase offsets (cycle fractions) of legs at body-frame ``mounts`` for ``pattern``.

    Sides by mount angle (left: (0, pi], right: (-pi, 0]), each side ordered back to front.
    """
    n = len(mounts)
    angle = np.arctan2(mounts[:, 1], mounts[:, 0])
    left = (angle > 0) | np.isclose(angle, np.pi)
    offsets = np.zeros(n)
    sides = [np.flatnonzero(left), np.flatnonzero(~left)]
    for side, legs in enumerate(sides):
        order = legs[np.argsort(mounts[legs, 0], kind="stable")]
        for rank, leg in enumerate(order):
            if pattern == "tripod":
                offsets[leg] = (rank % 2) / 2 + side / 2
            elif pattern == "ripple":
                offsets[leg] = rank / max(len(order), 1) + side / 2
            elif pattern == "wave":
                offsets[leg] = (rank + side * len(sides[0])) / n
            else:
                raise ValueError(f"unknown gait pattern {pattern!r}")
    return offsets % 1.0


class PeriodicGait(GaitPlugin):
    """A periodic gait under velocity (vx, vy, yaw rate) and body pose (height, roll, pitch)."""

    name: ClassVar[str] = "periodic"
    pattern: ClassVar[str] = "tripod"
    Config: ClassVar[type[msgspec.Struct]] = PeriodicConfig
    min_legs: ClassVar[int] = 2

    def __init__(self, config: PeriodicConfig | None = None, profile=None) -> None:
        super().__init__(config, profile)
        c: PeriodicConfig = self.config
        kin = Kinematics(profile)
        n = kin.n_legs
        if n < self.min_legs:
            raise PluginError(f"gait {self.name}: needs >= {self.min_legs} legs, profile has {n}")
        if c.phase_offsets is None:
            self.offsets = layout_offsets(kin.mount, self.pattern)
        elif len(c.phase_offsets) == n:
            self.offsets = np.asarray(c.phase_offsets, float) % 1.0
        else:
            raise PluginError(
                f"gait {self.name}: phase_offsets: expected {n} values (one per leg), "
                f"found {len(c.phase_offsets)}"
            )
        stand = profile.stand
        self.n = n
        self.height0 = c.body_height if c.body_height is not None else stand.body_height
        self.step_length = c.step_length if c.step_length is not None else 0.4 * stand.foot_reach
        self.step_height = c.step_height if c.step_height is not None else self.height0 / 3.0
        self.home = kin.stand_feet(self.height0)[:, :2].copy()
        self.home_perp = np.column_stack([-self.home[:, 1], self.home[:, 0]])
        self.swing_time = (1.0 - c.duty_factor) * c.cycle_time
        self._offsets = self.offsets.tolist()
        self._home = self.home.tolist()
        self._home_perp = self.home_perp.tolist()
        self.stance_time = c.duty_factor * c.cycle_time
        self.sway_coef = self._sway_series(c.sway)
        self._reset(np.column_stack([self.home, np.full(n, -self.height0)]))

    def _reset(self, feet: np.ndarray) -> None:
        # Ground-fixed points in the level frame, one [x, y, z] list per leg: the feet, and the
        # stepping legs' lift-off points and touch-down anchors (plain lists: for a few legs
        # scalar math beats numpy's per-call overhead in the tick).
        self._feet = np.asarray(feet, float).tolist()
        self._lift_point = [list(f) for f in self._feet]
        self._anchor = [list(f) for f in self._feet]
        self._command: MotionCommand | None = None
        self._command_targets = self._targets(None)
        self.phase = 0.0
        self.pose = np.array([0.0, 0.0, 0.0, -float(np.mean(feet, 0)[2]), 0.0, 0.0])
        self.pose_rate = np.zeros(6)
        self.pose_acc = np.zeros(6)
        self._settled = False
        self.sway_gain = 0.0
        self.commanded = False
        swing_fraction = 1.0 - self.config.duty_factor
        self._in_window = [(self.phase - o) % 1.0 < swing_fraction for o in self._offsets]
        self._stepping = [False] * self.n
        self._swing_start = [0.0] * self.n

    def start(self, body: BodyState, feet: np.ndarray) -> None:
        """Begin from the measured feet (body frame, body level): the first targets equal them."""
        feet = np.asarray(feet, float)
        if feet.shape != (self.n, 3):
            raise PluginError(
                f"gait {self.name}: start feet shape {feet.shape}, expected ({self.n}, 3)"
            )
        self._reset(feet)
        self.done = False

    # --- command following ------------------------------------------------------------

    def _targets(
        self, command: MotionCommand | None
    ) -> tuple[np.ndarray, float, float, float, float]:
        """Commanded velocity, yaw rate, height, roll, pitch; stop and stand without a command."""
        c: PeriodicConfig = self.config
        if command is None:
            return np.zeros(2), 0.0, self.height0, 0.0, 0.0
        span = c.height_range * self.height0
        height = self.height0 if command.body_height is None else command.body_height
        height = min(max(height, self.height0 - span), self.height0 + span)
        v = np.array([command.vx, command.vy], float)
        w = float(command.yaw_rate)
        if not (np.isfinite(v).all() and math.isfinite(w)):
            v, w = np.zeros(2), 0.0
        stroke = np.hypot(v[0] - w * self.home[:, 1], v[1] + w * self.home[:, 0]).max()
        stroke *= self.stance_time
        if stroke > self.step_length:
            scale = self.step_length / stroke
            v, w = v * scale, w * scale
        tilt = c.max_tilt
        roll = min(max(float(command.roll), -tilt), tilt) if math.isfinite(command.roll) else 0.0
        pitch = min(max(float(command.pitch), -tilt), tilt) if math.isfinite(command.pitch) else 0.0
        return v, w, height, roll, pitch

    @property
    def feet(self) -> np.ndarray:
        """Feet in the level frame now (n_legs, 3), m."""
        return np.array(self._feet)

    @property
    def stepping(self) -> np.ndarray:
        """Legs stepping (lifted off in this swing window and not yet landed)."""
        return np.array(self._stepping)

    @property
    def velocity(self) -> np.ndarray:
        """Body velocity (vx, vy) now, m/s."""
        return self.pose[:2]

    @property
    def yaw_rate(self) -> float:
        return float(self.pose[2])

    @property
    def height(self) -> float:
        return float(self.pose[3])

    @property
    def moving(self) -> bool:
        """Whether the body moves (or is commanded to) faster than MOVING_SPEED at any foot."""
        v, w = self.pose[:2], self.pose[2]
        speed = np.hypot(v[0] - w * self.home[:, 1], v[1] + w * self.home[:, 0]).max()
        return self.commanded or speed > MOVING_SPEED

    def _follow(self, dt: float, command: MotionCommand | None) -> float:
        """Filter (vx, vy, yaw rate, height, roll, pitch) towards the command; returns d(height)."""
        if command is not self._command:
            self._command, self._command_targets = command, self._targets(command)
            self._settled = False
        v, w, height, roll, pitch = self._command_targets
        self.commanded = bool(v[0] or v[1] or w)
        if self.config.sway > 0.0:
            v, w = v * self.sway_gain, w * self.sway_gain
            self._settled &= self.sway_gain in (0.0, 1.0)
        if self._settled:
            return 0.0
        target = np.array([v[0], v[1], w, height, roll, pitch])
        error = target - self.pose
        if max(np.abs(error).max(), np.abs(self.pose_rate).max()) < SETTLED:
            # Converged: snap (a sub-nanometre step) and skip the filter until the command changes.
            self.pose, self._settled = target, True
            self.pose_rate[:] = self.pose_acc[:] = 0.0
            return float(error[3])
        omega = 1.0 / self.config.ramp_time
        jerk = omega * (omega * (omega * error - 3.0 * self.pose_rate) - 3.0 * self.pose_acc)
        self.pose_acc += jerk * dt
        self.pose_rate += self.pose_acc * dt
        step = self.pose_rate * dt
        self.pose += step
        return float(step[3])

    # --- the tick ---------------------------------------------------------------------

    def _advect(self, dt: float, dz: float) -> None:
        """Move the ground-fixed points (level frame) by the body's motion over ``dt``, in place:
        p' = Rz(-w dt) (p - v dt) - dz z; a leg's lift-off and anchor points only while it steps.
        """
        vx, vy, w = self.pose[:3].tolist()
        sx, sy = vx * dt, vy * dt
        points = self._feet + [
            p
            for i, step in enumerate(self._stepping)
            if step
            for p in (self._lift_point[i], self._anchor[i])
        ]
        if w == 0.0:
            for p in points:
                p[0] -= sx
                p[1] -= sy
                p[2] -= dz
            return
        c, s = math.cos(w * dt), math.sin(w * dt)
        for p in points:
            x, y = p[0] - sx, p[1] - sy
            p[0] = c * x + s * y
            p[1] = c * y - s * x
            p[2] -= dz

    def _touch_down(self, leg: int, t_rem: float) -> tuple[float, float]:
        """Where, now (level frame), lies the ground point foot ``leg`` lands on in ``t_rem`` s."""
        vx, vy, w = self.pose[:3].tolist()
        (hx, hy), (px, py) = self._home[leg], self._home_perp[leg]
        half = 0.5 * self.stance_time
        tx, ty = hx + (vx + w * px) * half, hy + (vy + w * py) * half
        if w == 0.0:
            return tx + t_rem * vx, ty + t_rem * vy
        ca, sa = math.cos(w * t_rem), math.sin(w * t_rem)
        return ca * tx - sa * ty + vx * t_rem, sa * tx + ca * ty + vy * t_rem

    def step(
        self,
        t: float,
        dt: float,
        body: BodyState,
        world: dict[str, Message],
        command: MotionCommand | None,
    ) -> FootTargets:
        """Foot targets (body frame) of this tick."""
        c: PeriodicConfig = self.config
        swing_fraction = 1.0 - c.duty_factor
        if c.sway > 0.0:
            self._update_sway(dt)
        dz = self._follow(dt, command)
        self._advect(dt, dz)
        self.phase = phase = (self.phase + dt / c.cycle_time) % 1.0
        late = LATE_START * swing_fraction + 1e-9
        may_lift = c.sway == 0.0 or self.sway_gain == 1.0
        moving = None
        height = self.height
        stance = []
        for leg, offset in enumerate(self._offsets):
            psi = (phase - offset) % 1.0
            window = psi < swing_fraction
            was_in, was_stepping = self._in_window[leg], self._stepping[leg]
            stepping = was_stepping and was_in
            if window and not stepping and may_lift and psi <= late:
                if moving is None:
                    moving = self.moving
                if moving or self._away(leg):
                    stepping = True
                    self._swing_start[leg] = psi
                    self._lift_point[leg] = list(self._feet[leg])
                    self._anchor[leg] = list(self._feet[leg])
            swinging = window and stepping
            if swinging:
                self._swing(leg, psi, height)
            elif was_in and not window and was_stepping:
                # The swing ended: the foot lands on its (ground-fixed) touch-down point.
                touch = self._anchor[leg]
                touch[2] = -height
                self._feet[leg] = list(touch)
            self._stepping[leg] = stepping and window
            self._in_window[leg] = window
            stance.append(not swinging)
        return FootTargets(stamp=t, positions=self._posed(), stance=stance)

    def _swing(self, leg: int, psi: float, height: float) -> None:
        """Move swinging foot ``leg`` along its path at cycle phase ``psi`` (its window's)."""
        c: PeriodicConfig = self.config
        swing_fraction = 1.0 - c.duty_factor
        start = self._swing_start[leg]
        tau = min(max((psi - start) / (swing_fraction - start), 0.0), 1.0)
        s = progress(tau)
        # The touch-down point follows the command early in the swing and is held on the
        # ground as the swing ends, so the foot lands at rest relative to the ground.
        touch, lift_point = self._anchor[leg], self._lift_point[leg]
        px, py = self._touch_down(leg, (swing_fraction - psi) * c.cycle_time)
        touch[0] += (1.0 - s) * (px - touch[0])
        touch[1] += (1.0 - s) * (py - touch[1])
        touch[2] = -height
        foot = self._feet[leg]
        for k in range(3):
            foot[k] = lift_point[k] + s * (touch[k] - lift_point[k])
        foot[2] += self.step_height * lift(tau)

    def _sway_series(self, sway: float) -> np.ndarray:
        """Trigonometric series of the body sway over the cycle phase (coefficients, (k, 2)).

        It interpolates, at the middle of each leg's swing, the shift of the body that far
        (``sway``) towards the centroid of the other feet: the smoothest periodic path through
        those points (minimum-norm fit of harmonics up to n/2).
        """
        targets = sway * (self.home.mean(0) - self.home) / max(self.n - 1, 1)
        centres = (self.offsets + 0.5 * (1.0 - self.config.duty_factor)) % 1.0
        self.harmonics = np.arange(1, self.n // 2 + 1)
        coef, *_ = np.linalg.lstsq(self._sway_basis(centres), targets, rcond=None)
        return coef

    def _sway_basis(self, phase: np.ndarray | float) -> np.ndarray:
        angle = 2.0 * np.pi * np.multiply.outer(phase, self.harmonics)
        ones = np.ones((*np.shape(phase), 1))
        return np.concatenate([ones, np.cos(angle), np.sin(angle)], -1)

    def _away(self, leg: int) -> bool:
        """Whether foot ``leg`` is more than HOME_TOLERANCE from its stand position."""
        (x, y, z), (hx, hy) = self._feet[leg], self._home[leg]
        return max(math.hypot(x - hx, y - hy), abs(z + self.height)) > HOME_TOLERANCE

    def _update_sway(self, dt: float) -> None:
        """Establish the sway (over a quarter cycle, smoothstep) while walking; remove it once
        still. The body only follows a velocity command in proportion to the established sway."""
        walking = any(self._stepping) or self.moving or any(map(self._away, range(self.n)))
        rate = 4.0 * dt / self.config.cycle_time
        self.sway_gain = min(max(self.sway_gain + (rate if walking else -rate), 0.0), 1.0)

    def _posed(self) -> list[list[float]]:
        """Feet in the body frame: level-frame feet shifted by the sway and tilted by roll/pitch."""
        roll, pitch = self.pose[4:].tolist()
        if self.sway_gain == 0.0 and roll == 0.0 and pitch == 0.0:
            return [list(foot) for foot in self._feet]
        out = np.array(self._feet)
        if self.sway_gain > 0.0:
            g = self.sway_gain
            out[:, :2] -= g * g * (3.0 - 2.0 * g) * (self._sway_basis(self.phase) @ self.sway_coef)
        if roll != 0.0 or pitch != 0.0:
            cr, sr = math.cos(roll), math.sin(roll)
            cp, sp = math.cos(pitch), math.sin(pitch)
            rot = np.array([[cp, sp * sr, sp * cr], [0.0, cr, -sr], [-sp, cp * sr, cp * cr]])
            out = out @ rot
        return out.tolist()


class Tripod(PeriodicGait):
    """Tripod gait (duty factor 1/2): alternating groups of three legs, fastest hexapod gait."""

    name: ClassVar[str] = "tripod"
    pattern: ClassVar[str] = "tripod"
    Config: ClassVar[type[msgspec.Struct]] = TripodConfig


class Ripple(PeriodicGait):
    """Ripple gait (duty factor 2/3): each side back to front, sides half a cycle apart."""

    name: ClassVar[str] = "ripple"
    pattern: ClassVar[str] = "ripple"
    Config: ClassVar[type[msgspec.Struct]] = RippleConfig


class Wave(PeriodicGait):
    """Wave gait (duty factor 5/6): one leg at a time, the most stable hexapod gait."""

    name: ClassVar[str] = "wave"
    pattern: ClassVar[str] = "wave"
    Config: ClassVar[type[msgspec.Struct]] = WaveConfig


class Crawl(PeriodicGait):
    """Quadruped crawl (duty factor >= 3/4): left hind, left fore, right hind, right fore."""

    name: ClassVar[str] = "crawl"
    pattern: ClassVar[str] = "wave"
    Config: ClassVar[type[msgspec.Struct]] = CrawlConfig
    min_legs: ClassVar[int] = 4

    def __init__(self, config: CrawlConfig | None = None, profile=None) -> None:
        super().__init__(config, profile)
        if self.config.duty_factor < 0.75:
            raise PluginError(
                f"gait crawl: duty_factor: expected >= 0.75, found {self.config.duty_factor}"
            )
