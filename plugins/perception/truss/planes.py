"""Plane removal before member segmentation (paper 003 II-A: planes go first, linkers stay)."""

from __future__ import annotations

import numpy as np


def remove_planes(
    points: np.ndarray,
    normals: np.ndarray,
    rng: np.random.Generator,
    *,
    distance: float,
    angle_deg: float,
    min_points: int,
    min_width: float,
    max_planes: int,
    min_fill: float = 0.2,
    refits: int = 3,
    cell: float = 0.05,
    hypotheses: int = 64,
    sample: int = 2000,
) -> np.ndarray:
    """Mask of points kept after removing up to ``max_planes`` RANSAC planes.

    A plane hypothesis is one oriented point; inliers are near the plane with a normal within
    ``angle_deg`` of it. A plane is accepted only with ``min_points`` inliers spread over at
    least ``min_width`` in both directions, so a strip of a tube is never taken for a floor.
    Removed: every point within ``distance`` of the plane, and aligned ones within twice that
    (noisy far floor). A plane must also fill ``min_fill`` of its extent in ``cell``-sized
    cells: the front face of a truss is spread as widely as a floor but mostly empty.
    """
    keep = np.ones(len(points), bool)
    cos_limit = np.cos(np.radians(angle_deg))
    for _ in range(max_planes):
        active = np.flatnonzero(keep)
        if len(active) < min_points:
            break
        seeds = rng.choice(active, size=min(hypotheses, len(active)), replace=False)
        probe = rng.choice(active, size=min(sample, len(active)), replace=False)
        n = normals[seeds]
        offsets = np.einsum("hj,hj->h", n, points[seeds])
        near = np.abs(points[probe] @ n.T - offsets) < distance
        aligned = np.abs(normals[probe] @ n.T) > cos_limit
        best = int(np.argmax((near & aligned).sum(axis=0)))
        normal, offset = n[best], offsets[best]
        for _ in range(refits):
            inliers = active[
                (np.abs(points[active] @ normal - offset) < distance)
                & (np.abs(normals[active] @ normal) > cos_limit)
            ]
            if len(inliers) < min_points:
                return keep
            centroid = points[inliers].mean(axis=0)
            centred = points[inliers] - centroid
            _, _, vt = np.linalg.svd(centred, full_matrices=False)
            normal, offset = vt[2], vt[2] @ centroid
        flat = centred @ vt[:2].T
        spans = np.ptp(flat, axis=0)
        cells = np.unique(np.floor(flat / cell).astype(np.int64), axis=0)
        fill = len(cells) / np.prod(np.ceil(spans / cell) + 1)
        if spans.min() < min_width or fill < min_fill:
            break
        height = np.abs(points @ normal - offset)
        aligned = np.abs(normals @ normal) > cos_limit
        keep[(height < distance) | ((height < 2 * distance) & aligned)] = False
    return keep
