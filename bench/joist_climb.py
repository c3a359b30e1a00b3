"""Paper 000 Table 2 and a row of three joists, in the twin, in-process and through the driver.

Each setup runs twice in the same process: the gait's joint goals set in the twin in-process
(the baseline: what tests/test_joist_climb_twin.py runs) and the daemon's driver path
(Controller, Safety, leg odometry, dynamixel_sdk to the AX-18A emulator on the twin's pty,
lock-step). The joist map is built from the world's true joists (the gait isolated) or, with
``--perceived``, from joist perception on the twin's ray-cast depth at the pose the gait is
given. Prints each run's verdict (the tests' own checks), the simulated seconds of each
crossing, its replans (succeeded of requested; drifts after which the plan still kept its
margins) and its wall seconds per simulated second, with the driver path's ratio.

    .venv/bin/python bench/joist_climb.py [--only 1 3 row] [--perceived] [--in-process-only]
        [--set foot_margin=0.035]
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
from climbd.plugins.perception.joist_perception import JoistPerception  # noqa: E402


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
    parser.add_argument("--perceived", action="store_true", help="joists from perception")
    parser.add_argument("--in-process-only", action="store_true", help="skip the driver path")
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
    paths = (False,) if args.in_process_only else (False, True)
    joists = "perceived" if args.perceived else "true"
    print("| setup | joists | path | verdict | crossing s | replans ok/asked, kept | wall/sim |")
    print("|---|---|---|---|---|---|---|")
    for name, (row, goal, seconds) in chosen.items():
        rates = []
        for driver in paths:
            perception = JoistPerception() if args.perceived else None
            t0 = time.perf_counter()
            outcome = run_scenario(
                [row], goal=goal, seconds=seconds, perception=perception, driver=driver, **config
            )
            rates.append((time.perf_counter() - t0) / max(outcome.seconds, 1e-9))
            r = outcome.replans
            crossing = ", ".join(f"{s:.0f}" for s in outcome.crossings) or "–"
            ratio = f" ({rates[-1] / rates[0]:.1f}× in-process)" if driver else ""
            print(
                f"| {name} | {joists} | {'driver' if driver else 'in-process'} | "
                f"{verdict(outcome, row)} | {crossing} | {r.succeeded}/{r.attempts}, {r.kept} | "
                f"{rates[-1]:.3f}{ratio} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
