"""Initial truss modelling: RANSAC cylinder segmentation with normals (paper 003 II-A, eq. 1).

Each hypothesis comes from two oriented points near each other (axis = n1 x n2, centre where
the normal lines meet); hypotheses are scored on a random probe of the cloud; the best is
refined by Gauss-Newton on the geometric residual |distance to axis| - r (fitting r, not r^2,
so noise on a half-visible tube does not bias the radius). A segment is the longest run of
inliers along the axis: occlusions and linkers cut a member short, which is the
incompleteness the sliding bounding box repairs.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class Cylinder:
    """An infinite cylinder: a point on the axis, the unit axis, the radius (m)."""

    point: np.ndarray
    axis: np.ndarray
    radius: float


@dataclass(frozen=True)
class Segment:
    """A segmented piece of a member, C = {A, B, r} (eq. 1): cylinder, axial extent, its points."""

    cylinder: Cylinder
    t0: float
    t1: float
    indices: np.ndarray

    @property
    def a(self) -> np.ndarray:
        return self.cylinder.point + self.t0 * self.cylinder.axis

    @property
    def b(self) -> np.ndarray:
        return self.cylinder.point + self.t1 * self.cylinder.axis


def perpendicular_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing ``axis`` to a right-handed orthonormal frame."""
    x, y, z = axis
    u = np.array([0.0, z, -y]) if abs(x) < 0.9 else np.array([-z, 0.0, x])
    u /= np.sqrt(u @ u)
    v = np.array([y * u[2] - z * u[1], z * u[0] - x * u[2], x * u[1] - y * u[0]])
    return u, v


def surface_fit(
    points: np.ndarray, normals: np.ndarray, cylinder: Cylinder
) -> tuple[np.ndarray, np.ndarray]:
    """Per point: |distance to axis - r| (m) and |cos| of its normal to the radial direction."""
    w = points - cylinder.point
    radial = w - np.outer(w @ cylinder.axis, cylinder.axis)
    distance = np.sqrt(_rowdot(radial, radial))
    cos = np.abs(_rowdot(radial, normals)) / np.maximum(distance, 1e-12)
    return np.abs(distance - cylinder.radius), cos


def robust_sigma(off: np.ndarray) -> float:
    """One robust standard deviation (m) of distances ``off`` from a surface: 1.4826 times
    their median (the normal distribution's MAD scale), blind to a few outliers."""
    return float(1.4826 * np.median(np.abs(off)))


def axis_distance(points: np.ndarray, cylinder: Cylinder) -> np.ndarray:
    """Distance (m) of each point from the cylinder's axis line."""
    w = points - cylinder.point
    radial = w - np.outer(w @ cylinder.axis, cylinder.axis)
    return np.sqrt(_rowdot(radial, radial))


def spread(points: np.ndarray, cylinder: Cylinder) -> float:
    """The spread (m) of points about a cylinder's surface (``robust_sigma``): the depth noise
    a fit's radius carries."""
    return robust_sigma(axis_distance(points, cylinder) - cylinder.radius)


def within_radii(points: np.ndarray, cylinder: Cylinder, low: float, high: float) -> bool:
    """The fitted radius lies within [low, high], widened by the points' spread about it:
    depth noise pushes a tube's points off its surface, and the fit's radius outwards."""
    slack = spread(points, cylinder)
    return low - slack <= cylinder.radius <= high + slack


def _rowdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of two N x 3 arrays."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def refine(
    points: np.ndarray, cylinder: Cylinder, iterations: int = 8, max_points: int | None = None
) -> Cylinder:
    """Least-squares cylinder on the geometric residual d_i - r (Gauss-Newton, 5 parameters);
    on every k-th point when there are more than ``max_points``."""
    if max_points is not None and len(points) > max_points:
        points = points[:: -(-len(points) // max_points)]
    point, axis, radius = cylinder.point.copy(), cylinder.axis.copy(), cylinder.radius
    jacobian = np.empty((5, len(points)))
    jacobian[4] = -1.0
    for _ in range(iterations):
        u, v = perpendicular_basis(axis)
        t, pu, pv = np.array([axis, u, v]) @ (points - point).T
        t -= t.mean()
        distance = np.maximum(np.sqrt(pu * pu + pv * pv), 1e-12)
        np.divide(pu, -distance, out=jacobian[0])
        np.divide(pv, -distance, out=jacobian[1])
        np.multiply(t, jacobian[0], out=jacobian[2])
        np.multiply(t, jacobian[1], out=jacobian[3])
        normal = jacobian @ jacobian.T
        normal[np.diag_indices(5)] += 1e-12 + 1e-9 * np.trace(normal)
        step = np.linalg.solve(normal, jacobian @ (radius - distance))
        point = point + step[0] * u + step[1] * v
        axis = axis + step[2] * u + step[3] * v
        axis /= np.sqrt(axis @ axis)
        radius += step[4]
        if np.abs(step).max() < 1e-5:
            break
    point = point + axis * ((points - point) @ axis).mean()
    return Cylinder(point, axis, float(radius))


def hypotheses(
    p1: np.ndarray, n1: np.ndarray, p2: np.ndarray, n2: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cylinders through pairs of oriented points: centres, axes, radii, and a validity mask."""
    axes = np.cross(n1, n2)
    norm = np.linalg.norm(axes, axis=1)
    valid = norm > np.sin(np.radians(10.0))
    axes = axes / np.maximum(norm, 1e-12)[:, None]
    # centre c = p1 + s n1 = p2 + q n2 (+ k axis): solve the 2x2 normal equations of s, q
    d = p2 - p1
    b = np.einsum("ij,ij->i", n1, n2)
    e1, e2 = np.einsum("ij,ij->i", d, n1), np.einsum("ij,ij->i", d, n2)
    det = np.maximum(1.0 - b * b, 1e-12)
    s = (e1 - b * e2) / det
    q = (b * e1 - e2) / det
    centres = p1 + s[:, None] * n1
    radii = 0.5 * (np.abs(s) + np.abs(q))
    return centres, axes, radii, valid


def _axial_runs(t: np.ndarray, gap: float) -> list[np.ndarray]:
    """Indices (into t) of runs of axial coordinates without a gap above ``gap``."""
    order = np.argsort(t)
    breaks = np.flatnonzero(np.diff(t[order]) > gap) + 1
    return np.split(order, breaks)


def segment_cylinders(
    points: np.ndarray,
    normals: np.ndarray,
    tree: cKDTree,
    rng: np.random.Generator,
    *,
    radius_min: float,
    radius_max: float,
    partner_radius: float,
    distance: float,
    angle_deg: float,
    min_points: int,
    min_length: float,
    segment_gap: float,
    hypotheses_per_round: int,
    probe: int,
    max_failures: int,
    max_segments: int,
    claim: Callable[[Segment], np.ndarray] | None = None,
) -> list[Segment]:
    """Extract cylinder segments one by one until no hypothesis yields a long enough run.

    ``claim(segment)`` returns the indices leaving the pool with a segment (default: its own
    points); the modeller completes each segment at once and claims the whole member.
    """
    cos_limit = np.cos(np.radians(angle_deg))
    active = np.ones(len(points), bool)
    segments: list[Segment] = []
    failures = 0
    while failures < max_failures and len(segments) < max_segments:
        pool = np.flatnonzero(active)
        if len(pool) < min_points:
            break
        seeds = rng.choice(pool, size=hypotheses_per_round)
        balls = tree.query_ball_point(points[seeds], r=partner_radius)
        partners = np.array([ball[rng.integers(len(ball))] for ball in balls])
        centres, axes, radii, valid = hypotheses(
            points[seeds], normals[seeds], points[partners], normals[partners]
        )
        valid &= (radii >= radius_min) & (radii <= radius_max) & active[partners]
        if not valid.any():
            failures += 1
            continue
        sample = rng.choice(pool, size=min(probe, len(pool)), replace=False)
        centres, axes, radii = centres[valid], axes[valid], radii[valid]
        score = _scores(points[sample], normals[sample], centres, axes, radii, distance, cos_limit)
        best = int(np.argmax(score))
        if score[best] * len(pool) < 0.5 * min_points * len(sample):
            failures += 1
            continue
        cylinder = Cylinder(centres[best], axes[best], float(radii[best]))
        segment = _grow(points, normals, pool, cylinder, distance, cos_limit, segment_gap)
        if (
            segment is None
            or len(segment.indices) < min_points
            or segment.t1 - segment.t0 < min_length
            or not within_radii(points[segment.indices], segment.cylinder, radius_min, radius_max)
        ):
            failures += 1
            continue
        failures = 0
        active[segment.indices if claim is None else claim(segment)] = False
        segments.append(segment)
    return segments


def _scores(
    points: np.ndarray,
    normals: np.ndarray,
    centres: np.ndarray,
    axes: np.ndarray,
    radii: np.ndarray,
    distance: float,
    cos_limit: float,
) -> np.ndarray:
    """Inliers of each hypothesis among the probe points: on its surface within ``distance``,
    normal within the angle of its radial direction. Products of N x 3 by 3 x H arrays only."""
    along = points @ axes.T - (centres * axes).sum(axis=1)
    w2 = (points * points).sum(axis=1)[:, None] - 2 * points @ centres.T
    w2 += (centres * centres).sum(axis=1)
    radial = np.sqrt(np.maximum(w2 - along * along, 0.0))
    dot = normals @ centres.T
    normal_radial = (normals * points).sum(axis=1)[:, None] - dot - along * (normals @ axes.T)
    cos = np.abs(normal_radial) / np.maximum(radial, 1e-12)
    return ((np.abs(radial - radii) < distance) & (cos > cos_limit)).sum(axis=0)


GROW_POINTS = 1500
"""Points used by the refits while a segment grows (every k-th inlier); final fits use all."""
GROW_ROUNDS = 6
"""Most refits of a segment on its longest run of inliers, while the run grows."""


def _grow(
    points: np.ndarray,
    normals: np.ndarray,
    pool: np.ndarray,
    cylinder: Cylinder,
    distance: float,
    cos_limit: float,
    segment_gap: float,
) -> Segment | None:
    """Refine a hypothesis on its inliers twice, then grow its longest gap-free run along it;
    again from the run's cross-section recentred (``_recentred``); the longer run wins."""
    pool_points, pool_normals = points[pool], normals[pool]
    for _ in range(2):
        off, cos = surface_fit(pool_points, pool_normals, cylinder)
        inliers = (off < distance) & (cos > cos_limit)
        if inliers.sum() < 8:
            return None
        cylinder = refine(pool_points[inliers], cylinder, max_points=GROW_POINTS)
    tolerances = (distance, cos_limit, segment_gap)
    grown = _longest_run(pool_points, pool_normals, cylinder, *tolerances)
    if grown is None:
        return None
    start = _recentred(pool_points, grown, distance)
    if start is not None:
        again = _longest_run(pool_points, pool_normals, start, *tolerances)
        if again is not None and len(again.indices) > len(grown.indices):
            grown = again
    return Segment(grown.cylinder, grown.t0, grown.t1, pool[grown.indices])


def _longest_run(
    points: np.ndarray,
    normals: np.ndarray,
    cylinder: Cylinder,
    distance: float,
    cos_limit: float,
    segment_gap: float,
) -> Segment | None:
    """The longest gap-free run of the cylinder's inliers along it (indices into ``points``),
    refitted on the run while the run grows (a noisy hypothesis's axis is off: its inliers
    break into short runs)."""
    run = np.zeros(0, int)
    for _ in range(GROW_ROUNDS):
        off, cos = surface_fit(points, normals, cylinder)
        inliers = np.flatnonzero((off < distance) & (cos > cos_limit))
        if len(inliers) < 8:
            break
        t = (points[inliers] - cylinder.point) @ cylinder.axis
        longest = inliers[max(_axial_runs(t, segment_gap), key=len)]
        if len(longest) <= len(run):
            break
        run = longest
        cylinder = refine(points[run], cylinder, max_points=GROW_POINTS)
    if len(run) < 8:
        return None
    t = (points[run] - cylinder.point) @ cylinder.axis
    return Segment(cylinder, float(t.min()), float(t.max()), run)


def _recentred(points: np.ndarray, segment: Segment, distance: float) -> Cylinder | None:
    """The segment's cylinder moved to the centroid of the points inside it over its extent,
    with their median distance from that axis as radius: a start for a refit that escapes a
    wide cylinder fitted to one side of a noisy tube (the other side lies inside it). None
    without such points."""
    cylinder = segment.cylinder
    t = (points - cylinder.point) @ cylinder.axis
    radial = axis_distance(points, cylinder)
    inside = points[(t >= segment.t0) & (t <= segment.t1) & (radial < cylinder.radius + distance)]
    if len(inside) == 0:
        return None
    centre = inside.mean(axis=0)
    radius = np.median(axis_distance(inside, Cylinder(centre, cylinder.axis, 0.0)))
    return Cylinder(centre, cylinder.axis, float(radius))
