"""The joist crossing of paper 000 (Figure 8) as a free gait of statically stable phases.

Planned in a ground frame whose x axis is the joists' normal (the robot has already turned
square to them): each joist is a bar with its near face at ``x = face``, ``width`` deep and
``height`` tall on the floor (z = 0). The plan alternates two kinds of phase, each checked at
sampled instants by the profile's kinematics before it is accepted:

- a body move (all six feet down): the body rises to the climb height, advances, or lowers;
- a single-leg swing (five feet down): up, over any bar in its way, down onto a foothold
  outside every bar's band.

Every sampled pose must have every foot reachable within the joint limits, the coxa–femur
chord, tibia and foot of every moving leg ``leg_radius`` clear of every bar (links sampled,
plus the bars' top edges against each link), the body's underside ``body_clearance`` above
any bar under it, and the body centre ``support_margin`` inside the support polygon of the
standing feet. During the crossing the feet stand on a wider stance (``reach`` from the coxa
mount), so a foot lifted to the joist top does not fold the knee past its limit, and a
swinging foot may spread outward at its apex for the same reason. The order is the free
gait's greedy rule: a leg with a bar just ahead tries to step over it at every phase (so the
back pair finds the short window of body positions where it can), a leg far behind its home
steps, else the body advances as far as the constraints allow (at most 3 cm), else the others
step home while one waits to cross (stepping them home before every advance doubled the
swings). The front legs thus cross first, then the middle pair, then the back pair (Figure 8),
one leg at a time. Every margin keeps ``tolerance`` beyond its limit where it can, so the
robot found a few millimetres off the plan (perception, servo lag) still fits it
(``margin``). Body heights are tried from the lowest whose underside clears the joist; when
none gives a plan, ``CrossingError`` says which leg is stuck where.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.plugins.gaits.swing import progress


class CrossingError(RuntimeError):
    """No crossing fits: the joist is too high or too wide for this robot's legs."""


@dataclass(frozen=True)
class Bar:
    """A joist in the crossing frame: near face x (m), depth along x (m), height (m)."""

    face: float
    width: float
    height: float


@dataclass(frozen=True)
class CrossingGeometry:
    """The bars to cross, in order, and the body's half length (m)."""

    bars: tuple[Bar, ...]
    half_length: float


@dataclass(frozen=True)
class CrossingParams:
    """Clearances (m), body heights (m), step lengths (m) and timing (s, m/s) of the crossing.

    ``landing_height`` (m): where a swing ends above the floor. Position servos sag under load
    (an AX-18A stance leg about 3 mm), so a foot sent to the floor lands that much lower than
    the standing ones and jacks the body up: through the driver on Table 2 test 2 that lifted
    three feet and the robot slid 1 cm. 3 mm fixes that run but leaves the in-process row of
    three unfinished in 420 s, so the default stays 0. ``slip_recovery``: a plan that starts
    inside a margin first shifts the body out of it (``_recovery``); off by default, since
    through the driver it turned Table 2 test 5 from a clean crossing into a tibia touch.
    ``tolerance`` (m): how much every margin keeps beyond its limit in the plan, so that the
    body found that much off the planned pose (perception's noise, servo lag) still fits it;
    a phase that starts nearer a limit may not go nearer."""

    foot_margin: float
    clearance: float
    leg_radius: float
    support_margin: float
    body_clearance: float
    body_half_height: float
    climb_heights: tuple[float, ...]
    step_height: float
    reach: float
    lead: float
    body_speed: float
    foot_speed: float
    swing_time: float
    shift_time: float
    touchdown_time: float
    exit_distance: float
    landing_height: float
    slip_recovery: bool
    tolerance: float


class LegChains:
    """Batched coxa–femur–tibia kinematics: reachability and joint positions for many poses.

    Same convention and knee branch as daemon/algorithms/kinematics.py (whose ``ik`` works on one
    pose); used to check phases, where hundreds of candidate poses are checked at once.
    """

    def __init__(self, kin: Kinematics) -> None:
        if not kin.cft.all():
            raise CrossingError("joist crossing: needs coxa–femur–tibia legs")
        self.kin = kin
        self.cos, self.sin = np.cos(kin.yaw), np.sin(kin.yaw)
        shape = (kin.n_legs, 3)
        self.lower = kin.lower.reshape(shape)
        self.upper = kin.upper.reshape(shape)
        self.direction = kin.direction.reshape(shape)
        self.zero = kin.zero_offset.reshape(shape)

    def solve(self, feet: np.ndarray, joints: bool = True, legs=slice(None)):
        """For body-frame feet (..., k, 3) of ``legs`` (all by default): reachable mask (..., k),
        femur joints and knees (None unless ``joints``)."""
        k = self.kin
        mount, cos, sin = k.mount[legs], self.cos[legs], self.sin[legs]
        l1, l2, l3, sign = k.l1[legs], k.l2[legs], k.l3[legs], k.knee_sign[legs]
        rel = feet - mount
        x = cos * rel[..., 0] + sin * rel[..., 1]
        y = -sin * rel[..., 0] + cos * rel[..., 1]
        z = rel[..., 2]
        gamma = np.arctan2(y, x)
        u = np.hypot(x, y) - l1
        c = (u * u + z * z - l2**2 - l3**2) / (2.0 * l2 * l3)
        ok = np.abs(c) <= 1.0
        beta = sign * np.arccos(np.clip(c, -1.0, 1.0))
        alpha = np.arctan2(z, u) - np.arctan2(l3 * np.sin(beta), l2 + l3 * np.cos(beta))
        theta = np.stack([gamma, alpha, beta], axis=-1)
        q = theta * self.direction[legs] + self.zero[legs]
        tol = 1e-9
        ok &= ((q >= self.lower[legs] - tol) & (q <= self.upper[legs] + tol)).all(axis=-1)
        if not joints:
            return ok, None, None
        r = l1 + l2 * np.cos(alpha)
        cg, sg = np.cos(gamma), np.sin(gamma)

        def to_body(radial: np.ndarray, height: np.ndarray) -> np.ndarray:
            lx, ly = radial * cg, radial * sg
            bx = cos * lx - sin * ly + mount[:, 0]
            by = sin * lx + cos * ly + mount[:, 1]
            return np.stack([bx, by, height + mount[:, 2]], axis=-1)

        femur = to_body(np.broadcast_to(l1, r.shape), np.zeros_like(r))
        knee = to_body(r, l2 * np.sin(alpha))
        return ok, femur, knee


def support_margin(feet: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Signed distance (m) of ``point`` (..., 2) inside the convex polygon of ``feet`` (..., k, 2).

    The feet are ordered by angle about their centroid, so they must form a convex polygon
    (support feet of a hexapod do); negative outside.
    """
    centre = feet.mean(axis=-2, keepdims=True)
    ang = np.arctan2(feet[..., 1] - centre[..., 1], feet[..., 0] - centre[..., 0])
    order = np.argsort(ang, axis=-1)
    ring = np.take_along_axis(feet, order[..., None], axis=-2)
    nxt = np.roll(ring, -1, axis=-2)
    edge = nxt - ring
    length = np.maximum(np.hypot(edge[..., 0], edge[..., 1]), 1e-12)
    rel = point[..., None, :] - ring
    inside = (edge[..., 0] * rel[..., 1] - edge[..., 1] * rel[..., 0]) / length
    return inside.min(axis=-1)


def bar_gap(points: np.ndarray, bar: Bar) -> np.ndarray:
    """Distance (m) of ground-frame points (..., 3) from a bar's x–z section (0 inside)."""
    dx = np.maximum(np.maximum(bar.face - points[..., 0], points[..., 0] - bar.face - bar.width), 0)
    dz = np.maximum(points[..., 2] - bar.height, 0.0)
    return np.where(points[..., 2] <= bar.height, dx, np.hypot(dx, dz))


def corner_gap(a: np.ndarray, b: np.ndarray, bar: Bar) -> np.ndarray:
    """Least x–z distance (m) of a bar's two top edges from the links a→b (..., k, 3): what
    points sampled along a link can miss where it passes over an edge."""
    d = b[..., [0, 2]] - a[..., [0, 2]]
    length2 = np.maximum((d * d).sum(axis=-1), 1e-12)
    out = np.full(a.shape[:-2], np.inf)
    for x in (bar.face, bar.face + bar.width):
        rel = np.array([x, bar.height]) - a[..., [0, 2]]
        s = np.clip((rel * d).sum(axis=-1) / length2, 0.0, 1.0)
        near = rel - s[..., None] * d
        out = np.minimum(out, np.hypot(near[..., 0], near[..., 1]).min(axis=-1))
    return out


def waypoint_samples(paths: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """Points (C, T, 3) of C waypoint paths (C, W, 3) at swing fractions ``taus`` (T,): segments
    timed by length, at rest at each waypoint (quintic progress), as ``path_point`` for one."""
    seg = np.linalg.norm(np.diff(paths, axis=1), axis=2)
    edges = np.concatenate([np.zeros((len(paths), 1)), np.cumsum(seg, axis=1)], axis=1)
    edges /= np.maximum(edges[:, -1:], 1e-12)
    last = paths.shape[1] - 2
    k = np.clip((taus[None, :, None] >= edges[:, None, 1:-1]).sum(axis=2), 0, last)
    lo = np.take_along_axis(edges, k, axis=1)
    hi = np.take_along_axis(edges, k + 1, axis=1)
    local = progress(np.clip((taus[None, :] - lo) / np.maximum(hi - lo, 1e-12), 0.0, 1.0))
    a = np.take_along_axis(paths, k[..., None], axis=1)
    b = np.take_along_axis(paths, (k + 1)[..., None], axis=1)
    return a + local[..., None] * (b - a)


def segment_points(paths: np.ndarray, fractions: np.ndarray) -> np.ndarray:
    """Points (C, S·F, 3) at ``fractions`` (F,) of each of the S straight segments of C
    waypoint paths (C, S + 1, 3): every place a swing's foot passes, however it is timed."""
    a, b = paths[:, :-1, None, :], paths[:, 1:, None, :]
    points = a + fractions[None, None, :, None] * (b - a)
    return points.reshape(len(paths), -1, 3)


def path_point(path: np.ndarray, tau: float) -> np.ndarray:
    """Point of one waypoint path (W, 3) at ``tau`` ∈ [0, 1] (see ``waypoint_samples``)."""
    tau = float(np.clip(tau, 0.0, 1.0))
    return waypoint_samples(path[None], np.array([tau]))[0, 0]


@dataclass
class Move:
    """One phase of the plan: body from ``body0`` to ``body1`` (x, y, height) while the legs
    in ``paths`` follow their waypoints (ground frame); all other feet stay put."""

    duration: float
    body0: np.ndarray
    body1: np.ndarray
    feet0: np.ndarray
    paths: dict[int, np.ndarray] = field(default_factory=dict)

    def sample(self, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body (x, y, height), ground-frame feet (n×3) and stance flags at ``tau`` ∈ [0, 1]."""
        tau = float(np.clip(tau, 0.0, 1.0))
        body = self.body0 + float(progress(tau)) * (self.body1 - self.body0)
        feet = self.feet0.copy()
        stance = np.ones(len(feet), bool)
        for leg, path in self.paths.items():
            feet[leg] = path_point(path, tau)
            stance[leg] = tau >= 1.0
        return body, feet, stance


TAUS = np.linspace(0.0, 1.0, 17)
"""Instants (fraction of a phase) at which a candidate body move is checked."""
SEGMENT_FRACTIONS = np.linspace(0.0, 1.0, 9)
"""Points (fractions of each straight segment) at which a swing path is checked. Per segment,
not per instant of the swing: 17 instants left one or none on the short segment across the
apex, where a middle leg's femur peaks, and it passed its limit there by 0.01 rad."""
SLACK = 0.002
"""Added (m) to the legs' clearance from a bar, for the motion between checked instants."""
ADVANCES = np.arange(0.03, 0.0049, -0.005)
"""Candidate body advances (m) of one body move, longest first."""
FOOTHOLD_STEP = 0.005
"""Spacing (m) of candidate footholds along x."""
OVERSTEP = 0.06
"""How far (m) past its goal a foothold may be, e.g. when the goal lies on a bar."""
LOOK_AHEAD = 0.10
"""How far (m) ahead of its goal a bar makes a leg try to cross it."""
MIN_STEP = 0.01
"""Shortest forward step (m) worth a swing."""
RECOVERY_SHIFTS = np.array([-0.005, 0.005, -0.01, 0.01, -0.015, 0.015, -0.02, 0.02, -0.03, 0.03])
"""Candidate body shifts (m, along x, nearest first) out of a margin the robot slipped into."""
MAX_PHASES = 300
"""Bound on the phases of one plan (a crossing takes about 40)."""
SPREADS = np.array([0.0, 0.03, 0.06])
"""Candidate sideways spreads (m, outward) of a swinging foot at its apex."""
LINK_SAMPLES = np.linspace(0.0, 1.0, 7)[:, None]


@dataclass(frozen=True)
class Refusal:
    """A leg's refused swing: the best margin (m) its reachable candidate footholds keep, -inf
    when none is in reach, and the ``floor`` (m) a swing from that pose must keep."""

    margin: float
    floor: float


class CrossingPlan:
    """Builds and plays the free-gait crossing: ``sample(t)`` gives body, feet and stance.
    ``recovery`` is the body shift (m, along x) of its first move, backing out of a margin the
    robot slipped into or onto the place a re-anchored plan has it (0 when there is none)."""

    def __init__(
        self,
        geometry: CrossingGeometry,
        params: CrossingParams,
        kin: Kinematics,
        feet: np.ndarray,
        stand_height: float,
        height: float,
    ) -> None:
        """Plan from ground ``feet`` (n×3) under a body at (0, 0, ``height``); the plan ends
        with the body lowered to ``stand_height``."""
        self.g = geometry
        self.p = params
        self.chains = LegChains(kin)
        self.n = kin.n_legs
        self.stand_height = stand_height
        out = np.column_stack([np.cos(kin.yaw), np.sin(kin.yaw)])
        self.home = np.column_stack([kin.mount[:, :2] + params.reach * out, np.zeros(self.n)])
        errors = []
        for climb in self._heights(height):
            try:
                self.moves = self._build(np.array(feet, float), height, climb)
                break
            except CrossingError as e:
                errors.append(f"{climb:.3f} m: {e}")
        else:
            raise CrossingError("joist crossing: no body height works; " + "; ".join(errors))
        self.climb_height = climb
        self._play(self.moves)

    def _play(self, moves: list[Move]) -> None:
        """Make ``moves`` the plan that ``sample`` plays."""
        self.moves = moves
        self.duration = sum(m.duration for m in moves)
        self._starts = np.cumsum([0.0] + [m.duration for m in moves])

    def _heights(self, height: float) -> list[float]:
        """Climb heights to try: the lowest whose underside clears the target bar first."""
        p = self.p
        need = max(bar.height for bar in self.g.bars) + p.body_clearance + p.body_half_height
        return sorted({max(h, height) for h in p.climb_heights if h >= need}) or [need]

    # --- checks -------------------------------------------------------------------------

    def check(
        self,
        body: np.ndarray,
        feet: np.ndarray,
        stance: np.ndarray,
        legs=slice(None),
        bars: tuple[Bar, ...] | None = None,
    ) -> np.ndarray:
        """Worst margin (C,) over T instants of C candidates: body (C, T, 3) as (x, y, height),
        ground feet (C, T, n, 3), stance (n,); reach and clearance of ``legs`` only (the
        others stand still on a checked pose), from the plan's bars or ``bars``. Negative: a
        constraint is broken (-inf: unreachable)."""
        p = self.p
        moving = feet[:, :, legs]
        local = moving - body[:, :, None, :]
        ok, _, knee = self.chains.solve(local, legs=legs)
        # The chord from the coxa mount to the knee runs under the coxa and femur links.
        femur = np.broadcast_to(self.chains.kin.mount[legs], knee.shape)
        origin = body[:, :, None, :]
        joints = np.stack([femur + origin, knee + origin, moving], axis=3)
        a, b = joints[..., :-1, :], joints[..., 1:, :]
        pts = (a[..., None, :] + LINK_SAMPLES * (b - a)[..., None, :]).reshape(*a.shape[:3], -1, 3)
        margin = np.full(body.shape[:2], np.inf)
        underside = body[..., 2] - p.body_half_height
        for bar in self.g.bars if bars is None else bars:
            gap = np.minimum(bar_gap(pts, bar).min(axis=3), corner_gap(a, b, bar)).min(axis=2)
            gap = gap - p.leg_radius - SLACK
            margin = np.minimum(margin, gap)
            over = (body[..., 0] + self.g.half_length > bar.face - p.body_clearance) & (
                body[..., 0] - self.g.half_length < bar.face + bar.width + p.body_clearance
            )
            belly = np.where(over, underside - bar.height - p.body_clearance, np.inf)
            margin = np.minimum(margin, belly)
        support = support_margin(feet[:, :, stance, :2], body[..., :2]) - p.support_margin
        margin = np.minimum(margin, support)
        margin = np.where(ok.all(axis=2), margin, -np.inf)
        return margin.min(axis=1)

    def _free(self, x: np.ndarray) -> np.ndarray:
        """Footholds x (m) outside every bar's band widened by ``foot_margin``."""
        free = np.ones(x.shape, bool)
        for bar in self.g.bars:
            m = self.p.foot_margin
            free &= (x <= bar.face - m) | (x >= bar.face + bar.width + m)
        return free

    def _apex(self, start: np.ndarray, end: np.ndarray) -> np.ndarray:
        """Swing height (m) from feet ``start`` to ``end`` (C, 3): over every bar in between."""
        p = self.p
        apex = np.maximum(start[:, 2], end[:, 2]) + p.step_height
        lo = np.minimum(start[:, 0], end[:, 0]) - p.leg_radius
        hi = np.maximum(start[:, 0], end[:, 0]) + p.leg_radius
        for bar in self.g.bars:
            spans = (lo < bar.face + bar.width) & (hi > bar.face)
            apex = np.where(spans, np.maximum(apex, bar.height + p.clearance), apex)
        return apex

    def _swing_paths(self, start: np.ndarray, end: np.ndarray, spread: np.ndarray) -> np.ndarray:
        """Waypoints (C, 4, 3): up and ``spread`` (m, signed) sideways, across at the apex,
        down; spreading the foot out at the apex keeps the knee from folding past its limit."""
        apex = self._apex(start, end)
        paths = np.stack([start, start, end, end], axis=1)
        paths[:, 1:3, 2] = apex[:, None]
        paths[:, 1:3, 1] += spread[:, None]
        return paths

    # --- phases -------------------------------------------------------------------------

    def _try_body(
        self, body: np.ndarray, feet: np.ndarray, targets: np.ndarray, floor: float = 0.0
    ):
        """The first candidate body pose (rows of ``targets``) reachable by a checked move: its
        margins keep ``floor`` on the way, by default the tolerance or, from a start with less
        of it, no less than the start's. From a start that breaks a margin (``floor`` < 0),
        the move must end with every margin kept."""
        c = len(targets)
        path = body + progress(TAUS)[None, :, None] * (targets - body)[:, None, :]
        ground = np.broadcast_to(feet, (c, len(TAUS), self.n, 3))
        stance = np.ones(self.n, bool)
        if floor >= 0.0:
            floor = self._floor(path[:1, :1], ground[:1, :1], stance)
        good = self.check(path, ground, stance) >= floor
        if floor < 0.0:
            good &= self.check(path[:, -1:], ground[:, -1:], stance) >= 0.0
        good = np.flatnonzero(good)
        return targets[good[0]] if len(good) else None

    def _floor(self, body, feet, stance, legs=slice(None)) -> float:
        """The least margin a phase from this pose (1×1 instant) must keep: the tolerance, or
        what of it the pose has (a replan from a pose a drift carried into it: no worse)."""
        return min(self.p.tolerance, float(self.check(body, feet, stance, legs)[0]))

    def _recovery(self, body: np.ndarray, feet: np.ndarray) -> np.ndarray:
        """The body pose to plan from: ``body`` itself, or, when the robot has slipped into a
        margin (a link too near a bar), the nearest shift along x that backs out of it."""
        start = self.check(body[None, None], feet[None, None], np.ones(self.n, bool))[0]
        if start >= 0.0:
            return body
        if start == -np.inf:
            raise CrossingError("a standing foot is out of reach of its leg")
        shifts = np.zeros((len(RECOVERY_SHIFTS), 3))
        shifts[:, 0] = RECOVERY_SHIFTS
        target = self._try_body(body, feet, body + shifts, floor=start)
        if target is None:
            raise CrossingError(
                f"the start pose breaks a margin by {-start:.3f} m ({self._breach(body, feet)}) "
                f"and no body shift within {np.abs(RECOVERY_SHIFTS).max():.2f} m backs out of it"
            )
        return target

    def _breach(self, body: np.ndarray, feet: np.ndarray) -> str:
        """Which margin a standing pose breaks worst: a leg's links (its foot's own gap to the
        nearest bar given), or the support or body clearance shared by all."""
        stance = np.ones(self.n, bool)
        per_leg = [
            self.check(body[None, None], feet[None, None], stance, [i])[0] for i in range(self.n)
        ]
        worst = int(np.argmin(per_leg))
        if np.allclose(per_leg, per_leg[worst]):
            return "support or body clearance"
        foot = min(float(bar_gap(feet[worst], bar)) for bar in self.g.bars)
        name = self.chains.kin.leg_names[worst]
        return f"leg {name}, its foot {foot:.3f} m from a bar"

    def _try_swing(
        self, leg: int, body: np.ndarray, feet: np.ndarray, goal: float, y: float, cross: bool
    ):
        """The checked swing of ``leg`` to the free foothold nearest (``goal``, ``y``), or None.
        With ``cross`` it steps over the next bar ahead (and no other); without, it crosses no
        bar and must end nearer the goal."""
        start = feet[leg]
        ahead = [bar for bar in self.g.bars if bar.face > start[0]]
        over = ahead[0] if cross and ahead else None
        if over is not None:
            goal = max(goal, over.face + over.width + self.p.foot_margin)
        xs = np.arange(goal - OVERSTEP, goal + OVERSTEP + 1e-9, FOOTHOLD_STEP)
        keep = self._free(xs)
        if over is None and abs(y - start[1]) < MIN_STEP:
            keep &= np.abs(xs - goal) <= abs(start[0] - goal) - MIN_STEP
        for bar in self.g.bars:
            same_side = (xs < bar.face) == (start[0] < bar.face)
            keep &= ~same_side if bar is over else same_side
        xs = xs[keep]
        if not len(xs):
            return None
        side = np.sign(self.chains.kin.mount[leg, 1]) or 1.0
        spread = np.repeat(side * SPREADS, len(xs))
        xs = np.tile(xs, len(SPREADS))
        order = np.argsort(np.abs(xs - goal), kind="stable")
        xs, spread = xs[order], spread[order]
        end = np.tile(start, (len(xs), 1))
        end[:, 0], end[:, 1], end[:, 2] = xs, y, self.p.landing_height
        paths = self._swing_paths(np.tile(start, (len(xs), 1)), end, spread)
        swing = segment_points(paths, SEGMENT_FRACTIONS)
        samples = swing.shape[1]
        ground = np.repeat(np.broadcast_to(feet, (len(xs), self.n, 3))[:, None], samples, 1)
        ground = ground.copy()
        ground[:, :, leg] = swing
        stance = np.ones(self.n, bool)
        stance[leg] = False
        bodies = np.broadcast_to(body, (len(xs), samples, 3))
        local = (swing - bodies)[:, :, None, :]
        reach, _, _ = self.chains.solve(local, joints=False, legs=[leg])
        sel = np.flatnonzero(reach[..., 0].all(axis=1))
        if not len(sel):
            self.refused[leg] = Refusal(-np.inf, 0.0)
            return None
        margin = self.check(bodies[sel], ground[sel], stance, [leg])
        floor = self._floor(bodies[:1, :1], ground[:1, :1], stance, [leg])
        good = np.flatnonzero(margin >= floor)
        if not len(good):
            self.refused[leg] = Refusal(float(margin.max()), floor)
            return None
        return paths[sel[good[0]]]

    def _blocked(self, leg: int, body: np.ndarray, feet: np.ndarray, lead: float) -> bool:
        """Whether a bar lies between ``leg``'s foot and ``LOOK_AHEAD`` past its goal (home +
        ``lead``): then it tries to cross at every phase, so it finds the body's window."""
        goal = body[0] + self.home[leg, 0] + lead + LOOK_AHEAD
        return any(feet[leg, 0] < bar.face < goal for bar in self.g.bars)

    def _swing_first(self, legs, body, feet, lead, swing, cross=False) -> bool:
        """Swing the first of ``legs`` that has a checked swing towards home + ``lead``."""
        for leg in legs:
            goal = body[0] + self.home[leg, 0] + lead
            path = self._try_swing(leg, body, feet, goal, body[1] + self.home[leg, 1], cross)
            if path is not None:
                swing(leg, path)
                return True
        return False

    def _refusal(self, leg: int) -> str:
        """Why ``leg``'s last swing was refused, for the planner's error: how much of its
        margins the best reachable foothold keeps, or that none is in reach."""
        refusal = self.refused.get(leg)
        if refusal is None:
            return ""
        if refusal.margin == -np.inf:
            return ": no foothold in reach"
        return (
            f": its best foothold keeps {refusal.margin * 1000:.1f} mm of the "
            f"{refusal.floor * 1000:.1f} mm its margins need"
        )

    def _build(self, feet: np.ndarray, height: float, climb: float) -> list[Move]:
        g, p = self.g, self.p
        self.refused: dict[int, Refusal] = {}
        moves: list[Move] = []
        body = np.array([0.0, 0.0, height])
        last = max(g.bars, key=lambda bar: bar.face)
        goal = last.face + last.width + p.exit_distance - self.home[:, 0].min()

        def body_move(target: np.ndarray) -> None:
            nonlocal body
            span = float(np.abs(target - body).max())
            moves.append(Move(max(p.shift_time, span / p.body_speed), body, target, feet.copy()))
            body = target

        def swing(leg: int, path: np.ndarray) -> None:
            length = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
            duration = max(p.swing_time, length / p.foot_speed)
            moves.append(Move(duration, body, body, feet.copy(), {leg: path}))
            feet[leg] = path[-1]
            if p.touchdown_time > 0.0:
                # all six still while a foot late on its servos comes down: lifting the next
                # one then would rock the body on a foot that is not yet carrying it
                moves.append(Move(p.touchdown_time, body, body, feet.copy()))

        recovered = self._recovery(body, feet) if p.slip_recovery else body
        self.recovery = float(recovered[0] - body[0])
        if self.recovery:
            body_move(recovered)
        raised = np.array([body[0], body[1], climb])
        if abs(climb - body[2]) > 1e-6:
            if self._try_body(body, feet, raised[None]) is None:
                raise CrossingError(f"cannot raise the body to {climb:.3f} m")
            body_move(raised)
        homing = False
        for _ in range(MAX_PHASES):
            homing = homing or body[0] >= goal - 1e-6
            behind = feet[:, 0] - (body[0] + self.home[:, 0])
            wide = np.abs(feet[:, 1] - body[1] - self.home[:, 1]) > MIN_STEP
            behind = np.where(wide, np.minimum(behind, -1.0), behind)
            lead = 0.0 if homing else p.lead
            order = [int(i) for i in np.argsort(behind, kind="stable")]
            blocked = [i for i in order if self._blocked(i, body, feet, lead)]
            if self._swing_first(blocked, body, feet, lead, swing, cross=True):
                continue
            due = [i for i in order if behind[i] < -p.lead]
            if self._swing_first(due, body, feet, lead, swing):
                continue
            if not homing:
                steps = np.minimum(body[0] + ADVANCES, goal)
                targets = np.column_stack(
                    [steps, np.full_like(steps, body[1]), [climb] * len(steps)]
                )
                target = self._try_body(body, feet, targets)
                if target is not None and target[0] > body[0] + 1e-6:
                    body_move(target)
                    continue
            # A leg waits to cross and the body cannot advance: set the others at home, the
            # support it needs to swing.
            off = [i for i in order if abs(behind[i]) > MIN_STEP]
            if blocked and self._swing_first(off, body, feet, 0.0, swing):
                continue
            off = np.abs(behind) > MIN_STEP
            rest = [int(i) for i in np.argsort(-np.abs(behind), kind="stable") if off[i]]
            if self._swing_first(rest, body, feet, 0.0, swing):
                continue
            if homing:
                break
            stuck = (blocked or order)[0]
            raise CrossingError(
                f"stuck at body x {body[0]:.3f} m (leg {self.chains.kin.leg_names[stuck]} "
                f"cannot step{self._refusal(stuck)}, the body cannot advance) over a "
                f"{last.height:.3f} m joist"
            )
        else:
            raise CrossingError(f"no crossing within {MAX_PHASES} phases")
        lowered = np.array([body[0], body[1], self.stand_height])
        if self._try_body(body, feet, lowered[None]) is None:
            raise CrossingError(f"cannot lower the body to {self.stand_height:.3f} m")
        body_move(lowered)
        return moves

    # --- playing ----------------------------------------------------------------------

    def margin(self, bars: tuple[Bar, ...], phase: int) -> float:
        """Worst margin (m) of the moves from ``phase`` on with the joists at ``bars`` (the
        plan's frame) instead of where they were planned: the plan's tolerance to where the
        robot finds itself. Negative: a constraint the plan was built to keep is broken."""
        worst = np.inf
        for move in self.moves[phase:]:
            if move.paths:
                leg, path = next(iter(move.paths.items()))
                swing = segment_points(path[None], SEGMENT_FRACTIONS)
                ground = np.repeat(move.feet0[None, None], swing.shape[1], axis=1)
                ground[:, :, leg] = swing
                stance = np.ones(self.n, bool)
                stance[leg] = False
                body = np.broadcast_to(move.body0, (1, swing.shape[1], 3))
            else:
                body = (move.body0 + progress(TAUS)[:, None] * (move.body1 - move.body0))[None]
                ground = np.broadcast_to(move.feet0, (1, len(TAUS), self.n, 3))
                stance = np.ones(self.n, bool)
            worst = min(worst, float(self.check(body, ground, stance, bars=bars)[0]))
        return worst

    def reanchored(
        self, bars: tuple[Bar, ...], phase: int, geometry: CrossingGeometry
    ) -> CrossingPlan | None:
        """The rest of this plan from ``phase`` kept on the joists where the body now finds them
        (``bars`` in this plan's frame, ``geometry`` the same seen from the body: the new plan's
        frame), or None when that breaks a margin. The body first moves back onto its planned
        place relative to the joists; the later moves go with the joists, each leg's next
        swing lifting from where its foot stands and clearing the joists' new heights. A plan
        from scratch at a mid-crossing pose often finds none where the old one still works."""
        if len(bars) != len(self.g.bars):
            return None
        shift = float(np.mean([b.face - a.face for a, b in zip(self.g.bars, bars, strict=True)]))
        start = self.moves[phase]
        origin = np.array([start.body0[0], start.body0[1], 0.0])
        along = np.array([shift, 0.0, 0.0])
        standing = start.feet0 - origin
        plan = copy.copy(self)
        plan.g = geometry
        plan.recovery = shift
        moves = []
        if abs(shift) > 1e-6:
            duration = max(self.p.shift_time, abs(shift) / self.p.body_speed)
            body = start.body0 - origin
            moves.append(Move(duration, body, body + along, standing.copy()))
        unmoved = set(range(self.n))
        for move in self.moves[phase:]:
            feet = move.feet0 - origin + along
            for leg in unmoved:
                feet[leg] = standing[leg]
            paths = {}
            for leg, path in move.paths.items():
                path = path - origin + along
                if leg in unmoved:
                    path[:2, :2] += standing[leg, :2] - path[0, :2]
                    unmoved.discard(leg)
                apex = plan._apex(path[:1], path[-1:])[0]
                path[1:3, 2] = np.maximum(path[1:3, 2], apex)
                paths[leg] = path
            body0, body1 = move.body0 - origin + along, move.body1 - origin + along
            moves.append(Move(move.duration, body0, body1, feet, paths))
        plan._play(moves)
        return plan if plan.margin(geometry.bars, 0) >= 0.0 else None

    def phase(self, t: float) -> int:
        """Index of the phase playing ``t`` s into the plan."""
        k = np.searchsorted(self._starts, t, side="right") - 1
        return int(np.clip(k, 0, len(self.moves) - 1))

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body (x, y, height), ground-frame feet and stance flags ``t`` s into the plan."""
        k = self.phase(t)
        move = self.moves[k]
        return move.sample((t - self._starts[k]) / move.duration)
