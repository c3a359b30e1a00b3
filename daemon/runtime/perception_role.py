"""The perception role: camera → perception plugins → features on Zenoh, in its own OS process.

A capture thread keeps only the newest depth frame (newest wins, drops counted); a worker thread
pairs it with the body pose at the frame's stamp (from the history of the control role's
BodyState; a frame outside it is refused with a counted reason), drops the pixels that see the
robot's own legs at the joint reading nearest that stamp (``algorithms.self_filter``, when the
profile's ``[world] self_filter`` sets a radius), runs the profile's perception plugins on it
and publishes their features, then folds the frame and the features into the world
model (``algorithms.world``: terrain, holds, joists in the odometry frame; a frame it does not
fuse, such as one whose ground is not level, is counted by reason beside the pose refusals) and
publishes its maps every ``publish_period``, refused frames or not, and a decimated copy of the
frame for viewers (``DepthPreview``) every ``preview_period``, posed or not. Each plugin, and
the world model, is kept going by loader.Restarting: an error loses that frame's result for it
(counted), one failing frame after frame is restarted with back-off, and one that cannot be kept
going ends the role with exit status 1 so that its supervisor (or systemd) restarts it. The asyncio
main thread owns the bus: BodyState into the pose history, JointState into the joint history
(self filter only), Health (plugin status and errors,
dropped and refused frames) at 2 Hz, the ``perception`` liveliness token, signals.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import functools
import logging
import math
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.algorithms.pose_history import PoseHistory, PoseRefused, Refusal
from climbd.daemon.algorithms.self_filter import NO_JOINTS, JointHistory, SelfFilter
from climbd.daemon.algorithms.world import Unfusable, Unfused, WorldModel, world_config
from climbd.daemon.contract import messages as m
from climbd.daemon.contract.hardware import Camera, DepthFrame, DriverError
from climbd.daemon.contract.plugins import PerceptionPlugin, PluginError
from climbd.daemon.contract.profile import Profile
from climbd.daemon.runtime.capture import Capture
from climbd.daemon.runtime.control_role import StartupError, role_network
from climbd.daemon.runtime.counting import Tally
from climbd.daemon.runtime.loader import (
    Isolated,
    Restarting,
    RestartPolicy,
    instantiate,
    slowest,
)

log = logging.getLogger("climbd.perception")

HEALTH_PERIOD = 0.5
"""Seconds between Health publications."""

RESTART_POLICY = RestartPolicy()
"""A plugin failing 5 frames in a row is restarted, skipped 1 s, 2 s, then 4 s after each
restart in a row; one failing right after its third restart ends the role."""

GAVE_UP = 1
"""Exit status when a plugin cannot be kept going: the supervisor or systemd restarts the role
(2, a setup to fix, would stop the supervisor)."""


def preview_stride(width: int, height: int, max_points: int) -> int:
    """The smallest integer stride at which every stride-th pixel of every stride-th row of a
    ``width`` × ``height`` image is at most ``max_points`` pixels."""
    step = max(1, math.ceil(math.sqrt(width * height / max(1, max_points))))
    while math.ceil(width / step) * math.ceil(height / step) > max_points:
        step += 1
    return step


def depth_preview(frame: DepthFrame, camera: str, max_points: int) -> m.DepthPreview | None:
    """``frame`` decimated by an integer stride (``preview_stride``, keeping its aspect) to at
    most ``max_points`` pixels, with the decimated image's intrinsics, for a viewer; None for a
    frame that is not raw uint16 depth of its intrinsics' size or whose depth scale or
    intrinsics are not usable (the world model counts those). Copies a few thousand pixels:
    cheap enough for the worker thread on every preview."""
    k = frame.intrinsics
    depth = frame.depth
    if not isinstance(depth, np.ndarray) or depth.dtype != np.uint16 or depth.ndim != 2:
        return None
    if depth.shape != (k.height, k.width) or k.width < 1 or k.height < 1:
        return None
    scale = float(frame.depth_scale)
    if not (math.isfinite(scale) and scale > 0):
        return None
    if not all(math.isfinite(v) for v in (k.fx, k.fy, k.ppx, k.ppy)) or k.fx <= 0 or k.fy <= 0:
        return None
    step = preview_stride(k.width, k.height, max_points)
    small = depth[::step, ::step]
    return m.DepthPreview(
        stamp=time.monotonic(),
        camera=camera,
        frame_stamp=float(frame.timestamp),
        width=small.shape[1],
        height=small.shape[0],
        stride=step,
        depth_scale=scale,
        fx=k.fx / step,
        fy=k.fy / step,
        cx=k.ppx / step,
        cy=k.ppy / step,
        depth=small.astype("<u2").tobytes(),
    )


Feed = tuple[type[m.Message], Callable[[Any], None]]
"""A subscription the camera needs (the twin's ``sim/depth`` into a software device)."""


def make_plugins(
    profile: Profile,
    names: list[str] | None,
    on_failure: Callable[[str, BaseException], None],
    policy: RestartPolicy = RESTART_POLICY,
) -> list[Restarting[PerceptionPlugin]]:
    """The perception plugins to run, each kept going under ``policy``: ``names`` or the
    profile's list; each must declare the feature types it publishes. ``on_failure`` hears of a
    plugin given up."""

    specs = {s.name: s for s in profile.plugins.perception}
    chosen = names or list(specs)
    if not chosen:
        raise RuntimeError(f"{profile.source}: plugins.perception: no perception plugin configured")
    out = []
    for name in chosen:
        overrides = specs[name].config if name in specs else {}
        build = functools.partial(start_plugin, profile, name, overrides)
        out.append(Restarting(name, build, on_failure, policy))
    return out


def start_plugin(profile: Profile, name: str, overrides: dict[str, Any]) -> PerceptionPlugin:
    """A new instance of perception plugin ``name`` configured from the profile: at start and
    at each restart."""
    where = f"{profile.source}: plugins.perception {name}"
    plugin = instantiate("climbd.perception", name, overrides, profile, where)
    if not plugin.publishes:
        raise PluginError(f"{where}: declares no feature types (publishes) to publish")
    return plugin


class PerceptionRole:
    """Wires camera, capture, plugins and Zenoh together for one run of the perception role."""

    def __init__(
        self,
        profile: Profile,
        args: argparse.Namespace,
        camera: Camera | None = None,
        feeds: Sequence[Feed] = (),
        policy: RestartPolicy = RESTART_POLICY,
    ) -> None:
        """``camera`` is what the role reads (the CLI makes it); ``feeds`` are subscriptions it
        needs; ``policy`` says when a failing plugin is restarted or given up."""
        self.profile = profile
        self.args = args
        self.camera = camera
        self.feeds = feeds
        self.policy = policy
        self.poses = PoseHistory()
        self._poses_lock = threading.Lock()
        self.refused: dict[str, int] = {}
        """Frames given no pose (``Refusal`` values) or not fused into the world model
        (``Unfusable`` values), by reason."""
        self.published = 0
        self.undeclared = 0
        self.failure = ""
        """Why the role must end: a plugin given up ("" while all are kept going)."""
        config = world_config(profile)
        self.world = Restarting("world", lambda: WorldModel(config), self.plugin_failed, policy)
        self._next_map = -math.inf
        self._next_preview = -math.inf
        self.preview = (config.preview_period, config.preview_points)
        """Seconds between depth previews (0: none) and their most pixels (``[world]``)."""
        self.self_filter = (
            SelfFilter(Kinematics(profile), config.self_filter.radius)
            if config.self_filter.radius > 0
            else None
        )
        self.joint_age = config.self_filter.max_age
        self.joints = JointHistory()
        self._joints_lock = threading.Lock()
        self.self_pixels = 0
        """Depth pixels the self filter took for the robot's legs, over all frames."""
        self._stop = threading.Event()

    def _work(
        self,
        capture: Capture,
        plugins: Sequence[Isolated[PerceptionPlugin]],
        publish: Callable[[m.Message], None],
    ) -> None:
        """Worker thread: newest frame → every plugin not skipped → publish what they return, if
        it is of a type the plugin declares; until stopped, the camera stops, or a plugin is
        given up."""
        while not self._stop.is_set() and capture.running and not self.failure:
            frame = capture.latest(timeout=0.2)
            if frame is not None:
                self.perceive(frame, plugins, publish)
                self._publish_preview(frame, publish)

    def _publish_preview(self, frame: DepthFrame, publish: Callable[[m.Message], None]) -> None:
        """Publish the frame decimated for viewers (``DepthPreview``) if a preview period has
        passed since the last, on frame stamps as the maps; after the frame's features and
        maps, and whether or not it had a pose (the preview is in the camera's own frame)."""
        period, points = self.preview
        stamp = frame.timestamp
        if not period > 0 or not (
            stamp >= self._next_preview or stamp < self._next_preview - 2 * period
        ):
            return
        self._next_preview = stamp + period
        preview = depth_preview(frame, self.camera_name, points)
        if preview is not None:
            publish(preview)

    def perceive(
        self,
        frame: DepthFrame,
        plugins: Sequence[Isolated[PerceptionPlugin]],
        publish: Callable[[m.Message], None],
    ) -> None:
        """One frame: the pose at its stamp, the legs' pixels dropped (when the profile sets a
        self filter), every plugin not skipped, their features published (those of a type the
        plugin declares), then the world model (``climbd rebuild`` runs the same on a
        recording)."""
        body = self._pose_at(frame.timestamp)
        view = frame if body is None or self.self_filter is None else self._without_legs(frame)
        if body is None or view is None:
            self._publish_maps(frame.timestamp, publish)
            return
        features = []
        for iso in plugins:
            result = iso.call(iso.plugin.process, view, body)
            for feature in result if isinstance(result, tuple) else (result,):
                if feature is not None and self._declared(iso, feature):
                    feature.frame_position = list(body.position)
                    feature.frame_orientation = list(body.orientation)
                    publish(feature)
                    self.published += 1
                    features.append(feature)
        self._map(view, body, features, publish)

    def _declared(self, iso: Isolated[PerceptionPlugin], feature: m.Message) -> bool:
        """``feature`` is of a type its plugin declares; else it is counted and dropped (the
        first one logged)."""
        if isinstance(feature, iso.plugin.publishes):
            return True
        if not self.undeclared:
            log.error(
                "plugin %s returned %s, which it does not declare (publishes %s): dropped",
                iso.name,
                type(feature).__name__,
                ", ".join(t.__name__ for t in iso.plugin.publishes),
            )
        self.undeclared += 1
        return False

    def _map(
        self,
        frame: DepthFrame,
        body: m.BodyState,
        features: list[m.Feature],
        publish: Callable[[m.Message], None],
    ) -> None:
        """Fold a frame and its features into the world model (after they are published, so a
        lock-stepped twin never waits for the maps) and publish the maps when due. The features
        of a frame the world model did not fuse stay out of its maps too."""
        world = self.world
        unfused = world.call(world.plugin.frame, frame, body)
        if unfused is None:
            for feature in features:
                world.call(world.plugin.feature, feature)
        else:
            self._unfused(unfused)
        self._publish_maps(frame.timestamp, publish)

    def _publish_maps(self, stamp: float, publish: Callable[[m.Message], None]) -> None:
        """Publish the maps if a publish period has passed since the last time, on frame
        stamps; a stamp more than two periods before it (after a stamp from the future, or a
        restarted clock) publishes too and restarts the count; a NaN stamp never does."""
        world = self.world
        period = world.plugin.config.publish_period
        if not (stamp >= self._next_map or stamp < self._next_map - 2 * period):
            return
        self._next_map = stamp + period
        for message in world.call(world.plugin.messages, time.monotonic()) or ():
            publish(message)

    def _unfused(self, unfused: Unfused) -> None:
        """Count a frame the world model left out by its reason; warn of a tilted ground once
        it has lasted ``ground.frames`` frames in a row and every hundredth frame after, of
        the other reasons on the first and every hundredth."""
        reason = unfused.reason.value
        count = self.refused.get(reason, 0) + 1
        self.refused[reason] = count
        if unfused.reason is Unfusable.GROUND_NOT_LEVEL:
            streak, first = unfused.streak, self.world.plugin.config.ground.frames
            if streak == first or (streak > first and streak % 100 == 0):
                log.warning(
                    "camera %s: %s, %d frames in a row: is its mount in the profile right? "
                    "Frames not fused, the maps keep their last good state (%s: %d so far)",
                    self.camera_name,
                    unfused.detail,
                    streak,
                    reason,
                    count,
                )
        elif count == 1 or count % 100 == 0:
            log.warning(
                "camera %s: frame not fused (%s, %d so far): %s",
                self.camera_name,
                reason,
                count,
                unfused.detail,
            )

    @property
    def camera_name(self) -> str:
        """The camera the role reads, or the profile's cameras (``climbd rebuild`` has none)."""
        if self.camera is not None:
            return self.camera.config.name
        return ", ".join(c.name for c in self.profile.cameras) or "?"

    def plugin_failed(self, name: str, error: BaseException) -> None:
        """A plugin was given up (Restarting's ``on_failure``, on the worker thread): the role
        ends, its features would silently stop otherwise."""
        self.failure = (
            f"perception plugin {name} cannot be kept going ({type(error).__name__}: {error}); "
            "the role exits to be restarted"
        )

    def health(self, plugins: Sequence[Isolated[PerceptionPlugin]], undecodable: Tally) -> m.Health:
        """The role's Health but for the camera's part (``Capture.report`` adds it): each
        plugin's status, errors and slowest call, the bus's decode errors (by topic), refused
        frames."""
        return m.Health(
            stamp=time.monotonic(),
            role="perception",
            plugins={p.name: p.status for p in plugins},
            plugin_errors={p.name: p.failures for p in plugins},
            **slowest(plugins),
            decode_errors=undecodable.total,
            decode_errors_by=undecodable.counts(),
            refused_frames=dict(self.refused),
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

    def on_joints(self, joints: m.JointState) -> None:
        """Measured joints from the control role: into the joint history (the self filter)."""
        with self._joints_lock:
            self.joints.add(joints.stamp, np.asarray(joints.position, float))

    def _without_legs(self, frame: DepthFrame) -> DepthFrame | None:
        """``frame`` with the pixels that see the legs zeroed at the joints nearest its stamp,
        or None (counted as ``no_joints``, the first and every hundredth logged) when no
        reading is within ``max_age`` of it."""
        with self._joints_lock:
            q = self.joints.at(frame.timestamp, self.joint_age)
        if q is None:
            self._refuse(
                NO_JOINTS,
                f"no joint reading within {self.joint_age:.3f} s of {frame.timestamp:.3f} s, "
                "so where the legs are in it is not known",
            )
            return None
        frame, pixels = self.self_filter.apply(frame, q)
        self.self_pixels += pixels
        return frame

    def _pose_at(self, stamp: float) -> m.BodyState | None:
        """The body pose at a frame's stamp, or None (counted, the first of each reason and
        every hundredth logged) when the history has none."""
        try:
            with self._poses_lock:
                return self.poses.at(stamp)
        except PoseRefused as e:
            reason: Refusal = e.reason
            self._refuse(reason.value, str(e))
            return None

    def _refuse(self, reason: str, detail: str) -> None:
        """Count a frame refused for ``reason``; log the first of each reason and every
        hundredth."""
        count = self.refused.get(reason, 0) + 1
        self.refused[reason] = count
        if count == 1 or count % 100 == 0:
            log.warning("frame refused (%s, %d so far): %s", reason, count, detail)

    async def run(self) -> int:
        profile, args, camera = self.profile, self.args, self.camera
        if camera is None:
            raise StartupError(f"{profile.source}: the perception role was given no camera")
        aio = asyncio.get_running_loop()
        try:
            plugins = make_plugins(profile, args.plugin, self.plugin_failed, self.policy)
        except (RuntimeError, ValueError) as e:  # PluginError: a setup to fix
            print(f"error: {e}", file=sys.stderr)
            return 2
        net = role_network(profile, "perception", args, aio)
        publish = net.put

        net.subscribe(m.BodyState, self.on_body)
        if self.self_filter is not None:
            net.subscribe(m.JointState, self.on_joints)
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
                health = self.health([*plugins, self.world], net.undecodable)
                publish(capture.report(health))
                if self.failure:
                    break
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
        if self.failure:
            print(f"error: {self.failure}", file=sys.stderr)
            return GAVE_UP
        return 0
