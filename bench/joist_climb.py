"""Paper 000 Table 2 and a row of three joists, in the twin, in-process and through the driver.

Each setup runs twice in the same process: the gait's joint goals set in the twin in-process
(the baseline: what tests/test_joist_climb_twin.py runs) and the daemon's driver path
(Controller, Safety, leg odometry, dynamixel_sdk to the AX-18A emulator on the twin's pty,
lock-step). Prints each run's verdict (the tests' own checks) and its wall seconds per
simulated second, with the driver path's ratio to the baseline.

    .venv/bin/python bench/joist_climb.py [--only 1 3 row] [--set foot_margin=0.035]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from support.joist_twin_run import run_scenario  # noqa: E402
from test_joist_climb_twin import TABLE_2, assert_climbed, assert_went_round  # noqa: E402

from climbd.drivers.sim.worlds import INCH, JoistRow  # noqa: E402
from climbd.plugins.gaits.joist_climb import JoistClimbConfig  # noqa: E402


def setups() -> dict[str, tuple[JoistRow, float, float]]:
    """Name → (row, goal m, seconds): Table 2's seven tests and the attic row of three."""
    out = {
        str(test): (
            JoistRow(height=h, distance=d, width=0.04, length=1.8, yaw_deg=yaw),
            d + 0.5,
            300.0,
        )
        for test, d, yaw, h in TABLE_2
    }
    row = JoistRow(height=0.10, distance=1.0, count=3, spacing=16 * INCH, width=0.04, length=1.8)
    out["row"] = (row, 2.6, 420.0)
    return out


def verdict(outcome, row: JoistRow) -> str:
    """'pass', or the failed check's message (the tests' checks)."""
    try:
        if outcome.held:
            return f"held: {outcome.held}"
        if row.height < 0.14:
            assert_climbed(outcome, row, last=row.count - 1)
        else:
            assert_went_round(outcome, row)
    except AssertionError as e:
        first = str(e).splitlines()[0] if str(e) else "check failed"
        hits = f"; link contacts {sorted(outcome.link_hits)}" if outcome.link_hits else ""
        return f"FAIL ({first[:80]}{hits})"
    return "pass"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", help="setups to run (1-7, row)")
    parser.add_argument(
        "--set", nargs="*", default=[], metavar="KEY=VALUE", help="JoistClimbConfig overrides"
    )
    args = parser.parse_args()
    config = {}
    for item in args.set:
        key, _, value = item.partition("=")
        if key not in JoistClimbConfig.__struct_fields__:
            parser.error(f"--set {item}: JoistClimbConfig has no field {key!r}")
        try:
            config[key] = float(value)
        except ValueError:
            parser.error(f"--set {item}: {key} needs a number")
    chosen = {k: v for k, v in setups().items() if not args.only or k in args.only}
    print("| setup | in-process | wall/sim | driver path | wall/sim | ratio | replans |")
    print("|---|---|---|---|---|---|---|")
    for name, (row, goal, seconds) in chosen.items():
        cells = []
        for driver in (False, True):
            t0 = time.perf_counter()
            outcome = run_scenario([row], goal=goal, seconds=seconds, driver=driver, **config)
            rate = (time.perf_counter() - t0) / max(outcome.seconds, 1e-9)
            replans = sum("replanned" in e or "no new plan" in e for e in outcome.events)
            cells.append((verdict(outcome, row), rate, replans))
        (v0, r0, n0), (v1, r1, n1) = cells
        print(
            f"| {name} | {v0} | {r0:.3f} | {v1} | {r1:.3f} | {r1 / r0:.1f}× | {n0} / {n1} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
