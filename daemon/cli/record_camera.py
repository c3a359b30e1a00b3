"""``climbd record-camera PROFILE OUT.bag``: record a profile camera with librealsense's recorder.

The recording holds the device's own frames, timestamps and intrinsics, so ``climbd perceive
PLUGIN OUT.bag --profile PROFILE`` reruns perception on exactly what the camera saw.
"""

from __future__ import annotations

import argparse
import sys

from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.hardware import DriverError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("profile", help="robot profile (robots/*.toml)")
    parser.add_argument("out", help="recording to write (.bag)")
    parser.add_argument("--camera", help="profile camera name (default: the first)")
    parser.add_argument("--serial", help="override the profile camera's serial number")
    stop = parser.add_mutually_exclusive_group()
    stop.add_argument("--seconds", type=float, default=10.0, help="how long to record (s)")
    stop.add_argument("--frames", type=int, help="how many frames to record")


def main(args: argparse.Namespace) -> int:
    import time

    import msgspec

    from climbd.drivers.realsense.camera import RealSenseCamera

    try:
        profile = profiles.load(args.profile)
        cameras = {c.name: c for c in profile.cameras}
        if not cameras:
            raise DriverError(f"{args.profile}: the profile has no [[cameras]]")
        name = args.camera or next(iter(cameras))
        if name not in cameras:
            raise DriverError(
                f"{args.profile}: no camera named {name!r} (found: {', '.join(cameras)})"
            )
        config = cameras[name]
        if args.serial:
            config = msgspec.structs.replace(config, serial=args.serial)
        camera = RealSenseCamera.from_profile(config, record_to=args.out)
        camera.open()
    except (profiles.ProfileError, DriverError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    count = 0
    end = time.monotonic() + args.seconds
    try:
        for _ in camera.frames():
            count += 1
            if (args.frames is not None and count >= args.frames) or (
                args.frames is None and time.monotonic() >= end
            ):
                break
    except KeyboardInterrupt:
        pass
    finally:
        camera.close()
    health = camera.health()
    print(
        f"{args.out}: {count} frames from camera {name!r}, {health.reconnects} reconnects, "
        f"{health.dropped} dropped by this reader (the recording keeps every device frame)"
    )
    return 0
