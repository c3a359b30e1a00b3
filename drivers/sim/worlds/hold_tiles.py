"""Hold maps of the twin: the detected tile shipped as data, and paper 001 §4.1's tiling.

The tile is the graspable points detected on a hold cloud (paper 001 §2): x, y on the cloud's
regression plane and the height (m) above its board (the 5th-percentile level). The twin may
not run the detector (a plugin), so each tile ships as text beside its cloud,
``<cloud stem>.tile.txt``; ``bench/hold_tiles.py`` writes them with the real detector and
tests/test_hold_tiles.py checks they still match it.

``tile_map`` is paper 001 §4.1's "infinite discrete graspable point map": copies of one
detection result. The paper joins copies of the graspable points detected on a group of
climbing holds. Here each copy is turned by a multiple of 90° and mirrored at random (seeded),
so maps made from one detection differ by seed while keeping its density and spacing; copies
sit edge to edge with one mean neighbour spacing between them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

TILE_SUFFIX = ".tile.txt"
REGENERATE = ".venv/bin/python bench/hold_tiles.py"


def tile_file(cloud: Path) -> Path:
    """Where the detected tile of ``cloud`` is shipped: beside it, ``<stem>.tile.txt``."""
    cloud = Path(cloud)
    return cloud.with_name(cloud.stem + TILE_SUFFIX)


def write_tile(cloud: Path, tile: np.ndarray, header: str = "") -> Path:
    """Write ``tile`` (n×3: x, y, height; m) as the shipped tile of ``cloud``, exactly
    (17 significant digits round-trip every float64). Returns the file written."""
    tile = np.asarray(tile, float).reshape(-1, 3)
    path = tile_file(cloud)
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    lines.append("# x y height (m): cloud's regression-plane frame, height above its board")
    lines += [" ".join(f"{v:.17g}" for v in row) for row in tile]
    path.write_text("\n".join(lines) + "\n")
    return path


def read_tile(path: Path) -> np.ndarray:
    """The tile (n×3) in ``path``; ``OSError`` if unreadable, ``ValueError`` if malformed."""
    rows = []
    for n, line in enumerate(Path(path).read_text().splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        row = line.split()
        if len(row) != 3:
            raise ValueError(f"line {n}: expected 3 numbers (x y height), found {len(row)}")
        try:
            rows.append([float(v) for v in row])
        except ValueError:
            raise ValueError(f"line {n}: not a number in {line!r}") from None
    return np.array(rows, float).reshape(-1, 3)


def tile_map(
    tile: np.ndarray, seed: int, along: tuple[float, float], across: tuple[float, float]
) -> np.ndarray:
    """Wall-frame holds (k×3) covering ``along`` × ``across`` (m) with copies of ``tile`` (n
    points on the wall plane, n ≥ 2, with an optional third column: the hold's height, kept;
    else z = 0), each rotated and mirrored at random."""
    from scipy.spatial import cKDTree

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
