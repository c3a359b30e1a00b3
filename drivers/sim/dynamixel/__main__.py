"""Run the emulated servo chain of a robot profile on a pty until interrupted."""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from climbd.daemon.contract.profile import ProfileError, load
from climbd.drivers.sim.dynamixel import DynamixelEmulator, ServoChain


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m climbd.drivers.sim.dynamixel", description=__doc__
    )
    parser.add_argument("--profile", required=True, help="robot profile (robots/*.toml)")
    parser.add_argument("--baud", type=int, default=None, help="bus baud rate (default: profile)")
    parser.add_argument(
        "--spin-us", type=float, default=0.0, help="busy-wait this long before each reply (µs)"
    )
    parser.add_argument("--return-delay-us", type=int, default=None, help="initial return delay")
    parser.add_argument(
        "--latency-ms",
        type=float,
        default=0.0,
        help="put a USB serial adapter with this latency timer (ms, e.g. 1 or 16) before the bus "
        "(default 0: no adapter)",
    )
    args = parser.parse_args(argv)
    try:
        chain = ServoChain.from_profile(load(args.profile), baud=args.baud)
    except (ProfileError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.return_delay_us is not None:
        for servo in chain.servos.values():
            servo.set("return_delay_time", args.return_delay_us // 2)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    with DynamixelEmulator(chain, spin=args.spin_us * 1e-6, latency_ms=args.latency_ms) as emu:
        print(emu.port, flush=True)
        done.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())
