"""Which joist heights the WidowX's crossing planner can cross, and where it is stuck when not.

Paper 000 climbs every joist under 14 cm (its robot was shown on 10 cm). For a joist square
ahead at 0.31 m (the crossing's start), for heights from 8 to 14 cm, the planner
(plugins/gaits/joist_crossing.py) is asked for a crossing from the stand with the default
config and with body heights up to the most this leg can stand at; it prints the plan's
phases and simulated seconds, or the planner's own reason per body height. Kinematic only: no
twin, the plan is what the gait would play.

    .venv/bin/python bench/joist_heights.py [--tolerance 0.006]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.profile import stock_profiles
from climbd.plugins.gaits.joist_climb import JoistClimbConfig
from climbd.plugins.gaits.joist_crossing import Bar, CrossingError, CrossingGeometry, CrossingPlan

HEIGHTS = (0.08, 0.10, 0.11, 0.12, 0.13, 0.139)
BODY_HEIGHTS = (0.135, 0.145, 0.155, 0.165, 0.175)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tolerance", type=float, default=JoistClimbConfig().plan_tolerance)
    args = parser.parse_args()
    widowx = profiles.load(stock_profiles()["widowx"])
    kin = Kinematics(widowx)
    feet = kin.stand_feet()
    stand = -float(feet[0, 2])
    ground = np.column_stack([feet[:, :2], np.zeros(len(feet))])
    geometry_of = lambda h: CrossingGeometry(  # noqa: E731
        bars=(Bar(0.31, 0.04, h),), half_length=float(np.abs(kin.mount[:, 0]).max())
    )
    print(f"tolerance {args.tolerance} m; body heights tried: default, then {BODY_HEIGHTS}")
    print("| joist | body heights | outcome |")
    print("|---|---|---|")
    for height in HEIGHTS:
        for label, heights in (("default", None), ("up to 0.175 m", BODY_HEIGHTS)):
            config = JoistClimbConfig(plan_tolerance=args.tolerance)
            if heights is not None:
                config = JoistClimbConfig(plan_tolerance=args.tolerance, climb_heights=[*heights])
            t0 = time.perf_counter()
            try:
                plan = CrossingPlan(
                    geometry_of(height), config.crossing_params(), kin, ground, stand, stand
                )
                outcome = (
                    f"crossed at body {plan.climb_height:.3f} m: {len(plan.moves)} phases, "
                    f"{plan.duration:.0f} s"
                )
            except CrossingError as e:
                outcome = str(e).removeprefix("joist crossing: ")
            ms = (time.perf_counter() - t0) * 1e3
            print(f"| {height * 100:.1f} cm | {label} | {outcome} (planned in {ms:.0f} ms) |")


if __name__ == "__main__":
    main()
