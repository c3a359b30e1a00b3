"""Plane removal before member segmentation (paper 003 II-A: planes go first, linkers stay).

Planes are found on a coarse voxel copy of the cloud (a floor holds most of the points, and
its normals are cheap there), refined on the fine cloud, then removed in two bands: every
point within ``distance``, and points within twice that whose normal is along the plane's.
"""

from __future__ import annotations

import numpy as np


def find_planes(
    points: np.ndarray,
    normals: np.ndarray,
    rng: np.random.Generator,
    *,
    distance: float,
    angle_deg: float,
    min_points: int,
    min_width: float,
    min_fill: float,
    cell: float,
    max_planes: int,
    hypotheses: int = 64,
    sample: int = 2000,
) -> list[tuple[np.ndarray, float]]:
    """Up to ``max_planes`` RANSAC planes (unit normal, offset) of an oriented cloud.

    A hypothesis is one oriented point; inliers are near the plane with a normal within
    ``angle_deg`` of it. A plane is accepted only with ``min_points`` inliers spread over at
    least ``min_width`` in both directions (a strip of a tube is no floor) that fill at least
    ``min_fill`` of that extent in ``cell``-sized cells (the front face of a truss is as wide
    as a floor but mostly empty).
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
        centred = points[inliers] - points[inliers].mean(axis=0)
        _, _, vt = np.linalg.svd(centred, full_matrices=False)
        flat = centred @ vt[:2].T
        spans = np.ptp(flat, axis=0)
        cells = np.unique(np.floor(flat / cell).astype(np.int64), axis=0)
        fill = len(cells) / np.prod(np.ceil(spans / cell) + 1)
        if spans.min() < min_width or fill < min_fill:
            break
        planes.append((normal, offset))
        active[inliers] = False
    return planes


def fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane (unit normal, offset n . p) through points."""
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    return vt[2], float(vt[2] @ centroid)


def refine_plane(
    points: np.ndarray, plane: tuple[np.ndarray, float], distance: float
) -> tuple[np.ndarray, float]:
    """Refit a coarse plane on the fine points within ``distance`` of it."""
    normal, offset = plane
    near = points[np.abs(points @ normal - offset) < distance]
    return fit_plane(near) if len(near) >= 3 else plane


def plane_heights(points: np.ndarray, planes: list[tuple[np.ndarray, float]]) -> np.ndarray:
    """Distance of each point to its nearest plane (inf without planes), and that plane's index."""
    if not planes:
        return np.full(len(points), np.inf), np.zeros(len(points), int)
    heights = np.abs(np.stack([points @ n - o for n, o in planes]))
    nearest = heights.argmin(axis=0)
    return heights[nearest, np.arange(len(points))], nearest
