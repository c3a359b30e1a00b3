"""``climbd profile check FILE``: validate a robot profile and say what is wrong, where."""

from __future__ import annotations

import argparse
import sys

from climbd.daemon.algorithms.world import world_config
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.plugins import PluginError
from climbd.daemon.runtime.access import AccessError, check_network
from climbd.daemon.runtime.loader import check_driver, load_class, make_config


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=["check"], help="what to do with the profile")
    parser.add_argument("file", nargs="+", help="robots/*.toml profile file(s)")


def check_plugins(profile: profiles.Profile) -> None:
    """Every plugin the profile names exists and takes its config, as the daemon checks at start."""

    groups = (("perception", profile.plugins.perception), ("gaits", profile.plugins.gaits))
    for group, specs in groups:
        for i, spec in enumerate(specs):
            where = f"{profile.source}: $.plugins.{group}[{i}]"
            try:
                cls = load_class(f"climbd.{group}", spec.name)
            except PluginError as e:
                raise PluginError(f"{where}.name: {e}") from None
            make_config(cls, spec.config, f"{where}.config")


def main(args: argparse.Namespace) -> int:
    """Check each file, reporting each (an unreadable one too) and going on; 1 if any failed."""
    failed = 0
    for path in args.file:
        try:
            p = profiles.load(path)
            check_driver(p)
            check_plugins(p)
            world_config(p)
            check_network(p)
        except (profiles.ProfileError, PluginError, AccessError) as e:
            print(f"error: {e}", file=sys.stderr)
            failed += 1
            continue
        print(
            f"{path}: ok — {p.name} ({p.model}), {len(p.legs)} legs, {len(p.joints)} joints, "
            f"{p.rate_hz:g} Hz, bus {p.bus.kind}, e-stop {p.safety.estop_policy.value}"
        )
    if failed and len(args.file) > 1:
        print(f"error: {failed} of {len(args.file)} profiles failed", file=sys.stderr)
    return 1 if failed else 0
