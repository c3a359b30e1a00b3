"""Graspable-point detection of paper 001 (§2): terrain matrix, gripper mask, correlation.

The cloud is turned to its regression plane (z along the plane normal, towards the robot),
occlusions are filled by linear interpolation over a Delaunay triangulation onto a square
lattice, and the lattice's heights are voxelised into the 0/1 terrain matrix. The paper scans
every solid voxel with the gripper mask; the test is the same at every voxel, so it is a
correlation of the terrain matrix with the mask's void cells (plus a box count of solid cells).
A terrain matrix made from a height lattice holds one solid voxel per column, so the
correlation at a voxel reads each window column's solid depth directly; it is evaluated only
at the voxels the cheap rules (measured, void over known terrain, palm clear) leave.

Rule (paper §2.3, ClimbLab's thresholds): a solid voxel is graspable when the solid voxels
of its window that fall in the mask's void cells are at most ``void_fraction`` of the window's
solid voxels (0 = the paper's strict rule; a near-miss within that fraction, e.g. one sensor
speckle or a slope sampled into the 1-mm closing layer, is accepted, and beyond it rejected, as
ClimbLab's sub-target penalty does), the window holds more than ``solid_threshold`` solid
voxels (too little terrain under the gripper to trust), nothing stands more than
``above_tolerance`` voxels above the voxel within the palm's footprint (the paper's window
starts at the palm, but the palm cannot sink into rock: this keeps targets off the rims at the
feet of holds), the mask's void cells all lie over
measured or interpolated terrain (unknown is never taken for void), and the voxel itself is on
measured terrain (a cloud point within one lattice pitch): interpolation fills a target's
surroundings, never the target itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import cv2
import msgspec
import numpy as np
from scipy import ndimage
from scipy.spatial import Delaunay, QhullError

from climbd.daemon.algorithms.cloud import CloudPerception, within_range
from climbd.daemon.contract.geometry import regression_frame
from climbd.daemon.contract.messages import BodyState, GraspablePoints
from climbd.plugins.perception.gripper_mask import GripperGeometry, gripper_mask


class GraspableConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Detection settings; defaults are ClimbLab's (voxel 1 mm, threshold 120, HubRobo gripper).

    ``lattice_spacing`` is the interpolation lattice pitch (m), rounded to whole voxels so solid
    columns sit on a lattice; 3 mm is the D435's point pitch on holds at 0.5 m (ClimbLab's
    density rule gives 3-4 mm on its clouds), 0 derives it from the density as ClimbLab does.
    ``thin_distance`` (m): graspable points closer than this collapse to one target.
    ``max_range`` (m): points farther from the body are no hold in reach (HubRobo's D435 is cut
    at 1.5 m) and are discarded, as NaN and inf are.
    """

    voxel: float = 0.001
    lattice_spacing: float = 0.003
    solid_threshold: int = 120
    void_fraction: float = 0.02
    above_tolerance: int = 1
    thin_distance: float = 0.015
    max_range: float = 2.0
    gripper: GripperGeometry = msgspec.field(default_factory=GripperGeometry)

    def check(self) -> None:
        """Raise ValueError naming the field of a setting that cannot work."""
        if not (math.isfinite(self.voxel) and 0 < self.voxel <= 0.05):
            raise ValueError(f"graspable.voxel: expected 0 < voxel <= 0.05 m, found {self.voxel}")
        if not (math.isfinite(self.lattice_spacing) and self.lattice_spacing >= 0):
            raise ValueError(
                f"graspable.lattice_spacing: expected >= 0 m (0 = from density), "
                f"found {self.lattice_spacing}"
            )
        if self.solid_threshold < 0:
            raise ValueError(
                f"graspable.solid_threshold: expected >= 0, found {self.solid_threshold}"
            )
        if not 0 <= self.void_fraction < 1:
            raise ValueError(
                f"graspable.void_fraction: expected 0 <= fraction < 1, found {self.void_fraction}"
            )
        if self.above_tolerance < 0:
            raise ValueError(
                f"graspable.above_tolerance: expected >= 0 voxels, found {self.above_tolerance}"
            )
        if not (math.isfinite(self.thin_distance) and self.thin_distance >= 0):
            raise ValueError(
                f"graspable.thin_distance: expected >= 0 m, found {self.thin_distance}"
            )
        if not (math.isfinite(self.max_range) and self.max_range > 0):
            raise ValueError(f"graspable.max_range: expected > 0 m, found {self.max_range}")
        self.gripper.check()


class DegenerateCloud(ValueError):
    """A cloud with no terrain to detect on: too few points in range, or none spanning an area
    on their plane. The plugin reports it as nothing found; ``detect`` callers see why."""


@dataclass(frozen=True)
class HeightLattice:
    """Heights (m, NaN where unknown) on a square lattice of pitch ``spacing`` from (x0, y0).

    ``measured`` marks nodes with a cloud point within one pitch; the rest are interpolated.
    """

    x0: float
    y0: float
    spacing: float
    heights: np.ndarray
    measured: np.ndarray


def interpolate_heights(plane_points: np.ndarray, spacing: float) -> HeightLattice:
    """Fill occlusions by linear interpolation over the Delaunay triangulation (§2.1 step 2).

    Each triangle is rasterised onto the lattice nodes it covers (barycentric weights), which
    is what griddata does node by node, in one vectorised pass.
    """
    xy = plane_points[:, :2]
    lo = xy.min(axis=0)
    n = np.floor((xy.max(axis=0) - lo) / spacing).astype(np.int64) + 1
    try:
        simplices = Delaunay(xy).simplices
    except QhullError as e:
        raise DegenerateCloud(f"cloud is degenerate (no 2-D extent on its plane): {e}") from None
    corner = (xy[simplices] - lo) / spacing
    z = plane_points[simplices, 2]
    first = np.clip(np.ceil(corner.min(axis=1) - 1e-9).astype(np.int64), 0, None)
    last = np.minimum(np.floor(corner.max(axis=1) + 1e-9).astype(np.int64), n - 1)
    span = np.clip(last - first + 1, 0, None)
    count = span[:, 0] * span[:, 1]
    owner = np.repeat(np.arange(len(simplices)), count)
    local = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    ix = first[owner, 0] + local // span[owner, 1]
    iy = first[owner, 1] + local % span[owner, 1]
    a = corner[:, 1] - corner[:, 0]
    b = corner[:, 2] - corner[:, 0]
    det = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    px = ix - corner[owner, 0, 0]
    py = iy - corner[owner, 0, 1]
    with np.errstate(divide="ignore", invalid="ignore"):  # a flat triangle covers no node
        w1 = (px * b[owner, 1] - py * b[owner, 0]) / det[owner]
        w2 = (a[owner, 0] * py - a[owner, 1] * px) / det[owner]
        inside = (w1 >= -1e-9) & (w2 >= -1e-9) & (w1 + w2 <= 1 + 1e-9)
    o = owner[inside]
    heights = np.full(n, np.nan)
    heights[ix[inside], iy[inside]] = (
        z[o, 0] + w1[inside] * (z[o, 1] - z[o, 0]) + w2[inside] * (z[o, 2] - z[o, 0])
    )
    nearest = np.minimum(np.rint((xy - lo) / spacing).astype(np.int64), n - 1)
    measured = np.zeros(n, dtype=bool)
    measured[nearest[:, 0], nearest[:, 1]] = True
    measured = ndimage.binary_dilation(measured, structure=np.ones((3, 3), dtype=bool))
    return HeightLattice(float(lo[0]), float(lo[1]), spacing, heights, measured)


DENSE = 4.0
"""Points per lattice node on the mean above which a cloud is thinned to one point a node."""


def nearest_per_node(plane_points: np.ndarray, spacing: float) -> np.ndarray:
    """The point nearest each lattice node that has any (plane frame), for a cloud with more
    than ``DENSE`` points a node (the D435's at arm's length: about 10 on a 3 mm lattice): the
    nodes' heights come from the samples closest to them, and the Delaunay triangulation, the
    slow step, shrinks to one point a node. A sparser cloud (ClimbLab's: 1.1-2.1 a node) is
    kept whole, so the paper's interpolation stands on it as it was."""
    xy = plane_points[:, :2]
    offset = (xy - xy.min(axis=0)) / spacing
    node = np.rint(offset).astype(np.int64)
    key = node[:, 0] * (int(node[:, 1].max()) + 1) + node[:, 1]
    order = np.lexsort((np.sum((offset - node) ** 2, axis=1), key))
    first = np.ones(len(order), dtype=bool)
    first[1:] = key[order[1:]] != key[order[:-1]]
    if len(order) <= DENSE * np.count_nonzero(first):
        return plane_points
    corner = np.argmin(xy, axis=0)  # kept, so the lattice built on what is kept is this one
    return plane_points[np.union1d(order[first], corner)]


def lattice_spacing(plane_points: np.ndarray, voxel: float, requested: float) -> float:
    """The lattice pitch: ``requested`` or ClimbLab's density rule, in whole voxels (≥ 1)."""
    if requested <= 0:
        extent = np.ptp(plane_points[:, :2], axis=0)
        density = len(plane_points) / max(float(extent[0] * extent[1]), 1e-12)
        requested = 1.0 / math.sqrt(density * 5.0 / 3.0)
    return voxel * max(1, round(requested / voxel))


def column_depths(lattice: HeightLattice, voxel: float) -> np.ndarray:
    """Depth index k = ⌊(z_top − z) / voxel⌋ of each lattice column's solid voxel (−1 where
    unknown): the terrain matrix of §2.1 step 3 held as one index per column."""
    known = np.isfinite(lattice.heights)
    if not known.any():
        raise DegenerateCloud("cloud has no interpolated terrain")
    top = float(np.nanmax(lattice.heights))
    depth = np.full(lattice.heights.shape, -1, dtype=np.int64)
    depth[known] = np.floor((top - lattice.heights[known]) / voxel).astype(np.int64)
    return depth


def terrain_matrix(depth: np.ndarray) -> np.ndarray:
    """The 0/1 terrain matrix (columns × depth, §2.1 step 3) of the column depths; depth grows
    downwards, as the mask's does. The paper's form, for its per-voxel scan."""
    terrain = np.zeros((*depth.shape, int(depth.max()) + 1), dtype=bool)
    ix, iy = np.nonzero(depth >= 0)
    terrain[ix, iy, depth[ix, iy]] = True
    return terrain


def lattice_mask(mask: np.ndarray, step: int) -> np.ndarray:
    """The mask cells at whole multiples of ``step`` voxels from its centre (exact on a lattice)."""
    half = mask.shape[0] // 2
    keep = np.arange(half % step, mask.shape[0], step)
    return mask[np.ix_(keep, keep, np.arange(mask.shape[2]))]


class Correlator:
    """Counts, at chosen voxels, the solid voxels of their window and those in the mask's void.

    The window is the mask anchored with its centre column over the voxel and its depth 0 at
    the voxel's depth. With one solid voxel per column, a window column holds a solid cell
    exactly when its depth lies 0 ≤ k < mask depth below the voxel's, and that cell is a hit
    when the mask is void there: one gather of the window's column depths per voxel.
    """

    CHUNK = 256
    """Voxels per gather (keeps the working set in cache)."""

    def __init__(self, mask: np.ndarray) -> None:
        self.mask = mask
        n, _, d = mask.shape
        void = np.zeros((n * n, d + 1), dtype=np.uint8)
        void[:, :d] = ~mask.reshape(n * n, d)
        self._void = void.ravel()
        self._rows = np.arange(n * n, dtype=np.intp) * (d + 1)

    def counts(
        self, depth: np.ndarray, cols: tuple[np.ndarray, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray]:
        """(void hits, solid voxels) of the windows at columns ``cols`` (index arrays) of the
        column-depth lattice ``depth`` (−1 unknown), each anchored at its column's solid voxel."""
        n, _, d = self.mask.shape
        h = n // 2
        width = depth.shape[1] + 2 * h
        padded = np.full((depth.shape[0] + 2 * h, width), -1, dtype=np.int32)
        padded[h : h + depth.shape[0], h : h + depth.shape[1]] = depth
        flat = padded.ravel()
        oi, oj = np.mgrid[0:n, 0:n]
        offsets = (oi * width + oj).ravel()
        ix, iy = cols
        corner = ix * width + iy
        own = depth[ix, iy].astype(np.int32)
        hits = np.empty(len(ix), dtype=np.int64)
        solid = np.empty(len(ix), dtype=np.int64)
        for s in range(0, len(ix), self.CHUNK):
            below = flat[corner[s : s + self.CHUNK, None] + offsets] - own[s : s + self.CHUNK, None]
            below = below.view(np.uint32)  # above the voxel or unknown: huge, outside the window
            inside = below < d
            solid[s : s + self.CHUNK] = np.count_nonzero(inside, axis=1)
            np.minimum(below, d, out=below)
            hits[s : s + self.CHUNK] = self._void[self._rows + below].sum(axis=1)
        return hits, solid


def scan_window(
    terrain: np.ndarray, mask: np.ndarray, at: tuple[np.ndarray, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """The paper's per-voxel scan (§2.3): cut each voxel's window, count its solid cells in the
    mask's void and in all. The reference the correlation is tested and benchmarked against."""
    h = mask.shape[0] // 2
    depth = mask.shape[2]
    padded = np.zeros(
        (terrain.shape[0] + 2 * h, terrain.shape[1] + 2 * h, terrain.shape[2] + depth),
        dtype=terrain.dtype,
    )
    padded[h : h + terrain.shape[0], h : h + terrain.shape[1], : terrain.shape[2]] = terrain
    void = ~mask
    hits = np.empty(len(at[0]), dtype=np.int64)
    solid = np.empty(len(at[0]), dtype=np.int64)
    for i, (x, y, z) in enumerate(zip(*at, strict=True)):
        window = padded[x : x + 2 * h + 1, y : y + 2 * h + 1, z : z + depth]
        hits[i] = int(window[void].sum())
        solid[i] = int(window.sum())
    return hits, solid


def void_known(known: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """True at columns whose mask void cells all lie over known terrain (unknown is not void):
    a binary dilation of the unknown columns by the void footprint, outside the lattice
    unknown."""
    footprint = (~mask).any(axis=2)[::-1, ::-1].astype(np.uint8)
    unknown = cv2.dilate(
        (~known).astype(np.uint8), footprint, borderType=cv2.BORDER_CONSTANT, borderValue=1
    )
    return unknown == 0


def palm_clear(depth: np.ndarray, radius: float, tolerance: int) -> np.ndarray:
    """True where no column within ``radius`` lattice cells stands > ``tolerance`` voxels higher."""
    r = int(radius)
    offsets = np.arange(-r, r + 1)
    footprint = np.hypot(offsets[:, None], offsets[None, :]) <= radius
    highest = ndimage.minimum_filter(
        np.where(depth >= 0, depth, np.iinfo(np.int64).max), footprint=footprint, mode="nearest"
    )
    return highest >= depth - tolerance


def thin(points: np.ndarray, scores: np.ndarray, distance: float) -> np.ndarray:
    """Collapse points closer than ``distance`` to the best-scored one among them (greedy NMS)."""
    if len(points) == 0 or distance <= 0:
        return points
    order = np.argsort(-scores, kind="stable")
    kept: list[int] = []
    taken = np.zeros(len(points), dtype=bool)
    for i in order:
        if taken[i]:
            continue
        kept.append(i)
        taken |= np.linalg.norm(points - points[i], axis=1) < distance
    return points[kept]


@dataclass(frozen=True)
class Detection:
    """Result of one detection: thinned targets and every graspable voxel (body frame, m)."""

    points: np.ndarray
    candidates: np.ndarray
    lattice_spacing: float


class GraspableDetector:
    """The whole pipeline of §2 as a reusable object: mask and kernel spectra are built once."""

    def __init__(self, config: GraspableConfig) -> None:
        config.check()
        self.config = config
        self.mask = gripper_mask(config.gripper, config.voxel)
        self._correlators: dict[int, Correlator] = {}

    def correlator(self, step: int) -> Correlator:
        """The correlator of the mask sampled on a lattice of ``step`` voxels."""
        if step not in self._correlators:
            self._correlators[step] = Correlator(lattice_mask(self.mask, step))
        return self._correlators[step]

    def detect(self, points: np.ndarray, viewpoint: np.ndarray | None = None) -> Detection:
        """Graspable points of an N×3 cloud (body frame, m); the robot looks from ``viewpoint``.

        Points that are not finite or lie beyond ``max_range`` are dropped first; DegenerateCloud
        when what is left holds no terrain.
        """
        cloud = np.asarray(points, dtype=np.float64)
        if cloud.ndim != 2 or cloud.shape[1] != 3:
            raise ValueError(f"points: expected an N×3 array, found shape {cloud.shape}")
        cloud = within_range(cloud, self.config.max_range)
        if len(cloud) < 3:
            raise DegenerateCloud(
                f"points: need at least 3 finite points within max_range "
                f"{self.config.max_range} m, found {len(cloud)}"
            )
        eye = np.zeros(3) if viewpoint is None else np.asarray(viewpoint, dtype=np.float64)
        cfg = self.config
        frame = regression_frame(cloud, eye)
        plane = frame.to_plane(cloud)
        spacing = lattice_spacing(plane, cfg.voxel, cfg.lattice_spacing)
        lattice = interpolate_heights(nearest_per_node(plane, spacing), spacing)
        depth = column_depths(lattice, cfg.voxel)
        correlator = self.correlator(round(spacing / cfg.voxel))
        known = depth >= 0
        palm = (cfg.gripper.palm_diameter + cfg.gripper.margin_top_solid) / 2 / spacing
        cols = np.nonzero(
            lattice.measured
            & known
            & void_known(known, correlator.mask)
            & palm_clear(depth, palm, cfg.above_tolerance)
        )
        hits, solid = correlator.counts(depth, cols)
        ok = (hits <= cfg.void_fraction * solid) & (solid > cfg.solid_threshold)
        gx, gy = cols[0][ok], cols[1][ok]
        on_plane = np.column_stack(
            (lattice.x0 + gx * spacing, lattice.y0 + gy * spacing, lattice.heights[gx, gy])
        )
        body = frame.to_body(on_plane)
        targets = thin(body, on_plane[:, 2], cfg.thin_distance)
        return Detection(targets, body, spacing)


class GraspablePerception(CloudPerception):
    """Perception plugin publishing paper 001's graspable points (GraspablePoints, body frame)."""

    name: ClassVar[str] = "graspable"
    publishes = (GraspablePoints,)
    Config: ClassVar[type[msgspec.Struct]] = GraspableConfig

    def __init__(self, config: GraspableConfig | None = None, profile: object = None) -> None:
        super().__init__(config, profile)
        self.detector = GraspableDetector(self.config)

    def process_cloud(self, points: np.ndarray, body: BodyState, stamp: float) -> GraspablePoints:
        """The graspable targets of a body-frame cloud; none on a cloud without terrain (blank,
        sparse, all NaN or out of range)."""
        try:
            targets = self.detector.detect(points).points
        except DegenerateCloud:
            targets = np.zeros((0, 3))
        return GraspablePoints(stamp=stamp, frame_stamp=stamp, points=targets.tolist())
