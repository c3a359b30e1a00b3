"""Plane removal before member segmentation (paper 003 II-A: planes go first, linkers stay).

Candidate planes are found on a coarse voxel copy of the cloud (a floor holds most of the
points, and its normals are cheap there), then refitted and judged on the fine cloud.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage


def find_planes(
    points: np.ndarray,
    normals: np.ndarray,
    rng: np.random.Generator,
    *,
    distance: float,
    angle_deg: float,
    min_points: int,
    max_planes: int,
    hypotheses: int = 64,
    sample: int = 2000,
) -> list[tuple[np.ndarray, float]]:
    """Up to ``max_planes`` candidate RANSAC planes (unit normal, offset) of an oriented cloud.

    A hypothesis is one oriented point; inliers are near the plane with a normal within
    ``angle_deg`` of it; each candidate's inliers leave the pool before the next search.
    """
    active = np.ones(len(points), bool)
    cos_limit = np.cos(np.radians(angle_deg))
    planes = []
    for _ in range(max_planes):
        pool = np.flatnonzero(active)
        if len(pool) < min_points:
            break
        seeds = rng.choice(pool, size=min(hypotheses, len(pool)), replace=False)
        probe = rng.choice(pool, size=min(sample, len(pool)), replace=False)
        n = normals[seeds]
        offsets = np.einsum("hj,hj->h", n, points[seeds])
        near = np.abs(points[probe] @ n.T - offsets) < distance
        aligned = np.abs(normals[probe] @ n.T) > cos_limit
        best = int(np.argmax((near & aligned).sum(axis=0)))
        normal, offset = n[best], offsets[best]
        for _ in range(3):
            inliers = pool[
                (np.abs(points[pool] @ normal - offset) < distance)
                & (np.abs(normals[pool] @ normal) > cos_limit)
            ]
            if len(inliers) < min_points:
                return planes
            normal, offset = fit_plane(points[inliers])
        planes.append((normal, offset))
        active[inliers] = False
    return planes


def accept_plane(
    points: np.ndarray,
    plane: tuple[np.ndarray, float],
    *,
    distance: float,
    min_width: float,
    min_area: float,
    cell: float,
    max_points: int = 20000,
) -> tuple[tuple[np.ndarray, float], bool]:
    """Refit a candidate on the fine points within ``distance`` and judge it a real surface.

    Its points must span ``min_width`` in both directions and, on a grid of ``cell``-sized
    cells eroded by one cell, keep ``min_area`` (m^2) of interior: a floor does, while the
    face of a truss, however wide and densely built, is made of strips a cell or two wide.
    Judged on at most about ``max_points`` (every k-th).
    """
    normal, offset = plane
    near = points[np.abs(points @ normal - offset) < distance]
    near = near[:: max(1, len(near) // max_points)]
    if len(near) < 3:
        return plane, False
    centroid, axes = principal_axes(near)
    flat = (near - centroid) @ axes[:2].T
    spans = np.ptp(flat, axis=0)
    cells = np.floor((flat - flat.min(axis=0)) / cell).astype(np.int64)
    grid = np.zeros(cells.max(axis=0) + 1, bool)
    grid[cells[:, 0], cells[:, 1]] = True
    interior = ndimage.binary_erosion(grid, np.ones((3, 3), bool)).sum() * cell * cell
    refined = (axes[2], float(axes[2] @ centroid))
    return refined, bool(spans.min() >= min_width and interior >= min_area)


def fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane (unit normal, offset n . p) through points."""
    centroid, axes = principal_axes(points)
    return axes[2], float(axes[2] @ centroid)


def principal_axes(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The centroid of points and their principal axes as rows, widest spread first: the
    eigenvectors of the 3 x 3 scatter matrix (as an SVD of the N x 3 cloud gives, at a
    fraction of its cost on tens of thousands of points)."""
    centroid = points.mean(axis=0)
    centred = points - centroid
    _, vectors = np.linalg.eigh(centred.T @ centred)
    return centroid, vectors.T[::-1]


def plane_heights(points: np.ndarray, planes: list[tuple[np.ndarray, float]]) -> np.ndarray:
    """Distance of each point to its nearest plane (inf without planes), and that plane's index."""
    if not planes:
        return np.full(len(points), np.inf), np.zeros(len(points), int)
    heights = np.abs(np.stack([points @ n - o for n, o in planes]))
    nearest = heights.argmin(axis=0)
    return heights[nearest, np.arange(len(points))], nearest
