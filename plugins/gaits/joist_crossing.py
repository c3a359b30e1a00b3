"""The joist crossing of paper 000 (Figure 8) as a timed plan of body moves and leg swings.

Everything is planned in a ground frame whose x axis is the joist's normal (the robot has
already turned square to it): the near face is the line ``x = face``, the far face
``face + width``, the top at ``height`` above the floor (z = 0). Pairs cross, front, middle,
back: both legs of a pair swing over the joist through waypoints (up before the near face,
over, down past the far face) while the body leans forward, i.e. moves ahead on the other four
feet. Before each pair the body advances in tripod cycles (one group of three legs steps, then
the other, then the body moves) with footholds kept out of the joist's band, and the other
feet are set ahead of or behind their home so they stay in reach and under the body. Where the
pair starts, how far and when the body leans, its height and where the feet land are searched
over a grid: every leg must stay reachable (the profile's kinematics, batched), the swinging
legs' femur, tibia and foot must keep ``leg_radius`` off the joist, the body centre must stay
inside the other feet's support polygon, and the body's underside must clear the joist when it
is over it. When no candidate passes, ``CrossingError`` says which pair could not cross.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from daemon.kinematics import Kinematics
from plugins.gaits.swing import lift, progress


class CrossingError(RuntimeError):
    """No crossing fits: the joist is too high or too wide for this robot's legs."""


@dataclass(frozen=True)
class CrossingGeometry:
    """The joist (ground frame, m) and the robot's stand: home feet relative to the body."""

    face: float
    width: float
    height: float
    home: np.ndarray
    half_length: float
    pairs: tuple[tuple[int, ...], ...]
    groups: tuple[tuple[int, ...], ...]


@dataclass(frozen=True)
class CrossingParams:
    """Clearances (m) and timing (s) of the crossing."""

    foot_margin: float
    clearance: float
    leg_radius: float
    support_margin: float
    body_clearance: float
    body_half_height: float
    high_body: float
    stride: float
    step_height: float
    swing_time: float
    step_time: float
    shift_time: float
    exit_distance: float


class LegChains:
    """Batched coxa–femur–tibia kinematics: reachability and joint positions for many poses.

    Same convention and knee branch as daemon/kinematics.py (whose ``ik`` works on one pose);
    used to search crossings, where thousands of candidate poses are checked at once.
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

    def solve(self, feet: np.ndarray, joints: bool = True):
        """For body-frame feet (..., n, 3): reachable mask (..., n), femur joints and knees
        (None unless ``joints``)."""
        k = self.kin
        rel = feet - k.mount
        x = self.cos * rel[..., 0] + self.sin * rel[..., 1]
        y = -self.sin * rel[..., 0] + self.cos * rel[..., 1]
        z = rel[..., 2]
        gamma = np.arctan2(y, x)
        u = np.hypot(x, y) - k.l1
        c = (u * u + z * z - k.l2**2 - k.l3**2) / (2.0 * k.l2 * k.l3)
        ok = np.abs(c) <= 1.0
        beta = k.knee_sign * np.arccos(np.clip(c, -1.0, 1.0))
        alpha = np.arctan2(z, u) - np.arctan2(k.l3 * np.sin(beta), k.l2 + k.l3 * np.cos(beta))
        theta = np.stack([gamma, alpha, beta], axis=-1)
        q = theta * self.direction + self.zero
        tol = 1e-9
        ok &= ((q >= self.lower - tol) & (q <= self.upper + tol)).all(axis=-1)
        if not joints:
            return ok, None, None
        r = k.l1 + k.l2 * np.cos(alpha)
        cg, sg = np.cos(gamma), np.sin(gamma)

        def to_body(radial: np.ndarray, height: np.ndarray) -> np.ndarray:
            lx, ly = radial * cg, radial * sg
            bx = self.cos * lx - self.sin * ly + k.mount[:, 0]
            by = self.sin * lx + self.cos * ly + k.mount[:, 1]
            return np.stack([bx, by, height + k.mount[:, 2]], axis=-1)

        femur = to_body(np.broadcast_to(k.l1, r.shape), np.zeros_like(r))
        knee = to_body(r, k.l2 * np.sin(alpha))
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


def joist_gap(points: np.ndarray, face: float, width: float, height: float) -> np.ndarray:
    """Distance (m) of ground-frame points (..., 3) from the joist's x–z section (0 inside)."""
    dx = np.maximum(np.maximum(face - points[..., 0], points[..., 0] - face - width), 0.0)
    dz = np.maximum(points[..., 2] - height, 0.0)
    inside_z = points[..., 2] <= height
    return np.where(inside_z, dx, np.hypot(dx, dz))


@dataclass
class Move:
    """One segment of the plan: body from ``body0`` to ``body1`` (x, y, height) while the legs
    in ``paths`` follow their waypoints (ground frame); all other feet stay put."""

    duration: float
    body0: np.ndarray
    body1: np.ndarray
    feet0: np.ndarray
    paths: dict[int, np.ndarray] = field(default_factory=dict)
    hop: float = 0.0
    lean_from: float = 0.0

    def sample(self, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body (x, y, height), ground-frame feet (n×3) and stance flags at ``tau`` ∈ [0, 1]."""
        s = float(body_progress(np.asarray(tau), self.lean_from))
        body = self.body0 + s * (self.body1 - self.body0)
        feet = self.feet0.copy()
        stance = np.ones(len(feet), bool)
        for leg, path in self.paths.items():
            feet[leg] = path_point(path, tau, self.hop)
            stance[leg] = tau >= 1.0
        return body, feet, stance


def body_progress(tau: np.ndarray, start: np.ndarray | float) -> np.ndarray:
    """Quintic progress of the body over a swing that begins moving at ``start`` ∈ [0, 1)."""
    return progress(np.clip((tau - start) / np.maximum(1.0 - start, 1e-9), 0.0, 1.0))


def path_point(path: np.ndarray, tau: float, hop: float = 0.0) -> np.ndarray:
    """Point of a waypoint path at ``tau``: segments timed by length, at rest at each waypoint
    (quintic progress); a two-point path with ``hop`` > 0 is a step lifted by ``hop``."""
    tau = float(np.clip(tau, 0.0, 1.0))
    if hop > 0.0:
        p = path[0] + float(progress(tau)) * (path[-1] - path[0])
        p[2] += hop * float(lift(tau))
        return p
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    total = seg.sum()
    if total <= 0:
        return path[-1].copy()
    edges = np.concatenate([[0.0], np.cumsum(seg) / total])
    k = min(int(np.searchsorted(edges, tau, side="right")) - 1, len(seg) - 1)
    local = (tau - edges[k]) / max(edges[k + 1] - edges[k], 1e-12)
    return path[k] + float(progress(local)) * (path[k + 1] - path[k])


SEARCH_AHEAD = np.arange(-0.39, 0.201, 0.03)
"""Candidate distances (m) of the near face ahead of a crossing leg's home at swing start."""
SEARCH_LEAN = np.arange(0.0, 0.201, 0.04)
"""Candidate body travel (m) during one leg's swing: how far the body leans forward."""
SEARCH_LAND = np.array([0.02, 0.04, 0.06])
"""Candidate landing distances (m) past the far face."""
SEARCH_RESERVE = np.arange(-0.08, 0.081, 0.04)
"""Candidate forward offsets (m) of the other feet's footholds before a swing, so they stay
within reach while the body leans."""
SEARCH_TAUS = np.linspace(0.0, 1.0, 11)
COARSE = np.array([0.0, 0.3, 0.6, 1.0])
"""Instants (swing fraction) of the pruning pass of the search."""
TOUCH = 0.01
"""Height (m) under which a landing foot counts as support in the stability check."""


def swing_points(
    start: np.ndarray, near: float, far: float, top: float, land_x: np.ndarray, taus: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Crossing-swing samples (C, T, 3) for C start feet (C, 3) and landings (C,): up to the
    near face at ``top``, over to past the far face, down; as ``path_point`` does for one.
    Also the fraction of each swing at which the foot is up before the near face."""
    c = len(start)
    path = np.empty((c, 4, 3))
    path[:, 0] = start
    path[:, 1, 0] = np.maximum(start[:, 0], near)
    path[:, 2, 0] = np.maximum(far, land_x)
    path[:, 3, 0] = land_x
    path[:, 1:, 1] = start[:, 1:2]
    path[:, 1:3, 2] = top
    path[:, 3, 2] = 0.0
    seg = np.linalg.norm(np.diff(path, axis=1), axis=2)
    edges = np.concatenate([np.zeros((c, 1)), np.cumsum(seg, axis=1)], axis=1)
    edges /= np.maximum(edges[:, -1:], 1e-12)
    k = np.clip((taus[None, :, None] >= edges[:, None, 1:3]).sum(axis=2), 0, 2)
    lo = np.take_along_axis(edges, k, axis=1)
    hi = np.take_along_axis(edges, k + 1, axis=1)
    local = progress(np.clip((taus[None, :] - lo) / np.maximum(hi - lo, 1e-12), 0.0, 1.0))
    a = np.take_along_axis(path, k[..., None], axis=1)
    b = np.take_along_axis(path, (k + 1)[..., None], axis=1)
    return a + local[..., None] * (b - a), edges[:, 1]


class CrossingPlan:
    """Builds and plays the crossing: ``sample(t)`` gives body, feet and stance at time t."""

    def __init__(
        self,
        geometry: CrossingGeometry,
        params: CrossingParams,
        kin: Kinematics,
        feet: np.ndarray,
        height: float,
    ) -> None:
        self.g = geometry
        self.p = params
        self.chains = LegChains(kin)
        self.moves: list[Move] = []
        self.body = np.array([0.0, 0.0, height])
        self.stand_height = height
        self.feet = np.array(feet, float)
        self.crossed = np.zeros(len(feet), bool)
        self.climb_height = max(
            height, geometry.height + params.body_clearance + params.body_half_height
        )
        self._build()
        self.duration = sum(m.duration for m in self.moves)
        self._starts = np.cumsum([0.0] + [m.duration for m in self.moves])

    # --- planning ---------------------------------------------------------------------

    def _zone_clip(self, leg: int, point: np.ndarray) -> np.ndarray:
        """A foothold moved out of the joist band: before it until the leg crosses, after it."""
        g, p = self.g, self.p
        out = point.copy()
        if self.crossed[leg]:
            out[0] = max(out[0], g.face + g.width + p.foot_margin)
        else:
            out[0] = min(out[0], g.face - p.foot_margin)
        out[2] = 0.0
        return out

    def _body_move(self, target: np.ndarray, duration: float) -> None:
        if np.allclose(target, self.body, atol=1e-6):
            return
        self.moves.append(Move(duration, self.body.copy(), target.copy(), self.feet.copy()))
        self.body = target.copy()

    def _step_group(self, legs: tuple[int, ...], body_x: float) -> None:
        """Legs of one tripod group step together to their footholds for body x ``body_x``."""
        paths = {}
        for leg in legs:
            home = np.array([body_x, self.body[1], 0.0]) + self.g.home[leg]
            target = self._zone_clip(leg, home)
            if np.linalg.norm(target - self.feet[leg]) > 1e-3:
                paths[leg] = np.array([self.feet[leg], target])
        if not paths:
            return
        move = Move(self.p.step_time, self.body.copy(), self.body.copy(), self.feet.copy())
        move.paths, move.hop = paths, self.p.step_height
        self.moves.append(move)
        for leg, path in paths.items():
            self.feet[leg] = path[-1]

    def _advance_to(self, body_x: float) -> None:
        """Tripod cycles: each group steps towards the next body position, then the body moves."""
        while self.body[0] < body_x - 1e-6:
            nxt = min(body_x, self.body[0] + self.p.stride)
            for group in self.g.groups:
                self._step_group(group, nxt)
            target = self.body.copy()
            target[0] = nxt
            self._body_move(target, self.p.shift_time)
        for group in self.g.groups:
            self._step_group(group, self.body[0])

    def _swing_path(self, start: np.ndarray, land_x: float) -> np.ndarray:
        """Waypoints of a crossing swing: up before the near face, over, down past the far face."""
        g, p = self.g, self.p
        top = g.height + p.clearance
        near = g.face - p.leg_radius
        far = g.face + g.width + p.leg_radius
        land = np.array([land_x, start[1], 0.0])
        return np.array(
            [start, [max(start[0], near), start[1], top], [max(far, land_x), start[1], top], land]
        )

    def _footholds(self, body_x: np.ndarray, reserve: np.ndarray, legs: tuple[int, ...]):
        """Zone-clipped footholds (C, n, 3): ``legs`` at home for body x ``body_x``, the other
        feet ``reserve`` ahead of home."""
        g, p = self.g, self.p
        feet = np.zeros((len(body_x), len(g.home), 3))
        feet[..., 0] = body_x[:, None] + g.home[None, :, 0] + reserve[:, None]
        feet[:, list(legs), 0] -= reserve[:, None]
        feet[..., 1] = self.body[1] + g.home[None, :, 1]
        before = g.face - p.foot_margin
        after = g.face + g.width + p.foot_margin
        crossed = self.crossed[None, :]
        feet[..., 0] = np.where(
            crossed, np.maximum(feet[..., 0], after), np.minimum(feet[..., 0], before)
        )
        return feet

    def _search(self, legs: tuple[int, ...]) -> tuple[float, ...]:
        """Best (margin, body x, lean, landing x, reserve, height, lean start) for ``legs``.

        All of ``legs`` swing together while the body leans. The margin is the least of: the
        clearance (m) of their femurs, tibias and feet from the joist beyond ``leg_radius``,
        and the distance of the body centre inside the support polygon of the other feet less
        ``support_margin``; −inf when any leg cannot reach a sampled pose.
        """
        g, p = self.g, self.p
        heights = np.unique([self.body[2], self.climb_height, max(self.climb_height, p.high_body)])
        grid = np.array(
            np.meshgrid(
                SEARCH_AHEAD,
                SEARCH_LEAN,
                SEARCH_LAND,
                SEARCH_RESERVE,
                heights,
                [0.0, 1.0],
                indexing="ij",
            )
        ).reshape(6, -1)
        body_x = g.face - grid[0] - max(g.home[i][0] for i in legs)
        lean, land_x, reserve, height = grid[1], g.face + g.width + grid[2], grid[3], grid[4]
        # The body's underside must clear the joist whenever the body is over it.
        low = height - p.body_half_height < g.height + p.body_clearance
        span = (body_x + lean + g.half_length > g.face - p.body_clearance) & (
            body_x - g.half_length < g.face + g.width + p.body_clearance
        )
        keep = ~(low & span) & (body_x >= self.body[0] - 1e-9)
        grid, body_x = grid[:, keep], body_x[keep]
        lean, land_x, reserve, height = lean[keep], land_x[keep], reserve[keep], height[keep]
        lean_from = grid[5]
        # Reachability at a few instants prunes most candidates before the full check.
        ok, _ = self._evaluate(legs, body_x, lean, land_x, reserve, height, lean_from, COARSE, True)
        sel = np.flatnonzero(ok)
        body_x, lean, land_x = body_x[sel], lean[sel], land_x[sel]
        reserve, height, lean_from = reserve[sel], height[sel], lean_from[sel]
        ok, score = self._evaluate(legs, body_x, lean, land_x, reserve, height, lean_from)
        score = np.where(ok, score, -np.inf)
        # Enough margin first, then the calmest move: least lean, reserve, landing distance.
        good = score >= 0.0
        order = np.lexsort((self._lean_start, height, land_x, reserve, lean, ~good))
        i = order[0] if len(order) else None
        if i is None or not good[i]:
            names = [self.chains.kin.leg_names[j] for j in legs]
            raise CrossingError(
                f"joist crossing: legs {names} cannot swing over a {g.height:.3f} m joist "
                f"with {p.clearance:.3f} m clearance and a stable body"
            )
        values = (score, body_x, lean, land_x, reserve, height, self._lean_start)
        return tuple(float(v[i]) for v in values)

    def _evaluate(
        self, legs, body_x, lean, land_x, reserve, height, delayed, taus=None, reach_only=False
    ):
        """Reachability (C,) and margin (C,) of candidate swings sampled at ``taus``.

        The margin is the least of the legs' clearance from the joist beyond ``leg_radius``
        and the body centre's distance inside the other feet's support less
        ``support_margin``. Sets ``_lean_start``: when each candidate's body starts to lean.
        """
        g, p = self.g, self.p
        taus = SEARCH_TAUS if taus is None else taus
        feet = self._footholds(body_x, reserve, legs)
        near, far = g.face - p.leg_radius, g.face + g.width + p.leg_radius
        ground = np.repeat(feet[:, None], len(taus), axis=1)
        for leg in legs:
            ground[:, :, leg], up = swing_points(
                feet[:, leg], near, far, g.height + p.clearance, land_x, taus
            )
        # The body leans from the start of the swing, or once the foot is up (delayed).
        self._lean_start = up * delayed if legs else np.zeros_like(body_x)
        body = np.zeros((len(body_x), len(taus), 3))
        body[..., 0] = (
            body_x[:, None]
            + body_progress(taus[None, :], self._lean_start[:, None]) * lean[:, None]
        )
        body[..., 1] = self.body[1]
        body[..., 2] = height[:, None]
        local = ground - body[:, :, None, :]
        ok, femur, knee = self.chains.solve(local, joints=not reach_only)
        if reach_only:
            return ok.all(axis=(1, 2)), None
        idx = list(legs)
        links = np.linspace(0.0, 1.0, 7)[None, None, None, :, None]
        f, k, t = femur[:, :, idx, None], knee[:, :, idx, None], local[:, :, idx, None]
        pts = np.concatenate([f + links * (k - f), k + links * (t - k)], axis=3)
        pts = pts + body[:, :, None, None, :]
        gap = joist_gap(pts, g.face, g.width, g.height).min(axis=(1, 2, 3)) - p.leg_radius
        support = [i for i in range(len(g.home)) if i not in legs]
        margin = support_margin(ground[:, :, support, :2], body[..., :2])
        # Once the swinging feet are within TOUCH of the floor they carry the body too.
        landing = (ground[:, :, idx, 2] <= TOUCH).all(axis=2) & (taus[None, :] > 0.5)
        margin = np.where(landing, np.inf, margin).min(axis=1)
        return ok.all(axis=(1, 2)), np.minimum(gap, margin - p.support_margin)

    def _restep(self, reserve: float, legs: tuple[int, ...]) -> None:
        """Tripod groups (without ``legs``) step to footholds ``reserve`` ahead of home."""
        target = self._footholds(np.array([self.body[0]]), np.array([reserve]), legs)[0]
        for group in self.g.groups:
            paths = {
                i: np.array([self.feet[i], target[i]])
                for i in group
                if i not in legs and np.linalg.norm(target[i] - self.feet[i]) > 1e-3
            }
            if paths:
                move = Move(self.p.step_time, self.body.copy(), self.body.copy(), self.feet.copy())
                move.paths, move.hop = paths, self.p.step_height
                self.moves.append(move)
                for i, path in paths.items():
                    self.feet[i] = path[-1]

    def _cross(self, legs: tuple[int, ...]) -> None:
        """Advance, set the other feet, and swing ``legs`` over the joist while the body leans."""
        _, body_x, lean, land_x, reserve, height, lean_from = self._search(legs)
        self._advance_to(body_x)
        target = self.body.copy()
        target[2] = height
        self._body_move(target, self.p.shift_time)
        self._restep(reserve, legs)
        end = self.body + np.array([lean, 0.0, 0.0])
        move = Move(self.p.swing_time, self.body.copy(), end, self.feet.copy())
        move.paths = {leg: self._swing_path(self.feet[leg], land_x) for leg in legs}
        move.lean_from = lean_from
        self.moves.append(move)
        self.body = end
        for leg in legs:
            self.feet[leg] = move.paths[leg][-1]
            self.crossed[leg] = True

    def _build(self) -> None:
        g, p = self.g, self.p
        for pair in g.pairs:
            self._cross(pair)
        beyond = g.face + g.width + p.exit_distance - g.home[:, 0].min()
        self._advance_to(max(beyond, self.body[0]))
        lowered = self.body.copy()
        lowered[2] = self.stand_height
        self._body_move(lowered, p.shift_time)

    # --- playing ----------------------------------------------------------------------

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body (x, y, height), ground-frame feet and stance flags ``t`` s into the plan."""
        if not self.moves:
            return self.body.copy(), self.feet.copy(), np.ones(len(self.feet), bool)
        k = int(np.clip(np.searchsorted(self._starts, t, side="right") - 1, 0, len(self.moves) - 1))
        move = self.moves[k]
        return move.sample((t - self._starts[k]) / move.duration)
