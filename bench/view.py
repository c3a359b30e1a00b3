"""``climbd view``'s cost to the robot and its latency, each beside a baseline in the same run.

(a) **CPU of the control role** (``climbd run --profile robots/widowx.toml --driver fake``, 18
joints at 100 Hz; its process's user + system time from /proc) over windows of ``--window`` s
in three conditions, their order rotated round by round so the shared machine's drift hits all
alike: ``alone`` (nobody subscribed: the baseline), ``raw sub`` (a plain zenoh session
subscribed to ``climbd/widowx/**``, what any subscriber costs) and ``viewer`` (``climbd view``
connected, a Foxglove WebSocket client subscribed to every channel it advertises). The goal is
none added: the view subscribes only to what the robot already publishes. The view process's
own CPU is given beside.

(b) **Latency** from a joint state's ``stamp`` (the publisher's monotonic clock) to its
transforms leaving the view: this process publishes an 18-joint JointState at 100 Hz (robot
``benchview``, WidowX's joints, the first joint's angle stepping so that each message's
transforms are told apart), ``climbd view`` serves them (``--rate 30``), and a Foxglove client
here takes the time each ``/tf`` message arrives and finds the joint state it was drawn from
(the first leg's coxa frame, computed here by the same translation). Arrival over WebSocket on
loopback bounds the send from above. The baseline is the raw Zenoh hop of the same messages:
a plain zenoh subscriber in another session, stamp → callback. Goal: view p50 ≤ 20 ms.

    .venv/bin/python bench/view.py [--rounds 5] [--window 6] [--latency-rounds 3]
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import socket
import statistics
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zenoh
from websockets.sync.client import connect

from climbd.daemon.contract import messages as m
from climbd.daemon.contract import profile as profiles
from climbd.daemon.runtime import scene

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
from support.foxglove_ws import SUBPROTOCOLS, Proc  # noqa: E402  (the tests' own)
from support.scene_decode import proto_class  # noqa: E402

PROFILE = ROOT / "robots" / "widowx.toml"
TICK = os.sysconf("SC_CLK_TCK")
CONDITIONS = ("alone", "raw sub", "viewer")


def free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def cpu_seconds(pid: int) -> float:
    """User + system CPU time (s) of process ``pid``, all its threads."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK


def load() -> str:
    return Path("/proc/loadavg").read_text().split(" ", 1)[0]


def session(connect_to: list[str], listen: list[str] = ()) -> zenoh.Session:
    cfg = zenoh.Config()
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("connect/endpoints", json.dumps(connect_to))
    cfg.insert_json5("listen/endpoints", json.dumps(list(listen)))
    return zenoh.open(cfg)


class Client:
    """A Foxglove WebSocket client on a thread: subscribes to every advertised channel (or to
    ``only``) and hands each binary message to ``on_message(topic, payload, arrival)``."""

    def __init__(self, port: int, on_message=None, only: str | None = None) -> None:
        self.port = port
        self.on_message = on_message
        self.only = only
        self.channels: dict[int, dict] = {}
        self.received = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        uri = f"ws://127.0.0.1:{self.port}"
        with connect(uri, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
            while not self.stop.is_set():
                try:
                    frame = ws.recv(timeout=0.2)
                except TimeoutError:
                    continue
                at = time.monotonic()
                if isinstance(frame, str):
                    msg = json.loads(frame)
                    if msg["op"] == "advertise":
                        new = {
                            c["id"]: c
                            for c in msg["channels"]
                            if self.only is None or c["topic"] == self.only
                        }
                        self.channels.update(new)
                        subs = [{"id": cid, "channelId": cid} for cid in new]
                        if subs:
                            ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                    continue
                self.received += 1
                if self.on_message is not None:
                    subscription = int.from_bytes(frame[1:5], "little")
                    self.on_message(self.channels[subscription], frame[13:], at)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)


def wait_until(predicate, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise RuntimeError(f"timed out waiting for {what}")
        time.sleep(0.05)


def view_port(view: Proc) -> int:
    return int(
        view.wait_for("to Foxglove on ws://", timeout=30.0).split("ws://127.0.0.1:")[1].split()[0]
    )


# --- (a) CPU of the control role ------------------------------------------------------------


def cpu_rounds(rounds: int, window: float) -> dict[str, dict[str, list[float]]]:
    """Per condition: the control role's CPU (% of a core) per window, and the view's own."""
    ep = free_endpoint()
    robot = Proc("run", "--profile", str(PROFILE), "--driver", "fake", "--listen", ep, "--quiet")
    out = {c: {"robot": [], "view": []} for c in CONDITIONS}
    try:
        robot.wait_for("control role", timeout=30.0)
        time.sleep(3.0)  # standing up, start-up transients
        pid = robot.proc.pid
        for k in range(rounds):
            order = CONDITIONS[k % 3 :] + CONDITIONS[: k % 3]
            for condition in order:
                extra = []
                view = client = None
                if condition == "raw sub":
                    s = session([ep])
                    s.declare_subscriber("climbd/widowx/**", lambda _s: None)
                    extra.append(s.close)
                elif condition == "viewer":
                    view = Proc("view", "--robot", "widowx", "--connect", ep, "--port", "0")
                    client = Client(view_port(view))
                    view.wait_for("robot 'widowx' heard", timeout=30.0)
                    wait_until(lambda c=client: c.received > 60, 20, "the view's messages")
                    extra += [client.close, view.stop]
                time.sleep(0.5)  # settle: connection set-up out of the window
                c0, v0, t0 = cpu_seconds(pid), view and cpu_seconds(view.proc.pid), time.monotonic()
                time.sleep(window)
                dt = time.monotonic() - t0
                out[condition]["robot"].append(100 * (cpu_seconds(pid) - c0) / dt)
                if view is not None:
                    out[condition]["view"].append(100 * (cpu_seconds(view.proc.pid) - v0) / dt)
                for close in extra:
                    close()
    finally:
        robot.stop()
    return out


# --- (b) latency: joint state stamp → WebSocket send ----------------------------------------


class Stamps:
    """The stamp of each joint state sent, by the rotation of the coxa frame it draws."""

    def __init__(self, profile: profiles.Profile) -> None:
        self.robot = scene.RobotScene(profile)
        self.names = [j.name for j in profile.joints]
        self.frame = self.names[0]
        self.base = np.zeros(len(self.names))
        self.keys = []
        schema = scene.fg.FrameTransforms.get_schema()
        decode = proto_class(schema.name, bytes(schema.data)).FromString
        for k in range(STEPS):
            tf = decode(self.robot.transforms(None, self.joints(k, 0.0), 0).encode())
            (t,) = (t for t in tf.transforms if t.child_frame_id == self.frame)
            self.keys.append(key_of(t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w))
        assert len(set(self.keys)) == STEPS, "each step's coxa frame told apart"
        self.index = {k: i for i, k in enumerate(self.keys)}
        self.sent: dict[int, float] = {}

    def joints(self, k: int, stamp: float) -> m.JointState:
        q = self.base.copy()
        q[0] = -0.5 + (k % STEPS) * 1e-3
        return m.JointState(stamp=stamp, names=self.names, position=q.tolist())


STEPS = 1000
"""Distinct coxa angles: 10 s of joint states at 100 Hz before one repeats."""


def key_of(x: float, y: float, z: float, w: float) -> tuple[float, ...]:
    return tuple(round(v, 9) for v in (x, y, z, w))


def latency_rounds(rounds: int, seconds: float) -> dict[str, list[list[float]]]:
    """Latencies (s) per round: view (stamp → /tf arrival) and raw (stamp → zenoh callback)."""
    profile = profiles.load(PROFILE)
    stamps = Stamps(profile)
    ep = free_endpoint()
    pub_session = session([], [ep])
    raw_session = session([ep])
    k_joints = m.key("benchview", m.JointState)
    publisher = pub_session.declare_publisher(
        k_joints,
        priority=zenoh.Priority.REAL_TIME,
        congestion_control=zenoh.CongestionControl.DROP,
        express=True,
    )
    lat = {"view": [], "raw": []}
    current = {"view": [], "raw": []}

    def on_raw(sample) -> None:
        at = time.monotonic()
        msg = m.decode(sample.payload.to_bytes(), m.JointState)
        current["raw"].append(at - msg.stamp)

    classes: dict[int, type] = {}

    def on_view(channel: dict, payload: bytes, at: float) -> None:
        cls = classes.get(channel["id"])
        if cls is None:
            schema = base64.b64decode(channel["schema"])
            cls = classes[channel["id"]] = proto_class(channel["schemaName"], schema)
        msg = cls.FromString(payload)
        for t in msg.transforms:
            if t.child_frame_id == stamps.frame:
                r = t.rotation
                step = stamps.index.get(key_of(r.x, r.y, r.z, r.w))
                if step is not None and step in stamps.sent:
                    current["view"].append(at - stamps.sent[step])
                return

    raw_session.declare_subscriber(k_joints, on_raw)
    view = Proc(
        "view", "--robot", "benchview", "--profile", str(PROFILE), "--connect", ep,
        "--port", "0",
    )  # fmt: skip
    stop = threading.Event()

    def publish() -> None:
        period, k = 1.0 / profile.rate_hz, 0
        next_at = time.monotonic()
        while not stop.is_set():
            now = time.monotonic()
            stamps.sent[k % STEPS] = now
            publisher.put(m.encode(stamps.joints(k, now)))
            k += 1
            next_at += period
            stop.wait(max(0.0, next_at - time.monotonic()))

    thread = threading.Thread(target=publish, daemon=True)
    client = None
    try:
        thread.start()
        client = Client(view_port(view), on_view, only="/tf")
        view.wait_for("robot 'benchview' heard", timeout=30.0)
        wait_until(lambda: len(current["view"]) > 30, 20, "transforms from the view")
        time.sleep(1.0)
        for _ in range(rounds):
            for side in current.values():
                side.clear()
            time.sleep(seconds)
            for side, values in current.items():
                lat[side].append(list(values))
    finally:
        stop.set()
        thread.join(2)
        if client is not None:
            client.close()
        view.stop()
        raw_session.close()
        pub_session.close()
    return lat


def spread(values: list[float], fmt: str = ".1f") -> str:
    """Median and range of per-round values."""
    if len(values) == 1:
        return format(values[0], fmt)
    return f"{statistics.median(values):{fmt}} ({min(values):{fmt}}–{max(values):{fmt}})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5, help="CPU rounds (each condition once)")
    parser.add_argument("--window", type=float, default=6.0, help="seconds of CPU per window")
    parser.add_argument("--latency-rounds", type=int, default=3)
    parser.add_argument("--latency-seconds", type=float, default=6.0)
    parser.add_argument("--json", help="also write the results here")
    args = parser.parse_args()
    started = time.monotonic()
    print(f"load {load()}", flush=True)
    cpu = cpu_rounds(args.rounds, args.window)
    lat = latency_rounds(args.latency_rounds, args.latency_seconds)
    print(f"load {load()}, {time.monotonic() - started:.0f} s\n")

    alone = cpu["alone"]["robot"]
    print(
        f"(a) control role CPU, % of one core: {args.rounds} rounds × {args.window:g} s per "
        "condition; median (min–max) over rounds; ratio = per-round condition / alone"
    )
    print("\n| condition | control role CPU % | − alone (points) | / alone | view process CPU % |")
    print("|---|---:|---:|---:|---:|")
    for c in CONDITIONS:
        robot = cpu[c]["robot"]
        ratios = [a / b for a, b in zip(robot, alone, strict=True)]
        added = [a - b for a, b in zip(robot, alone, strict=True)]
        view = spread(cpu[c]["view"]) if cpu[c]["view"] else "–"
        print(
            f"| {c} | {spread(robot)} | {spread(added, '+.1f')} | {spread(ratios, '.2f')} "
            f"| {view} |"
        )

    print(
        f"\n(b) latency from a joint state's stamp, ms: {args.latency_rounds} rounds × "
        f"{args.latency_seconds:g} s, 100 Hz joint states; per-round p50 / p90 / p99, median "
        "(min–max) over rounds; ratio = per-round view p50 / raw p50"
    )
    print("\n| path | messages / round | p50 ms | p90 ms | p99 ms | p50 / raw |")
    print("|---|---:|---:|---:|---:|---:|")
    p50 = {s: [float(np.percentile(r, 50)) * 1e3 for r in lat[s]] for s in lat}
    for side, name in (("raw", "raw Zenoh hop (stamp → callback)"),
                       ("view", "climbd view (stamp → /tf at client)")):  # fmt: skip
        q = {p: [float(np.percentile(r, p)) * 1e3 for r in lat[side]] for p in (50, 90, 99)}
        ratios = [a / b for a, b in zip(p50[side], p50["raw"], strict=True)]
        count = spread([float(len(r)) for r in lat[side]], ".0f")
        print(
            f"| {name} | {count} | {spread(q[50], '.2f')} | {spread(q[90], '.2f')} "
            f"| {spread(q[99], '.2f')} | {spread(ratios, '.1f')} |"
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"cpu": cpu, "latency_s": lat}, f)


if __name__ == "__main__":
    main()
