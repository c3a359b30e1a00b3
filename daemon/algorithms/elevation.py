"""Elevation grid (paper 000): body-frame points → 1 cm height cells over the crop box.

Successive frames are fused in the odometry frame, so the map holds still while the robot
walks and cells that leave the field of view (under the body) keep their heights. The crop box
is then read back in the robot's yaw frame (x forward, y left, heights above the ground under
the body) and its holes are filled by Telea inpainting on the float heights.

Cell (row, col) of a grid covers x ∈ [origin_x + row·res, origin_x + (row+1)·res) and likewise
y with col; a cell's height is the fused top of the points that fell in it (per-frame maximum,
averaged over the last ``memory_frames`` frames), so the face of a joist seen from below its
top still reads its top. Each cell also keeps how many points fell in it and the variance of
its per-frame top over frames (the uncertainty of its height) and the stamp of the last frame
that saw it (the map's age there).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import msgspec
import numpy as np

from climbd.daemon.contract.geometry import rotation, yaw
from climbd.daemon.contract.messages import BodyState, ElevationGrid


class ElevationConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Crop box (m, body frame; paper: 1 m × 1.2 m × 0.4 m), 1 cm cells, fusion and inpainting."""

    resolution: float = 0.01
    x_min: float = 0.1
    length: float = 1.0
    width: float = 1.2
    z_min: float = -0.1
    z_max: float = 0.3
    memory_frames: float = 10.0
    inpaint_radius: float = 0.01
    margin: float = 0.5

    def __post_init__(self) -> None:
        for name in ("resolution", "length", "width", "memory_frames", "inpaint_radius"):
            if not getattr(self, name) > 0:
                raise ValueError(f"elevation config: {name} must be > 0, got {getattr(self, name)}")
        if not self.z_max > self.z_min:
            raise ValueError(f"elevation config: z_max {self.z_max} must exceed z_min {self.z_min}")


@dataclass
class Grid:
    """A crop-box grid in the robot's yaw frame: heights (m, NaN unknown), point count, variance
    of the height over frames (m²).

    ``filled`` is ``heights`` with holes inpainted (Telea); ``observed`` marks measured cells.
    """

    heights: np.ndarray
    filled: np.ndarray
    count: np.ndarray
    variance: np.ndarray
    origin_x: float
    origin_y: float
    resolution: float

    @property
    def observed(self) -> np.ndarray:
        return ~np.isnan(self.heights)

    def to_message(self, stamp: float) -> ElevationGrid:
        """The wire form: the inpainted-free heights, NaN where no point was ever seen."""
        rows, cols = self.heights.shape
        return ElevationGrid(
            stamp=stamp,
            frame_stamp=stamp,
            origin_x=self.origin_x,
            origin_y=self.origin_y,
            resolution=self.resolution,
            rows=rows,
            cols=cols,
            heights=np.ascontiguousarray(self.heights, dtype="<f4").tobytes(),
        )


INPAINT_UNIT = 1e-5

HEIGHT, WEIGHT, COUNT, VARIANCE = range(4)
"""Layers of the odometry-frame map, in one float32 array so a crop is a single warp."""


@dataclass(frozen=True)
class Window:
    """Rows ``r0:r1`` and columns ``c0:c1`` of the odometry window: the cells a frame touched."""

    r0: int
    r1: int
    c0: int
    c1: int


def fill_holes(heights: np.ndarray, radius_cells: int) -> np.ndarray:
    """Telea inpainting (paper 000, ref. [11]) of the NaN cells, on float32 heights.

    OpenCV's float Telea leaves a ripple of about one unit in filled cells, so heights are
    inpainted in units of 0.01 mm (``INPAINT_UNIT``) and the ripple stays well below 0.1 mm.
    """
    holes = np.isnan(heights)
    if not holes.any():
        return heights.copy()
    if holes.all():
        return np.zeros_like(heights)
    src = np.where(holes, np.float32(0.0), heights * np.float32(1.0 / INPAINT_UNIT))
    out = cv2.inpaint(src.astype(np.float32), holes.view(np.uint8), radius_cells, cv2.INPAINT_TELEA)
    out *= np.float32(INPAINT_UNIT)
    return out


class ElevationMap:
    """Fuses body-frame clouds into an odometry-frame height map and reads the crop box back."""

    def __init__(self, config: ElevationConfig | None = None) -> None:
        self.config = config or ElevationConfig()
        c = self.config
        self.rows = int(round(c.length / c.resolution))
        self.cols = int(round(c.width / c.resolution))
        far_x = max(abs(c.x_min), abs(c.x_min + c.length))
        reach = math.hypot(far_x, c.width / 2) + c.margin + 2 * c.resolution
        self.side = int(math.ceil(2 * reach / c.resolution))
        self._reach = reach
        self.reset()

    def reset(self) -> None:
        """Forget everything seen so far."""
        self._layers = self._empty()
        self._seen = np.full((self.side, self.side), np.nan)
        self._origin: np.ndarray | None = None
        self._centre = np.zeros(2)
        self.recentred = 0
        """Times the window moved (each move shifts every layer; readers recompute theirs)."""

    @property
    def origin(self) -> np.ndarray | None:
        """Odometry (x, y) of the window's cell (0, 0), or None before the first cloud."""
        return self._origin

    @property
    def heights(self) -> np.ndarray:
        """The window's fused heights (m, odometry frame, NaN unknown), a view."""
        return self._layers[..., HEIGHT]

    @property
    def variance(self) -> np.ndarray:
        """The window's height variance over frames (m²), a view."""
        return self._layers[..., VARIANCE]

    @property
    def seen(self) -> np.ndarray:
        """Stamp (s) of the last frame that saw each cell, NaN never; a view."""
        return self._seen

    def _empty(self) -> np.ndarray:
        """Odometry-window layers: height (NaN unknown), frame weight, point count, variance."""
        layers = np.zeros((self.side, self.side, 4), np.float32)
        layers[..., HEIGHT] = np.nan
        return layers

    def _recentre(self, centre: np.ndarray) -> None:
        """Move the odometry window so ``centre`` (x, y) sits in its middle; keep the overlap."""
        res = self.config.resolution
        new_origin = np.floor(centre / res) * res - (self.side // 2) * res
        self._centre = np.asarray(centre, float).copy()
        if self._origin is None:
            self._origin = new_origin
            return
        shift = np.round((new_origin - self._origin) / res).astype(int)
        new = self._empty()
        sr, sc = shift
        src_r = slice(max(sr, 0), self.side + min(sr, 0))
        dst_r = slice(max(-sr, 0), self.side + min(-sr, 0))
        src_c = slice(max(sc, 0), self.side + min(sc, 0))
        dst_c = slice(max(-sc, 0), self.side + min(-sc, 0))
        seen = np.full_like(self._seen, np.nan)
        if src_r.start < src_r.stop and src_c.start < src_c.stop:
            new[dst_r, dst_c] = self._layers[src_r, src_c]
            seen[dst_r, dst_c] = self._seen[src_r, src_c]
        self._layers, self._seen = new, seen
        self._origin = self._origin + shift * res
        self.recentred += 1

    def integrate(self, points: np.ndarray, body: BodyState) -> Window | None:
        """Fuse one cloud (N×3 body frame, m) taken at pose ``body`` into the map; the window
        it touched, or None when no point fell in the crop box."""
        points = np.asarray(points)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"elevation: points must be N×3, got shape {points.shape}")
        if not len(points):
            return None  # nothing in range (a wall up close, a covered lens): nothing to fuse
        c = self.config
        res = c.resolution
        position = np.asarray(body.position, float)
        if self._origin is None or np.abs(position[:2] - self._centre).max() > c.margin / 2:
            self._recentre(position[:2])

        inv = 1.0 / res
        rot = rotation(body.orientation, zero_norm_ok=True)
        half = c.width / 2
        shift = (position[:2] - self._origin) * inv
        corners = np.array(
            [
                [c.x_min, -half],
                [c.x_min, half],
                [c.x_min + c.length, -half],
                [c.x_min + c.length, half],
            ]
        )
        spread = (c.z_max - c.z_min) * inv
        cells = corners @ rot[:2, :2].T * inv + shift
        r0, c0 = np.maximum(np.floor(cells.min(axis=0) - spread).astype(int), 0)
        r1, c1 = np.minimum(np.ceil(cells.max(axis=0) + spread).astype(int) + 1, self.side)
        wcols = c1 - c0
        size = (r1 - r0) * wcols
        # OpenCV does the per-point work in single passes: the crop test (inRange, which also
        # drops NaN, inf and far points, so only points of the box reach the cell arithmetic)
        # and the transform to window cells, offset by one so that truncation is a floor for
        # every cell of the window (index 0 and the last are outside it).
        cloud = np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 1, 3)
        lo = (c.x_min, -half, c.z_min)
        hi = (np.nextafter(c.x_min + c.length, -np.inf), np.nextafter(half, -np.inf), c.z_max)
        cloud = cloud[cv2.inRange(cloud, lo, hi).reshape(-1) > 0]
        affine = np.zeros((3, 4))
        affine[:2, :3] = rot[:2] * inv
        affine[:2, 3] = shift - (r0, c0) + 1.0
        affine[2, :3] = rot[2]
        affine[2, 3] = position[2]
        cell = cv2.transform(cloud, affine).reshape(-1, 3)
        rows = cell[:, 0].astype(np.int32)
        cols = cell[:, 1].astype(np.int32)
        zs = cell[:, 2]
        keep = (rows >= 1) & (rows <= r1 - r0) & (cols >= 1) & (cols <= wcols)
        flat = np.where(keep, (rows - 1) * wcols + (cols - 1), size)
        count = np.bincount(flat, minlength=size + 1)[:size]
        if not count.any():
            return None
        top = np.full(size + 1, -np.inf, np.float32)
        np.maximum.at(top, flat, zs)
        seen = np.flatnonzero(count)
        top = top[seen]

        win = self._layers[r0:r1, c0:c1].reshape(-1, 4)[seen]
        w_old = win[:, WEIGHT]
        h_old = np.where(w_old > 0, win[:, HEIGHT], top)
        w_new = np.minimum(w_old + 1.0, np.float32(c.memory_frames))
        alpha = 1.0 / w_new
        delta = top - h_old
        win[:, HEIGHT] = h_old + alpha * delta
        win[:, VARIANCE] = (1.0 - alpha) * (win[:, VARIANCE] + alpha * delta * delta)
        win[:, WEIGHT] = w_new
        win[:, COUNT] += count[seen]
        block = self._layers[r0:r1, c0:c1].reshape(-1, 4)
        block[seen] = win
        self._layers[r0:r1, c0:c1] = block.reshape(r1 - r0, wcols, 4)
        stamps = self._seen[r0:r1, c0:c1].reshape(-1)
        stamps[seen] = body.stamp
        self._seen[r0:r1, c0:c1] = stamps.reshape(r1 - r0, wcols)
        rows, cols = np.divmod(seen, wcols)
        return Window(
            int(r0 + rows.min()),
            int(r0 + rows.max() + 1),
            int(c0 + cols.min()),
            int(c0 + cols.max() + 1),
        )

    def _warp(self, body: BodyState) -> np.ndarray:
        """2×3 affine taking crop-box cells (col, row) to odometry-window cells (col, row)."""
        c = self.config
        res = c.resolution
        psi = yaw(body.orientation)
        cs, sn = math.cos(psi), math.sin(psi)
        ax = c.x_min / res + 0.5
        ay = -c.width / 2 / res + 0.5
        tx, ty = (np.asarray(body.position[:2], float) - self._origin) / res - 0.5
        b_row = cs * ax - sn * ay + tx
        b_col = sn * ax + cs * ay + ty
        return np.array([[cs, sn, b_col], [-sn, cs, b_row]], np.float64)

    def crop(self, body: BodyState, fill: bool = True) -> Grid:
        """The crop box around ``body`` in its yaw frame, heights above the ground under it."""
        c = self.config
        shape = (self.rows, self.cols)
        if self._origin is None:
            empty = np.full(shape, np.nan, np.float32)
            zeros = np.zeros(shape, np.float32)
            return Grid(empty, zeros, zeros, zeros, c.x_min, -c.width / 2, c.resolution)
        m = self._warp(body)
        flags = cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP
        size = (self.cols, self.rows)

        border = (float("nan"), 0.0, 0.0, 0.0)
        layers = cv2.warpAffine(self._layers, m, size, flags=flags, borderValue=border)
        heights = layers[..., HEIGHT] - np.float32(body.position[2])
        radius = max(1, int(round(c.inpaint_radius / c.resolution)))
        filled = fill_holes(heights, radius) if fill else heights
        return Grid(
            heights=heights,
            filled=filled,
            count=layers[..., COUNT],
            variance=layers[..., VARIANCE],
            origin_x=c.x_min,
            origin_y=-c.width / 2,
            resolution=c.resolution,
        )

    def update(self, points: np.ndarray, body: BodyState) -> Grid:
        """Fuse a cloud and return the filled crop box at the same pose (one call per frame)."""
        self.integrate(points, body)
        return self.crop(body)
