"""Depth frames to body-frame point clouds, and the crop box of paper 000 (pure numpy, no I/O).

A pixel (u, v) with depth z (m) is the optical-frame point z·((u − ppx)/fx, (v − ppy)/fy, 1);
the mount extrinsics take it to the body frame. The per-pixel rays are rotated into the body
frame once per (intrinsics, extrinsics, decimation) and cached, so a frame costs one gather and
one multiply-add per valid pixel.
"""

from __future__ import annotations

from functools import lru_cache

import msgspec
import numpy as np

from drivers.base import DepthFrame, Intrinsics


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


@lru_cache(maxsize=16)
def _rays(intrinsics: Intrinsics, rotation: bytes, decimation: int) -> np.ndarray:
    """Body-frame direction (per unit depth) of every kept pixel, (H', W', 3) float32."""
    i = intrinsics
    u = (np.arange(0, i.width, decimation) - i.ppx) / i.fx
    v = (np.arange(0, i.height, decimation) - i.ppy) / i.fy
    optical = np.stack(np.broadcast_arrays(u[None, :], v[:, None], 1.0), axis=-1)
    r = np.frombuffer(rotation, dtype=np.float64).reshape(3, 3)
    return np.ascontiguousarray(optical @ r.T, dtype=np.float32)


@lru_cache(maxsize=16)
def _depth_bounds(
    intrinsics: Intrinsics,
    transform: bytes,
    decimation: int,
    depth_scale: float,
    min_range: float | None,
    max_range: float | None,
    box: CropBox | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel raw-depth interval [lo, hi] whose points land in ``box`` and the range limits.

    Along a pixel's ray each body coordinate is r·z + t, linear in the depth z, so the box is
    an interval of z per pixel: the crop becomes two uint16 comparisons before any projection.
    """
    t = np.frombuffer(transform, dtype=np.float64).reshape(4, 4)
    rays = _rays(intrinsics, np.ascontiguousarray(t[:3, :3]).tobytes(), decimation)
    lo = np.full(rays.shape[:2], 0.0 if min_range is None else min_range)
    hi = np.full(rays.shape[:2], np.inf if max_range is None else max_range)
    if box is not None:
        limits = ((box.x_min, box.x_max), (box.y_min, box.y_max), (box.z_min, box.z_max))
        with np.errstate(divide="ignore", invalid="ignore"):
            for axis, (cmin, cmax) in enumerate(limits):
                r = rays[..., axis].astype(np.float64)
                a, b = (cmin - t[axis, 3]) / r, (cmax - t[axis, 3]) / r
                inside = cmin <= t[axis, 3] <= cmax
                flat = r == 0
                lo = np.maximum(lo, np.where(flat, 0.0 if inside else np.inf, np.minimum(a, b)))
                hi = np.minimum(hi, np.where(flat, np.inf if inside else -1.0, np.maximum(a, b)))
    lo_raw = np.clip(np.ceil(lo / depth_scale), 1, 65536)
    hi_raw = np.clip(np.floor(hi / depth_scale), 0, 65535)
    empty = lo_raw > hi_raw
    lo_raw[empty], hi_raw[empty] = 65535, 0
    return lo_raw.astype(np.uint16), hi_raw.astype(np.uint16)


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
    transform = np.ascontiguousarray(frame.extrinsics, dtype=np.float64)
    rays = _rays(i, np.ascontiguousarray(transform[:3, :3]).tobytes(), decimation)
    depth = frame.depth[::decimation, ::decimation] if decimation > 1 else frame.depth
    if box is None and max_range is None:
        lo = 1 if min_range is None else max(1, int(np.ceil(min_range / frame.depth_scale)))
        keep = depth >= lo
    else:
        lo, hi = _depth_bounds(
            i, transform.tobytes(), decimation, frame.depth_scale, min_range, max_range, box
        )
        keep = depth >= lo
        keep &= depth <= hi
    index = np.flatnonzero(keep)
    z = depth.ravel()[index].astype(np.float32)
    z *= np.float32(frame.depth_scale)
    points = rays.reshape(-1, 3)[index]
    points *= z[:, None]
    points += transform[:3, 3].astype(np.float32)
    return points


def crop(points: np.ndarray, box: CropBox) -> np.ndarray:
    """The points (N×3, body frame) inside ``box``, bounds included."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    keep = (x >= box.x_min) & (x <= box.x_max)
    keep &= (y >= box.y_min) & (y <= box.y_max)
    keep &= (z >= box.z_min) & (z <= box.z_max)
    return points[keep]
