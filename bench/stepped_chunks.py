"""How many ticks a ControlLoop on a SteppedClock runs per second of clock when a rig runs it in
chunks (``loop.run(max_ticks=loop.ticks + n)``, as tests/support/walk_run.py does with n = 10)
against one call: the rate, since the schedule carries on across calls. (When each call ticked
first at the clock's present time, a chunk of n ticks spanned n - 1 periods and the controller,
which takes each tick as a period, ran ahead of the physics: 111 ticks a second in chunks of 10.)

    .venv/bin/python bench/stepped_chunks.py [--rate 100] [--seconds 10]
"""

from __future__ import annotations

import argparse

from climbd.daemon.runtime.loop import ControlLoop, SteppedClock


def ticks_per_second(rate: float, seconds: float, chunk: int | None) -> float:
    """Ticks per second of clock over ``seconds`` of ticks, run whole (None) or in chunks."""
    clock = SteppedClock()
    loop = ControlLoop(rate, clock, lambda t, dt: None)
    total = round(seconds * rate)
    if chunk is None:
        loop.run(max_ticks=total)
    while loop.ticks < total:
        loop.run(max_ticks=min(total, loop.ticks + chunk))
    return loop.ticks / clock.now()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=100.0, help="loop rate (Hz)")
    parser.add_argument("--seconds", type=float, default=10.0, help="seconds of ticks")
    args = parser.parse_args()
    print("| run | ticks per second of clock | against the rate |")
    print("|---|---|---|")
    for chunk in (None, 100, 10, 2):
        rate = ticks_per_second(args.rate, args.seconds, chunk)
        name = "one call" if chunk is None else f"chunks of {chunk}"
        print(f"| {name} | {rate:.2f} | {rate / args.rate:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
