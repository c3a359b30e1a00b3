"""Joist detection (paper 000): Edge Drawing lines on the height image, heights, distance, yaw.

The paper's steps: an 8-bit top-down height image, ED-lines on it, lines under 5 cm dropped,
the nearest line's distance along the direction of motion and its yaw ψ (eq. 2). Beyond the
paper: a line's height is the joist top minus the floor beside it (not the strip mean of eq. 1,
which mixes both and reads low), parallel segments of one joist are merged, the near edge is
located to a fraction of a cell, ψ is signed, and every joist carries a confidence.

Frames: grids are in the robot's yaw frame (x forward, y left); ψ is the yaw of the joist's
normal pointing away from the robot, positive counter-clockwise, so turning by ψ squares the
robot to the joist; eq. 2's ψ is its absolute value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import msgspec
import numpy as np

from climbd.daemon.algorithms.elevation import Grid
from climbd.daemon.contract.messages import Joist

REFINE_PIECE = 8.0
"""Cells of the near edge each half-height crossing of the refinement is taken over."""
REFINE_MIN_PIECES = 4
"""Pieces with a crossing needed to refine the edge's line."""


class JoistConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Detection thresholds (paper 000 defaults) and Edge Drawing parameters."""

    min_height: float = 0.05
    image_floor: float = -0.1
    image_scale: float = 625.0
    side_near: int = 1
    side_far: int = 4
    min_length: float = 0.10
    min_observed: float = 0.5
    merge_angle_deg: float = 6.0
    merge_offset: float = 0.08
    merge_gap: float = 0.30
    edge_bias: float = 0.5
    ed_gradient_threshold: int = 20
    ed_anchor_threshold: int = 0
    ed_min_line_length: int = 10
    ed_sigma: float = 1.0

    def __post_init__(self) -> None:
        if not self.image_scale > 0:
            raise ValueError(f"joists config: image_scale must be > 0, got {self.image_scale}")
        if not 0 < self.side_near <= self.side_far:
            raise ValueError(
                f"joists config: need 0 < side_near <= side_far, got "
                f"{self.side_near}, {self.side_far}"
            )
        levels = self.min_height * self.image_scale
        if levels < 8:
            raise ValueError(
                f"joists config: image_scale {self.image_scale} puts min_height "
                f"{self.min_height} m at {levels:.1f} grey levels; need >= 8"
            )


def height_image(heights: np.ndarray, floor: float, scale: float) -> np.ndarray:
    """8-bit top-down image: (h − floor) · scale grey levels, clipped to 0–255.

    The default 625 levels/m (1.6 mm a level over 0.4 m) puts 5 cm at 31 levels and 14 cm at
    87, so both thresholds of the paper stay far apart after quantisation.
    """
    img = (heights - np.float32(floor)) * np.float32(scale)
    return np.clip(img, 0, 255).astype(np.uint8)


def edge_drawing(config: JoistConfig) -> cv2.ximgproc.EdgeDrawing:
    """An Edge Drawing detector (ref. [1]) set up for height images."""
    ed = cv2.ximgproc.createEdgeDrawing()
    p = cv2.ximgproc.EdgeDrawing.Params()
    p.GradientThresholdValue = config.ed_gradient_threshold
    p.AnchorThresholdValue = config.ed_anchor_threshold
    p.MinLineLength = config.ed_min_line_length
    p.Sigma = config.ed_sigma
    ed.setParams(p)
    return ed


def segment_limit(shape: tuple[int, int]) -> int:
    """Longest edge segment EdgeDrawing.detectLines can take for an image of ``shape``.

    detectLines copies each segment into scratch buffers of 8·(width + height) doubles
    without a bounds check (opencv_contrib #3429): a longer, winding segment overflows them.
    """
    return 8 * (shape[0] + shape[1])


def detect_lines(ed: cv2.ximgproc.EdgeDrawing, image: np.ndarray) -> tuple[np.ndarray, str]:
    """Line segments (M×4: x1, y1, x2, y2 in pixels) and which detector found them.

    Edge Drawing as the paper, guarded: when a segment is too long for detectLines'
    buffers, the line segment detector (LSD) runs on the same image instead.
    """
    ed.detectEdges(image)
    segments = ed.getSegments()
    if any(len(s) >= segment_limit(image.shape) for s in segments):
        lines = cv2.createLineSegmentDetector().detect(image)[0]
        source = "lsd"
    else:
        lines = ed.detectLines()
        source = "edge_drawing"
    if lines is None or len(lines) == 0:
        return np.zeros((0, 4), np.float64), source
    return np.asarray(lines, np.float64).reshape(-1, 4), source


def bilinear(grid: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``grid`` at fractional cell coordinates (clamped to the grid)."""
    h, w = grid.shape
    r = np.clip(rows, 0, h - 1.001)
    c = np.clip(cols, 0, w - 1.001)
    r0 = r.astype(np.intp)
    c0 = c.astype(np.intp)
    fr = r - r0
    fc = c - c0
    g00 = grid[r0, c0]
    g01 = grid[r0, c0 + 1]
    g10 = grid[r0 + 1, c0]
    g11 = grid[r0 + 1, c0 + 1]
    return (g00 * (1 - fc) + g01 * fc) * (1 - fr) + (g10 * (1 - fc) + g11 * fc) * fr


@dataclass
class EdgeStep:
    """A height step across one line: floor and top (m), the support along the line (0–1).

    ``rising`` is True when the high side lies along +normal; ``crossing`` is the offset
    (cells, along +normal) where the step passes half height; ``observed`` is the fraction of
    samples along the line with a measured (not inpainted) cell beside them, on its less-seen
    side.
    """

    floor: float
    top: float
    support: float
    rising: bool
    crossing: float
    observed: float

    @property
    def height(self) -> float:
        return self.top - self.floor


@dataclass
class Segment:
    """A line segment in cell coordinates (row, col) with its unit normal (rows, cols)."""

    p0: np.ndarray
    p1: np.ndarray

    @property
    def direction(self) -> np.ndarray:
        d = self.p1 - self.p0
        return d / max(float(np.hypot(*d)), 1e-9)

    @property
    def normal(self) -> np.ndarray:
        """Unit normal pointing away from the robot (+row is forward)."""
        d = self.direction
        n = np.array([d[1], -d[0]])
        if n[0] < 0 or (n[0] == 0 and n[1] < 0):
            n = -n
        return n

    @property
    def length(self) -> float:
        return float(np.hypot(*(self.p1 - self.p0)))


def edge_step(
    filled: np.ndarray, observed: np.ndarray, seg: Segment, near: int, far: int, min_h: float
) -> EdgeStep:
    """Floor, top and support of the step across ``seg``, from profiles along its normal."""
    n_samples = max(2, int(math.ceil(seg.length)) + 1)
    t = np.linspace(0.0, 1.0, n_samples)
    base = seg.p0[None, :] + t[:, None] * (seg.p1 - seg.p0)[None, :]
    offsets = np.arange(-far, far + 1, dtype=np.float64)
    n = seg.normal
    rows = base[:, 0][None, :] + offsets[:, None] * n[0]
    cols = base[:, 1][None, :] + offsets[:, None] * n[1]
    prof = bilinear(filled, rows, cols)
    seen = bilinear(observed.astype(np.float32), rows, cols)
    # A side counts as measured at a sample when some cell across it there was seen: far-range
    # floor comes in sparse rows, an inpainted area beyond the field of view has none.
    seen_minus = float(np.mean(seen[: far - near + 1].max(axis=0) >= 0.5))
    seen_plus = float(np.mean(seen[far + near :].max(axis=0) >= 0.5))
    profile = np.median(prof, axis=1)
    minus = prof[: far - near + 1]
    plus = prof[far + near :]
    rising = bool(np.median(plus) >= np.median(minus))
    high, low = (plus, minus) if rising else (minus, plus)
    floor = float(np.median(low))
    top = float(np.max(np.median(high, axis=1)))
    local = np.max(high, axis=0) - np.median(low, axis=0)
    support = float(np.mean(local >= min_h))
    half = 0.5 * (floor + top)
    signed = profile - half if rising else half - profile
    idx = np.nonzero(signed >= 0)[0]
    crossing = 0.0
    if idx.size and 0 < idx[0] < offsets.size:
        i = idx[0]
        a, b = signed[i - 1], signed[i]
        crossing = float(offsets[i - 1] + (0 - a) / (b - a) if b != a else offsets[i])
    return EdgeStep(floor, top, support, rising, crossing, min(seen_minus, seen_plus))


class JoistDetector:
    """Joists of a filled elevation grid, nearest along the direction of motion first."""

    def __init__(self, config: JoistConfig | None = None) -> None:
        self.config = config or JoistConfig()
        self._ed = edge_drawing(self.config)
        self.last_source = ""
        self.last_lines = np.zeros((0, 4))

    def lines(self, grid: Grid) -> np.ndarray:
        """Edge Drawing lines (M×4, x1 y1 x2 y2 = col row col row) of the grid's height image."""
        c = self.config
        image = height_image(grid.filled, c.image_floor, c.image_scale)
        lines, self.last_source = detect_lines(self._ed, image)
        self.last_lines = lines
        return lines

    def detect(self, grid: Grid) -> list[Joist]:
        """Detect joists: lines → steps ≥ min_height → merged joists with distance, ψ, height."""
        c = self.config
        observed = grid.observed
        min_cells = c.min_length / grid.resolution
        kept: list[tuple[Segment, EdgeStep]] = []
        for x1, y1, x2, y2 in self.lines(grid):
            seg = Segment(np.array([y1, x1]), np.array([y2, x2]))
            if seg.length < min(min_cells, c.ed_min_line_length):
                continue
            step = edge_step(grid.filled, observed, seg, c.side_near, c.side_far, c.min_height)
            if step.height >= c.min_height and step.observed >= c.min_observed:
                kept.append((seg, step))
        joists = [self._joist(grid, group) for group in self._groups(kept, grid.resolution)]
        joists = [j for j in joists if j is not None]
        joists.sort(key=lambda j: j.distance)
        return joists

    def _groups(
        self, kept: list[tuple[Segment, EdgeStep]], res: float
    ) -> list[list[tuple[Segment, EdgeStep]]]:
        """Union of segments that are parallel, close across and near along: one joist each."""
        c = self.config
        parent = list(range(len(kept)))

        def find(i: int) -> int:
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        max_angle = math.radians(c.merge_angle_deg)
        for i in range(len(kept)):
            si = kept[i][0]
            ni, di = si.normal, si.direction
            for j in range(i + 1, len(kept)):
                sj = kept[j][0]
                cos = abs(float(di @ sj.direction))
                if math.acos(min(1.0, cos)) > max_angle:
                    continue
                mid_j = 0.5 * (sj.p0 + sj.p1)
                across = abs(float(ni @ (mid_j - si.p0))) * res
                if across > c.merge_offset:
                    continue
                a = sorted([float(di @ (si.p0 - si.p0)), float(di @ (si.p1 - si.p0))])
                b = sorted([float(di @ (sj.p0 - si.p0)), float(di @ (sj.p1 - si.p0))])
                gap = max(0.0, max(a[0], b[0]) - min(a[1], b[1])) * res
                if gap <= c.merge_gap:
                    parent[find(j)] = find(i)
        groups: dict[int, list[tuple[Segment, EdgeStep]]] = {}
        for i, item in enumerate(kept):
            groups.setdefault(find(i), []).append(item)
        return list(groups.values())

    def _refine(
        self, grid: Grid, n: np.ndarray, d: np.ndarray, c_near: float, along: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """The near edge's line (n · p = c, cells) fitted to its half-height crossings, piece
        by piece along it: Edge Drawing's segments sit on whole cells, so their direction is
        off by up to a degree; the crossings are sub-cell. Unchanged when too few pieces show
        the step (an occluded or short edge)."""
        cfg = self.config
        at, offsets = [], []
        for a in np.arange(along.min(), along.max() - REFINE_PIECE / 2, REFINE_PIECE):
            piece = Segment(c_near * n + a * d, c_near * n + (a + REFINE_PIECE) * d)
            step = edge_step(
                grid.filled, grid.observed, piece, cfg.side_near, cfg.side_far, cfg.min_height
            )
            if step.support >= 0.5 and step.observed >= cfg.min_observed and step.crossing:
                at.append(a + REFINE_PIECE / 2)
                offsets.append(step.crossing * float(n @ piece.normal))
        if len(at) < REFINE_MIN_PIECES:
            return n, d, c_near
        slope, intercept = np.polyfit(at, offsets, 1)
        scale = math.hypot(1.0, slope)
        refined_n = (n - slope * d) / scale
        refined_d = (d + slope * n) / scale
        return refined_n, refined_d, float(refined_n @ ((c_near + intercept) * n))

    def _joist(self, grid: Grid, group: list[tuple[Segment, EdgeStep]]) -> Joist | None:
        """One joist from a group of segments: near edge, ψ, height, extent, confidence.

        Confidence = support × coverage of the near edge: the fraction of it where the step
        exceeds ``min_height``, times the fraction measured (not inpainted) on both sides.
        """
        c = self.config
        res = grid.resolution
        weights = np.array([s.length for s, _ in group])
        if weights.sum() * res < c.min_length:
            return None
        # Direction by doubled-angle averaging, so opposite segment orientations agree.
        angles = np.array([math.atan2(s.direction[1], s.direction[0]) for s, _ in group])
        mean2 = math.atan2(float(weights @ np.sin(2 * angles)), float(weights @ np.cos(2 * angles)))
        d = np.array([math.cos(mean2 / 2), math.sin(mean2 / 2)])
        n = np.array([d[1], -d[0]])
        if n[0] < 0 or (n[0] == 0 and n[1] < 0):
            n = -n

        # Near edge: the nearest rising edge (floor → top going away from the robot).
        def offset(item: tuple[Segment, EdgeStep]) -> float:
            s, st = item
            return float(n @ (0.5 * (s.p0 + s.p1))) + st.crossing * float(n @ s.normal)

        rising = [it for it in group if it[1].rising == bool(n @ it[0].normal > 0)]
        near_seg, near_step = min(rising or group, key=offset)
        ends = np.array([p for s, _ in group for p in (s.p0, s.p1)])
        along = ends @ d
        n, d, c_near = self._refine(grid, n, d, offset((near_seg, near_step)), along)
        along = ends @ d
        c_cells = c_near + c.edge_bias
        # Cell coordinates (row, col) → body (x, y): centre of cell (r, c).
        origin = np.array([grid.origin_x, grid.origin_y]) / res + 0.5
        c_body = c_cells + float(n @ origin)
        a_shift = float(d @ origin)
        points = [(c_body * n + (a + a_shift) * d) * res for a in (along.min(), along.max())]
        psi = math.atan2(n[1], n[0])
        ys = sorted(p[1] for p in points)
        y_path = min(max(0.0, ys[0]), ys[1])
        if abs(n[0]) < 1e-6:
            return None
        distance = (c_body * res - n[1] * y_path) / n[0]
        height = near_step.height
        top = near_step.top
        confidence = near_step.support * near_step.observed
        return Joist(
            distance=float(distance),
            yaw=float(psi),
            height=float(height),
            endpoints=[[float(p[0]), float(p[1]), float(top)] for p in points],
            confidence=float(min(1.0, max(0.0, confidence))),
        )
