"""``climbd status``: the live mode, loop rate, overruns and joint health of a robot, over Zenoh."""

from __future__ import annotations

import argparse
import sys
import threading

from climbd.daemon.cli.client import add_credential_arguments, open_client
from climbd.daemon.contract.messages import Health, ModeState, decode


def add_arguments(parser: argparse.ArgumentParser) -> None:
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument("--robot", help="robot name (profile name)")
    target.add_argument("--all", action="store_true", help="fleet view: every robot and role")
    parser.add_argument(
        "--connect", action="append", default=[], help="Zenoh endpoint of the robot (repeatable)"
    )
    parser.add_argument("--timeout", type=float, default=3.0, help="seconds to wait for health")
    parser.add_argument("--json", action="store_true", help="print the Health message as JSON")
    parser.add_argument(
        "--role", default="control", help="whose health: control (default) or perception"
    )
    add_credential_arguments(parser)


def fleet(net, timeout: float) -> dict[str, dict]:
    """Every robot on the network: its live roles (liveliness) and last mode (ModeState)."""
    import time

    import zenoh

    robots: dict[str, dict] = {}
    lock = threading.Lock()

    def on_mode(sample) -> None:
        robot = str(sample.key_expr).split("/")[1]
        try:
            state = decode(sample.payload.to_bytes(), ModeState)
        except Exception:  # another climbd version's payload: the robot is listed, mode unknown
            return
        with lock:
            robots.setdefault(robot, {"roles": []})["mode"] = state

    def on_alive(sample) -> None:
        _, robot, _, role = str(sample.key_expr).split("/")
        with lock:
            roles = robots.setdefault(robot, {"roles": []})["roles"]
            if sample.kind == zenoh.SampleKind.PUT and role not in roles:
                roles.append(role)
            elif sample.kind == zenoh.SampleKind.DELETE and role in roles:
                roles.remove(role)

    # A liveliness subscriber with history sees the tokens already declared and those whose
    # routes arrive while we listen; a one-shot query right after connecting can miss peers
    # that are one hop away.
    alive = net.session.liveliness().declare_subscriber("climbd/*/alive/*", on_alive, history=True)
    sub = net.session.declare_subscriber("climbd/*/" + ModeState.TOPIC, on_mode)
    try:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            time.sleep(0.05)
        end = time.monotonic() + 1.0  # ModeState comes at 2 Hz
        while time.monotonic() < end and any("mode" not in r for r in robots.values()):
            time.sleep(0.05)
    finally:
        sub.undeclare()
        alive.undeclare()
    return robots


def format_fleet(robots: dict[str, dict]) -> str:
    """One line per robot: name, live roles, mode and why."""
    lines = []
    for name in sorted(robots):
        r = robots[name]
        mode = r.get("mode")
        what = f"{mode.mode.value} ({mode.reason})" if mode is not None else "mode unknown"
        lines.append(f"{name:<16} roles {','.join(sorted(r['roles'])) or '-':<28} {what}")
    return "\n".join(lines)


def format_health(health) -> str:
    """A short human-readable view of one Health message."""
    s = health.loop
    lines = [
        f"{health.role}: mode {health.mode.value}; loop {s.rate_hz:g} Hz, {s.ticks} ticks, "
        f"lateness p50 {s.lateness_p50 * 1e6:.0f} µs p99 {s.lateness_p99 * 1e6:.0f} µs, "
        f"overruns {s.overruns}; refused commands {health.refused_commands}, "
        f"decode errors {health.decode_errors}"
    ]
    if (b := health.bus) is not None:
        by = ", ".join(f"{name} {count}" for name, count in b.missed_by.items())
        lines.append(
            f"  bus: {b.reads_per_tick:.1f} reads a tick ({b.reads_per_s:.0f}/s), goals "
            f"{b.writes_per_s:.0f}/s; oldest joint state p50 {b.oldest_age_p50 * 1e3:.0f} ms "
            f"p99 {b.oldest_age_p99 * 1e3:.0f} ms max {b.oldest_age_max * 1e3:.0f} ms "
            f"(bound {b.age_bound * 1e3:.0f} ms); {b.missed} replies missed"
            + (f" ({by})" if by else "")
        )
        if b.plan:
            lines.append(f"  bus plan: {b.plan}")
    for j in health.joints:
        flags = ",".join(
            j.errors + (["LOST"] if j.lost else []) + (["derated"] if j.derated else [])
        )
        lines.append(f"  {j.name:<14} {j.temperature:5.1f} °C {j.voltage:5.1f} V {flags}")
    lines += [f"  plugin {name}: {status}" for name, status in health.plugins.items()]
    return "\n".join(lines)


def main(args: argparse.Namespace) -> int:
    import msgspec

    net = open_client(args, args.robot or "*", "status")
    if net is None:
        return 2
    if args.all:
        try:
            robots = fleet(net, args.timeout)
        finally:
            net.close()
        if not robots:
            print(f"no climbd robot answered within {args.timeout:g} s", file=sys.stderr)
            return 1
        print(format_fleet(robots))
        return 0
    got: list[Health] = []
    arrived = threading.Event()

    def on_health(h: Health) -> None:
        if h.role == args.role:
            got.append(h)
            arrived.set()

    try:
        net.subscribe(Health, on_health)
        if not arrived.wait(args.timeout):
            print(f"no health from robot {args.robot!r} within {args.timeout:g} s", file=sys.stderr)
            return 1
        health = got[-1]
        print(msgspec.json.encode(health).decode() if args.json else format_health(health))
        return 0
    finally:
        net.close()
