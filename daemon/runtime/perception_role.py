"""The perception role: camera → perception plugins → features on Zenoh, in its own OS process.

A capture thread keeps only the newest depth frame (newest wins, drops counted); a worker thread
runs the profile's perception plugins on it, each isolated (one that raises is marked failed and
skipped, the role goes on), and publishes their features. The asyncio main thread owns the bus:
the latest BodyState from the control role, Health (plugin status, dropped frames) at 2 Hz, the
``perception`` liveliness token, signals.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import math
import signal
import sys
import threading
import time
from collections.abc import Iterator

import numpy as np

from climbd.daemon.contract.hardware import DepthFrame, Intrinsics, mount_extrinsics

log = logging.getLogger("climbd.perception")

HEALTH_PERIOD = 0.5
"""Seconds between Health publications."""


class FloorCamera:
    """A test source: the profile camera looking at flat ground ``height`` m below the body.

    Depth is exact ray-plane intersection from the mount's pose and nominal intrinsics, paced at
    the camera's frame rate with monotonic timestamps: the perception path runs as with a camera.
    """

    def __init__(self, camera, intrinsics: Intrinsics, height: float, depth_scale: float = 1e-3):
        self.config = camera
        self.intrinsics = intrinsics
        self.extrinsics = mount_extrinsics(camera)
        self.depth_scale = depth_scale
        self.period = 1.0 / camera.fps
        self.depth = self._render(height)
        self._open = threading.Event()

    def _render(self, height: float) -> np.ndarray:
        k = self.intrinsics
        u, v = np.meshgrid(np.arange(k.width), np.arange(k.height))
        rays = np.stack([(u - k.ppx) / k.fx, (v - k.ppy) / k.fy, np.ones(u.shape)], axis=-1)
        rot, origin = self.extrinsics[:3, :3], self.extrinsics[:3, 3]
        down = rays @ rot[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            z = (-height - origin[2]) / down
        valid = (down < 0) & (z > self.config.min_range) & (z < self.config.max_range)
        return np.where(valid, np.round(z / self.depth_scale), 0).astype(np.uint16)

    def open(self) -> None:
        self._open.set()

    def frames(self) -> Iterator[DepthFrame]:
        n = 0
        next_at = time.monotonic()
        while self._open.is_set():
            time.sleep(max(0.0, next_at - time.monotonic()))
            next_at += self.period
            yield DepthFrame(
                self.depth, self.depth_scale, self.intrinsics, self.extrinsics, time.monotonic(), n
            )
            n += 1

    def close(self) -> None:
        self._open.clear()


def make_camera(profile, source: str, camera_name: str | None, playback: str | None):
    """The camera the role reads: the profile's (by driver entry point), the ``floor`` source, or
    the twin's depth over Zenoh (``sim``)."""
    from climbd.daemon.runtime.loader import load_class
    from climbd.drivers.realsense.models import model

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
        from climbd.daemon.cli.sim_host import sim_camera

        return sim_camera(profile, config)
    cls = load_class("climbd.drivers", config.kind)
    options = {"playback": playback} if playback else {}
    return cls.from_profile(config, **options)


def make_plugins(profile, names: list[str] | None, on_failure):
    """The perception plugins to run, isolated: ``names`` or the profile's list."""
    from climbd.daemon.runtime.loader import Isolated, instantiate

    specs = {s.name: s for s in profile.plugins.perception}
    chosen = names or list(specs)
    if not chosen:
        raise RuntimeError(f"{profile.source}: plugins.perception: no perception plugin configured")
    out = []
    for name in chosen:
        overrides = specs[name].config if name in specs else {}
        where = f"{profile.source}: plugins.perception {name}"
        plugin = instantiate("climbd.perception", name, overrides, profile, where)
        out.append(Isolated(name, plugin, on_failure))
    return out


class PerceptionRole:
    """Wires camera, capture, plugins and Zenoh together for one run of the perception role."""

    def __init__(self, profile, args: argparse.Namespace) -> None:
        self.profile = profile
        self.args = args
        self.body = None
        self.published = 0
        self._stop = threading.Event()

    def _work(self, capture, plugins, publish) -> None:
        """Worker thread: newest frame → every healthy plugin → publish what they return."""
        from climbd.daemon.contract.messages import BodyState

        idle = False
        while not self._stop.is_set() and capture.running:
            frame = capture.latest(timeout=0.2)
            if frame is None:
                continue
            body = self.body or BodyState(stamp=frame.timestamp)
            for iso in plugins:
                feature = iso.call("process", frame, body)
                if feature is not None:
                    publish(feature)
                    self.published += 1
            if not idle and all(iso.failed for iso in plugins):
                idle = True
                log.error(
                    "every perception plugin has failed (%s): this role publishes no features "
                    "until it is restarted",
                    "; ".join(f"{iso.name} {iso.status}" for iso in plugins),
                )

    async def run(self) -> int:
        from climbd.daemon.cli.run import StartupError
        from climbd.daemon.contract import messages as m
        from climbd.daemon.contract.hardware import DriverError
        from climbd.daemon.runtime.network import Bus, Endpoints, zenoh_config
        from climbd.drivers.realsense.capture import Capture

        profile, args = self.profile, self.args
        aio = asyncio.get_running_loop()
        try:
            camera = make_camera(profile, args.source, args.camera, args.playback)
            plugins = make_plugins(profile, args.plugin, lambda name, e: None)
        except (RuntimeError, ValueError) as e:  # PluginError, DriverError: a setup to fix
            print(f"error: {e}", file=sys.stderr)
            return 2
        endpoints = None
        if args.listen or args.connect:
            endpoints = Endpoints(args.listen or [], args.connect or [])
        try:
            bus = Bus(profile.name, zenoh_config(profile, "perception", endpoints), aio)
        except Exception as e:  # zenoh raises ZError for a bad endpoint or a port in use
            raise StartupError(f"zenoh: {e}") from None
        publish = bus.put

        def on_body(body: m.BodyState) -> None:
            self.body = body

        bus.subscribe(m.BodyState, on_body, latest_only=True)
        if args.source == "sim":
            from climbd.daemon.cli.sim_host import feed

            bus.subscribe(m.DepthImage, feed(camera, camera.config))
        bus.alive("perception")
        capture = Capture(camera, camera.config.name)
        try:
            capture.start()
        except DriverError as e:
            bus.close()
            raise StartupError(str(e)) from None
        worker = threading.Thread(
            target=self._work, args=(capture, plugins, publish), name="perception", daemon=True
        )
        worker.start()
        print(
            f"climbd: {profile.name} perception role, plugins {', '.join(p.name for p in plugins)}",
            flush=True,
        )
        stop = asyncio.Event()
        for sig in (signal.SIGTERM, signal.SIGINT):
            aio.add_signal_handler(sig, stop.set)
        end = aio.time() + args.duration if args.duration else math.inf
        try:
            while not stop.is_set() and aio.time() < end:
                health = m.Health(
                    stamp=time.monotonic(),
                    role="perception",
                    plugins={p.name: p.status for p in plugins},
                    decode_errors=bus.decode_errors,
                )
                publish(capture.report(health))
                if not capture.running and not self._stop.is_set():
                    log.error("camera stopped: %s", capture.error or "end of stream")
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(stop.wait(), HEALTH_PERIOD)
        finally:
            self._stop.set()
            capture.stop()
            await aio.run_in_executor(None, worker.join, 2.0)
            bus.close()
        print(
            f"climbd: perception stopped; {self.published} features published, "
            f"{capture.dropped} frames dropped, "
            + ", ".join(f"{p.name} {p.status}" for p in plugins),
            flush=True,
        )
        return 0
