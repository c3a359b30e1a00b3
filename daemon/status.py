"""``climbd status``: the live mode, loop rate, overruns and joint health of a robot, over Zenoh."""

from __future__ import annotations

import argparse
import sys
import threading


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", required=True, help="robot name (profile name)")
    parser.add_argument(
        "--connect", action="append", default=[], help="Zenoh endpoint of the robot (repeatable)"
    )
    parser.add_argument("--timeout", type=float, default=3.0, help="seconds to wait for health")
    parser.add_argument("--json", action="store_true", help="print the Health message as JSON")


def format_health(health) -> str:
    """A short human-readable view of one Health message."""
    s = health.loop
    lines = [
        f"{health.role}: mode {health.mode.value}; loop {s.rate_hz:g} Hz, {s.ticks} ticks, "
        f"lateness p50 {s.lateness_p50 * 1e6:.0f} µs p99 {s.lateness_p99 * 1e6:.0f} µs, "
        f"overruns {s.overruns}; refused commands {health.refused_commands}, "
        f"decode errors {health.decode_errors}"
    ]
    for j in health.joints:
        flags = ",".join(
            j.errors + (["LOST"] if j.lost else []) + (["derated"] if j.derated else [])
        )
        lines.append(f"  {j.name:<14} {j.temperature:5.1f} °C {j.voltage:5.1f} V {flags}")
    lines += [f"  plugin {name}: {status}" for name, status in health.plugins.items()]
    return "\n".join(lines)


def main(args: argparse.Namespace) -> int:
    import msgspec

    from daemon.bus import Bus, Endpoints, zenoh_config
    from daemon.messages import Health

    bus = Bus(args.robot, zenoh_config(None, "status", Endpoints([], args.connect)))
    got: list[Health] = []
    arrived = threading.Event()

    def on_health(h: Health) -> None:
        got.append(h)
        arrived.set()

    try:
        bus.subscribe(Health, on_health)
        if not arrived.wait(args.timeout):
            print(f"no health from robot {args.robot!r} within {args.timeout:g} s", file=sys.stderr)
            return 1
        health = got[-1]
        print(msgspec.json.encode(health).decode() if args.json else format_health(health))
        return 0
    finally:
        bus.close()
