"""``climbd top``: a live terminal view of one robot or the fleet, refreshed with plain ANSI.

Per robot: live roles, mode and why, active session, control-loop rate (measured from the tick
count between Health messages) and lateness, per-joint position, temperature, voltage and
errors, and per feature topic its arrival rate and a summary of the latest message.
``--once`` prints one frame without escape codes and exits (scripts, tests, logs).
"""

from __future__ import annotations

import argparse
import collections
import math
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field

from climbd.daemon.cli.client import add_credential_arguments, client_config
from climbd.daemon.contract.messages import (
    FEATURES,
    ElevationGrid,
    GraspablePoints,
    Health,
    JointState,
    Joists,
    Message,
    ModeState,
    SchemaMismatch,
    Stairs,
    TrussMembers,
    decode,
    key,
)
from climbd.daemon.runtime.access import AccessError

RATE_WINDOW = 5.0
"""Seconds of arrivals a feature rate is averaged over."""
STALE_AFTER = 3.0
"""Seconds without Health after which a robot is shown as silent."""
CLEAR = "\x1b[H\x1b[2J"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    who = parser.add_mutually_exclusive_group(required=True)
    who.add_argument("--robot", help="robot name (profile name)")
    who.add_argument("--all", action="store_true", help="every robot on the network")
    parser.add_argument(
        "--connect", action="append", default=[], help="Zenoh endpoint of a robot (repeatable)"
    )
    parser.add_argument("--interval", type=float, default=0.5, help="refresh period (s)")
    parser.add_argument(
        "--once", action="store_true", help="print one frame (plain text) after --window and exit"
    )
    parser.add_argument(
        "--window", type=float, default=2.0, help="--once: seconds to listen before printing"
    )
    add_credential_arguments(parser)


@dataclass
class RobotView:
    """What top knows of one robot: the latest of each topic and arrival times of features."""

    name: str
    health: dict[str, Health] = field(default_factory=dict)
    heard: float = -math.inf
    mode: ModeState | None = None
    joints: JointState | None = None
    loop_rate: float | None = None
    features: dict[str, Message] = field(default_factory=dict)
    arrivals: dict[str, collections.deque] = field(default_factory=dict)
    roles: list[str] = field(default_factory=list)

    def on_message(self, msg: Message, now: float) -> None:
        """Take one message received at ``now`` (top's monotonic clock)."""
        if isinstance(msg, Health):
            previous = self.health.get(msg.role)
            if (
                msg.role == "control"
                and previous is not None
                and msg.stamp > previous.stamp
                and msg.loop.ticks >= previous.loop.ticks
            ):
                ticks = msg.loop.ticks - previous.loop.ticks
                self.loop_rate = ticks / (msg.stamp - previous.stamp)
            self.health[msg.role] = msg
            self.heard = now
        elif isinstance(msg, ModeState):
            self.mode = msg
        elif isinstance(msg, JointState):
            self.joints = msg
        else:
            self.features[msg.TOPIC] = msg
            times = self.arrivals.setdefault(msg.TOPIC, collections.deque(maxlen=1024))
            times.append(now)

    def rate(self, topic: str, now: float) -> float:
        """Arrivals per second of ``topic`` over the last RATE_WINDOW seconds."""
        times = self.arrivals.get(topic, ())
        recent = [t for t in times if now - t <= RATE_WINDOW]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-9)


def summarise(msg: Message) -> str:
    """One line describing a feature message (counts, nearest joist, grid coverage)."""
    if isinstance(msg, Joists):
        if not msg.joists:
            return "no joists"
        j = msg.joists[0]
        return (
            f"{len(msg.joists)} joists; nearest {j.distance:.3f} m, "
            f"yaw {math.degrees(j.yaw):+.1f}°, height {j.height:.3f} m, "
            f"confidence {j.confidence:.2f}"
        )
    if isinstance(msg, ElevationGrid):
        import numpy as np

        heights = np.frombuffer(msg.heights, dtype="<f4")
        known = float(np.isfinite(heights).mean() * 100) if heights.size else 0.0
        return f"{msg.rows}×{msg.cols} cells of {msg.resolution * 100:g} cm, {known:.0f} % known"
    if isinstance(msg, GraspablePoints):
        return f"{len(msg.points)} graspable points"
    if isinstance(msg, TrussMembers):
        return f"{len(msg.members)} truss members"
    if isinstance(msg, Stairs):
        if not msg.steps:
            return "no stairs"
        return f"{len(msg.steps)} steps; first rise {msg.steps[0].rise:.3f} m"
    return type(msg).__name__


def render_robot(view: RobotView, now: float) -> list[str]:
    """The lines of one robot's block."""
    control = view.health.get("control")
    roles = ", ".join(view.roles) or "none found"
    silent = "" if now - view.heard <= STALE_AFTER else "  (SILENT: no health for a while)"
    lines = [f"── {view.name} ── roles: {roles}{silent}"]
    if view.mode is not None:
        lines.append(f"mode {view.mode.mode.value}: {view.mode.reason}")
    elif control is not None:
        lines.append(f"mode {control.mode.value}")
    if control is not None:
        s = control.loop
        measured = f"{view.loop_rate:.1f}" if view.loop_rate is not None else "?"
        lines.append(
            f"loop {measured} Hz of {s.rate_hz:g} Hz; lateness p50 {s.lateness_p50 * 1e6:.0f} µs"
            f" p99 {s.lateness_p99 * 1e6:.0f} µs max {s.lateness_max * 1e6:.0f} µs; "
            f"overruns {s.overruns}"
        )
        lines.append(
            f"session {control.session or 'none'}; refused {control.refused_commands}, "
            f"unauthorised {control.unauthorised_commands}, decode errors {control.decode_errors}"
        )
        lines += _joint_lines(control, view.joints)
        lines += [f"  ! {m}" for m in control.messages[-3:]]
    for role, h in sorted(view.health.items()):
        for name, status in h.plugins.items():
            lines.append(f"plugin {name} ({role}): {status}")
        if role != "control" and h.dropped_frames:
            lines.append(f"{role}: {h.dropped_frames} frames dropped")
        if h.refused_frames:
            reasons = ", ".join(f"{n} {r}" for r, n in sorted(h.refused_frames.items()))
            lines.append(f"{role}: frames without a body pose: {reasons}")
    for topic, msg in sorted(view.features.items()):
        lines.append(f"{topic:<20} {view.rate(topic, now):5.1f} Hz  {summarise(msg)}")
    return lines


def _joint_lines(health: Health, state: JointState | None) -> list[str]:
    position = dict(zip(state.names, state.position, strict=False)) if state is not None else {}
    lines = [f"  {'joint':<14} {'pos rad':>8} {'°C':>6} {'V':>5}  errors"]
    for j in health.joints:
        q = position.get(j.name)
        flags = j.errors + (["LOST"] if j.lost else []) + (["derated"] if j.derated else [])
        q_text = f"{q:+8.3f}" if q is not None else f"{'?':>8}"
        lines.append(
            f"  {j.name:<14} {q_text} {j.temperature:6.1f} {j.voltage:5.1f}  {','.join(flags)}"
        )
    return lines


def render(views: dict[str, RobotView], now: float) -> list[str]:
    """A whole frame: every robot's block, robots by name."""
    if not views:
        return ["no climbd robot heard yet"]
    lines: list[str] = []
    for name in sorted(views):
        lines += render_robot(views[name], now)
        lines.append("")
    return lines[:-1]


class Top:
    """Subscriptions of a top session; views are updated on Zenoh threads under a lock."""

    def __init__(self, session, robot: str) -> None:
        self.session = session
        self.robot = robot
        self.views: dict[str, RobotView] = {}
        self.lock = threading.Lock()
        self._subscribers = []

    def start(self) -> None:
        for m in (Health, ModeState, JointState, *FEATURES):
            self._subscribers.append(
                self.session.declare_subscriber(key(self.robot, m), self._handler(m))
            )

    def _handler(self, message: type[Message]):
        import msgspec

        def on_sample(sample) -> None:
            try:
                msg = decode(sample.payload.to_bytes(), message)
            except (msgspec.DecodeError, msgspec.ValidationError, SchemaMismatch):
                return
            robot = str(sample.key_expr).split("/")[1]
            with self.lock:
                view = self.views.get(robot)
                if view is None:
                    view = self.views[robot] = RobotView(robot)
                view.on_message(msg, time.monotonic())

        return on_sample

    def refresh_roles(self) -> None:
        """Ask the network which roles are alive (liveliness tokens)."""

        found: dict[str, list[str]] = {}
        for reply in self.session.liveliness().get(key(self.robot, "alive/*"), timeout=0.5):
            if reply.ok is not None:
                parts = str(reply.ok.key_expr).split("/")
                found.setdefault(parts[1], []).append(parts[3])
        with self.lock:
            for robot, roles in found.items():
                view = self.views.get(robot)
                if view is None:
                    view = self.views[robot] = RobotView(robot)
                view.roles = sorted(set(roles))

    def frame(self) -> list[str]:
        with self.lock:
            return render(self.views, time.monotonic())

    def close(self) -> None:
        for s in self._subscribers:
            s.undeclare()


def main(args: argparse.Namespace) -> int:
    import zenoh

    try:
        config = client_config(args, "top")
    except AccessError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):  # explicit: an inherited SIG_IGN would hang us
        signal.signal(sig, lambda *_: stop.set())
    session = top = None
    try:  # a signal at any point, even while the session opens, still closes it
        session = zenoh.open(config)
        top = Top(session, "*" if args.all else args.robot)
        top.start()
        if args.once:
            time.sleep(args.window)
            top.refresh_roles()
            print("\n".join(top.frame()), flush=True)
            return 0 if top.views else 1
        last_roles = -math.inf
        while not stop.is_set():
            if time.monotonic() - last_roles > 2.0:
                top.refresh_roles()
                last_roles = time.monotonic()
            sys.stdout.write(CLEAR + "\n".join(top.frame()) + "\n")
            sys.stdout.flush()
            stop.wait(args.interval)
        return 0
    except BrokenPipeError:  # piped into head or less that quit: not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    finally:
        if top is not None:
            top.close()
        if session is not None:
            session.close()
