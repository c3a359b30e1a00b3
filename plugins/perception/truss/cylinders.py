"""Initial truss modelling: RANSAC cylinder segmentation with normals (paper 003 II-A, eq. 1).

Each hypothesis comes from two oriented points near each other (axis = n1 x n2, centre where
the normal lines meet); hypotheses are scored on a random probe of the cloud; the best is
refined by Gauss-Newton on the geometric residual |distance to axis| - r (fitting r, not r^2,
so noise on a half-visible tube does not bias the radius). A segment is the longest run of
inliers along the axis: occlusions and linkers cut a member short, which is the
incompleteness the sliding bounding box repairs.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack
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
    _, u, v = _frame_rows(*axis.tolist())
    return np.array(u), np.array(v)


def _frame_rows(x: float, y: float, z: float) -> tuple[tuple[float, float, float], ...]:
    """The unit axis (x, y, z) and two unit vectors completing it to a right-handed frame, in
    scalars (called per Gauss-Newton iteration on small fits)."""
    if abs(x) < 0.9:
        norm = math.sqrt(y * y + z * z)
        ux, uy, uz = 0.0, z / norm, -y / norm
    else:
        norm = math.sqrt(x * x + z * z)
        ux, uy, uz = -z / norm, 0.0, x / norm
    return (x, y, z), (ux, uy, uz), (y * uz - z * uy, z * ux - x * uz, x * uy - y * ux)


def surface_fit(
    points: np.ndarray, normals: np.ndarray, cylinder: Cylinder
) -> tuple[np.ndarray, np.ndarray]:
    """Per point: |distance to axis - r| (m) and |cos| of its normal to the radial direction."""
    radial, cos = surface_offset(points, normals, cylinder)
    return np.abs(radial, out=radial), cos


def surface_offset(
    points: np.ndarray, normals: np.ndarray, cylinder: Cylinder
) -> tuple[np.ndarray, np.ndarray]:
    """Per point: distance to axis - r (m; negative inside the surface) and |cos| of its normal
    to the radial direction (its dot with the normal follows from w.n and n.a, ``_around``)."""
    w, along, distance = _around(points, cylinder)
    normal_radial = _rowdot(w, normals) - along * (normals @ cylinder.axis)
    cos = np.abs(normal_radial) / np.maximum(distance, 1e-12)
    distance -= cylinder.radius
    return distance, cos


def robust_sigma(off: np.ndarray) -> float:
    """One robust standard deviation (m) of distances ``off`` from a surface: 1.4826 times
    their median (the normal distribution's MAD scale), blind to a few outliers."""
    return float(1.4826 * np.median(np.abs(off)))


def axis_distance(points: np.ndarray, cylinder: Cylinder) -> np.ndarray:
    """Distance (m) of each point from the cylinder's axis line."""
    return _around(points, cylinder)[2]


def _around(points: np.ndarray, cylinder: Cylinder) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each point's offset w from the cylinder's axis point, its axial coordinate w.a and its
    distance from the axis, sqrt(w.w - (w.a)^2): the radial vector is never formed."""
    w = points - cylinder.point
    along = w @ cylinder.axis
    return w, along, np.sqrt(np.maximum(_rowdot(w, w) - along * along, 0.0))


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


STEP_TOLERANCE = 1e-4
"""A fit has converged when no step moves the axis point or the radius by 0.1 mm or turns the
axis by 0.1 mrad: a tenth of the depth noise and of the voxel the cloud is sampled at."""


def refine(
    points: np.ndarray, cylinder: Cylinder, iterations: int = 8, max_points: int | None = None
) -> Cylinder:
    """Least-squares cylinder on the geometric residual d_i - r (Gauss-Newton, 5 parameters:
    the axis point's and the axis's moves along u, v perpendicular to it, and r); on every k-th
    point when there are more than ``max_points``. The points are centred once and the axis
    turns about the centroid's foot on it, where the Jacobian's tilt terms pivot. Its fits run
    on a few hundred points, where call overhead dominates: the pose is kept in scalars and an
    iteration is one product of a 3 x 4 frame with the homogeneous points and the normal
    equations."""
    if max_points is not None and len(points) > max_points:
        points = points[:: -(-len(points) // max_points)]
    origin = points.mean(axis=0)
    homogeneous = np.ones((4, len(points)))
    homogeneous[:3] = (points - origin).T
    px, py, pz = (cylinder.point - origin).tolist()
    ax, ay, az = cylinder.axis.tolist()
    radius = cylinder.radius
    # a guard against singular fits: 1e-9 of a bound on the normal matrix's trace, 2n + sum t^2
    spread2 = float(np.einsum("ij,ij", homogeneous[:3], homogeneous[:3]))
    damping = np.eye(5) * (1e-12 + 1e-9 * (2 * len(points) + spread2))
    jacobian = np.empty((5, len(points)))
    jacobian[4] = -1.0
    across = np.empty((3, len(points)))
    for _ in range(iterations):
        along = px * ax + py * ay + pz * az  # the centroid's foot: tilts turn about it
        px, py, pz = px - along * ax, py - along * ay, pz - along * az
        (_, _, _), (ux, uy, uz), (vx, vy, vz) = _frame_rows(ax, ay, az)
        frame = np.array(
            [
                [ax, ay, az, 0.0],
                [ux, uy, uz, -(ux * px + uy * py + uz * pz)],
                [vx, vy, vz, -(vx * px + vy * py + vz * pz)],
            ]
        )
        np.matmul(frame, homogeneous, out=across)
        distance = np.hypot(across[1], across[2])
        np.maximum(distance, 1e-12, out=distance)
        np.divide(across[1:], -distance, out=jacobian[:2])
        np.multiply(across[0], jacobian[:2], out=jacobian[2:4])
        normal = jacobian @ jacobian.T
        normal += damping
        _, step, info = lapack.dposv(normal, jacobian @ (radius - distance))
        if info != 0:
            break
        s0, s1, s2, s3, s4 = step.tolist()
        px, py, pz = px + s0 * ux + s1 * vx, py + s0 * uy + s1 * vy, pz + s0 * uz + s1 * vz
        ax, ay, az = ax + s2 * ux + s3 * vx, ay + s2 * uy + s3 * vy, az + s2 * uz + s3 * vz
        norm = math.sqrt(ax * ax + ay * ay + az * az)
        ax, ay, az = ax / norm, ay / norm, az / norm
        radius += s4
        if max(abs(s0), abs(s1), abs(s2), abs(s3), abs(s4)) < STEP_TOLERANCE:
            break
    along = px * ax + py * ay + pz * az
    point = np.array([px - along * ax, py - along * ay, pz - along * az]) + origin
    return Cylinder(point, np.array([ax, ay, az]), float(radius))


def hypotheses(
    p1: np.ndarray, n1: np.ndarray, p2: np.ndarray, n2: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cylinders through pairs of oriented points: centres, axes, radii, and a validity mask."""
    axes = np.cross(n1, n2)
    norm = np.sqrt(np.einsum("ij,ij->i", axes, axes))
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


def _longest_axial_run(t: np.ndarray, gap: float) -> np.ndarray:
    """Indices (into t) of the longest run of axial coordinates without a gap above ``gap``
    (the first of equally long runs)."""
    order = np.argsort(t)
    bounds = np.concatenate(([0], np.flatnonzero(np.diff(t[order]) > gap) + 1, [len(t)]))
    k = int(np.argmax(np.diff(bounds)))
    return order[bounds[k] : bounds[k + 1]]


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
GROW_REACH = 0.15
"""How far (m) outside a hypothesis's surface a segment may grow: its refits turn the axis by
a few degrees at most, 0.15 m at 2 m from where it started."""


def _grow(
    points: np.ndarray,
    normals: np.ndarray,
    pool: np.ndarray,
    cylinder: Cylinder,
    distance: float,
    cos_limit: float,
    segment_gap: float,
) -> Segment | None:
    """Refine a hypothesis on its inliers twice, then grow its longest gap-free run along it
    among the pool's points within ``GROW_REACH`` of its surface; again from the run's
    cross-section recentred (``_recentred``); the longer run wins, unless its bore holds as
    many points as its surface (``_bore_points``)."""
    pool_points, pool_normals = points[pool], normals[pool]
    for _ in range(2):
        off, cos = surface_fit(pool_points, pool_normals, cylinder)
        inliers = (off < distance) & (cos > cos_limit)
        if inliers.sum() < 8:
            return None
        cylinder = refine(pool_points[inliers], cylinder, max_points=GROW_POINTS)
    near = np.flatnonzero(axis_distance(pool_points, cylinder) < cylinder.radius + GROW_REACH)
    pool, pool_points, pool_normals = pool[near], pool_points[near], pool_normals[near]
    tolerances = (distance, cos_limit, segment_gap)
    grown = _longest_run(pool_points, pool_normals, cylinder, *tolerances)
    if grown is None:
        return None
    start = _recentred(pool_points, grown, distance)
    if start is not None:
        again = _longest_run(pool_points, pool_normals, start, *tolerances)
        if again is not None and len(again.indices) > len(grown.indices):
            grown = again
    if _bore_points(pool_points, grown, distance) >= len(grown.indices):
        return None
    return Segment(grown.cylinder, grown.t0, grown.t1, pool[grown.indices])


def _bore_points(points: np.ndarray, segment: Segment, distance: float) -> int:
    """How many of ``points`` lie in the segment's bore (nearer its axis than r - ``distance``,
    within its extent). A tube's solid shell hides its bore (a fifth of its surface inliers at
    most, in the noisy space frames); a cylinder drawn through a volume of scattered points
    has more inside it than on it (three times as many in a cube of uniform noise)."""
    cylinder = segment.cylinder
    _, t, radial = _around(points, cylinder)
    inside = radial < cylinder.radius - distance
    return int((inside & (t >= segment.t0) & (t <= segment.t1)).sum())


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
        longest = inliers[_longest_axial_run(t, segment_gap)]
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
    _, t, radial = _around(points, cylinder)
    inside = points[(t >= segment.t0) & (t <= segment.t1) & (radial < cylinder.radius + distance)]
    if len(inside) == 0:
        return None
    centre = inside.mean(axis=0)
    radius = np.median(axis_distance(inside, Cylinder(centre, cylinder.axis, 0.0)))
    return Cylinder(centre, cylinder.axis, float(radius))
