"""Writes the twin's detected hold tiles: the graspable points the real detector finds on each
hold cloud, shipped beside it as ``<stem>.tile.txt`` (drivers/sim/worlds/hold_tiles.py).

The twin builds paper 001 §4.1's hold map from that tile but may not import the detector (a
plugin), so the detection is data, written here: ``GraspableDetector(GraspableConfig())`` on
the cloud, mapped into the cloud's regression-plane frame, heights above its board (the 5th
percentile of the cloud's heights). Run it after changing the detector or its defaults;
tests/test_hold_tiles.py fails until the shipped tiles match the detector again. With no
arguments it writes the tiles of the clouds shipped in drivers/sim/worlds/data/; ``--check``
writes nothing and exits 1 if a shipped tile differs from the detector's output.

    .venv/bin/python bench/hold_tiles.py [--check] [cloud.pcd ...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from climbd.daemon.contract.cloudio import read_cloud
from climbd.daemon.contract.geometry import regression_frame
from climbd.drivers.sim.worlds import DATA
from climbd.drivers.sim.worlds.hold_tiles import read_tile, tile_file, write_tile
from climbd.plugins.perception.graspable import GraspableConfig, GraspableDetector

TOLERANCE = 1e-9
"""Largest difference (m) between a shipped tile and the detector's output that still matches
(the detector is deterministic: repeated runs agree bit for bit, and the file is exact)."""


def detect_tile(cloud: Path) -> np.ndarray:
    """The graspable points detected on ``cloud`` (n×3): x, y on its regression plane and the
    height (m) above its board (5th-percentile level)."""
    pts = read_cloud(cloud)
    frame = regression_frame(pts, np.zeros(3))
    board = float(np.percentile(frame.to_plane(pts)[:, 2], 5))
    tile = frame.to_plane(GraspableDetector(GraspableConfig()).detect(pts).points)
    tile[:, 2] -= board
    return tile


def matches(shipped: np.ndarray, detected: np.ndarray) -> bool:
    """Same points in the same order, each coordinate within ``TOLERANCE``."""
    return shipped.shape == detected.shape and bool(np.all(np.abs(shipped - detected) <= TOLERANCE))


def shipped_clouds() -> list[Path]:
    return sorted(DATA.glob("*.pcd"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("clouds", nargs="*", type=Path, help="PCD files (default: the shipped)")
    parser.add_argument("--check", action="store_true", help="compare, write nothing")
    args = parser.parse_args(argv)
    stale = 0
    for cloud in args.clouds or shipped_clouds():
        tile = detect_tile(cloud)
        path = tile_file(cloud)
        if args.check:
            ok = path.exists() and matches(read_tile(path), tile)
            stale += not ok
            print(f"{path}: {'matches' if ok else 'STALE'} ({len(tile)} points)")
            continue
        header = (
            f"Graspable points detected on {cloud.name} (paper 001 §2) by\n"
            "GraspableDetector(GraspableConfig()) of plugins/perception/graspable.py.\n"
            "Written by bench/hold_tiles.py; do not edit: rerun it after changing the detector."
        )
        write_tile(cloud, tile, header)
        print(f"{path}: {len(tile)} points, {path.stat().st_size} bytes")
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
