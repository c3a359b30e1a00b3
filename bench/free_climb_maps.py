"""The free-climb planners over many hold maps, kinematically: how close each comes to the bound.

Each map (``slope_map`` seeds, the twin bench's maps) is climbed for ``--swings`` swings by
the planner alone (each swing's plan applied exactly: no twin, so a map takes a second or two
instead of a minute), once per ``--config`` (ClimbConfig overrides as JSON; ``"duration"``
tells the search the run's length) and by the periodic gait (the baseline, same run). Printed
per configuration: the mean base travel, its ratio to the periodic gait's, its share of the
bound on each map (the beam-400 search that knows the run's end, over the default planner's
feasible steps: tests/support/climb_run.py's ``search_reach``), the worst share, and plan CPU
time (median, 90th percentile, max). For a quick look at a planner change over more maps than the
twin bench's eight; the twin's figures are bench/free_climb.py's.

    .venv/bin/python bench/free_climb_maps.py [--seeds 0:16] [--swings 11] [--jobs 2]
        [--config '{"duration": 45}' --config '{}']
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support.climb_run import planned_climb, search_reach  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0:16", help="first:end of the maps' seeds")
    parser.add_argument("--swings", type=int, default=11, help="swings per climb (45 s / 4 s)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--config", action="append", default=None, help="ClimbConfig JSON")
    args = parser.parse_args()
    first, end = map(int, args.seeds.split(":"))
    seeds = list(range(first, end))
    configs = [json.loads(c) for c in args.config or ['{"duration": 45}', "{}"]]
    n = len(seeds)
    with ProcessPoolExecutor(args.jobs) as pool:
        bounds = list(pool.map(search_reach, seeds, [args.swings] * n))
        periodic = [
            d for d, _ in pool.map(planned_climb, seeds, [args.swings] * n, [True] * n, [{}] * n)
        ]
        print(
            f"maps {args.seeds}, {args.swings} swings: bound {np.mean(bounds):.3f} m mean, "
            f"periodic {np.mean(periodic):.3f} m mean ({np.mean(bounds) / np.mean(periodic):.2f}x)"
        )
        print(
            "| config | mean (m) | / periodic | worst share of bound | share per map |"
            " plan CPU median / p90 / max (ms) |"
        )
        print("|---|---|---|---|---|---|")
        for config in configs:
            done = list(
                pool.map(planned_climb, seeds, [args.swings] * n, [False] * n, [config] * n)
            )
            distance = np.array([d for d, _ in done])
            share = distance / np.array(bounds)
            ms = 1e3 * np.array([t for _, times in done for t in times])
            print(
                f"| `{json.dumps(config)}` | {distance.mean():.3f} "
                f"| {distance.mean() / np.mean(periodic):.2f} | {share.min():.2f} "
                f"| {' '.join(f'{s:.2f}' for s in share)} "
                f"| {np.median(ms):.0f} / {np.percentile(ms, 90):.0f} / {ms.max():.0f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
