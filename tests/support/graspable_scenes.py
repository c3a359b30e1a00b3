"""Synthetic climbing-hold scenes with known hold apexes, and real-cloud hold analysis for tests."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


def dome_board(
    domes: list[tuple[float, float, float, float]],
    pins: list[tuple[float, float, float, float]] = (),
    size: float = 0.36,
    pitch: float = 0.003,
    noise: float = 0.0004,
    seed: int = 0,
) -> np.ndarray:
    """A flat board (z = 0) sampled on a jittered grid, with domes and pins on it (plane frame).

    A dome (x, y, radius, height) is z = height·(1 − (r/radius)²); a pin (x, y, radius, height)
    is a flat-topped cylinder. Returns N×3 points (m) with Gaussian sensor noise.
    """
    rng = np.random.default_rng(seed)
    g = np.arange(-size / 2, size / 2, pitch)
    x, y = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    x = x + rng.uniform(-pitch / 3, pitch / 3, x.shape)
    y = y + rng.uniform(-pitch / 3, pitch / 3, y.shape)
    z = np.zeros_like(x)
    for cx, cy, radius, height in domes:
        r = np.hypot(x - cx, y - cy)
        z = np.maximum(z, np.where(r < radius, height * (1 - (r / radius) ** 2), 0.0))
    for cx, cy, radius, height in pins:
        z = np.where(np.hypot(x - cx, y - cy) < radius, height, z)
    return np.column_stack((x, y, z + rng.normal(0, noise, x.shape)))


def _rotation(roll: float, pitch: float) -> np.ndarray:
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    return ry @ rx


def pose(points: np.ndarray, roll: float, pitch: float, offset: np.ndarray) -> np.ndarray:
    """Points of a plane-frame scene placed in the body frame: rotated (rad), then shifted (m)."""
    return points @ _rotation(roll, pitch).T + offset


def unpose(points: np.ndarray, roll: float, pitch: float, offset: np.ndarray) -> np.ndarray:
    """The inverse of ``pose``: body-frame points back in the scene's own frame."""
    return (points - offset) @ _rotation(roll, pitch)


def board_plane(points: np.ndarray, tolerance: float = 0.002) -> tuple[np.ndarray, np.ndarray]:
    """The board's plane by RANSAC (seeded): the plane with most points within ``tolerance``.

    Holds cover less of the view than the board, so the best-supported plane is the board; it
    is refined by least squares on its inliers. Returns (point on plane, unit normal to sensor).
    """
    rng = np.random.default_rng(0)
    triples = points[np.array([rng.choice(len(points), 3, replace=False) for _ in range(300)])]
    a, b, c = triples[:, 0], triples[:, 1], triples[:, 2]
    normals = np.cross(b - a, c - a)
    length = np.linalg.norm(normals, axis=1)
    keep = length >= 1e-12
    a, normals = a[keep], normals[keep] / length[keep, None]
    offsets = np.einsum("ij,ij->i", a, normals)
    counts = (np.abs(points @ normals.T - offsets) < tolerance).sum(axis=0)
    best = int(np.argmax(counts))
    a, n = a[best], normals[best]
    inliers = points[np.abs((points - a) @ n) < tolerance]
    centre = inliers.mean(axis=0)
    normal = np.linalg.svd(inliers - centre, full_matrices=False)[2][2]
    if normal @ -centre < 0:
        normal = -normal
    return centre, normal


def hold_cores(
    points: np.ndarray, height: np.ndarray, above: float = 0.03, link: float = 0.005
) -> list[np.ndarray]:
    """Holds as connected groups of points more than ``above`` over the board (≤ ``link`` apart).

    The holds are 40-50 mm tall and touch at their feet; their parts above 30 mm are separate,
    so each component is one hold's core. Returns index arrays into ``points``.
    """
    idx = np.nonzero(height > above)[0]
    pairs = cKDTree(points[idx]).query_pairs(link, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), (len(idx), len(idx)))
    n, label = connected_components(graph, directed=False)
    return [idx[label == i] for i in range(n) if (label == i).sum() >= 30]
