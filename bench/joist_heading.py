"""Where the crossing's heading comes from: the twin's yaw, the estimator's, and the joist's.

Runs one Table 2 case on perceived joists through the driver (bench/joist_climb.py's
scenario) and, at each of the crossing's drift checks, prints the simulated time, the plan's
phase, the twin's body yaw, the daemon's estimated yaw, the yaw and distance of the joist as
the behaviour sees it from its pose, and whether the check found a drift; then the replans.
The behaviour's drift check is wrapped to log (the run is otherwise bench/joist_climb.py's).

    .venv/bin/python bench/joist_heading.py [--test 1] [--in-process]
        [--landmark-min-distance -1]   (-1: the joist fixes the pose however near, as before)
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from support.joist_twin_run import run_scenario  # noqa: E402
from test_joist_climb_twin import TABLE_2, table_2_row  # noqa: E402

from climbd.daemon.contract.geometry import yaw  # noqa: E402
from climbd.drivers.sim.twin import Twin  # noqa: E402
from climbd.plugins.gaits.joist_climb import JoistClimb  # noqa: E402
from climbd.plugins.perception.joist_perception import JoistPerception  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--test", type=int, default=1, help="Table 2 test (1-7)")
    parser.add_argument("--in-process", action="store_true", help="skip the driver")
    parser.add_argument(
        "--landmark-min-distance", type=float, default=None, help="JoistClimbConfig override (m)"
    )
    args = parser.parse_args()
    twins: list[Twin] = []
    started, checked = Twin.start, JoistClimb._drifted

    def start(twin: Twin) -> Twin:
        twins.append(twin)
        return started(twin)

    def drifted(behaviour: JoistClimb, body, sightings) -> bool:
        out = checked(behaviour, body, sightings)
        twin = twins[-1]
        distance, seen = behaviour.ahead(behaviour.target)
        cells = (
            f"{twin.time:.1f}",
            behaviour._phase,
            f"{math.degrees(yaw(twin.body_pose()[1])):+.2f}",
            f"{math.degrees(yaw(np.array(body.orientation))):+.2f}",
            f"{math.degrees(seen):+.2f}",
            f"{distance:.3f}",
            "yes" if out else "no",
        )
        print("| " + " | ".join(map(str, cells)) + " |", flush=True)
        return out

    Twin.start, JoistClimb._drifted = start, drifted
    config = {}
    if args.landmark_min_distance is not None:
        config["landmark_min_distance"] = args.landmark_min_distance
    _, distance, yaw_deg, height = TABLE_2[args.test - 1]
    row = table_2_row(distance, yaw_deg, height)
    print("| sim s | phase | twin yaw ° | estimate ° | joist seen ° | joist m | drifted |")
    print("|---|---|---|---|---|---|---|")
    outcome = run_scenario(
        [row],
        goal=distance + 0.5,
        seconds=300.0,
        perception=JoistPerception(),
        driver=not args.in_process,
        **config,
    )
    print(outcome.replans)


if __name__ == "__main__":
    main()
