"""``climbd perceive PLUGIN FILE``: run a perception plugin on a point cloud file or a recording.

Prints the plugin's feature message as one JSON line (field names and SI units as on the wire);
a recording (.bag) gives one line per frame, ``null`` where the plugin found nothing. A cloud
file is in the body frame (x forward, y left, z up, origin on the ground under the body centre)
unless ``--frame camera``, which applies the profile camera's mount.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.cloudio import CloudFileError, read_cloud
from climbd.daemon.contract.hardware import DriverError, mount_extrinsics
from climbd.daemon.contract.messages import BodyState
from climbd.daemon.contract.plugins import PluginError
from climbd.daemon.runtime.loader import instantiate


class PerceiveError(Exception):
    """A command-line problem: a missing profile, camera or mount."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("plugin", help="perception plugin (entry point in climbd.perception)")
    parser.add_argument("file", help="cloud file (.pcd, .ply, .npy of N×3 metres) or a .bag")
    parser.add_argument("--profile", help="robot profile: plugin config and camera mount")
    parser.add_argument(
        "--frame",
        choices=["body", "camera"],
        default="body",
        help="frame of the cloud file's points (camera = optical frame of the profile camera)",
    )
    parser.add_argument("--camera", help="profile camera name (default: the first)")


def main(args: argparse.Namespace) -> int:
    import msgspec

    errors = (profiles.ProfileError, PluginError, CloudFileError, DriverError, PerceiveError)

    try:
        profile = profiles.load(args.profile) if args.profile else None
        camera = _camera(profile, args.camera)
        overrides = {}
        if profile is not None:
            for spec in profile.plugins.perception:
                if spec.name == args.plugin:
                    overrides = spec.config
        where = f"{args.profile or 'command line'}: plugins.perception[{args.plugin}]"
        plugin = instantiate("climbd.perception", args.plugin, overrides, profile, where)
        encoder = msgspec.json.Encoder()
        path = Path(args.file)
        if path.suffix.lower() == ".bag":
            if camera is None:
                raise PerceiveError(f"{path}: a recording needs --profile for the camera mount")
            return _recording(plugin, path, camera, encoder)
        points = read_cloud(path)
        if args.frame == "camera":
            if camera is None:
                raise PerceiveError("--frame camera needs --profile for the camera mount")
            t = mount_extrinsics(camera)
            points = points @ t[:3, :3].T + t[:3, 3]
        result = plugin.process_cloud(points, BodyState(), 0.0)
        sys.stdout.write(encoder.encode(result).decode() + "\n")
        return 0
    except errors as e:
        print(f"error: {e}", file=sys.stderr)
        return 1


def _camera(profile, name: str | None):
    if profile is None:
        return None
    cameras = profile.cameras
    if name is None:
        if not cameras:
            raise PerceiveError(f"{profile.source}: the profile has no [[cameras]]")
        return cameras[0]
    for camera in cameras:
        if camera.name == name:
            return camera
    found = ", ".join(c.name for c in cameras) or "none"
    raise PerceiveError(f"{profile.source}: no camera named {name!r} (found: {found})")


def _recording(plugin, path: Path, camera, encoder) -> int:
    from climbd.drivers.realsense.camera import PlaybackSource, RealSenseCamera

    source = PlaybackSource(path, real_time=False)
    device = RealSenseCamera(camera, source, timeout=None)
    device.open()
    try:
        for frame in device.frames():
            result = plugin.process(frame, BodyState(stamp=frame.timestamp))
            sys.stdout.write(encoder.encode(result).decode() + "\n")
            sys.stdout.flush()
    finally:
        device.close()
    return 0
