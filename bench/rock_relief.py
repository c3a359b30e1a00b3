"""The rock relief's seams: graspable detection over slope_map's whole rock, seen from above.

Per hold-map seed: the share of the map's holds the detector (paper 001 §2, the perception
plugin's defaults) finds within 1 cm, its detections, those off the map (over 1 cm from every
hold: rock the twin lets no gripper hold), and of those the ones within 2 cm of a seam where two
tile copies meet. ``--blend`` sets ``hold_tiles.SEAM_BLEND`` for the run (0: the copies' rock
meets unblended, the relief before the blend), so both are measured by the same script.

    .venv/bin/python bench/rock_relief.py [--seeds 8] [--blend 0.06]
"""

from __future__ import annotations

import argparse

import msgspec
import numpy as np
from scipy.spatial import cKDTree

from climbd.drivers.sim.worlds import (
    hold_map_holds,
    hold_map_rock,
    hold_map_seam_gap,
    hold_map_seams,
    hold_tiles,
)
from climbd.drivers.sim.worlds import load as load_world
from climbd.plugins.perception.graspable import GraspableConfig, GraspableDetector

FOUND = 0.01
"""m (wall plane): a detection within this of a hold found it."""
NEAR_SEAM = 0.02
"""m (wall plane): a detection this close to a seam line lies at the seam."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--blend", type=float, default=hold_tiles.SEAM_BLEND)
    args = parser.parse_args()
    hold_tiles.SEAM_BLEND = args.blend
    detector = GraspableDetector(GraspableConfig())
    print(f"slope_map rock relief, seams blended over {args.blend * 100:g} cm")
    print("seed  holds found  detections  off the map  of them at a seam  seams: wall x; y (m)")
    for seed in range(args.seeds):
        stock = load_world("slope_map")
        hold_map = msgspec.structs.replace(stock.hold_map, seed=seed, relief="rock")
        world = msgspec.structs.replace(stock, hold_map=hold_map)
        found = detector.detect(hold_map_rock(world), np.array([0.2, 0.0, 1.0])).points
        holds = hold_map_holds(world)
        hit = cKDTree(found[:, :2]).query(holds[:, :2])[0] <= FOUND
        off = cKDTree(holds[:, :2]).query(found[:, :2])[0] > FOUND
        at_seam = hold_map_seam_gap(world, found[:, :2]) < NEAR_SEAM
        xs, ys = hold_map_seams(world)
        print(
            f"{seed:4d}  {hit.mean():11.2f}  {len(found):10d}  {off.sum():5d} ({off.mean():.2f})"
            f"  {np.count_nonzero(off & at_seam):17d}  {np.round(xs, 3).tolist()}; "
            f"{np.round(ys, 3).tolist()}"
        )


if __name__ == "__main__":
    main()
