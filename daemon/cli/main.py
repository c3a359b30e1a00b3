"""The ``climbd`` command: one subcommand per module, each with ``add_arguments`` and ``main``.

Subcommand modules keep heavy imports (zenoh, pyrealsense2, mujoco) inside ``main`` so that
building the parser stays fast and a broken device library only breaks the command using it.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from climbd.daemon.runtime import logs

COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("climbd.daemon.cli.run", "run the daemon for a robot profile"),
    "status": (
        "climbd.daemon.cli.status",
        "print live mode, loop rate and joint health over Zenoh",
    ),
    "estop": ("climbd.daemon.cli.estop", "engage (or reset) the e-stop of a robot over Zenoh"),
    "teleop": (
        "climbd.daemon.cli.teleop",
        "drive or override a robot: keyboard UI or a timed script",
    ),
    "profile": ("climbd.daemon.cli.profile_cmd", "check a robot profile"),
    "schema": ("climbd.daemon.cli.schema_cmd", "write the JSON Schema of every message"),
    "certs": (
        "climbd.daemon.cli.certs",
        "generate a CA and per-role/operator certificates for mutual TLS",
    ),
    "perceive": (
        "climbd.daemon.cli.perceive",
        "run a perception plugin on a point cloud file or recording",
    ),
    "record-camera": ("climbd.daemon.cli.record_camera", "record a profile camera to a .bag file"),
    "install": ("climbd.daemon.cli.install", "write systemd units and udev rules for a profile"),
    "record": (
        "climbd.daemon.cli.record",
        "record a robot's topics to an MCAP file (JSON + JSON Schema)",
    ),
    "rebuild": (
        "climbd.daemon.cli.rebuild",
        "re-run perception on a recording and rebuild its maps, compared with the live ones",
    ),
    "replay": (
        "climbd.daemon.cli.replay",
        "republish an MCAP recording on the bus at real or chosen speed",
    ),
    "top": ("climbd.daemon.cli.top", "live terminal view of a robot or the fleet"),
    "urdf": ("climbd.daemon.cli.urdf", "write a robot's URDF from its profile"),
    "view": (
        "climbd.daemon.cli.view",
        "serve a robot live to Foxglove (WebSocket): its frames, links and maps in 3-D",
    ),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="climbd", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module)
        importlib.import_module(module).add_arguments(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logs.setup(args.verbose)
    return int(importlib.import_module(args._module).main(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
