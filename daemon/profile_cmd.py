"""``climbd profile check FILE``: validate a robot profile and say what is wrong, where."""

from __future__ import annotations

import argparse
import sys

from daemon import profile as profiles


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=["check"], help="what to do with the profile")
    parser.add_argument("file", nargs="+", help="robots/*.toml profile file(s)")


def main(args: argparse.Namespace) -> int:
    status = 0
    for path in args.file:
        try:
            p = profiles.load(path)
        except profiles.ProfileError as e:
            print(f"error: {e}", file=sys.stderr)
            status = 1
            continue
        print(
            f"{path}: ok — {p.name} ({p.model}), {len(p.legs)} legs, {len(p.joints)} joints, "
            f"{p.rate_hz:g} Hz, bus {p.bus.kind}, e-stop {p.safety.estop_policy.value}"
        )
    return status
