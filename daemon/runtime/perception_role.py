"""The perception role: camera → perception plugins → features on Zenoh, in its own OS process.

A capture thread keeps only the newest depth frame (newest wins, drops counted); a worker thread
pairs it with the body pose at the frame's stamp (from the history of the control role's
BodyState; a frame outside it is refused with a counted reason), runs the profile's perception
plugins on it, each isolated (one that raises is marked failed and skipped, the role goes on),
and publishes their features. The asyncio main thread owns the bus: BodyState into the pose
history, Health (plugin status, dropped and refused frames) at 2 Hz, the ``perception``
liveliness token, signals.
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
from collections.abc import Callable, Sequence
from typing import Any

from climbd.daemon.algorithms.pose_history import PoseHistory, PoseRefused, Refusal
from climbd.daemon.contract import messages as m
from climbd.daemon.contract.hardware import Camera, DriverError
from climbd.daemon.contract.plugins import PerceptionPlugin, PluginError
from climbd.daemon.contract.profile import Profile
from climbd.daemon.runtime.capture import Capture
from climbd.daemon.runtime.control_role import StartupError, role_network
from climbd.daemon.runtime.loader import Isolated, instantiate, slowest

log = logging.getLogger("climbd.perception")

HEALTH_PERIOD = 0.5
"""Seconds between Health publications."""


Feed = tuple[type[m.Message], Callable[[Any], None]]
"""A subscription the camera needs (the twin's ``sim/depth`` into a software device)."""


def make_plugins(
    profile: Profile, names: list[str] | None, on_failure: Callable[[str, BaseException], None]
) -> list[Isolated[PerceptionPlugin]]:
    """The perception plugins to run, isolated: ``names`` or the profile's list; each must
    declare the feature types it publishes."""

    specs = {s.name: s for s in profile.plugins.perception}
    chosen = names or list(specs)
    if not chosen:
        raise RuntimeError(f"{profile.source}: plugins.perception: no perception plugin configured")
    out = []
    for name in chosen:
        overrides = specs[name].config if name in specs else {}
        where = f"{profile.source}: plugins.perception {name}"
        plugin = instantiate("climbd.perception", name, overrides, profile, where)
        if not plugin.publishes:
            raise PluginError(f"{where}: declares no feature types (publishes) to publish")
        out.append(Isolated(name, plugin, on_failure))
    return out


class PerceptionRole:
    """Wires camera, capture, plugins and Zenoh together for one run of the perception role."""

    def __init__(
        self,
        profile: Profile,
        args: argparse.Namespace,
        camera: Camera | None = None,
        feeds: Sequence[Feed] = (),
    ) -> None:
        """``camera`` is what the role reads (the CLI makes it); ``feeds`` are subscriptions it
        needs."""
        self.profile = profile
        self.args = args
        self.camera = camera
        self.feeds = feeds
        self.poses = PoseHistory()
        self._poses_lock = threading.Lock()
        self.refused: dict[str, int] = {}
        """Frames given no pose, by reason (``Refusal`` values)."""
        self.published = 0
        self.undeclared = 0
        self._stop = threading.Event()

    def _work(
        self,
        capture: Capture,
        plugins: list[Isolated[PerceptionPlugin]],
        publish: Callable[[m.Message], None],
    ) -> None:
        """Worker thread: newest frame → every healthy plugin → publish what they return, if it
        is of a type the plugin declares."""
        idle = False
        while not self._stop.is_set() and capture.running:
            frame = capture.latest(timeout=0.2)
            if frame is None:
                continue
            body = self._pose_at(frame.timestamp)
            if body is None:
                continue
            for iso in plugins:
                feature = iso.call(iso.plugin.process, frame, body)
                if feature is None:
                    continue
                if not isinstance(feature, iso.plugin.publishes):
                    if not self.undeclared:
                        log.error(
                            "plugin %s returned %s, which it does not declare (publishes %s): "
                            "dropped",
                            iso.name,
                            type(feature).__name__,
                            ", ".join(t.__name__ for t in iso.plugin.publishes),
                        )
                    self.undeclared += 1
                    continue
                feature.frame_position = list(body.position)
                feature.frame_orientation = list(body.orientation)
                publish(feature)
                self.published += 1
            if not idle and all(iso.failed for iso in plugins):
                idle = True
                log.error(
                    "every perception plugin has failed (%s): this role publishes no features "
                    "until it is restarted",
                    "; ".join(f"{iso.name} {iso.status}" for iso in plugins),
                )

    def on_body(self, body: m.BodyState) -> None:
        """A body state from the control role: into the pose history."""
        with self._poses_lock:
            restarts = self.poses.restarts
            self.poses.add(body)
            if self.poses.restarts != restarts:
                log.warning(
                    "body states went back to %.3f s: the control role restarted its clock; "
                    "pose history begins anew",
                    body.stamp,
                )

    def _pose_at(self, stamp: float) -> m.BodyState | None:
        """The body pose at a frame's stamp, or None (counted, the first of each reason and
        every hundredth logged) when the history has none."""
        try:
            with self._poses_lock:
                return self.poses.at(stamp)
        except PoseRefused as e:
            reason: Refusal = e.reason
            count = self.refused.get(reason.value, 0) + 1
            self.refused[reason.value] = count
            if count == 1 or count % 100 == 0:
                log.warning("frame refused (%s, %d so far): %s", reason.value, count, e)
            return None

    async def run(self) -> int:
        profile, args, camera = self.profile, self.args, self.camera
        if camera is None:
            raise StartupError(f"{profile.source}: the perception role was given no camera")
        aio = asyncio.get_running_loop()
        try:
            plugins = make_plugins(profile, args.plugin, lambda name, e: None)
        except (RuntimeError, ValueError) as e:  # PluginError: a setup to fix
            print(f"error: {e}", file=sys.stderr)
            return 2
        net = role_network(profile, "perception", args, aio)
        publish = net.put

        net.subscribe(m.BodyState, self.on_body)
        for message, callback in self.feeds:
            net.subscribe(message, callback)
        net.alive("perception")
        capture = Capture(camera, camera.config.name)
        try:
            capture.start()
        except DriverError as e:
            net.close()
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
                    **slowest(plugins),
                    decode_errors=net.decode_errors,
                    refused_frames=dict(self.refused),
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
            net.close()
        print(
            f"climbd: perception stopped; {self.published} features published, "
            f"{capture.dropped} frames dropped, "
            + ", ".join(f"{p.name} {p.status}" for p in plugins),
            flush=True,
        )
        return 0
