"""``climbd run``: a robot's control role, perception role, or both under a supervisor.

The asyncio main thread owns the Zenoh bus, signals and reporting; the ControlLoop runs in
its own thread so I/O on the asyncio side never delays a tick. SIGTERM/SIGINT bring the
robot to a safe pose under the profile's e-stop policy, then the process exits 0.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from collections.abc import Callable

from climbd.daemon.cli.sim_host import SimHost, feed, sim_camera
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import DepthImage, Message
from climbd.daemon.contract.plugins import PluginError
from climbd.daemon.contract.profile import Profile
from climbd.daemon.runtime.control_role import ControlRole, StartupError
from climbd.daemon.runtime.loader import check_driver, load_class
from climbd.daemon.runtime.perception_role import PerceptionRole
from climbd.daemon.runtime.supervisor import supervise
from climbd.drivers.fake import FloorCamera
from climbd.drivers.realsense.models import model
from climbd.drivers.sim.worlds import WorldError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--profile", required=True, help="robot profile (robots/*.toml)")
    parser.add_argument(
        "--driver",
        help="joint bus driver (entry point in climbd.drivers; default: profile bus.kind)",
    )
    parser.add_argument("--port", help="joint bus port, overriding the profile (e.g. a pty)")
    parser.add_argument("--duration", type=float, help="stop by itself after S seconds")
    parser.add_argument("--gait", help="gait plugin for ACTIVE (default: profile default_gait)")
    parser.add_argument("--no-stand", action="store_true", help="stay OFF instead of standing up")
    parser.add_argument(
        "--listen", action="append", help="Zenoh listen endpoint (repeatable; overrides profile)"
    )
    parser.add_argument(
        "--connect", action="append", help="Zenoh connect endpoint (repeatable; overrides profile)"
    )
    parser.add_argument("--quiet", action="store_true", help="no periodic loop statistics")
    parser.add_argument(
        "--sim", metavar="WORLD", help="run in the physics twin (a stock world name or file)"
    )
    parser.add_argument(
        "--stepped",
        action="store_true",
        help="with --sim: simulated time in lock-step (repeatable, faster or slower than real)",
    )
    parser.add_argument(
        "--activate", action="store_true", help="start the default behaviour once standing"
    )
    parser.add_argument(
        "--snapshot", default="climbd-sim.png", help="with --sim: top-view PNG written at the end"
    )
    parser.add_argument(
        "--role",
        choices=("control", "perception", "all"),
        default="control",
        help="control (joints, loop), perception (camera, plugins), or all as supervised "
        "processes (default: control)",
    )
    parser.add_argument(
        "--source",
        choices=("camera", "floor", "sim"),
        default="camera",
        help="perception input: the profile's camera, or a synthetic flat floor (tests, demos)",
    )
    parser.add_argument("--camera", help="perception: profile camera name (default: first)")
    parser.add_argument("--playback", help="perception: play a .bag recording instead")
    parser.add_argument(
        "--plugin", action="append", help="perception plugin (repeatable; default: profile's)"
    )


def main(args: argparse.Namespace) -> int:
    try:
        profile = profiles.load(args.profile)
        check_driver(profile)
    except (profiles.ProfileError, PluginError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    try:
        if args.role == "all":
            return asyncio.run(supervise(profile, args))
        if args.role == "perception":
            try:
                camera = make_camera(profile, args.source, args.camera, args.playback)
            except (RuntimeError, ValueError) as e:  # PluginError, DriverError: a setup to fix
                print(f"error: {e}", file=sys.stderr)
                return 2
            feeds = [(DepthImage, feed(camera, camera.config))] if args.source == "sim" else []
            return asyncio.run(PerceptionRole(profile, args, camera, feeds).run())
        twin = None
        if args.sim:

            def twin(publish: Callable[[Message], None]) -> SimHost:
                return start_twin(profile, args.sim, args.stepped, publish)

        return asyncio.run(ControlRole(profile, args, twin).run())
    except StartupError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1


def start_twin(
    profile: Profile, world: str, stepped: bool, publish: Callable[[Message], None]
) -> SimHost:
    """The twin of a ``--sim`` run, started; a bad world is a StartupError naming it."""
    try:
        sim = SimHost(profile, world, stepped, publish)
    except (WorldError, OSError, ValueError) as e:
        raise StartupError(f"--sim {world}: {e}") from None
    sim.start()
    return sim


def make_camera(profile: Profile, source: str, camera_name: str | None, playback: str | None):
    """The camera the perception role reads: the profile's (by driver entry point), the
    ``floor`` source, or the twin's depth over Zenoh (``sim``)."""
    cameras = {c.name: c for c in profile.cameras}
    if not cameras:
        raise RuntimeError(f"{profile.source}: cameras: the perception role needs a camera")
    name = camera_name or next(iter(cameras))
    if name not in cameras:
        raise RuntimeError(f"{profile.source}: cameras: no camera {name!r} ({', '.join(cameras)})")
    config = cameras[name]
    if source == "floor":
        intrinsics = model(config.model).intrinsics(config.width, config.height)
        return FloorCamera(config, intrinsics, profile.stand.body_height)
    if source == "sim":
        return sim_camera(profile, config)
    cls = load_class("climbd.drivers", config.kind)
    options = {"playback": playback} if playback else {}
    return cls.from_profile(config, **options)
