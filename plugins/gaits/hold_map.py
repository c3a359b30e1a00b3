"""Paper 001 §4.1's "infinite discrete graspable point map": copies of one detection result.

The paper joins copies of the graspable points detected on a group of climbing holds. Here
each copy is turned by a multiple of 90° and mirrored at random (seeded), so maps made from
one detection differ by seed while keeping its density and spacing; copies sit edge to edge
with one mean neighbour spacing between them.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def tile_map(
    tile: np.ndarray, seed: int, along: tuple[float, float], across: tuple[float, float]
) -> np.ndarray:
    """Wall-frame holds (k×3) covering ``along`` × ``across`` (m) with copies of ``tile`` (n
    points on the wall plane, n ≥ 2, with an optional third column: the hold's height, kept;
    else z = 0), each rotated and mirrored at random."""
    tile = np.asarray(tile, float)
    if len(tile) < 2:
        raise ValueError(f"tile: need at least 2 graspable points, found {len(tile)}")
    height = tile[:, 2] if tile.shape[1] > 2 else np.zeros(len(tile))
    tile = tile[:, :2] - (tile[:, :2].min(axis=0) + tile[:, :2].max(axis=0)) / 2
    spacing = float(np.mean(cKDTree(tile).query(tile, k=2)[0][:, 1]))
    pitch = float(np.ptp(tile, axis=0).max()) + spacing
    rng = np.random.default_rng(seed)
    xs = np.arange(along[0] + pitch / 2, along[1] + pitch / 2, pitch)
    ys = np.arange(across[0] + pitch / 2, across[1] + pitch / 2, pitch)
    copies = []
    for x in xs:
        for y in ys:
            turn = rng.integers(4) * np.pi / 2
            c, s = np.cos(turn), np.sin(turn)
            mirror = 1.0 if rng.integers(2) else -1.0
            local = tile * [1.0, mirror]
            copies.append(local @ np.array([[c, s], [-s, c]]) + [x, y])
    points = np.vstack(copies)
    return np.column_stack((points, np.tile(height, len(copies))))
