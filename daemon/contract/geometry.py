"""Shared geometry: rotations, quaternions and a cloud's regression plane.

Quaternions are (w, x, y, z), scalar first, throughout climbd. Pure functions of numbers:
numpy, math and the standard library only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


def rotation(q: Sequence[float], *, zero_norm_ok: bool = False) -> np.ndarray:
    """Rotation matrix of quaternion (w, x, y, z), normalised first.

    A quaternion of zero norm (all zero, or so small its squares underflow) raises
    ZeroDivisionError, unless ``zero_norm_ok``: then its components are used as they are,
    which makes an all-zero quaternion the identity.
    """
    w, x, y, z = map(float, q)
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if zero_norm_ok:
        norm = norm or 1.0
    w, x, y, z = w / norm, x / norm, y / norm, z / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def yaw(q: Sequence[float]) -> float:
    """Heading (rad) of quaternion (w, x, y, z): the yaw of its ZYX Euler angles, from the
    components as given (not normalised)."""
    w, x, y, z = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def slerp(q0: Sequence[float], q1: Sequence[float], s: float) -> list[float]:
    """Spherical linear interpolation from unit quaternion ``q0`` (s = 0) to ``q1`` (s = 1),
    along the shorter arc (``s`` outside [0, 1] extrapolates); equal quaternions are blended
    linearly and renormalised."""
    a = np.asarray(q0, float)
    b = np.asarray(q1, float)
    dot = float(a @ b)
    if dot < 0.0:
        b, dot = -b, -dot
    if dot > 1.0 - 1e-12:
        q = a + s * (b - a)
    else:
        theta = math.acos(dot)
        q = (math.sin((1.0 - s) * theta) * a + math.sin(s * theta) * b) / math.sin(theta)
    return (q / np.linalg.norm(q)).tolist()


@dataclass(frozen=True)
class PlaneFrame:
    """The regression plane's frame Σ_R: origin at the centroid, rows of ``rotation`` = axes."""

    origin: np.ndarray
    rotation: np.ndarray

    def to_plane(self, points: np.ndarray) -> np.ndarray:
        return (points - self.origin) @ self.rotation.T

    def to_body(self, points: np.ndarray) -> np.ndarray:
        return points @ self.rotation + self.origin


def regression_frame(points: np.ndarray, viewpoint: np.ndarray) -> PlaneFrame:
    """Least-squares plane of ``points`` (paper 001 §2.1 step 1), its normal turned towards
    ``viewpoint``."""
    origin = points.mean(axis=0)
    _, _, axes = np.linalg.svd(points - origin, full_matrices=False)
    axes = axes.copy()
    if axes[2] @ (viewpoint - origin) < 0:
        axes[1:] *= -1.0
    return PlaneFrame(origin, axes)
