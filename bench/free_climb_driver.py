"""Paper 001's climb through HubRobo's own control path (issue 36, item 3), beside the
in-process harness on the same maps.

Per map (``slope_map`` seeds): the default planner, told the run's length, climbs for
``--seconds`` (a) through the control role (tests/support/climb_driver.py: the Dynamixel
Protocol 2.0 driver on the twin's emulated servos and gripper servos over a pty, controller,
guard and loop on a stepped clock, the plugin planning on its worker from the leg odometry's
body, grips as the driver reports them) and (b) with its joint goals and grips set in the twin
in-process (tests/support/climb_run.py, the baseline ``bench/free_climb.py`` measures). Both
read the world's true holds (a: placed in the odometry frame by the body's estimate), so the
gait is isolated from perception. Printed per map: distance up the slope (twin truth) of
each and their ratio, slips, missed grips, least TSM of the holding grippers, the driver run's
plan CPU per swing (max, and as a share of the 4 s swing) and its control ticks' CPU (p99 and
max, the tick's thread: it never plans).

    .venv/bin/python bench/free_climb_driver.py [--seeds 8] [--seconds 45] [--jobs 2]
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
sys.path.insert(0, str(HERE))
from free_climb import ThreadCpu  # noqa: E402
from free_climb import run as in_process  # noqa: E402
from support.climb_driver import DriverClimb  # noqa: E402
from support.climb_run import ClimbLog  # noqa: E402

from climbd.plugins.gaits.free_climb import FreeClimb  # noqa: E402


@dataclass
class DriverRun:
    """The driver run's twin log, why it left ACTIVE (empty: it did not), the CPU time of its
    plans (worker thread) and control ticks (loop thread), and its wall time (s)."""

    log: ClimbLog
    left: str
    plans: list[float]
    ticks: list[float]
    wall: float


def through_driver(seed: int, seconds: float) -> DriverRun:
    """Climb map ``seed`` for ``seconds`` through the control role, timing plans and ticks."""
    t0 = time.perf_counter()
    plans, ticks = ThreadCpu(), ThreadCpu()
    climb = DriverClimb(seed, duration=seconds)
    gait: FreeClimb = climb.gait
    start = gait.start

    def timed_start(body, feet) -> None:
        start(body, feet)
        gait.planner.plan = plans.wrap(gait.planner.plan)

    gait.start = timed_start
    climb.stack.loop.tick = ticks.wrap(climb.stack.loop.tick)
    try:
        climb.begin()
        ticks.samples.clear()
        log = climb.run(seconds)
    finally:
        climb.close()
    return DriverRun(log, climb.left, plans.samples, ticks.samples, time.perf_counter() - t0)


def climb_map(seed: int, seconds: float) -> tuple[DriverRun, ClimbLog]:
    """Map ``seed`` through the driver and in-process (the default planner told the length)."""
    return through_driver(seed, seconds), in_process(False, seed, seconds, {"duration": None}).log


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=45.0)
    parser.add_argument("--jobs", type=int, default=1, help="maps climbed at once (processes)")
    args = parser.parse_args()
    seeds = range(args.seeds)
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(climb_map, seeds, [args.seconds] * len(seeds)))
    swing = 4.0
    print(
        f"HubRobo, slope_map, {args.seconds:g} s, default planner told the run's length; "
        "driver = control role through the Dynamixel driver, in-process = joint goals set in "
        "the twin"
    )
    print(
        "seed  driver m  in-proc m  ratio  slips d/i  missed d/i  min TSM d/i (m)  "
        "plan max s  plan/swing  tick p99 ms  tick max ms  wall s  left"
    )
    distances = []
    for seed, (d, i) in zip(seeds, results, strict=True):
        plan = max(d.plans, default=0.0)
        ticks = np.array(d.ticks) * 1e3
        distances.append((d.log.distance, i.distance))
        print(
            f"{seed:4d}  {d.log.distance:8.3f}  {i.distance:9.3f}  "
            f"{d.log.distance / i.distance:5.2f}  {d.log.slips:5d}/{i.slips:<3d}  "
            f"{d.log.missed:6d}/{i.missed:<3d}  {min(d.log.tsm):7.3f}/{min(i.tsm):.3f}  "
            f"{plan:10.3f}  {plan / swing:9.1%}  {np.percentile(ticks, 99):11.2f}  "
            f"{ticks.max():11.2f}  {d.wall:6.0f}  {d.left or '-'}"
        )
    dist = np.array(distances)
    print(
        f"mean  {dist[:, 0].mean():8.3f}  {dist[:, 1].mean():9.3f}  "
        f"{dist[:, 0].mean() / dist[:, 1].mean():5.2f}"
    )


if __name__ == "__main__":
    main()
