"""Stairs from point clouds (paper 004, section 3.2): horizontal planes by RANSAC, 5 % of each
plane's points near its edges ignored, successive clouds stitched by ICP; each step's height,
rise, tread depth and edge line.

Clouds arrive in the body frame and are placed in the global (odometry) frame with the body
pose (eq. 10); the stitched map is the union of aligned clouds, voxel-thinned.
"""

from __future__ import annotations

from typing import Annotated, ClassVar, NamedTuple

import msgspec
import numpy as np
from scipy.spatial import cKDTree

from climbd.daemon.algorithms.cloud import CloudPerception, within_range
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.messages import BodyState, Stair, Stairs
from climbd.daemon.contract.units import Positive

Fraction = Annotated[float, msgspec.Meta(ge=0, lt=0.5)]


class StairsConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """RANSAC and stitching parameters (SI); ``edge_fraction`` is the paper's 5 %.

    ``max_tilt_deg``: a plane counts as horizontal within this tilt. ``inlier``: distance (m) of
    a point to its plane. ``min_points``: smallest plane kept; ``min_depth``: narrowest
    tread (m) along the ascent (a riser's slice is not a tread). ``voxel``: map thinning (m).
    ``icp_max_shift`` (m): an alignment moving the cloud more is rejected (a flight's treads
    look alike one tread apart). ``icp_min_area`` (m²): a direction counts as constrained when
    this much matched surface faces it, counted in points of ``voxel`` (see
    ``constrained_directions``; on the recorded stair run at 2 cm voxels a riser coming into
    view is ~100 points, stray normals on the top landing at most 41).
    ``icp_max_variation``: a map point takes part in ICP only where its neighbourhood is a
    surface, its variation λ0 / (λ0 + λ1 + λ2) below this (risers 0.007 median; floor seen
    2 m off, as noisy as it is sampled, 0.10-0.25: normals at random, which on the 180 mm
    flight's top landing made 500 points of false risers and pulled the estimate 6 cm).
    ``max_range`` (m): body-frame points farther than this are no measurement of the stairs
    ahead (Qingzhui's D435 is cut at 3 m) and are discarded, as NaN and inf are.
    ``cell`` (m), ``max_shared``: a camera above the stairs sees one surface per place, so a
    plane with more than ``max_shared`` of its points in ``cell``-sized xy cells where a larger
    plane has more is a slice of that plane's depth noise, not a tread (the D435's σ is 1.7 cm
    at 2 m: from the top landing, the floor beyond it made a 'step' 3.5 cm above the floor).
    """

    inlier: Positive = 0.01
    max_tilt_deg: Positive = 3.0
    iterations: int = 200
    min_points: int = 200
    edge_fraction: Fraction = 0.05
    min_rise: Positive = 0.03
    min_depth: Positive = 0.08
    voxel: Positive = 0.01
    icp_iterations: int = 30
    icp_max_distance: Positive = 0.05
    icp_max_shift: Positive = 0.05
    icp_min_area: Positive = 0.024
    icp_max_variation: Positive = 0.05
    max_range: Positive = 5.0
    cell: Positive = 0.05
    max_shared: Fraction = 0.3
    seed: int = 0


class Surface(NamedTuple):
    """An ICP target: its KD-tree, each point's normal, and which normals are a surface's."""

    tree: cKDTree
    normals: np.ndarray
    flat: np.ndarray


NEIGHBOURS = 12
"""Points a normal is fitted to: a cloud that starts the map needs at least this many."""


def normals(
    points: np.ndarray, tree: cKDTree, k: int = NEIGHBOURS
) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals of a cloud from the smallest principal axis of each point's k neighbours,
    and each neighbourhood's surface variation λ0 / (λ0 + λ1 + λ2): 0 on a plane, 1/3 for a
    blob without one (Pauly et al. 2002), where the normal is noise."""
    _, idx = tree.query(points, k=k)
    nb = points[idx] - points[idx].mean(1, keepdims=True)
    vals, vecs = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb))
    total = vals.sum(1)
    variation = np.divide(vals[:, 0], total, out=np.ones(len(total)), where=total > 0)
    return vecs[:, :, 0], variation


def constrained_directions(n: np.ndarray, min_points: int) -> np.ndarray:
    """Unit directions (k, 3) along which matched surfaces of normals ``n`` pin a translation.

    Treads (|n_z| >= 0.5) pin z; risers (|n_z| < 0.5) pin the principal horizontal directions
    of their normals that carry at least ``min_points`` points' weight (a riser gives the
    ascent, a flight wider than the view nothing across it). Counted on risers rather than as
    a share of all normals: a floor's normal noise alone puts ~2 % of the weight on x and y.
    """
    vertical = np.abs(n[:, 2]) < 0.5
    out = [np.array([0.0, 0.0, 1.0])] if (~vertical).sum() >= min_points else []
    flat = n[vertical, :2]
    vals, vecs = np.linalg.eigh(flat.T @ flat)
    out += [np.array([*vecs[:, i], 0.0]) for i in range(2) if vals[i] >= min_points]
    return np.array(out).reshape(-1, 3)


def icp_translation(
    source: np.ndarray,
    target: np.ndarray,
    surface: Surface,
    iterations: int = 30,
    max_distance: float = 0.05,
    min_points: int = 60,
) -> tuple[np.ndarray, np.ndarray]:
    """Translation (3,) moving ``source`` onto ``target`` by point-to-plane ICP, and the unit
    directions (k, 3) it was solved along (``constrained_directions``; zero along the rest).

    Stair surfaces are planes, so distances are measured along the target's normals (a
    point-to-point fit lets two samplings of a plane slide); pairs farther apart than
    ``max_distance`` are left out. The rotation stays the estimate's (gravity-tilted, within
    0.3 deg on the recorded stair run): a rotation solved about the map origin, metres from
    the body, moves the body by its lever arm. ``surface``: the target's (``target_surface``);
    only its points with a surface's normal are matched.
    """
    tree, tn, flat = surface
    shift, dirs = np.zeros(3), np.zeros((0, 3))
    for _ in range(iterations):
        dist, idx = tree.query(source + shift, distance_upper_bound=max_distance)
        keep = np.flatnonzero(np.isfinite(dist))
        keep = keep[flat[idx[keep]]]
        n = tn[idx[keep]]
        dirs = constrained_directions(n, min_points)
        if not len(dirs):
            break
        a = n @ dirs.T
        gap = np.einsum("ij,ij->i", target[idx[keep]] - source[keep] - shift, n)
        step = np.linalg.solve(a.T @ a, a.T @ gap) @ dirs
        shift = shift + step
        if np.linalg.norm(step) < 1e-7:
            break
    return shift, dirs


def target_surface(target: np.ndarray, max_variation: float) -> Surface:
    """KD-tree and normals of an ICP target, built once per map; normals whose neighbourhood
    varies by ``max_variation`` or more are not a surface's and take no part."""
    tree = cKDTree(target)
    n, variation = normals(target, tree)
    return Surface(tree, n, variation < max_variation)


SCORED = 32
"""RANSAC hypotheses scored against the cloud at once (a points × SCORED distance block)."""
CELL_KEY = 1 << 32
"""An xy cell's key: column index times this plus row index (both well inside 2**31)."""


def horizontal_planes(points: np.ndarray, config: StairsConfig) -> list[np.ndarray]:
    """Point sets of horizontal planes in ``points`` (global frame) by RANSAC, largest first."""
    rng = np.random.default_rng(config.seed)
    cos_tilt = np.cos(np.radians(config.max_tilt_deg))
    rest = points
    planes = []
    while len(rest) >= config.min_points:
        best = best_horizontal_plane(rest, rng, config.iterations, cos_tilt, config.inlier)
        if best is None or best.sum() < config.min_points:
            break
        z = np.median(rest[best, 2])
        member = np.abs(rest[:, 2] - z) < config.inlier
        if member.sum() >= config.min_points:
            planes.append(rest[member])
        rest = rest[~(member | best)]
    return distinct(planes, config)


def distinct(planes: list[np.ndarray], config: StairsConfig) -> list[np.ndarray]:
    """``planes`` (largest first) without those that have more than ``max_shared`` of their
    points in xy cells where a larger plane kept has more: a noisy surface's slice above or
    below its own plane. (A plane's z band also takes slivers of the risers at its height; in
    their cells the tread beside them has more points, so they take no tread away.)"""
    kept: list[np.ndarray] = []
    most: dict[int, int] = {}
    for plane in planes:
        ij = np.floor(plane[:, :2] / config.cell).astype(np.int64)
        keys, counts = np.unique(ij[:, 0] * CELL_KEY + ij[:, 1], return_counts=True)
        larger = np.array([most.get(k, 0) for k in keys.tolist()], np.int64)
        if counts[larger > counts].sum() > config.max_shared * len(plane):
            continue
        kept.append(plane)
        for k, n in zip(keys.tolist(), counts.tolist(), strict=True):
            most[k] = max(most.get(k, 0), n)
    return kept


def best_horizontal_plane(
    points: np.ndarray, rng: np.random.Generator, iterations: int, cos_tilt: float, inlier: float
) -> np.ndarray | None:
    """Inlier mask of the best of ``iterations`` RANSAC hypotheses (planes through three random
    points) tilted from horizontal by at most acos(``cos_tilt``); None when none is. All are
    drawn at once and scored in blocks: a hypothesis at a time spent most of its time in
    numpy's per-call overhead on three points."""
    p = points[rng.integers(len(points), size=(iterations, 3))]
    u, v = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    n = np.stack(
        [
            u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1],
            u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2],
            u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0],
        ],
        1,
    )
    norm = np.linalg.norm(n, axis=1)
    level = (norm > 1e-12) & (np.abs(n[:, 2]) >= cos_tilt * norm)  # repeated points: norm 0
    if not level.any():
        return None
    n = n[level] / norm[level, None]
    offset = np.einsum("ij,ij->i", p[level, 0], n)
    best, most = 0, -1
    for k in range(0, len(n), SCORED):
        counts = (np.abs(points @ n[k : k + SCORED].T - offset[k : k + SCORED]) < inlier).sum(0)
        j = int(np.argmax(counts))
        if counts[j] > most:
            best, most = k + j, counts[j]
    return np.abs(points @ n[best] - offset[best]) < inlier


def stairs_from_planes(
    planes: list[np.ndarray], config: StairsConfig, direction: np.ndarray | None = None
) -> list[Stair]:
    """Steps (bottom first) from horizontal planes; ``direction`` is the ascent (x by default).

    The lowest plane is the floor the robot stands on: the first step's rise is above it.
    Each plane keeps its central points: ``edge_fraction`` of them nearest its edges along the
    ascent (half at each end) are ignored. The edge line is the plane's near edge.
    """
    d = np.array([1.0, 0.0, 0.0]) if direction is None else np.asarray(direction, float)
    d = d / np.linalg.norm(d[:2]) * np.array([1.0, 1.0, 0.0])
    side = np.array([-d[1], d[0], 0.0])
    planes = sorted(planes, key=lambda p: float(np.median(p[:, 2])))
    out: list[Stair] = []
    prev = None
    for pts in planes:
        along = pts @ d
        lo, hi = np.quantile(along, [config.edge_fraction / 2, 1 - config.edge_fraction / 2])
        core = pts[(along >= lo) & (along <= hi)]
        height = float(np.median(core[:, 2]))
        a, s = core @ d, core @ side
        near, far = float(a.min()), float(a.max())
        if far - near < config.min_depth or (prev is not None and height - prev < config.min_rise):
            continue
        left, right = float(s.max()), float(s.min())
        edge = [
            (near * d + left * side + [0, 0, height]).tolist(),
            (near * d + right * side + [0, 0, height]).tolist(),
        ]
        if prev is None:
            prev = height
            continue
        rise = height - prev
        out.append(Stair(height=height, rise=rise, depth=far - near, edge=edge))
        prev = height
    return out


def voxel_thin(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point per occupied voxel (the first)."""
    keys = np.floor(points / voxel).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]


class StairPerception(CloudPerception):
    """Stitches clouds into a global stair map and reports its steps (``Stairs``)."""

    name: ClassVar[str] = "stairs"
    publishes = (Stairs,)
    Config: ClassVar[type[msgspec.Struct]] = StairsConfig

    def __init__(self, config: StairsConfig | None = None, profile=None) -> None:
        super().__init__(config, profile)
        self.map: np.ndarray | None = None
        self._surface: Surface | None = None
        self.last_correction: tuple[np.ndarray, np.ndarray] | None = None
        self.rejected = 0

    def add_cloud(self, points: np.ndarray, body: BodyState) -> np.ndarray:
        """Place a body-frame cloud in the global frame (eq. 10), align it on the map by ICP.

        The alignment, its translation (3,) and the directions (k, 3) the map constrains it
        along, is kept in ``last_correction``: the estimator's filter 2 input. An implausible
        alignment (see StairsConfig) is counted in ``rejected``, the cloud is left out of the
        map and ``last_correction`` is None. Points beyond ``max_range`` or not finite are
        dropped first; a cloud too sparse to fit normals to does not start the map.
        """
        c: StairsConfig = self.config
        rot = rotation(np.asarray(body.orientation, float))
        seen = within_range(points, c.max_range)
        world = voxel_thin(seen, c.voxel) @ rot.T + body.position
        if self.map is None:
            self.last_correction = None
            if len(world) >= NEIGHBOURS:
                self.map = world
                self._surface = target_surface(world, c.icp_max_variation)
            return world
        shift, dirs = icp_translation(
            world,
            self.map,
            self._surface,
            c.icp_iterations,
            c.icp_max_distance,
            round(c.icp_min_area / c.voxel**2),
        )
        if np.linalg.norm(shift) > c.icp_max_shift:
            self.rejected += 1
            self.last_correction = None
            return world
        self.last_correction = (shift, dirs)
        aligned = world + shift
        self.map = voxel_thin(np.vstack([self.map, aligned]), c.voxel)
        self._surface = target_surface(self.map, c.icp_max_variation)
        return aligned

    def process_cloud(self, points: np.ndarray, body: BodyState, stamp: float) -> Stairs:
        self.add_cloud(points, body)
        planes = [] if self.map is None else horizontal_planes(self.map, self.config)
        yaw_axis = rotation(np.asarray(body.orientation, float))[:, 0]
        shift, dirs = self.last_correction or (np.zeros(0), np.zeros((0, 3)))
        return Stairs(
            stamp=stamp,
            frame_stamp=stamp,
            steps=stairs_from_planes(planes, self.config, yaw_axis),
            alignment=shift.tolist(),
            constrained=dirs.tolist(),
        )
