"""``climbd urdf --profile P [-o FILE]``: the robot's URDF, written from its profile.

Its links are the frames ``climbd view`` publishes (``body``, each joint's link, ``<leg>_foot``,
``camera_<name>``), so a URDF loaded in Foxglove or RViz moves with the view's transforms or
with any JointState (see daemon/runtime/urdf.py).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from climbd.daemon.contract import profile as profiles
from climbd.daemon.runtime.urdf import urdf


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--profile", required=True, help="profile file, or a stock robot's name (e.g. widowx)"
    )
    parser.add_argument("-o", "--output", help="URDF file to write (default: standard output)")


def load(name: str) -> profiles.Profile:
    """The profile at path ``name``, or the stock profile called ``name``."""
    stock = profiles.stock_profiles()
    if not Path(name).exists() and name in stock:
        return profiles.load(stock[name])
    return profiles.load(name)


def main(args: argparse.Namespace) -> int:
    try:
        text = urdf(load(args.profile))
    except (profiles.ProfileError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.output is None:
        sys.stdout.write(text)
        return 0
    try:
        Path(args.output).write_text(text)
    except OSError as e:
        print(f"error: cannot write {args.output}: {e}", file=sys.stderr)
        return 2
    print(f"wrote {args.output}", file=sys.stderr)
    return 0
