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


SEAM_BLEND = 0.06
"""m across a seam over which two copies' rock is blended linearly. Unblended, unrelated rock met
in a cliff of up to 4 cm whose rim the detector took for holds the twin lets no gripper hold:
on slope_map's rock, seeds 0-7, 7-16 of the 16-26 detections off the map lay within 2 cm of a
seam, and HubRobo missed grips there; blended over 6 cm, 0-2 (over 4 cm, 2-8;
bench/rock_relief.py --blend). Half of it reaches into each copy's margin
(``GRIPPER_REACH``), which keeps 1.5 cm of its own rock round its outer holds."""


def tile_copies(
    tile: np.ndarray,
    seed: int,
    along: tuple[float, float],
    across: tuple[float, float],
    margin: float = 0.0,
) -> tuple[np.ndarray, float, list[tuple[np.ndarray, np.ndarray]]]:
    """How ``tile_map`` lays copies of ``tile`` (n×2 or n×3, n ≥ 2) over ``along`` × ``across``:
    the tile's centre (its points are taken about it), the pitch between copies (m), and per
    copy the 2×2 map (a turn by a multiple of 90°, maybe mirrored) and its offset (m); a local
    point p lands at ``p @ map + offset``. Copies sit one mean neighbour spacing apart, or
    ``2 × margin`` where that is more (a copy's outer holds then keep ``margin`` of their own
    rock around them)."""
    from scipy.spatial import cKDTree

    tile = np.asarray(tile, float)
    if len(tile) < 2:
        raise ValueError(f"tile: need at least 2 graspable points, found {len(tile)}")
    centre = (tile[:, :2].min(axis=0) + tile[:, :2].max(axis=0)) / 2
    local = tile[:, :2] - centre
    spacing = float(np.mean(cKDTree(local).query(local, k=2)[0][:, 1]))
    pitch = float(np.ptp(local, axis=0).max()) + max(spacing, 2 * margin)
    rng = np.random.default_rng(seed)
    xs = np.arange(along[0] + pitch / 2, along[1] + pitch / 2, pitch)
    ys = np.arange(across[0] + pitch / 2, across[1] + pitch / 2, pitch)
    copies = []
    for x in xs:
        for y in ys:
            turn = rng.integers(4) * np.pi / 2
            c, s = np.cos(turn), np.sin(turn)
            mirror = 1.0 if rng.integers(2) else -1.0
            copies.append((np.diag([1.0, mirror]) @ np.array([[c, s], [-s, c]]), np.array([x, y])))
    return centre, pitch, copies


def tile_map(
    tile: np.ndarray,
    seed: int,
    along: tuple[float, float],
    across: tuple[float, float],
    margin: float = 0.0,
) -> np.ndarray:
    """Wall-frame holds (k×3) covering ``along`` × ``across`` (m) with copies of ``tile`` (n
    points on the wall plane, n ≥ 2, with an optional third column: the hold's height, kept;
    else z = 0), each rotated and mirrored at random, laid as ``tile_copies`` lays them."""
    tile = np.asarray(tile, float)
    centre, _, copies = tile_copies(tile, seed, along, across, margin)
    height = tile[:, 2] if tile.shape[1] > 2 else np.zeros(len(tile))
    local = tile[:, :2] - centre
    points = np.vstack([local @ turn + offset for turn, offset in copies])
    return np.column_stack((points, np.tile(height, len(copies))))


def tile_relief(
    patch: np.ndarray,
    tile: np.ndarray,
    seed: int,
    along: tuple[float, float],
    across: tuple[float, float],
    resolution: float,
    margin: float,
) -> np.ndarray:
    """Heights (m, rows along, columns across, cell ``resolution``) of the rock under
    ``tile_map``'s holds (laid with ``margin``): each copy carries the square of ``patch`` (the
    hold cloud in the tile's frame, heights above its board) it was detected on, turned and
    mirrored as its holds are; the board (height 0) elsewhere. The field starts at the low
    corner of ``along`` × ``across`` and reaches past its high edges to the last copy's. Cells
    the cloud did not measure (its camera's shadows) are interpolated linearly, as the detector
    fills them (§2.1). Where copies meet, their rock is blended over ``SEAM_BLEND`` (at most
    twice ``margin``)."""
    from scipy.interpolate import griddata

    centre, pitch, copies = tile_copies(tile, seed, along, across, margin)
    half = int(round(pitch / 2 / resolution))
    local = (np.asarray(patch, float)[:, :2] - centre) / resolution
    keep = np.all(np.abs(local) <= half + 0.5, axis=1)
    idx = np.clip(np.round(local[keep]).astype(int) + half, 0, 2 * half)
    square = np.full((2 * half + 1, 2 * half + 1), -np.inf)
    np.maximum.at(square, (idx[:, 0], idx[:, 1]), np.asarray(patch, float)[keep, 2])
    known = np.isfinite(square)
    empty = np.argwhere(~known)
    square[~known] = griddata(np.argwhere(known), square[known], empty, method="linear")
    outside = ~np.isfinite(square)
    square[outside] = griddata(
        np.argwhere(known), square[known], np.argwhere(outside), method="nearest"
    )
    square = np.maximum(square, 0.0)
    reach = np.max([offset for _, offset in copies], axis=0) + pitch / 2
    shape = tuple(int(round((reach[k] - (along, across)[k][0]) / resolution)) + 1 for k in (0, 1))
    heights, weights = np.zeros(shape), np.zeros(shape)
    cells = np.stack(np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij"), -1)
    at = cells * resolution + [along[0], across[0]]
    blend = min(SEAM_BLEND, 2.0 * margin)
    for turn, offset in copies:
        q = at - offset
        if blend > 0.0:
            ramp = np.clip((pitch / 2 + blend / 2 - np.abs(q)) / blend, 0.0, 1.0)
            weight = ramp[..., 0] * ramp[..., 1]
        else:
            weight = np.all(np.abs(q) <= pitch / 2, axis=-1).astype(float)
        inside = weight > 0.0
        p = np.round(q[inside] @ turn.T / resolution).astype(int) + half
        p = np.clip(p, 0, 2 * half)  # past its edge a copy's rock goes on as its edge
        heights[inside] += weight[inside] * square[p[:, 0], p[:, 1]]
        weights[inside] += weight[inside]
    return np.divide(heights, weights, out=np.zeros(shape), where=weights > 0.0)
