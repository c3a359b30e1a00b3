"""Terrain layers of a height grid: normals, slope, roughness, step height, traversability.

The filter chain of grid_map's traversability estimation (paper 000 runs its map through such
a chain), computed in closed form on the whole grid at once: a least-squares plane
z = a·x + b·y + c over each cell's window of known cells gives the normal (-a, -b, 1)/‖·‖, the
slope atan‖(a, b)‖ and the roughness (the residuals' standard deviation); the step height is
the highest minus the lowest known cell in the window. Traversability in [0, 1] weighs how far
each stays below its critical value, and is 0 where any reaches it. Window sums are separable
box correlations, so the chain costs a few passes over the grid whatever the radius.

Cell (row, col) lies at x = row·resolution, y = col·resolution (rows along x); NaN is unknown.

``ground_tilt`` reads one frame's ground near the body with the same plane fit: a camera whose
mount in the profile is wrong by a large rotation shows the ground the robot stands on tilted in
the body frame, where a right mount shows it level (on a slope too: the body leans with it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import msgspec
import numpy as np

from climbd.daemon.contract.units import NonNegative, Positive


class TerrainConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Windows (m), critical values (rad, m) and weights of the traversability chain."""

    plane_radius: Positive = 0.03
    """Half-width of the window a cell's plane is fitted over (normals, slope, roughness)."""
    step_radius: Positive = 0.03
    """Half-width of the window a step is sought in."""
    min_cells: int = 6
    """Known cells a window needs for a plane (fewer: the cell's layers are unknown)."""
    critical_slope: Positive = math.radians(35.0)
    critical_step: Positive = 0.14
    """Paper 000's climbable limit for the WidowX: a step of 14 cm or more is not traversable."""
    critical_roughness: Positive = 0.03
    slope_weight: NonNegative = 0.3
    step_weight: NonNegative = 0.4
    roughness_weight: NonNegative = 0.3

    def __post_init__(self) -> None:
        total = self.slope_weight + self.step_weight + self.roughness_weight
        if not math.isclose(total, 1.0, abs_tol=1e-6):
            raise ValueError(f"terrain config: the three weights must sum to 1, found {total:g}")
        if self.min_cells < 3:
            raise ValueError(f"terrain config: min_cells must be >= 3, found {self.min_cells}")


GROUND_POINTS = 8000
"""Points of the footprint a ground reading bins at most (evenly spread in pixel order): a few
per 2 cm cell, at a fraction of the cost of a 640×480 frame's 40 000."""


class GroundConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """The check that a frame shows the ground near the body level in the body frame (the
    camera's mount in the profile is right), before the frame is fused."""

    max_tilt: Positive = math.radians(10.0)
    """rad: a frame whose ground leans more than this from the body's xy plane is not fused. A
    walking body rolls and pitches a few degrees over level ground; a mount wrong by 20° shows
    the ground 20° off."""
    radius: Positive = 0.6
    """m: the footprint, a disc about the body's origin (body frame): the ground the camera
    sees nearest the feet (a forward camera tilted 30–45° down sees it from 0.1–0.5 m)."""
    cell: Positive = 0.02
    """m: the footprint's cells (one mean height each, so near, dense pixels do not outweigh
    far ones)."""
    window: Positive = 0.05
    """m: half-width of the window each cell's plane is fitted over."""
    min_cells: int = 100
    """Seen cells the footprint needs for a reading (fewer: no reading, the frame is fused)."""
    frames: int = 3
    """Consecutive tilted frames after which the perception role warns that the camera's
    mount looks wrong (a stumble or a pose glitch tilts one or two)."""

    def __post_init__(self) -> None:
        if self.min_cells < 3:
            raise ValueError(f"ground config: min_cells must be >= 3, found {self.min_cells}")
        if self.frames < 1:
            raise ValueError(f"ground config: frames must be >= 1, found {self.frames}")


@dataclass(frozen=True)
class GroundTilt:
    """How a frame's ground near the body leans from the body's xy plane, two readings.

    ``surface``: the median of the cells' own planes, the dominant surface (a joist, a step or
    a hold in the footprint does not move it; π/2 when no cell has a plane). ``plane``: one
    plane through every cell (a stair flight the body pitches with reads level, its treads do
    not). The ground is as level as the more level of the two: ``tilt``, with the ground's rise
    along body x and y (rad) in that reading.
    """

    surface: float
    plane: float
    rise_x: float
    rise_y: float
    cells: int

    @property
    def tilt(self) -> float:
        """rad from the body's xy plane: the smaller reading."""
        return min(self.surface, self.plane)


@dataclass
class TerrainLayers:
    """Per-cell layers on the height grid's cells; NaN where unknown."""

    normals: np.ndarray
    """rows × cols × 3 unit normals (x, y, z), z up."""
    slope: np.ndarray
    """rad from horizontal."""
    roughness: np.ndarray
    """m: standard deviation of the heights about the window's plane."""
    step: np.ndarray
    """m: highest minus lowest known height in the step window."""
    traversability: np.ndarray
    """[0, 1]: 1 flat and smooth, 0 beyond a critical value."""


def _window_sum(values: np.ndarray, along_x: np.ndarray, along_y: np.ndarray) -> np.ndarray:
    """Σ over each cell's window of values(i+di, j+dj)·along_x[di]·along_y[dj] (zero outside):
    one separable correlation (OpenCV's kernel X runs along columns, our y)."""
    return cv2.sepFilter2D(values, -1, along_y, along_x, borderType=cv2.BORDER_CONSTANT)


def _plane_fit(
    heights: np.ndarray, resolution: float, radius: float, min_cells: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares plane of each cell's window: slopes a (∂z/∂x), b (∂z/∂y) and the residual
    variance, from centred window moments; NaN where the window has too few known cells."""
    k = max(1, int(round(radius / resolution)))
    ones = np.ones(2 * k + 1)
    offsets = np.arange(-k, k + 1) * resolution
    known = np.isfinite(heights)
    w = known.astype(np.float64)
    z = np.where(known, heights, 0.0).astype(np.float64)
    n = _window_sum(w, ones, ones)
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = 1.0 / n
        mu = _window_sum(w, offsets, ones) * inv
        mv = _window_sum(w, ones, offsets) * inv
        mz = _window_sum(z, ones, ones) * inv
        cuu = _window_sum(w, offsets**2, ones) * inv - mu * mu
        cvv = _window_sum(w, ones, offsets**2) * inv - mv * mv
        cuv = _window_sum(w, offsets, offsets) * inv - mu * mv
        cuz = _window_sum(z, offsets, ones) * inv - mu * mz
        cvz = _window_sum(z, ones, offsets) * inv - mv * mz
        czz = _window_sum(z * z, ones, ones) * inv - mz * mz
        det = cuu * cvv - cuv * cuv
        a = (cuz * cvv - cvz * cuv) / det
        b = (cvz * cuu - cuz * cuv) / det
        residual = np.maximum(czz - a * cuz - b * cvz, 0.0)
    bad = (n < min_cells) | ~known | ~(det > 1e-12 * resolution**4)
    for layer in (a, b, residual):
        layer[bad] = np.nan
    return a, b, residual


def _step(heights: np.ndarray, resolution: float, radius: float) -> np.ndarray:
    """Highest minus lowest known height in each cell's window; NaN on unknown cells."""
    size = 2 * max(1, int(round(radius / resolution))) + 1
    kernel = np.ones((size, size), np.uint8)
    known = np.isfinite(heights)
    low = np.float32(-1e6)
    top = cv2.dilate(np.where(known, heights, low).astype(np.float32), kernel)
    bottom = cv2.erode(np.where(known, heights, -low).astype(np.float32), kernel)
    return np.where(known, top - bottom, np.nan)


def terrain_layers(
    heights: np.ndarray, resolution: float, config: TerrainConfig | None = None
) -> TerrainLayers:
    """The filter chain on a height grid (m, NaN unknown) of ``resolution`` m cells."""
    c = config or TerrainConfig()
    a, b, residual = _plane_fit(heights, resolution, c.plane_radius, c.min_cells)
    norm = np.sqrt(a * a + b * b + 1.0)
    normals = np.stack([-a / norm, -b / norm, 1.0 / norm], axis=-1)
    slope = np.arctan(np.hypot(a, b))
    roughness = np.sqrt(residual)
    step = _step(heights, resolution, c.step_radius)
    scores = [
        (slope / c.critical_slope, c.slope_weight),
        (step / c.critical_step, c.step_weight),
        (roughness / c.critical_roughness, c.roughness_weight),
    ]
    with np.errstate(invalid="ignore"):
        traversability = sum(w * (1.0 - r) for r, w in scores)
        blocked = np.zeros(heights.shape, bool)
        for r, _ in scores:
            blocked |= r >= 1.0
        traversability = np.where(blocked, 0.0, traversability)
    traversability[np.isnan(slope) | np.isnan(step)] = np.nan
    return TerrainLayers(normals, slope, roughness, step, traversability)


def ground_tilt(
    points: np.ndarray, band: tuple[float, float], config: GroundConfig | None = None
) -> GroundTilt | None:
    """The tilt of the ground in one frame's body-frame points (N×3, m) over the footprint
    disc, of the points whose z lies in ``band`` (m, the map's); None when the disc holds fewer
    than ``min_cells`` seen cells (the camera does not see the ground near the body)."""
    c = config or GroundConfig()
    side = 2 * int(math.ceil(c.radius / c.cell))
    # One OpenCV pass crops the box around the disc (and drops NaN) before any arithmetic.
    cloud = np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 1, 3)
    box = cv2.inRange(cloud, (-c.radius, -c.radius, band[0]), (c.radius, c.radius, band[1]))
    near = cloud[box.reshape(-1) > 0].reshape(-1, 3)
    near = near[:: max(1, len(near) // GROUND_POINTS)].astype(np.float64)
    near = near[np.einsum("ij,ij->i", near[:, :2], near[:, :2]) <= c.radius**2]
    index = np.minimum(((near[:, :2] + c.radius) / c.cell).astype(np.int64), side - 1)
    flat = index[:, 0] * side + index[:, 1]
    count = np.bincount(flat, minlength=side * side)
    seen = count > 0
    if seen.sum() < c.min_cells:
        return None
    total = np.bincount(flat, weights=near[:, 2], minlength=side * side)
    heights = np.full(side * side, np.nan)
    heights[seen] = total[seen] / count[seen]
    heights = heights.reshape(side, side)
    a, b, _ = _plane_fit(heights, c.cell, c.window, 6)
    fitted = np.isfinite(a)
    sa, sb = (np.median(a[fitted]), np.median(b[fitted])) if fitted.any() else (math.inf, 0.0)
    rows, cols = np.nonzero(np.isfinite(heights))
    design = np.column_stack([rows * c.cell, cols * c.cell, np.ones(len(rows))])
    (pa, pb, _), *_ = np.linalg.lstsq(design, heights[rows, cols], rcond=None)
    surface, plane = math.atan(math.hypot(sa, sb)), math.atan(math.hypot(pa, pb))
    rise = (sa, sb) if surface < plane else (pa, pb)
    return GroundTilt(
        surface=surface,
        plane=plane,
        rise_x=math.atan(rise[0]),
        rise_y=math.atan(rise[1]),
        cells=int(seen.sum()),
    )
