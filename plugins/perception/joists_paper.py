"""Paper 000's joist pipeline as written, kept as the baseline that tests and bench/ compare to.

Every frame: the accumulated (SLAM-like) cloud of the last frames is cropped and re-gridded
from scratch (mean height per 1 cm cell), quantised to 8 bits, inpainted (Telea) as an 8-bit
image, Edge Drawing lines found, each line's height taken as the strip mean of eq. 1, lines
under 5 cm dropped, distance as the forward pixel distance of the line's centre from the
grid's near edge, yaw by eq. 2 (unsigned).
"""

from __future__ import annotations

import math
from collections import deque

import cv2
import numpy as np

from climbd.daemon.algorithms.elevation import ElevationConfig
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.messages import BodyState, Joist
from climbd.plugins.perception.joists import JoistConfig, detect_lines, edge_drawing, height_image


def strip_mean_eq1(grid: np.ndarray, x1: float, y1: float, x2: float, y2: float) -> float:
    """Eq. 1: mean of ``grid`` over the line's box widened by 2 px each side (x = col, y = row)."""
    h, w = grid.shape
    c0, c1 = sorted((int(round(x1)), int(round(x2))))
    r0, r1 = sorted((int(round(y1)), int(round(y2))))
    box = grid[max(r0 - 2, 0) : min(r1 + 2, h - 1) + 1, max(c0 - 2, 0) : min(c1 + 2, w - 1) + 1]
    return float(box.mean())


def yaw_eq2(x1: float, y1: float, x2: float, y2: float) -> float:
    """Eq. 2: ψ = arctan(|Δforward| / |Δlateral|) of a line in image pixels (x = col, y = row)."""
    return math.atan2(abs(y1 - y2), abs(x1 - x2))


def _rotate(rot: np.ndarray, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``rot`` applied to 3×N points, elementwise (no threaded BLAS: fair timing on a busy host)."""
    r = rot.astype(np.float32)
    x, y, z = xyz
    return tuple(r[i, 0] * x + r[i, 1] * y + r[i, 2] * z for i in range(3))


class PaperPipeline:
    """The paper's detect stage per frame: re-grid the accumulated cloud, 8-bit, eq. 1, eq. 2."""

    def __init__(
        self,
        grid: ElevationConfig | None = None,
        detection: JoistConfig | None = None,
        frames: int = 10,
    ) -> None:
        self.grid = grid or ElevationConfig()
        self.detection = detection or JoistConfig()
        self.cloud: deque[np.ndarray] = deque(maxlen=frames)
        self._ed = edge_drawing(self.detection)

    def regrid(self, body: BodyState) -> np.ndarray:
        """Mean height per cell of the accumulated cloud in the body's crop box (NaN: empty)."""
        g = self.grid
        world = np.concatenate(self.cloud, axis=1) - np.asarray(body.position, np.float32)[:, None]
        x, y, z = _rotate(rotation(body.orientation, zero_norm_ok=True).T, world)
        rows, cols = int(round(g.length / g.resolution)), int(round(g.width / g.resolution))
        keep = (x >= g.x_min) & (x < g.x_min + g.length) & (np.abs(y) < g.width / 2)
        keep &= (z >= g.z_min) & (z <= g.z_max)
        r = ((x[keep] - g.x_min) / g.resolution).astype(int)
        c = ((y[keep] + g.width / 2) / g.resolution).astype(int)
        flat = np.clip(r, 0, rows - 1) * cols + np.clip(c, 0, cols - 1)
        n = np.bincount(flat, minlength=rows * cols)
        s = np.bincount(flat, weights=z[keep], minlength=rows * cols)
        with np.errstate(invalid="ignore", divide="ignore"):
            return (s / n).reshape(rows, cols)

    def process(self, points: np.ndarray, body: BodyState) -> list[Joist]:
        """Add a body-frame cloud to the accumulated map and detect joists the paper's way."""
        world = np.stack(
            _rotate(rotation(body.orientation, zero_norm_ok=True), np.asarray(points, np.float32).T)
        )
        self.cloud.append(world + np.asarray(body.position, np.float32)[:, None])
        heights = self.regrid(body)
        d = self.detection
        holes = np.isnan(heights)
        image = height_image(np.where(holes, d.image_floor, heights), d.image_floor, d.image_scale)
        image = cv2.inpaint(image, holes.astype(np.uint8), 3, cv2.INPAINT_TELEA)
        grid = image.astype(np.float64) / d.image_scale + d.image_floor
        lines, _ = detect_lines(self._ed, image)
        res, g = self.grid.resolution, self.grid
        joists = []
        for x1, y1, x2, y2 in lines:
            height = strip_mean_eq1(grid, x1, y1, x2, y2)
            if height < d.min_height:
                continue
            ends = [
                [g.x_min + (yy + 0.5) * res, -g.width / 2 + (xx + 0.5) * res, height]
                for xx, yy in ((x1, y1), (x2, y2))
            ]
            joists.append(
                Joist(
                    distance=g.x_min + (0.5 * (y1 + y2) + 0.5) * res,
                    yaw=yaw_eq2(x1, y1, x2, y2),
                    height=height,
                    endpoints=ends,
                )
            )
        joists.sort(key=lambda j: j.distance)
        return joists
