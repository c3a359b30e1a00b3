"""Qingzhui's 1 kHz control loop through the torque-leg driver, beside bench/loop.py's C loop.

The real ``ControlLoop`` on ``MonotonicClock`` runs ``Controller.tick`` as ``climbd run`` builds
it for the Qingzhui profile (paper 004's estimator, gravity feed-forward, tripod gait walking
ACTIVE, heartbeats and motion commands arriving from another thread) over ``MitJointBus`` on
python-can's virtual bus, answered by 18 emulated MIT motors (their rotor model serving in a
thread of this process). The C ``clock_nanosleep`` loop runs in the same run, so the p99
lateness ratio means something on a loaded machine. Goal (issue 2's): ratio ≤ 1.5.

    .venv/bin/python bench/torque_loop.py [--seconds 20]
"""

from __future__ import annotations

import argparse
import itertools
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from loop import c_loop, pct  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SESSION = "bench"
_channels = itertools.count()


def torque_loop(seconds: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Lateness and compute samples (s) of the Qingzhui tick at 1 kHz, and its overruns."""
    from daemon import profile as profiles
    from daemon.control import Controller
    from daemon.estimation import EstimatorConfig, StateEstimator
    from daemon.loop import ControlLoop, MonotonicClock, TimingWindow
    from daemon.messages import Heartbeat, Mode, MotionCommand
    from daemon.plugins import Isolated
    from daemon.safety import Safety
    from drivers.sim.mit_motors import MitMotorChain
    from drivers.torque.bus import MitJointBus
    from plugins.gaits.periodic import Tripod

    profile = profiles.load(ROOT / "robots" / "qingzhui.toml")
    channel = f"bench-torque-{next(_channels)}"
    chain = MitMotorChain([j.id for j in profile.joints], profile.bus.actuator, channel).start()
    bus = MitJointBus(profile, [channel], interface="virtual")
    bus.open()
    clock = MonotonicClock()
    safety = Safety(profile)
    gait = Isolated("tripod", Tripod(None, profile))
    controller = Controller(
        profile,
        bus,
        safety,
        clock.now,
        gait,
        estimator=StateEstimator(profile, EstimatorConfig()),
        feed_forward=True,
    )
    n = int(profile.rate_hz * seconds)
    loop = ControlLoop(profile.rate_hz, clock, controller.tick)
    loop.timing = TimingWindow(size=n)
    stop = threading.Event()
    command = MotionCommand(vx=0.1, session=SESSION)

    def operator() -> None:
        """The teleop client: session, heartbeats and the walk command at 10 Hz."""
        safety.claim(SESSION, "bench", clock.now())
        while not stop.wait(0.1):
            controller.on_heartbeat(Heartbeat(session=SESSION))
            controller.on_motion(command)
            if safety.mode == Mode.HOLD:
                safety.request(Mode.ACTIVE, clock.now(), SESSION)

    safety.request(Mode.STAND, clock.now())
    feeder = threading.Thread(target=operator, daemon=True)
    feeder.start()
    thread = threading.Thread(target=loop.run, kwargs={"max_ticks": n})
    thread.start()
    thread.join()
    stop.set()
    feeder.join()
    bus.close()
    chain.stop()
    mode = safety.mode
    if mode != Mode.ACTIVE:
        raise RuntimeError(f"the loop ended in {mode.value}, not walking: {safety.reason}")
    timing = loop.timing
    count = min(n, timing.count)
    return timing.lateness[:count].copy(), timing.compute[:count].copy(), timing.overruns


def report(seconds: float) -> dict:
    """Run the C loop and the torque-leg loop, print the table, return the figures (µs)."""
    with tempfile.TemporaryDirectory() as tmp:
        c = c_loop(1000.0, seconds, Path(tmp))
    late, compute, overruns = torque_loop(seconds)
    lp, cp = pct(late), pct(compute)
    print(f"## 1 kHz loop through the torque-leg driver ({seconds:g} s each; times in µs)")
    print("| loop | lateness p50 | p99 | p99.9 | compute p50 | compute p99 | p99 ratio to C |")
    print("|---|---|---|---|---|---|---|")
    ratio = float("nan")
    if c is None:
        print("| C clock_nanosleep | skipped: no C compiler | | | | | |")
    else:
        c_p = pct(c)
        ratio = lp[1] / c_p[1]
        print(f"| C clock_nanosleep | {c_p[0]:.0f} | {c_p[1]:.0f} | {c_p[2]:.0f} | – | – | 1.00 |")
    print(
        f"| climbd Qingzhui tick, MitJointBus (virtual CAN) | {lp[0]:.0f} | {lp[1]:.0f} | "
        f"{lp[2]:.0f} | {cp[0]:.0f} | {cp[1]:.0f} | {ratio:.2f} |"
    )
    verdict = "met" if ratio <= 1.5 else "not met"
    print(f"overruns {overruns} of {len(late)} ticks; goal p99 ratio <= 1.5: {verdict}\n")
    return {"lateness_us": lp, "compute_us": cp, "ratio_p99_to_c": ratio, "overruns": overruns}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    report(parser.parse_args().seconds)


if __name__ == "__main__":
    main()
