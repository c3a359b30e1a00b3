"""Stair gait parameters (paper 004, section 3.3): the leg-stair interference model, near/middle/
far areas per tread, each stance foot's feasible section of step length and step height, and
their intersection over the tripod, planned two steps ahead.

Geometry. The robot walks along the horizontal heading ``u`` of its plan frame (origin ``o``,
left ``v``, z up); ``s`` is the coordinate along ``u``. The stairs (a ``Stairs`` message,
odometry frame) become a piecewise-constant height profile along each foot's lane (the line
its foot walks on), treads bounded by the edges' crossings of that lane. The body's height and
pitch follow the terrain under it: a Hann-weighted line fit over the feet's span, so the body
rises along the flight (pitched with it) and levels on the landings, smoothly (C1).

Interference (eqs. 11-12). The shin is a cylinder (knee to foot centre, radius ``shin_radius``),
every stair edge a cylinder along the edge line (radius ``edge_radius``); they collide where the
distance between the axes is below the sum of the radii. Eq. 11 is the distance between the
infinite axes; where the common perpendicular's foot falls beyond the shin, the nearer shin end
is used instead (eq. 11 would flag the shin's extension past the knee or the foot). The foot
sphere is checked against the same edge cylinders. Knees follow the profile's knee type ("a":
knee above the hip-foot line, "b": below), so both types get their own interference.

Feasible sections. A tripod's next step has one step length ``L`` (foot travel) and one step
height ``h`` (swing apex above lift-off). For each foot, ``L`` is feasible when its landing lies
in the middle area of a tread (``area`` from both ends, 5 cm by default, widened where the shin
interferes), the leg reaches it within its joint limits and ``reach`` of its stand position
(horizontally), and
no shin or foot interference occurs at touch-down or at the end of its stance; ``h`` is feasible
from ``min_step_height`` above the highest tread the swing passes up to where the apex is still
reachable without interference. The tripod's sections are the intersections over its three feet;
the step after (the other tripod's) is planned at the same time, its swing included (a feasible
step height from where the first step leaves the body), and the pair with the longest joint
progress (then the most even) is chosen. The body advances half a step from one lift-off to the
next; with a transfer (both tripods down at the half cycle's start) a swing lands that much short
of the half step's end, and is checked there too.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import msgspec
import numpy as np

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.messages import Stairs
from climbd.daemon.contract.units import NonNegative, Positive

CANDIDATES = 4
"""Step pairs whose second swing the plan checks at a time, best first."""
WINDOW_SPAN = 1.5
"""The body's terrain fit spans this much more than the feet (paper 004's body follows the
flight's slope): over the feet's span alone, 150 mm rises pitch the body up so early that the
rear feet, still a tread below, leave the legs' reach (a walk up 150 × 320 mm stalls at 1.38 m)."""
ROW_LAYOUTS = 64
"""Row layouts (legs per configuration) whose batched kinematics a planner keeps."""


class StairGeometry(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """What the plan needs (SI). ``area``: near and far areas of a tread (paper 004: 5 cm);
    ``landing_margin``: planned footholds keep this much more, for the feet's tracking error;
    ``roll_margin``: and this much more from their tread's far end (along the walking
    direction): a sphere foot rolls that way while the body passes over it.
    ``shin_radius``, ``edge_radius``: the interference cylinders (eq. 12); ``shin_margin``:
    planned shins keep this much more from the edge cylinders, for the same error;
    ``foot_radius``:
    feet are placed by their centres. ``reach``: farthest a stance foot may be from its stand
    position (body frame, x y). ``min_step_height``/``max_step_height``/``height_resolution``:
    the step height's range and grid (the swing apex above the highest tread under the foot's
    path); ``resolution``: the step length's grid. ``body_height``: above the feet's centres
    (default: the profile's stand). ``max_pitch``: body pitch bound; ``window``: half-width of
    the terrain fit the body follows (default: ``WINDOW_SPAN`` × the feet's stand span along x)."""

    body_height: Positive | None = None
    area: NonNegative = 0.05
    landing_margin: NonNegative = 0.0
    roll_margin: NonNegative = 0.0
    shin_radius: Positive = 0.02
    edge_radius: NonNegative = 0.01
    shin_margin: NonNegative = 0.0
    foot_radius: NonNegative = 0.025
    reach: Positive = 0.2
    min_step_height: Positive = 0.05
    max_step_height: Positive = 0.25
    height_resolution: Positive = 0.02
    resolution: Positive = 0.02
    max_pitch: Positive = 0.5
    window: Positive | None = None


# --- the stair model along the walking line ------------------------------------------------


class StairModel:
    """Stairs along the walking line: per-lane height profile, tread areas, edge cylinders.

    ``lanes`` are lateral offsets (m, along ``v``) of the feet's lines; lane ``-1`` is appended
    for the body's centre line. Without steps the terrain is flat at ``ground``. Beyond the last
    tread seen the terrain is unknown: no foothold there.
    """

    def __init__(
        self,
        stairs: Stairs | None,
        origin: np.ndarray,
        yaw: float,
        lanes: np.ndarray,
        ground: float,
    ) -> None:
        self.origin = np.array([origin[0], origin[1], 0.0])
        self.yaw = float(yaw)
        self.u = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        self.v = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
        self.lanes = np.append(np.asarray(lanes, float), 0.0)
        steps = list(stairs.steps) if stairs is not None else []
        n_lanes = len(self.lanes)
        if not steps:
            self.bounds = np.zeros((n_lanes, 0))
            self.levels = np.array([ground])
            self.known = np.array([True])
            self.edge_point = np.zeros((0, 3))
            self.edge_dir = np.zeros((0, 3))
            self.edge_half = np.zeros(0)
            self.edge_axes, self.edge_coords = np.zeros((3, 0)), np.zeros(0)
            return
        ends = np.array([s.edge for s in steps], float)  # (K, 2, 3): left, right end
        heights = np.array([s.height for s in steps], float)
        floor = heights[0] - steps[0].rise
        side = ends[:, 0] - ends[:, 1]
        side /= np.linalg.norm(side, axis=1, keepdims=True)
        ascent = np.column_stack([side[:, 1], -side[:, 0], np.zeros(len(steps))])
        self.edge_point = 0.5 * (ends[:, 0] + ends[:, 1])
        self.edge_dir = side
        self.edge_half = 0.5 * np.linalg.norm(ends[:, 0] - ends[:, 1], axis=1)
        self.edge_axes, self.edge_coords = edge_frames(self.edge_point, self.edge_dir)
        # crossing of each edge line with each lane, in s
        rel = self.edge_point - self.origin
        ps, pl = rel @ self.u, rel @ self.v
        ds, dl = side @ self.u, side @ self.v
        if np.any(np.abs(dl) < 1e-6):
            raise ValueError("stairs: an edge runs along the walking direction (no crossing)")
        cross = ps[None, :] + (self.lanes[:, None] - pl[None, :]) / dl[None, :] * ds[None, :]
        # the last tread ends `depth` further along its ascent, measured along the heading
        cos_a = ascent[-1] @ self.u
        if abs(cos_a) < 1e-6:
            raise ValueError("stairs: the flight ascends across the walking direction")
        end = cross[:, -1] + steps[-1].depth / cos_a
        ascending = cos_a > 0
        if ascending:
            self.bounds = np.column_stack([cross, end])
            self.levels = np.array([floor, *heights, heights[-1]])
            self.known = np.array([True] * (len(steps) + 1) + [False])
        else:
            self.bounds = np.column_stack([end, cross[:, ::-1]])
            self.levels = np.array([heights[-1], *heights[::-1], floor])
            self.known = np.array([False] + [True] * (len(steps) + 1))
        if np.any(np.diff(self.bounds, axis=1) <= 0):
            raise ValueError("stairs: treads overlap along the walking line")

    # --- profile --------------------------------------------------------------------------

    def segment(self, lane: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Index of the segment (tread) under ``s`` on each ``lane`` (broadcast)."""
        s = np.asarray(s, float)
        return (s[..., None] >= self.bounds[lane]).sum(-1)

    def height(self, lane: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Terrain height (m) at ``s`` on ``lane``."""
        return self.levels[self.segment(lane, s)]

    def margin(self, lane: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Distance (m) from ``s`` to the nearer end of its tread; -1 on unknown terrain."""
        lane, s = np.broadcast_arrays(np.asarray(lane), np.asarray(s, float))
        seg = self.segment(lane, s)
        b = np.pad(self.bounds, ((0, 0), (1, 1)), constant_values=(-np.inf, np.inf))
        lo, hi = b[lane, seg], b[lane, seg + 1]
        m = np.minimum(s - lo, hi - s)
        return np.where(self.known[seg], m, -1.0)

    def swept_top(self, lane: np.ndarray, s0: np.ndarray, s1: np.ndarray) -> np.ndarray:
        """Highest terrain (m) between ``s0`` and ``s1`` on ``lane`` (a swing's path)."""
        lane, s0, s1 = np.broadcast_arrays(np.asarray(lane), s0, s1)
        a, b = self.segment(lane, np.minimum(s0, s1)), self.segment(lane, np.maximum(s0, s1))
        top = np.maximum(self.levels[a], self.levels[b])
        for k in range(len(self.levels)):
            inside = (a <= k) & (k <= b)
            top = np.where(inside, np.maximum(top, self.levels[k]), top)
        return top

    def clear_of_drop(
        self, lane: np.ndarray, s0: np.ndarray, s1: np.ndarray, clearance: float
    ) -> np.ndarray:
        """Where a swing from ``s0`` to ``s1`` on ``lane`` has passed the end of the last tread
        above its landing by ``clearance`` (at most ``s1``): a foot stepping down may descend
        from there, not only over its landing. ``s1`` where no tread on the path is higher
        (steps up or along a tread)."""
        lane, s0, s1 = np.broadcast_arrays(np.asarray(lane), s0, s1)
        a, b = self.segment(lane, s0), self.segment(lane, s1)
        landing = self.levels[b]
        forward = s1 >= s0
        bounds = np.pad(self.bounds, ((0, 0), (1, 1)), constant_values=(-np.inf, np.inf))
        edge = np.where(forward, -np.inf, np.inf)
        for k in range(len(self.levels)):
            above = self.levels[k] > landing
            ahead = above & forward & (a <= k) & (k < b)
            behind = above & ~forward & (b < k) & (k <= a)
            edge = np.where(ahead, np.maximum(edge, bounds[lane, k + 1]), edge)
            edge = np.where(behind, np.minimum(edge, bounds[lane, k]), edge)
        past = np.where(forward, np.minimum(edge + clearance, s1), np.maximum(edge - clearance, s1))
        return np.where(np.isfinite(edge), past, s1)

    def areas(self, lane: int, direction: float, area: float) -> list[tuple[float, float, float]]:
        """Known treads on ``lane`` as (start, end, level), start/end along the walking
        ``direction`` (+1/-1); each has a near and a far area of ``area`` at its ends."""
        b = np.concatenate([[-np.inf], self.bounds[lane], [np.inf]])
        out = [
            (float(b[k]), float(b[k + 1]), float(self.levels[k]))
            for k in range(len(self.levels))
            if self.known[k]
        ]
        if direction < 0:
            out = [(e, s, z) for s, e, z in reversed(out)]
        return out

    # --- the body over the terrain ----------------------------------------------------------

    def body_pose(self, s: np.ndarray, geometry: StairGeometry) -> tuple[np.ndarray, np.ndarray]:
        """Body height (m) and pitch (rad, + nose down) at body coordinates ``s``: the line fit
        of the centre line's terrain over ``window`` with Hann weights w = cos²(πx/2W), exact
        over the piecewise-constant profile (so height and pitch are C1 in ``s``); height above
        the fit by ``body_height`` plus the foot radius (feet are placed by their centres)."""
        s = np.asarray(s, float)
        half = geometry.window
        k = math.pi / half
        x = np.clip(self.bounds[-1] - s[..., None], -half, half)
        step = np.diff(self.levels)
        mean = self.levels[0] + (step * (_hann(half, k) - _hann(x, k))).sum(-1) / half
        moment = (step * (_hann_moment(half, k) - _hann_moment(x, k))).sum(-1)
        slope = moment / (half**3 * (1.0 / 3.0 - 2.0 / math.pi**2))
        pitch = np.clip(-np.arctan(slope), -geometry.max_pitch, geometry.max_pitch)
        return mean + geometry.foot_radius + geometry.body_height, pitch

    def body_frames(
        self, s: np.ndarray, geometry: StairGeometry, offset: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Body positions (n, 3) and rotations (n, 3, 3) at ``s``; ``offset`` adds
        (dz, d_roll, d_pitch) per row (the start's measured-vs-planned difference)."""
        s = np.atleast_1d(np.asarray(s, float))
        z, pitch = self.body_pose(s, geometry)
        roll = np.zeros_like(s)
        if offset is not None:
            z, roll, pitch = z + offset[..., 0], roll + offset[..., 1], pitch + offset[..., 2]
        pos = self.origin + s[:, None] * self.u
        pos[:, 2] = z
        return pos, rotations(self.yaw, roll, pitch)

    def to_plane(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(s, lateral) coordinates of global points."""
        rel = np.asarray(points, float) - self.origin
        return rel @ self.u, rel @ self.v

    def to_global(self, s: np.ndarray, lane_offset: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Global points from (s, lateral, z)."""
        out = self.origin + np.multiply.outer(s, self.u) + np.multiply.outer(lane_offset, self.v)
        out[..., 2] = z
        return out


def _hann(x, k: float):
    """Antiderivative of the Hann weight cos²(kx/2)."""
    return 0.5 * x + np.sin(k * x) / (2.0 * k)


def _hann_moment(x, k: float):
    """Antiderivative of x·cos²(kx/2)."""
    return 0.25 * x * x + x * np.sin(k * x) / (2.0 * k) + np.cos(k * x) / (2.0 * k * k)


def rotations(yaw: float, roll: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """Rz(yaw) @ Ry(pitch) @ Rx(roll) for arrays of roll and pitch, shape (n, 3, 3)."""
    cy, sy = math.cos(yaw), math.sin(yaw)
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    rot = np.empty((len(roll), 3, 3))
    rot[:, 0] = np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], 1)
    rot[:, 1] = np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], 1)
    rot[:, 2] = np.stack([-sp, cp * sr, cp * cr], 1)
    return rot


# --- the interference model (eqs. 11-12) -----------------------------------------------------


def edge_frames(edge_point: np.ndarray, edge_dir: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per edge two unit normals a, b and its direction e as the columns of one (3, 3E) matrix
    [a_1..a_E | b_1..b_E | e_1..e_E], and the edge centres' coordinates on them (3E,): a point
    projected by one matrix product lands in every edge's frame at once."""
    e = edge_dir / np.linalg.norm(edge_dir, axis=1, keepdims=True)
    ref = np.where(np.abs(e[:, 2:3]) < 0.9, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    a = np.cross(e, ref)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(e, a)
    axes = np.concatenate([a, b, e]).T
    coords = np.concatenate(
        [(a * edge_point).sum(1), (b * edge_point).sum(1), (e * edge_point).sum(1)]
    )
    return axes, coords


def in_edge_frames(points: np.ndarray, axes: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """Coordinates (3, E, n) of points (n, 3) from every edge's centre on its normals a, b and
    its direction e (``edge_frames``); edge-major, so each (E, n) block is contiguous."""
    return (axes.T @ points.T - coords[:, None]).reshape(3, len(coords) // 3, -1)


def axis_distance(knee: np.ndarray, foot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (E, n) between each shin axis (knee → foot) and each edge axis (eq. 11), and
    the position of the closest point along each edge from its centre (E, n); knee and foot
    as ``in_edge_frames`` gives them.

    Seen along an edge, its axis is a point and the shin a segment: the distance between the
    axes is the point's distance to the segment's line where the common perpendicular meets
    the shin, and to the nearer shin end past it. Computed over (E, n) arrays: the plan calls
    this on thousands of configurations.
    """
    (ka, kb, ke), (sa, sb, se) = knee, foot - knee
    ss = sa * sa + sb * sb
    parallel = ss < 1e-12
    t = np.where(parallel, 0.5, -(sa * ka + sb * kb) / np.where(parallel, 1.0, ss))
    t = np.minimum(np.maximum(t, 0.0), 1.0)
    da, db = ka + t * sa, kb + t * sb
    return np.sqrt(da * da + db * db), ke + t * se


def interferes(
    knee: np.ndarray, foot: np.ndarray, model: StairModel, geometry: StairGeometry
) -> np.ndarray:
    """Eq. 12 per configuration: the shin cylinder (widened by ``shin_margin``) or the foot
    sphere meets an edge cylinder."""
    if len(model.edge_point) == 0:
        return np.zeros(len(knee), bool)
    knee = in_edge_frames(knee, model.edge_axes, model.edge_coords)
    foot = in_edge_frames(foot, model.edge_axes, model.edge_coords)
    dist, along = axis_distance(knee, foot)
    half = model.edge_half[:, None]
    shin_reach = geometry.shin_radius + geometry.edge_radius + geometry.shin_margin
    shin = (dist < shin_reach) & (np.abs(along) <= half + geometry.shin_radius)
    fa, fb, on = foot
    foot_hit = (np.sqrt(fa * fa + fb * fb) < geometry.foot_radius + geometry.edge_radius) & (
        np.abs(on) <= half + geometry.foot_radius
    )
    return (shin | foot_hit).any(0)


# --- batched leg kinematics ------------------------------------------------------------------


def batched(kin: Kinematics, legs: np.ndarray) -> Kinematics:
    """A copy of ``kin`` whose rows are the legs ``legs`` (indices, repeats allowed): IK of
    many configurations at once with the daemon's own kinematics."""
    legs = np.asarray(legs, int)
    out = copy.copy(kin)
    out.n_legs, out.n_joints = len(legs), 3 * len(legs)
    for name in ("mount", "yaw", "rot", "cos_yaw", "sin_yaw", "l1", "l2", "l3", "cft"):
        setattr(out, name, getattr(kin, name)[legs])
    out.knee_sign = kin.knee_sign[legs]
    joints = (3 * legs[:, None] + np.arange(3)).ravel()
    for name in ("direction", "zero_offset", "lower", "upper", "_mid", "_half_range"):
        setattr(out, name, getattr(kin, name)[joints])
    out.all_cft = bool(out.cft.all())
    return out


def knees(kin: Kinematics, theta: np.ndarray) -> np.ndarray:
    """Knee positions (n, 3) in the body frame from kinematic angles (n, 3)."""
    a, b = theta[:, 0], theta[:, 1]
    r, rise = kin.l1 + kin.l2 * np.cos(b), kin.l2 * np.sin(b)
    cos_a, sin_a = np.cos(a), np.sin(a)
    forms = []  # (x, y, z) of coxa-femur-tibia legs, then of abduction-thigh-shank legs
    if kin.cft.any():
        forms.append((r * cos_a, r * sin_a, rise))
    if not kin.all_cft:
        forms.append((r, rise * sin_a, -rise * cos_a))
    if len(forms) == 2:
        forms = [[np.where(kin.cft, c, t) for c, t in zip(*forms, strict=True)]]
    return kin.to_body(np.column_stack(forms[0]))


def leg_checks(
    kin: Kinematics,
    home: np.ndarray,
    feet: np.ndarray,
    pos: np.ndarray,
    rot: np.ndarray,
    model: StairModel,
    geometry: StairGeometry,
    standing: np.ndarray | bool = False,
) -> np.ndarray:
    """Whether each configuration is usable: the row's leg (``kin`` batched) reaches the global
    foot centre ``feet`` from the body pose (``pos``, ``rot``) within its joint limits and
    ``reach`` of ``home`` (x y in the body's heading frame: horizontal, as the support polygon
    is; the body's pitch on a flight would otherwise count the foot's depth below it as reach),
    and neither shin nor foot meets an edge. Rows ``standing`` (a foot over where it stands,
    the body where it is) are exempt from ``reach``: stance feet follow the estimated body's
    lead, and a foot drifted millimetres past it must still be able to hold and lift off."""
    rel = feet - pos
    body = np.einsum("nji,nj->ni", rot, rel)
    heading = rot[:, :2, 0] / np.hypot(rot[:, 0, 0], rot[:, 1, 0])[:, None]
    ahead = heading[:, 0] * rel[:, 0] + heading[:, 1] * rel[:, 1]
    left = heading[:, 0] * rel[:, 1] - heading[:, 1] * rel[:, 0]
    near = standing | (np.hypot(ahead - home[:, 0], left - home[:, 1]) <= geometry.reach)
    theta, ok = kin.ik_leg(kin.to_leg(body))
    q = theta.reshape(-1) * kin.direction + kin.zero_offset
    inside = (np.abs(q - kin._mid) <= kin._half_range).reshape(-1, 3).all(1)
    good = near & ok & inside
    rows = np.flatnonzero(good)  # interference only where the leg reaches at all
    knee = pos[rows] + np.einsum("nij,nj->ni", rot[rows], knees(kin, theta)[rows])
    good[rows] = ~interferes(knee, feet[rows], model, geometry)
    return good


# --- the plan --------------------------------------------------------------------------------


@dataclass
class StepPlan:
    """The next two steps: tripod ``group`` steps ``length`` with step ``height`` (the swing
    apex above the highest tread under each foot's path), then the other tripod steps
    ``next_length``; ``landing`` are the swinging feet's new foot centres (global), ``apex``
    their swing apex heights (z), ``crossed`` the share of each foot's travel made at the apex
    (the rest descends to the landing: steps down leave the apex once past the drop's edge),
    ``sections`` the feasible step lengths (m) of the tripod."""

    group: np.ndarray
    length: float
    height: float
    next_length: float
    landing: np.ndarray
    apex: np.ndarray
    crossed: np.ndarray
    sections: np.ndarray
    blocked: bool


class StepPlanner:
    """Plans a tripod's next two steps over a StairModel (the paper's parameter computation)."""

    def __init__(self, kin: Kinematics, geometry: StairGeometry, transfer: float = 0.0) -> None:
        """``transfer``: the share of the half cycle both tripods stand at its start; the body
        moves half a step from one lift-off to the next, so a swing lands with the body
        ``transfer`` of that half step short of where the tripods change."""
        stand = kin.profile.stand
        height = geometry.body_height if geometry.body_height is not None else stand.body_height
        home = kin.stand_feet(height)
        span = float(np.abs(home[:, 0]).max())
        window = geometry.window if geometry.window is not None else WINDOW_SPAN * span
        self.kin = kin
        self.geometry = msgspec.structs.replace(geometry, body_height=height, window=window)
        self.home = home[:, :2]
        self.home_s = self.home[:, 0]
        self.transfer = transfer
        self.clearance = self.geometry.foot_radius + self.geometry.edge_radius
        self.clearance += self.geometry.shin_radius
        self._rows: dict[bytes, Kinematics] = {}

    def _batched(self, legs: np.ndarray) -> Kinematics:
        """``batched`` kinematics of the rows ``legs``, kept: a plan's row layouts repeat from
        one half cycle to the next (they depend on the tripod, the step grid and the batch)."""
        key = legs.tobytes()
        kin = self._rows.get(key)
        if kin is None:
            if len(self._rows) >= ROW_LAYOUTS:
                self._rows.clear()
            kin = self._rows[key] = batched(self.kin, legs)
        return kin

    def plan(
        self,
        model: StairModel,
        feet: np.ndarray,
        body_s: float,
        group: np.ndarray,
        direction: float,
        max_length: float,
    ) -> StepPlan:
        """Step lengths (this and the next step) and this step's height for ``group`` (leg
        indices, swinging now) from footholds ``feet`` (global foot centres, all legs) with the
        body at ``body_s``, walking ``direction`` (+1 forward / -1 backward along the heading).
        """
        g = self.geometry
        group = np.asarray(group, int)
        other = np.setdiff1d(np.arange(self.kin.n_legs), group)
        n = int(math.floor(max_length / g.resolution + 1e-9)) + 1
        lengths = np.arange(n) * g.resolution
        s_feet, lat = model.to_plane(feet)
        lanes = np.arange(self.kin.n_legs)
        # the far area widened by roll_margin: the margin at a point roll/2 further along
        half_roll = 0.5 * g.roll_margin
        middle = model.margin(lanes[:, None], s_feet[:, None] + direction * (lengths + half_roll))
        middle = middle >= g.area + g.landing_margin + half_roll
        # the body every quarter step along the walk: where each of this plan's checks puts it
        quarter = model.body_frames(body_s + direction * 0.25 * g.resolution * np.arange(4 * n), g)
        heights, apex, crossed, lift_ok = self._heights(
            model, feet, s_feet, lat, quarter, group, direction, middle[group].all(0)
        )
        # T[leg, m, j]: the leg's foot moved by lengths[m], the body by (m + j) half-steps;
        # checked only where it can matter: the swinging tripod's steps that land in middle
        # areas with a feasible swing, the other's that land in middle areas, and its hold
        need = np.zeros((len(lanes), n), bool)
        need[group] = lift_ok
        need[other] = middle[other].all(0)
        need[other, 0] = True
        rows = np.flatnonzero(np.repeat(need.ravel(), n))
        legs, m, j = rows // (n * n), rows // n % n, rows % n
        foot = self._moved(model, feet, s_feet, lat, legs, direction * lengths[m])
        pos, rot = quarter[0][2 * (m + j)], quarter[1][2 * (m + j)]
        ok = np.zeros(len(lanes) * n * n, bool)
        ok[rows] = leg_checks(
            self._batched(legs), self.home[legs], foot, pos, rot, model, g, (m == 0) & (j == 0)
        )
        ok = ok.reshape(len(lanes), n, n)
        # swinging tripod: lands in a middle area, fine at touch-down and at its stance's end
        touch = (ok[group][:, :, 0] & middle[group]).all(0)
        touch &= self._landing(model, feet, s_feet, lat, body_s, group, direction, lengths)
        stance_end = ok[group].all(0)
        # other tripod: holds until the body has moved L1/2, then lands after L2 with the body
        # at (L1 + L2)/2
        hold = ok[other][:, 0, :].all(0)
        land = (ok[other].transpose(0, 2, 1) & middle[other][:, None, :]).all(0)
        pair = touch[:, None] & stance_end & hold[:, None] & land  # pair[L1, L2]
        pair &= lift_ok[:, None]
        sections = lengths[pair.any(1)]
        score = self._score(s_feet, body_s, group, other, direction, lengths)
        choice = self._choose(model, feet, s_feet, lat, quarter, other, direction, pair, score)
        if choice is None:
            stay, whole = feet[group].copy(), np.ones(len(group))
            return StepPlan(
                group, 0.0, g.min_step_height, 0.0, stay, stay[:, 2], whole, sections, True
            )
        l1, l2 = choice
        shift = np.full(len(group), direction * lengths[l1])
        landing = (
            feet[group].copy() if l1 == 0 else self._moved(model, feet, s_feet, lat, group, shift)
        )
        return StepPlan(
            group,
            float(lengths[l1]),
            float(heights[l1]),
            float(lengths[l2]),
            landing,
            apex[:, l1],
            crossed[:, l1],
            sections,
            False,
        )

    def _moved(self, model, feet, s_feet, lat, legs, shift) -> np.ndarray:
        """Global foot centres of rows ``legs`` moved ``shift`` along the walking line onto the
        treads (a foot not moved stays where it stands)."""
        s_foot = s_feet[legs] + shift
        on_tread = model.height(legs, s_foot) + self.geometry.foot_radius
        z_foot = np.where(shift != 0, on_tread, feet[legs, 2])
        return model.to_global(s_foot, lat[legs], z_foot)

    def _landing(self, model, feet, s_feet, lat, body_s, group, direction, lengths):
        """Whether ``group`` lands clear with the body ``transfer`` of the half step short of
        its end, where it is at touch-down (n,)."""
        if self.transfer == 0.0:
            return np.ones(len(lengths), bool)
        g = self.geometry
        legs = np.repeat(group, len(lengths))
        step = np.tile(lengths, len(group))
        foot = self._moved(model, feet, s_feet, lat, legs, direction * step)
        pos, rot = model.body_frames(body_s + direction * 0.5 * (1.0 - self.transfer) * step, g)
        ok = leg_checks(self._batched(legs), self.home[legs], foot, pos, rot, model, g, step == 0)
        return ok.reshape(len(group), len(lengths)).all(0)

    def _choose(self, model, feet, s_feet, lat, quarter, other, direction, pair, score):
        """The best-scoring feasible pair (L1, L2) whose second step also has a feasible swing
        (a step height from where the first step leaves the body): without that check, walks
        dead-locked with both tripods' swings beyond their joint limits. Candidates are checked
        best first, ``CANDIDATES`` at a time (the first batch nearly always holds the choice)."""
        flat = np.where(pair, score, -np.inf).ravel()
        order = np.argsort(-flat, kind="stable")[: int(pair.sum())]
        for start in range(0, len(order), CANDIDATES):
            l1, l2 = np.unravel_index(order[start : start + CANDIDATES], pair.shape)
            ok = self._second_swing(model, feet, s_feet, lat, quarter, other, direction, l1, l2)
            if ok.any():
                first = int(np.argmax(ok))
                return int(l1[first]), int(l2[first])
        return None

    def _second_swing(self, model, feet, s_feet, lat, quarter, group, direction, l1, l2):
        """Whether ``group``'s step of index ``l2`` after the other's of index ``l1`` has a step
        height feasible for its three feet at lift-off, mid-crossing and where the crossing ends
        (over the landing, or past the drop's edge stepping down), the body
        having moved half the first step (c,); a step of length 0 does not swing. ``quarter``:
        the body frames every quarter step from the plan's start."""
        g = self.geometry
        lengths = np.arange(max(l1.max(), l2.max()) + 1) * g.resolution
        steps = np.arange(g.min_step_height, g.max_step_height + 1e-9, g.height_resolution)
        c, k = len(l1), len(steps)
        # rows (candidate, leg, end, height)
        cand = np.repeat(np.arange(c), 3 * 3 * k)
        leg = np.tile(np.repeat(np.arange(3), 3 * k), c)
        end = np.tile(np.repeat([0, 1, 2], k), 3 * c)
        hi = np.tile(np.arange(k), 9 * c)
        legs = group[leg]
        step = lengths[l2[cand]]
        s0 = s_feet[legs]
        top = model.swept_top(legs, s0, s0 + direction * step) + g.foot_radius
        top = np.maximum(top, feet[legs, 2])
        s_clear = model.clear_of_drop(legs, s0, s0 + direction * step, self.clearance)
        s_apex = s0 + 0.5 * (s_clear - s0) * end
        apex = model.to_global(s_apex, lat[legs], top + steps[hi])
        # the body half the first step on, then a quarter of the second per half crossing
        frame = 2 * l1[cand] + l2[cand] * end
        pos, rot = quarter[0][frame], quarter[1][frame]
        ok = leg_checks(self._batched(legs), self.home[legs], apex, pos, rot, model, g)
        return ok.reshape(c, 3, 3, k).all(2).all(1).any(-1) | (l2 == 0)

    def _score(self, s_feet, body_s, group, other, direction, lengths) -> np.ndarray:
        """Progress of the two steps less the stance's spread off centre after them: a tripod
        that just swung sits a quarter of the longest step ahead of its stand position, the
        other a quarter behind (the steady tripod); (n, n) over (L1, L2)."""
        l1, l2 = lengths[:, None], lengths[None, :]
        body = body_s + direction * 0.5 * (l1 + l2)
        home = self.home_s
        quarter = 0.25 * lengths[-1]
        dev = 0.0
        for leg in group:
            off = direction * (s_feet[leg] + direction * l1 - body - home[leg])
            dev = dev + (off + quarter) ** 2
        for leg in other:
            off = direction * (s_feet[leg] + direction * l2 - body - home[leg])
            dev = dev + (off - quarter) ** 2
        return l1 + l2 - 1.0 * np.sqrt(dev / len(self.home))

    def _heights(self, model, feet, s_feet, lat, quarter, group, direction, wanted):
        """Step height per step length (the lowest in every swinging foot's feasible section of
        step height: the apex above the highest tread under its path, reachable and free of
        interference over lift-off, mid-crossing and where the crossing ends: over the landing,
        or past the drop's edge stepping down), apex heights, the share of each foot's travel
        crossed at the apex (3, n), and whether one exists; computed for the ``wanted`` step
        lengths (n,) only (others: none)."""
        g = self.geometry
        n = len(wanted)
        lengths = np.arange(n) * g.resolution
        s0 = s_feet[group][:, None] + 0.0 * lengths
        s1 = s_feet[group][:, None] + direction * lengths
        top = model.swept_top(group[:, None], s0, s1) + g.foot_radius  # (3, n)
        top = np.maximum(top, feet[group, 2][:, None])
        s_clear = model.clear_of_drop(group[:, None], s0, s1, self.clearance)
        travel = s1 - s0
        moving = travel != 0.0
        crossed = np.where(moving, (s_clear - s0) / np.where(moving, travel, 1.0), 1.0)
        steps = np.arange(g.min_step_height, g.max_step_height + 1e-9, g.height_resolution)
        k, idx = len(steps), np.flatnonzero(wanted)
        w = len(idx)
        legs = np.repeat(group, 3 * w * k)
        end = np.tile(np.repeat([0, 1, 2], w * k), len(group))
        li = idx[np.tile(np.repeat(np.arange(w), k), 3 * len(group))]
        hi = np.tile(np.arange(k), 3 * w * len(group))
        foot = np.repeat(np.arange(len(group)), 3 * w * k)
        s_apex = s_feet[legs] + 0.5 * (s_clear - s0)[foot, li] * end
        z_apex = top[foot, li] + steps[hi]
        apex = model.to_global(s_apex, lat[legs], z_apex)
        # the body at a quarter of the step per half of the swing's crossing
        pos, rot = quarter[0][li * end], quarter[1][li * end]
        ok = np.zeros((n, k), bool)
        if w:
            checked = leg_checks(
                self._batched(legs), self.home[legs], apex, pos, rot, model, g, end == 0
            )
            ok[idx] = checked.reshape(len(group), 3, w, k).all(1).all(0)  # every foot, 3 points
        first = np.argmax(ok, axis=1)
        return steps[first], top + steps[first], crossed, ok.any(1)
