"""``climbd view``: a robot's topics served live to Foxglove over its WebSocket protocol.

A process of its own (never in a role's interpreter): it subscribes to what the robot already
publishes over Zenoh (read-only, with the operator tools' credential options) and serves it
with the Foxglove SDK in Foxglove's well-known schemas (daemon/runtime/scene.py), so that the
3-D panel of Foxglove, connected to ``ws://HOST:PORT``, draws the robot without configuration:

    /tf          foxglove.FrameTransforms  odom → body → each leg's links → feet; body → cameras
    /robot       foxglove.SceneUpdate      links, feet, body and cameras, locked to their frames
    /joists /holds /stairs /truss          foxglove.SceneUpdate, the world model's maps (odom)
    /elevation   foxglove.Grid             perception's height map, placed in odom
    /mode /health                          the robot's ModeState and Health as JSON
    /loop        JSON (climbd.Loop)        the control role's loop statistics, flat, to plot
    /estop       JSON (climbd.EStopState)  whether an e-stop is latched, and by whom
    /plan        foxglove.SceneUpdate      while a gait steps: each foot's target (body frame;
                                           stance green, swing magenta) and a swinging foot's
                                           path from where it is to its target
    /grasp       foxglove.SceneUpdate      perception's graspable points, when it publishes them
    /depth       foxglove.PointCloud       each camera's depth in its optical frame, when the
                                           robot publishes depth (the perception role's
                                           state/depth preview, or the twin's sim/depth in a
                                           --sim run), at --cloud-rate of --cloud-points at most
    /truth/joists /truth/stairs /truth/holds /truth/truss
                 foxglove.SceneUpdate      the twin world's true maps, in translucent blue
                                           beside perception's: from the twin's sim/truth in a
                                           --sim run, or with --truth WORLD for a robot that
                                           publishes none (odom is the world frame in a --sim
                                           run)

Zenoh callbacks only keep the latest message of each kind; a publisher thread translates at
``--rate`` (transforms) or on arrival (maps, mode, health), so a 1 kHz joint stream costs the
view one translation per period. A slow WebSocket client loses its oldest messages past
``--backlog`` (the SDK drops them) rather than queueing without bound. The view says on
stderr, and to connected clients as a Foxglove status, when no robot is heard, when the robot
goes silent and when it is heard again; Zenoh reconnects to ``--connect`` by itself.
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
import time

import foxglove
import foxglove.messages as fg
from foxglove import channels as ch

from climbd.daemon.cli.client import add_credential_arguments, find_profile, open_client
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.hardware import Intrinsics
from climbd.daemon.contract.messages import DepthImage, DepthPreview, Health, Message
from climbd.daemon.runtime import scene
from climbd.drivers.realsense.models import model
from climbd.drivers.sim.truth import truth
from climbd.drivers.sim.worlds import WorldError
from climbd.drivers.sim.worlds import load as load_world

SUBSCRIBED = scene.INPUTS
"""What the view takes from the robot; all of it the robot publishes whether or not anyone
watches."""

TYPED_CHANNELS = {
    fg.FrameTransforms: ch.FrameTransformsChannel,
    fg.SceneUpdate: ch.SceneUpdateChannel,
    fg.Grid: ch.GridChannel,
    fg.PointCloud: ch.PointCloudChannel,
}
"""The SDK's channel of each Foxglove message a scene topic carries (``scene.TOPICS``)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", required=True, help="robot name (profile name)")
    parser.add_argument(
        "--connect", action="append", default=[], help="Zenoh endpoint of the robot (repeatable)"
    )
    parser.add_argument(
        "--profile",
        help="the robot's profile (default: the stock profile robots/<robot>.toml), for its "
        "kinematics and camera mounts",
    )
    parser.add_argument("--host", default="127.0.0.1", help="WebSocket address to serve on")
    parser.add_argument(
        "--port", type=int, default=8765, help="WebSocket port (0: any free port, printed)"
    )
    parser.add_argument("--rate", type=float, default=30.0, help="transforms per second sent")
    parser.add_argument(
        "--backlog",
        type=int,
        default=64,
        help="messages queued per WebSocket client; a slow client loses the oldest past it",
    )
    parser.add_argument(
        "--silent-after",
        type=float,
        default=3.0,
        help="seconds without a message after which the robot is reported silent",
    )
    parser.add_argument(
        "--cloud-rate",
        type=float,
        default=2.0,
        help="depth point clouds per second and camera (0: depth not subscribed to)",
    )
    parser.add_argument(
        "--cloud-points", type=int, default=20_000, help="most points of one depth point cloud"
    )
    parser.add_argument(
        "--truth",
        metavar="WORLD",
        help="the twin world the robot runs in: its true joists, stairs, holds and truss drawn "
        "beside perception's (/truth/...); not needed for climbd run --sim, whose twin "
        "publishes its truth (sim/truth), which then takes over",
    )
    add_credential_arguments(parser)


def camera_intrinsics(profile: profiles.Profile):
    """The nominal intrinsics of the profile's cameras by name and image size (the twin renders
    its depth with them), for ``scene.SceneStream``."""
    configs = {c.name: c for c in profile.cameras}

    def intrinsics(camera: str, width: int, height: int) -> Intrinsics | None:
        config = configs.get(camera)
        if config is None:
            return None
        try:
            return model(config.model).intrinsics(width, height)
        except (KeyError, ValueError):
            return None

    return intrinsics


class Latest:
    """The latest message of each kind (Health: of each role; depth: of each camera), filled on
    Zenoh's threads.

    ``put`` only stores under a lock: it never blocks on the viewer and never calls Zenoh."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._fresh: dict[object, Message] = {}
        self.heard = -float("inf")
        """time.monotonic() of the last message."""

    def put(self, msg: Message) -> None:
        if isinstance(msg, Health):
            kind = (Health, msg.role)
        elif isinstance(msg, (DepthImage, DepthPreview)):
            kind = (type(msg), msg.camera)
        else:
            kind = type(msg)
        now = time.monotonic()
        with self._lock:
            self._fresh[kind] = msg
            self.heard = now

    def take(self) -> dict[object, Message]:
        """What arrived since the last take, the latest of each kind."""
        with self._lock:
            fresh, self._fresh = self._fresh, {}
        return fresh


class Presence:
    """Whether the robot is heard: the lines the view says when that changes."""

    def __init__(self, robot: str, where: str, silent_after: float, started: float) -> None:
        self.robot = robot
        self.where = where
        self.silent_after = silent_after
        self.started = started
        self.state = "waiting"  # waiting → (heard ⇄ silent); "unheard" once waiting is reported

    def update(self, heard: float, now: float) -> str | None:
        """The message to report at ``now`` given the last message at ``heard``, or None."""
        recent = now - heard <= self.silent_after
        if recent and self.state != "heard":
            before, self.state = self.state, "heard"
            if before == "silent":
                return f"robot {self.robot!r} heard again"
            return f"robot {self.robot!r} heard"
        if recent:
            return None
        if self.state == "waiting" and now - self.started > self.silent_after:
            self.state = "unheard"
            return (
                f"no robot {self.robot!r} heard on {self.where} after {self.silent_after:g} s; "
                "still listening"
            )
        if self.state == "heard":
            self.state = "silent"
            return (
                f"robot {self.robot!r} silent for {self.silent_after:g} s; "
                "still listening, it will show again when it comes back"
            )
        return None


class Viewer:
    """The Foxglove channels of one robot in a foxglove Context (``scene.TOPICS``), and what
    goes on each (``scene.SceneStream``); an optional topic (``scene.OPTIONAL_TOPICS``: plan,
    graspable points, depth, truth) is advertised when its first message is drawn."""

    def __init__(
        self, robot_scene: scene.RobotScene, context: foxglove.Context, **stream_options
    ) -> None:
        self.scene = robot_scene
        self.context = context
        self.stream = scene.SceneStream(robot_scene, refused=_say, **stream_options)
        self.channels = {}
        for topic in scene.TOPICS:
            self.channels[topic] = self._channel(topic)

    def _channel(self, topic: str):
        kind = scene.TOPICS.get(topic) or scene.OPTIONAL_TOPICS[topic]
        if kind in TYPED_CHANNELS:
            return TYPED_CHANNELS[kind](topic, context=self.context)
        declared = scene.channel_schema(topic)
        schema = foxglove.Schema(name=declared.name, encoding=declared.encoding, data=declared.data)
        return foxglove.Channel(
            topic, schema=schema, message_encoding=declared.message_encoding, context=self.context
        )

    def publish(self, fresh: dict[object, Message], now_ns: int, now: float) -> None:
        """Translate and log what arrived; transforms whenever the body or joints moved, and
        the robot's geometry every scene.GEOMETRY_PERIOD."""
        for topic, out in self.stream.update(fresh.values(), now_ns, now):
            channel = self.channels.get(topic)
            if channel is None:
                channel = self.channels[topic] = self._channel(topic)
            channel.log(out, log_time=now_ns)


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def main(args: argparse.Namespace) -> int:
    try:
        robot_scene = scene.RobotScene(find_profile(args.robot, args.profile))
        world_truth = truth(load_world(args.truth)) if args.truth else []
    except (profiles.ProfileError, WorldError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.rate <= 0 or args.backlog < 1 or args.cloud_rate < 0 or args.cloud_points < 1:
        print(
            "error: --rate must be positive, --cloud-rate not negative, --backlog and "
            "--cloud-points at least 1",
            file=sys.stderr,
        )
        return 2
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):  # explicit: an inherited SIG_IGN would hang us
        signal.signal(sig, lambda *_: stop.set())

    context = foxglove.Context()
    clouds = args.cloud_rate > 0
    viewer = Viewer(
        robot_scene,
        context,
        clouds=clouds,
        intrinsics=camera_intrinsics(robot_scene.profile) if clouds else None,
        cloud_period=1.0 / args.cloud_rate if clouds else math.inf,
        cloud_points=args.cloud_points,
        truth=world_truth,
    )
    try:
        server = foxglove.start_server(
            name=f"climbd {args.robot}",
            host=args.host,
            port=args.port,
            context=context,
            message_backlog_size=args.backlog,
        )
    except Exception as e:  # the SDK raises its own error types for a taken port
        print(f"error: cannot serve on {args.host}:{args.port}: {e}", file=sys.stderr)
        return 2
    where = ", ".join(args.connect) or "no endpoint (give the robot's with --connect)"
    print(
        f"serving robot {args.robot!r} to Foxglove on ws://{args.host}:{server.port} "
        f"(listening for it on {where})",
        file=sys.stderr,
        flush=True,
    )
    net = None
    try:
        net = open_client(args, args.robot, "view")
        if net is None:
            return 2
        latest = Latest()
        for message in SUBSCRIBED + ((DepthPreview, DepthImage) if clouds else ()):
            net.subscribe(message, latest.put)
        presence = Presence(args.robot, where, args.silent_after, time.monotonic())
        period = 1.0 / args.rate
        while not stop.is_set():
            now = time.monotonic()
            viewer.publish(latest.take(), time.time_ns(), now)
            said = presence.update(latest.heard, now)
            if said is not None:
                print(said, file=sys.stderr, flush=True)
                level = (
                    foxglove.StatusLevel.Info
                    if presence.state == "heard"
                    else foxglove.StatusLevel.Warning
                )
                server.publish_status(said, level, id="robot")
            stop.wait(max(0.0, period - (time.monotonic() - now)))
        return 0
    finally:
        if net is not None:
            net.close()
        server.stop()
