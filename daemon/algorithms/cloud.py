"""Depth frames to body-frame point clouds, and the crop box of paper 000 (pure numpy, no I/O).

A pixel (u, v) with depth z (m) is the optical-frame point z·((u − ppx)/fx, (v − ppy)/fy, 1);
the mount extrinsics take it to the body frame. Once per camera setup (intrinsics, extrinsics,
decimation, depth unit, range limits, crop box) the rays are scaled by the depth unit, rotated
into the body frame and stored as float32 planes, and the crop box becomes a pixel window and
per-pixel raw-depth bounds; a frame then costs two uint16 comparisons per window pixel and one
gather, multiply and add per kept pixel and axis.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import msgspec
import numpy as np

from climbd.daemon.contract.hardware import DepthFrame, Intrinsics
from climbd.daemon.contract.messages import BodyState, Message
from climbd.daemon.contract.plugins import PerceptionPlugin


class CropBox(msgspec.Struct, forbid_unknown_fields=True, kw_only=True, frozen=True):
    """Axis-aligned box in the body frame (m): what perception keeps of a cloud (paper 000)."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float
    z_min: float
    z_max: float

    def __post_init__(self) -> None:
        for axis in "xyz":
            lo, hi = getattr(self, f"{axis}_min"), getattr(self, f"{axis}_max")
            if not hi > lo:
                raise ValueError(f"crop box: {axis}_max {hi} must exceed {axis}_min {lo}")


PAPER_000 = CropBox(x_min=0.1, x_max=1.1, y_min=-0.6, y_max=0.6, z_min=-0.1, z_max=0.3)
"""Paper 000's 1 m × 1.2 m × 0.4 m chunk ahead of the body (x forward, ground at z = 0)."""

PAPER_000_TEST_7 = CropBox(x_min=0.1, x_max=3.1, y_min=-0.6, y_max=0.6, z_min=-0.1, z_max=0.3)
"""Paper 000's test 7 box, 3 m × 1.2 m × 0.4 m, so a joist stays in view from 2.7 m."""


_RAW_END = 65536
"""One past the largest uint16 depth: the "never" of a raw-depth search."""


def _rays(intrinsics: Intrinsics, rotation: np.ndarray, decimation: int) -> np.ndarray:
    """Body-frame direction (per unit depth) of every kept pixel, (H', W', 3) float64."""
    i = intrinsics
    u = (np.arange(0, i.width, decimation) - i.ppx) / i.fx
    v = (np.arange(0, i.height, decimation) - i.ppy) / i.fy
    optical = np.stack(np.broadcast_arrays(u[None, :], v[:, None], 1.0), axis=-1)
    return optical @ rotation.T


def _project(ray: np.ndarray, raw: np.ndarray, origin: np.float32) -> np.ndarray:
    """One body coordinate of raw depths along scaled rays, in the float32 steps of the frames."""
    return np.multiply(ray, raw.astype(np.float32)) + origin


def _first_raw(ray: np.ndarray, origin: np.float32, face: np.ndarray, reached) -> np.ndarray:
    """Per pixel, the smallest raw depth in [0, 65536] at which ``reached(coordinate)`` holds.

    ``reached`` flips at most once, false to true, along each ray, near where the coordinate
    crosses ``face``. Bisection over the same float32 arithmetic as the conversion (bracketed by
    the float64 crossing), so a crop by depth bounds equals cropping the cloud point by point.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        crossing = (face - np.float64(origin)) / ray.astype(np.float64)
    crossing = np.nan_to_num(np.clip(crossing, -1.0, _RAW_END), nan=_RAW_END)
    lo = np.clip(np.floor(crossing) - 1, 0, _RAW_END).astype(np.int32)
    hi = np.clip(np.ceil(crossing) + 1, 0, _RAW_END).astype(np.int32)
    below = (lo > 0) & reached(_project(ray, lo - 1, origin))
    above = (hi < _RAW_END) & ~reached(_project(ray, np.minimum(hi, _RAW_END - 1), origin))
    lo[below | above], hi[below | above] = 0, _RAW_END
    while (open_ := np.flatnonzero(lo < hi)).size:
        mid = (lo[open_] + hi[open_]) >> 1
        hit = reached(_project(ray[open_], mid, origin), open_)
        hi[open_] = np.where(hit, mid, hi[open_])
        lo[open_] = np.where(hit, lo[open_], mid + 1)
    return hi


def _box_bounds(
    rays: np.ndarray, origin: np.ndarray, box: CropBox
) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel raw-depth interval [lo, hi] whose float32 points lie inside ``box``.

    Along a pixel's ray each body coordinate is monotone in the depth, so each pair of faces
    bounds an interval of raw depth; a box is the intersection of three of them.
    """
    shape = rays.shape[1:]
    lo = np.zeros(shape, np.int32)
    hi = np.full(shape, _RAW_END - 1, np.int32)
    limits = ((box.x_min, box.x_max), (box.y_min, box.y_max), (box.z_min, box.z_max))
    for ray, t, (cmin, cmax) in zip(rays.reshape(3, -1), origin, limits, strict=True):
        rising = ray >= 0

        def entered(c, at=slice(None), r=rising, a=cmin, b=cmax):
            return np.where(r[at], c >= a, c <= b)

        def left(c, at=slice(None), r=rising, a=cmin, b=cmax):
            return np.where(r[at], c > b, c < a)

        enter = _first_raw(ray, t, np.where(rising, cmin, cmax), entered)
        leave = _first_raw(ray, t, np.where(rising, cmax, cmin), left)
        lo = np.maximum(lo, enter.reshape(shape))
        hi = np.minimum(hi, leave.reshape(shape) - 1)
    return lo, hi


def _frozen(array: np.ndarray) -> np.ndarray:
    """A read-only contiguous copy: cached plans are shared by every frame of a setup."""
    array = np.array(array, order="C")
    array.flags.writeable = False
    return array


class _Plan(NamedTuple):
    """What a frame's conversion needs, fixed per camera setup: the pixel window that can reach
    the crop box, the scaled body-frame rays of its pixels (3 planes), and per-pixel raw bounds."""

    rows: slice
    cols: slice
    rays: np.ndarray
    origin: np.ndarray
    lo: np.ndarray | int
    hi: np.ndarray | None


@lru_cache(maxsize=8)
def _plan(
    intrinsics: Intrinsics,
    transform: bytes,
    decimation: int,
    depth_scale: float,
    min_range: float | None,
    max_range: float | None,
    box: CropBox | None,
) -> _Plan:
    """Precompute a camera setup's conversion: rays × depth scale in float32, rotated to the body
    frame, so a frame is raw depth × ray + origin; the crop box becomes raw-depth bounds."""
    t = np.frombuffer(transform, dtype=np.float64).reshape(4, 4)
    rays64 = _rays(intrinsics, t[:3, :3], decimation)
    rays = np.ascontiguousarray(np.moveaxis(rays64 * depth_scale, -1, 0), dtype=np.float32)
    origin = _frozen(t[:3, 3].astype(np.float32))
    lo = 1 if min_range is None else max(1, int(np.ceil(min_range / depth_scale)))
    hi = (
        _RAW_END - 1
        if max_range is None
        else min(_RAW_END - 1, int(np.floor(max_range / depth_scale)))
    )
    full = slice(0, None, decimation)
    rays.flags.writeable = False
    if box is None:
        return _Plan(
            full, full, rays.reshape(3, -1), origin, lo, None if hi == _RAW_END - 1 else hi
        )
    box_lo, box_hi = _box_bounds(rays, origin, box)
    lo_px, hi_px = np.maximum(box_lo, lo), np.minimum(box_hi, hi)
    reachable = lo_px <= hi_px
    rows, cols = np.flatnonzero(reachable.any(axis=1)), np.flatnonzero(reachable.any(axis=0))
    if len(rows) == 0:
        none = slice(0, 0)
        return _Plan(none, none, rays[:, :0, :0].reshape(3, 0), origin, 1, None)
    (r0, r1), (c0, c1) = (int(rows[0]), int(rows[-1]) + 1), (int(cols[0]), int(cols[-1]) + 1)
    window = (slice(r0, r1), slice(c0, c1))
    lo_px[~reachable], hi_px[~reachable] = _RAW_END - 1, 0
    return _Plan(
        slice(r0 * decimation, (r1 - 1) * decimation + 1, decimation),
        slice(c0 * decimation, (c1 - 1) * decimation + 1, decimation),
        _frozen(rays[(slice(None), *window)].reshape(3, -1)),
        origin,
        _frozen(lo_px[window].astype(np.uint16)),
        _frozen(hi_px[window].astype(np.uint16)),
    )


def frame_to_points(
    frame: DepthFrame,
    decimation: int = 1,
    min_range: float | None = None,
    max_range: float | None = None,
    box: CropBox | None = None,
) -> np.ndarray:
    """(N, 3) float32 body-frame points (m) of a frame's valid pixels, in row-major pixel order.

    ``decimation`` keeps every n-th row and column; ``min_range``/``max_range`` bound the depth
    z along the optical axis (m), as the RealSense threshold filter does; ``box`` keeps only the
    points inside a crop box (same result as ``crop``, without projecting what it drops).
    Zero depth is no return.
    """
    if decimation < 1:
        raise ValueError(f"frame_to_points: decimation must be >= 1, got {decimation}")
    i = frame.intrinsics
    if frame.depth.shape != (i.height, i.width):
        raise ValueError(
            f"frame_to_points: depth shape {frame.depth.shape} does not match intrinsics "
            f"{i.width}x{i.height}"
        )
    if frame.depth.dtype != np.uint16:
        raise ValueError(
            f"frame_to_points: depth must be uint16 raw units, got {frame.depth.dtype}"
        )
    transform = np.ascontiguousarray(frame.extrinsics, dtype=np.float64).tobytes()
    plan = _plan(i, transform, decimation, frame.depth_scale, min_range, max_range, box)
    depth = frame.depth[plan.rows, plan.cols]
    keep = depth >= plan.lo
    if plan.hi is not None:
        keep &= depth <= plan.hi
    index = np.flatnonzero(keep)
    raw = np.take(depth, index)
    points = np.empty((len(index), 3), np.float32)
    ray = np.empty(len(index), np.float32)
    for axis in range(3):
        np.take(plan.rays[axis], index, out=ray)
        np.multiply(ray, raw, out=ray)
        np.add(ray, plan.origin[axis], out=points[:, axis])
    return points


def within_range(points: np.ndarray, max_range: float) -> np.ndarray:
    """The rows of an N×3 cloud (m) that are finite and at most ``max_range`` from its origin,
    as float64.

    NaN and inf are no return, and a point beyond a plugin's working range is no measurement
    (a wrong depth scale, a corrupt file): both are discarded here, never processed.
    """
    points = np.asarray(points, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        squared = np.einsum("ij,ij->i", points, points)
    return points[squared <= max_range * max_range]


def crop(points: np.ndarray, box: CropBox) -> np.ndarray:
    """The points (N×3, body frame) inside ``box``, bounds included."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    keep = (x >= box.x_min) & (x <= box.x_max)
    keep &= (y >= box.y_min) & (y <= box.y_max)
    keep &= (z >= box.z_min) & (z <= box.z_max)
    return points[keep]


class CloudPerception(PerceptionPlugin):
    """A perception plugin that works on points: ``process`` projects the frame's valid pixels
    to body-frame points and hands them to ``process_cloud``."""

    def process(self, frame: DepthFrame, body: BodyState) -> Message | tuple[Message, ...] | None:
        return self.process_cloud(frame_to_points(frame), body, frame.timestamp)
