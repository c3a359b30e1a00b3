"""Control-loop timing: climbd's loop (18 joints, fake bus, full tick) beside a C loop.

Lateness is wake-up time minus the absolute deadline; compute is the tick's own time. Both
loops run in the same run at 100 Hz and 1000 Hz, so the ratios mean something on a noisy
machine. Usage: ``python bench/loop.py [--seconds 20]``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

import msgspec
import numpy as np

C_LOOP = r"""
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
int main(int argc, char **argv) {
    double rate = atof(argv[1]); double seconds = atof(argv[2]);
    long n = (long)(rate * seconds); long period = (long)(1e9 / rate);
    double *late = malloc(sizeof(double) * n);
    struct timespec start, deadline, now;
    clock_gettime(CLOCK_MONOTONIC, &start); deadline = start;
    for (long k = 0; k < n; k++) {
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &deadline, NULL);
        clock_gettime(CLOCK_MONOTONIC, &now);
        late[k] = (now.tv_sec - deadline.tv_sec) + (now.tv_nsec - deadline.tv_nsec) * 1e-9;
        deadline.tv_nsec += period;
        if (deadline.tv_nsec >= 1000000000L) { deadline.tv_nsec -= 1000000000L; deadline.tv_sec++; }
    }
    for (long k = 0; k < n; k++) printf("%.9f\n", late[k]);
    return 0;
}
"""

ROOT = Path(__file__).resolve().parent.parent
SERVICE_PRIORITY = 50
"""SCHED_FIFO priority of the control role under systemd/climbd-control.service.in."""


def realtime(priority: int) -> bool:
    """Run the calling process SCHED_FIFO at ``priority``; False if not permitted."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError):
        return False
    return True


def normal_scheduling() -> None:
    """Put the calling process back on the normal scheduler (a child's ``preexec_fn``)."""
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def c_loop(rate: float, seconds: float, workdir: Path) -> np.ndarray | None:
    """Lateness samples of the C loop, or None where no C compiler exists."""
    gcc = shutil.which("gcc") or shutil.which("cc")
    if gcc is None:
        return None
    exe = workdir / "cloop"
    if not exe.exists():
        src = workdir / "cloop.c"
        src.write_text(C_LOOP)
        subprocess.run([gcc, "-O2", "-o", str(exe), str(src)], check=True)
    cmd = [str(exe), str(rate), str(seconds)]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return np.array([float(x) for x in out.stdout.split()])


def climbd_loop(profile_name: str, rate: float, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """Lateness and compute samples of ControlLoop running the full control tick on a fake bus."""
    from climbd.daemon.contract import profile as profiles
    from climbd.daemon.contract.messages import Mode
    from climbd.daemon.runtime.loop import MonotonicClock, TimingWindow
    from climbd.daemon.runtime.stack import control_stack
    from climbd.drivers.fake import FakeJointBus

    profile = msgspec.structs.replace(
        profiles.load(ROOT / "robots" / f"{profile_name}.toml"), rate_hz=rate
    )
    clock = MonotonicClock()
    bus = FakeJointBus(profile, clock=clock.now)
    bus.open()
    stack = control_stack(profile, bus, clock)
    safety, loop = stack.safety, stack.loop
    n = int(rate * seconds)
    loop.timing = TimingWindow(size=n)
    safety.request(Mode.STAND, clock.now())
    thread = threading.Thread(target=loop.run, kwargs={"max_ticks": n})
    thread.start()
    thread.join()
    return loop.timing.lateness[:n].copy(), loop.timing.compute[:n].copy()


def pct(a: np.ndarray) -> tuple[float, float, float]:
    return tuple(float(x) * 1e6 for x in np.percentile(a, [50, 99, 99.9]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--json", help="also write the figures to this file")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for rate, robot in ((100.0, "widowx"), (1000.0, "widowx")):
            c = c_loop(rate, args.seconds, Path(tmp))
            late, compute = climbd_loop(robot, rate, args.seconds)
            rows.append((rate, c, late, compute))
    print(f"18 joints, fake bus, {args.seconds:g} s per loop; times in µs")
    print(
        "| rate | loop | lateness p50 | p99 | p99.9 | compute p50 | compute p99 | "
        "compute p50 / period | p99 lateness ratio to C |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    figures = {}
    for rate, c, late, compute in rows:
        lp = pct(late)
        cp = pct(compute)
        if c is None:
            print(f"| {rate:g} Hz | C clock_nanosleep | skipped: no C compiler | | | | | | |")
            ratio = float("nan")
        else:
            c_p = pct(c)
            ratio = lp[1] / c_p[1]
            print(
                f"| {rate:g} Hz | C clock_nanosleep | {c_p[0]:.0f} | {c_p[1]:.0f} | {c_p[2]:.0f} "
                "| – | – | – | 1.00 |"
            )
        share = cp[0] * 1e-6 * rate
        print(
            f"| {rate:g} Hz | climbd ControlLoop | {lp[0]:.0f} | {lp[1]:.0f} | {lp[2]:.0f} | "
            f"{cp[0]:.0f} | {cp[1]:.0f} | {share:.1%} | {ratio:.2f} |"
        )
        figures[f"{rate:g}"] = {"lateness_us": lp, "compute_us": cp, "ratio_p99_to_c": ratio}
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2))


if __name__ == "__main__":
    main()
