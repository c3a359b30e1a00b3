"""Stairs from point clouds (paper 004, section 3.2): horizontal planes by RANSAC, 5 % of each
plane's points near its edges ignored, successive clouds stitched by ICP; each step's height,
rise, tread depth and edge line.

Clouds arrive in the body frame and are placed in the global (odometry) frame with the body
pose (eq. 10); the stitched map is the union of aligned clouds, voxel-thinned.
"""

from __future__ import annotations

from typing import Annotated, ClassVar

import msgspec
import numpy as np
from scipy.spatial import cKDTree

from daemon.estimation import exp_so3, log_so3, rotation
from daemon.messages import BodyState, Stair, Stairs
from daemon.plugins import PerceptionPlugin

Positive = Annotated[float, msgspec.Meta(gt=0)]
Fraction = Annotated[float, msgspec.Meta(ge=0, lt=0.5)]


class StairsConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """RANSAC and stitching parameters (SI); ``edge_fraction`` is the paper's 5 %.

    ``max_tilt_deg``: a plane counts as horizontal within this tilt. ``inlier``: distance (m) of
    a point to its plane. ``min_points``: smallest plane kept; ``min_depth``: narrowest
    tread (m) along the ascent (a riser's slice is not a tread). ``voxel``: map thinning (m).
    ``icp_max_shift`` (m) and ``icp_max_turn_deg``: an alignment moving the body more along
    the directions the map constrains, or turning it more, is rejected (a flight's treads look
    alike one tread apart).
    ``icp_min_share``: a direction counts as constrained when the matched surfaces' normals put
    at least this share of their weight on it.
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
    icp_max_turn_deg: Positive = 3.0
    icp_min_share: Fraction = 0.05
    seed: int = 0


def normals(points: np.ndarray, tree: cKDTree, k: int = 12) -> np.ndarray:
    """Unit normals of a cloud from the smallest principal axis of each point's k neighbours."""
    _, idx = tree.query(points, k=k)
    nb = points[idx] - points[idx].mean(1, keepdims=True)
    _, vecs = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb))
    return vecs[:, :, 0]


def icp(
    source: np.ndarray,
    target: np.ndarray,
    iterations: int = 30,
    max_distance: float = 0.05,
    surface: tuple[cKDTree, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Rigid transform (R, t) aligning ``source`` onto ``target`` (point-to-plane ICP).

    Stair surfaces are planes, so distances are measured along the target's normals (a
    point-to-point fit lets two samplings of a plane slide); pairs farther apart than
    ``max_distance`` are left out; each step solves the linearised 6-DOF least squares
    (minimum norm: a direction no surface constrains, e.g. along the edges of a flight wider
    than the view, gets no correction). ``surface``: the target's tree and normals, if known.
    """
    tree, tn = surface or target_surface(target)
    rot, trans = np.eye(3), np.zeros(3)
    moved = source.copy()
    for _ in range(iterations):
        dist, idx = tree.query(moved, distance_upper_bound=max_distance)
        keep = np.isfinite(dist)
        if keep.sum() < 6:
            break
        a, b, n = moved[keep], target[idx[keep]], tn[idx[keep]]
        rows = np.hstack([np.cross(a, n), n])
        x, *_ = np.linalg.lstsq(rows, np.einsum("ij,ij->i", b - a, n), rcond=None)
        step = exp_so3(x[:3])
        moved = moved @ step.T + x[3:]
        rot, trans = step @ rot, step @ trans + x[3:]
        if np.linalg.norm(x) < 1e-7:
            break
    return rot, trans


def target_surface(target: np.ndarray) -> tuple[cKDTree, np.ndarray]:
    """KD-tree and normals of an ICP target, built once per map."""
    tree = cKDTree(target)
    return tree, normals(target, tree)


def constrained_directions(
    aligned: np.ndarray, surface: tuple[cKDTree, np.ndarray], max_distance: float, share: float
) -> np.ndarray:
    """Unit directions (k, 3) along which the aligned cloud's matched target normals constrain
    a translation: eigenvectors of their mean n·nᵀ holding at least ``share`` of it (treads
    give z, risers the ascent; a flight wider than the view gives nothing across it)."""
    tree, tn = surface
    dist, idx = tree.query(aligned, distance_upper_bound=max_distance)
    keep = np.isfinite(dist)
    if keep.sum() < 6:
        return np.zeros((0, 3))
    n = tn[idx[keep]]
    vals, vecs = np.linalg.eigh(n.T @ n / len(n))
    return vecs[:, vals >= share].T


def horizontal_planes(points: np.ndarray, config: StairsConfig) -> list[np.ndarray]:
    """Point sets of horizontal planes in ``points`` (global frame) by RANSAC, largest first."""
    rng = np.random.default_rng(config.seed)
    cos_tilt = np.cos(np.radians(config.max_tilt_deg))
    rest = points
    planes = []
    while len(rest) >= config.min_points:
        best = None
        for _ in range(config.iterations):
            p = rest[rng.choice(len(rest), 3, replace=False)]
            n = np.cross(p[1] - p[0], p[2] - p[0])
            norm = np.linalg.norm(n)
            if norm < 1e-12 or abs(n[2]) / norm < cos_tilt:
                continue
            n /= norm
            inliers = np.abs((rest - p[0]) @ n) < config.inlier
            if best is None or inliers.sum() > best.sum():
                best = inliers
        if best is None or best.sum() < config.min_points:
            break
        z = np.median(rest[best, 2])
        member = np.abs(rest[:, 2] - z) < config.inlier
        if member.sum() >= config.min_points:
            planes.append(rest[member])
        rest = rest[~(member | best)]
    return planes


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


class StairPerception(PerceptionPlugin):
    """Stitches clouds into a global stair map and reports its steps (``Stairs``)."""

    name: ClassVar[str] = "stairs"
    Config: ClassVar[type[msgspec.Struct]] = StairsConfig

    def __init__(self, config: StairsConfig | None = None, profile=None) -> None:
        super().__init__(config, profile)
        self.map: np.ndarray | None = None
        self._surface: tuple[cKDTree, np.ndarray] | None = None
        self.last_correction: tuple[np.ndarray, np.ndarray] | None = None
        self.rejected = 0

    def add_cloud(self, points: np.ndarray, body: BodyState) -> np.ndarray:
        """Place a body-frame cloud in the global frame (eq. 10), align it on the map by ICP.

        The alignment (R, t) is kept in ``last_correction``: the estimator's filter 2 input. An
        implausible alignment (see StairsConfig) is counted in ``rejected``, the cloud is left
        out of the map and ``last_correction`` is None.
        """
        c: StairsConfig = self.config
        rot = rotation(np.asarray(body.orientation, float))
        world = voxel_thin(np.asarray(points, float), c.voxel) @ rot.T + body.position
        if self.map is None:
            self.map = world
            self._surface = target_surface(world)
            self.last_correction = None
            return world
        r, t = icp(world, self.map, c.icp_iterations, c.icp_max_distance, self._surface)
        aligned = world @ r.T + t
        constrained = constrained_directions(
            aligned, self._surface, c.icp_max_distance, c.icp_min_share
        )
        body_shift = constrained @ (r @ np.asarray(body.position, float) + t - body.position)
        turn = np.degrees(np.linalg.norm(log_so3(r)))
        if np.linalg.norm(body_shift) > c.icp_max_shift or turn > c.icp_max_turn_deg:
            self.rejected += 1
            self.last_correction = None
            return world
        self.last_correction = (r, t)
        self.map = voxel_thin(np.vstack([self.map, aligned]), c.voxel)
        self._surface = target_surface(self.map)
        return aligned

    def process_cloud(self, points: np.ndarray, body: BodyState, stamp: float) -> Stairs:
        self.add_cloud(points, body)
        planes = horizontal_planes(self.map, self.config)
        yaw_axis = rotation(np.asarray(body.orientation, float))[:, 0]
        alignment = []
        if self.last_correction is not None:
            r, t = self.last_correction
            alignment = [*log_so3(r).tolist(), *t.tolist()]
        return Stairs(
            stamp=stamp,
            frame_stamp=stamp,
            steps=stairs_from_planes(planes, self.config, yaw_axis),
            alignment=alignment,
        )
