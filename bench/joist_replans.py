"""How a crossing replans when the joist is found off its planned place mid-crossing.

For the 10 cm joist square ahead at 0.31 m (the crossing's start), the WidowX's crossing plan
is built from the stand; then, for the joist found 1–3 cm nearer or farther (and 5 mm
taller), at every phase where the rest of the plan no longer keeps its margins, it counts how
often the rest moved onto the joist (``CrossingPlan.reanchored``) fits, how often a plan from
scratch at that pose does, and how often either does (what ``joist_climb`` tries, in that
order). Kinematic only: no twin. Prints a row per displacement and the wall seconds of each
kind of replan (median over the broken phases).

    .venv/bin/python bench/joist_replans.py
"""

from __future__ import annotations

import time

import numpy as np

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.profile import stock_profiles
from climbd.plugins.gaits.joist_climb import JoistClimbConfig
from climbd.plugins.gaits.joist_crossing import Bar, CrossingError, CrossingGeometry, CrossingPlan

SHIFTS = (-0.03, -0.02, -0.01, 0.01, 0.02, 0.03)
TALLER = (0.0, 0.005)


def main() -> None:
    kin = Kinematics(profiles.load(stock_profiles()["widowx"]))
    feet = kin.stand_feet()
    stand = -float(feet[0, 2])
    ground = np.column_stack([feet[:, :2], np.zeros(len(feet))])
    bar = Bar(0.31, 0.04, 0.10)
    half_length = float(np.abs(kin.mount[:, 0]).max())
    params = JoistClimbConfig().crossing_params()
    plan = CrossingPlan(CrossingGeometry((bar,), half_length), params, kin, ground, stand, stand)
    print(f"plan of {len(plan.moves)} phases for a {bar.height:.2f} m joist at {bar.face} m")
    print("| joist off (m) | taller (m) | phases broken | re-anchored fits | fresh fits | either |")
    print("|---|---|---|---|---|---|")
    took: dict[str, list[float]] = {"re-anchored": [], "fresh": []}
    for shift in SHIFTS:
        for taller in TALLER:
            moved = (Bar(bar.face + shift, bar.width, bar.height + taller),)
            broken = [k for k in range(len(plan.moves)) if plan.margin(moved, k) < 0.0]
            anchored = fresh = either = 0
            for k in broken:
                start = plan.moves[k]
                origin = np.array([start.body0[0], start.body0[1], 0.0])
                seen = Bar(moved[0].face - origin[0], moved[0].width, moved[0].height)
                geometry = CrossingGeometry((seen,), half_length)
                t0 = time.perf_counter()
                a = plan.reanchored(moved, k, geometry) is not None
                took["re-anchored"].append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                try:
                    CrossingPlan(geometry, params, kin, start.feet0 - origin, stand, start.body0[2])
                    f = True
                except CrossingError:
                    f = False
                took["fresh"].append(time.perf_counter() - t0)
                anchored, fresh, either = anchored + a, fresh + f, either + (a or f)
            row = (f"{shift:+.2f}", f"{taller:.3f}", len(broken), anchored, fresh, either)
            print("| " + " | ".join(map(str, row)) + " |", flush=True)
    for kind, seconds in took.items():
        print(f"{kind}: median {np.median(seconds) * 1e3:.0f} ms over {len(seconds)} replans")


if __name__ == "__main__":
    main()
