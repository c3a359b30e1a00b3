"""Paper 001's climb on the holds HubRobo's own camera finds (issue 36 item 1), beside the same
climb on the world's true holds, both through the control role on the rock relief.

Per map (``slope_map`` seeds, ``relief = "rock"``: each tile of holds carries the ClimbLab rock
it was detected on, and a gripper holds on the rock only at a hold of the map), the default
planner, told the run's length, climbs for ``--seconds`` through the Dynamixel driver
(tests/support/climb_driver.py) twice: on the perception role's hold map, built from the twin's
ray-cast D435 frames through the pyrealsense2 software device (legs cut at the joints of the
frame's time, graspable detection, tracks with the leg odometry's body at the frame's time,
2 Hz) and sent over Zenoh, after the frames of the way up to the start (its camera cannot see
the holds its rear limbs reach from there); and on the world's true holds placed by the body's
estimate (the gait isolated); and the periodic gait ([9], the paper's baseline) on its own
perception likewise. Printed per map: distance up the slope (twin truth) of each, the
perceived climb's ratio to the true one and to the periodic one, slips, missed grips, least
TSM of the holding grippers, and the default planner's perceived map at the end: its holds,
and how many lie within 1 cm (in the wall plane) of a true hold. The mean row gives the
ratios of the mean distances (#36's goal: ≥ 0.17 m and ≥ 2× periodic).

    .venv/bin/python bench/free_climb_perceived.py [--seeds 4] [--seconds 45] [--jobs 2]
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support.climb_driver import DriverClimb  # noqa: E402
from support.climb_run import ClimbLog  # noqa: E402


def climb(
    seed: int, seconds: float, perceive: bool, periodic: bool = False
) -> tuple[ClimbLog, str, int, int]:
    """One climb: its log, why it left ACTIVE (empty: it did not), and the hold map's holds at
    the end with how many of them lie within 1 cm of a true hold."""
    run = DriverClimb(seed, relief="rock", perceive=perceive, periodic=periodic, duration=seconds)
    try:
        run.begin()
        log = run.run(seconds)
        check = run.map_check()
        return log, run.left, len(check.mapped), int(np.count_nonzero(check.to_true <= 0.01))
    finally:
        run.close()


def each(seed: int, seconds: float) -> tuple[tuple, tuple, tuple]:
    """The default planner perceived and on the true holds, and the periodic gait perceived."""
    return (
        climb(seed, seconds, True),
        climb(seed, seconds, False),
        climb(seed, seconds, True, periodic=True),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--seconds", type=float, default=45.0)
    parser.add_argument("--jobs", type=int, default=1, help="maps climbed at once (processes)")
    args = parser.parse_args()
    seeds = range(args.seeds)
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(each, seeds, [args.seconds] * len(seeds)))
    print(
        f"HubRobo, slope_map on its rock relief, {args.seconds:g} s, default planner, through "
        "the Dynamixel driver; perceived = the perception role's hold map from its own D435, "
        "over Zenoh; true = the world's holds (gait isolated); periodic p = the periodic gait "
        "on its own perception"
    )
    print(
        "seed  perceived m  true m  ratio  periodic p m  x periodic  slips p/t/pp  "
        "missed p/t/pp  min TSM p/t/pp (m)  mapped  on a hold  left p/t/pp"
    )
    distances = []
    for seed, (perceived, true, periodic) in zip(seeds, results, strict=True):
        (p, p_left, mapped, on), (t, t_left, _, _), (q, q_left, _, _) = perceived, true, periodic
        distances.append((p.distance, t.distance, q.distance))
        print(
            f"{seed:4d}  {p.distance:11.3f}  {t.distance:6.3f}  {p.distance / t.distance:5.2f}  "
            f"{q.distance:12.3f}  {p.distance / q.distance:10.2f}  "
            f"{p.slips:5d}/{t.slips}/{q.slips:<3d}  {p.missed:6d}/{t.missed}/{q.missed:<3d}  "
            f"{min(p.tsm):7.3f}/{min(t.tsm):.3f}/{min(q.tsm):.3f}  {mapped:6d}  {on:9d}  "
            f"{p_left or '-'}/{t_left or '-'}/{q_left or '-'}"
        )
    dist = np.array(distances).mean(axis=0)
    print(
        f"mean  {dist[0]:11.3f}  {dist[1]:6.3f}  {dist[0] / dist[1]:5.2f}  "
        f"{dist[2]:12.3f}  {dist[0] / dist[2]:10.2f}"
    )


if __name__ == "__main__":
    main()
