"""Run the physics twin in its own process, in real time, until SIGTERM/SIGINT.

``python -m climbd.drivers.sim --profile robots/widowx.toml --world attic`` prints the port the
emulated bus answers on (a pty path, or a python-can virtual channel for torque legs) on the
first line of stdout, so a daemon in another process (another interpreter, no shared GIL)
opens it exactly as it opens hardware. On exit it prints the simulated and wall seconds.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from climbd.daemon.contract.profile import ProfileError, load
from climbd.drivers.sim.twin import Twin
from climbd.drivers.sim.worlds import WorldError


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m climbd.drivers.sim", description=__doc__)
    parser.add_argument("--profile", required=True, help="robot profile (robots/*.toml)")
    parser.add_argument("--world", default="attic", help="stock world name or world file")
    parser.add_argument("--no-cameras", action="store_true", help="do not render depth")
    args = parser.parse_args(argv)
    try:
        profile = load(args.profile)
        twin = Twin(profile, args.world)
    except (ProfileError, WorldError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if not args.no_cameras:
        twin.on_depth(lambda name, frame: None)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    wall0 = time.monotonic()
    with twin:
        print(twin.port, flush=True)
        done.wait()
        sim = twin.time
    print(f"simulated {sim:.3f} s in {time.monotonic() - wall0:.3f} s wall", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
