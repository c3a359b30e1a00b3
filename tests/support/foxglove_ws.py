"""A plain Foxglove WebSocket client (not climbd's code) and a ``climbd`` subprocess, for the
tests and benches of ``climbd view``: subscribe to every advertised channel, collect or pick
messages, decode each against the schema its channel advertises."""

from __future__ import annotations

import asyncio
import base64
import json
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import jsonschema
import numpy as np
import websockets
import zenoh

from climbd.daemon.contract import messages as m
from support.scene_decode import proto_dict

ROOT = Path(__file__).resolve().parent.parent.parent
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
"""What the client offers: foxglove-sdk ≥ 0.30 names the protocol foxglove.sdk.v1."""


class Proc:
    """A ``climbd`` subprocess, its output (stdout and stderr) collected line by line."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "climbd.daemon.cli", *args],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line)

    def wait_for(self, text: str, timeout: float = 20.0, after: int = 0) -> str:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for line in self.lines[after:]:
                if text in line:
                    return line
            if self.proc.poll() is not None:
                break
            time.sleep(0.05)
        raise AssertionError(f"{text!r} not printed; output:\n{''.join(self.lines)}")

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise


async def foxglove_client(
    port: int, until: float, wanted: frozenset[str] = frozenset()
) -> tuple[dict, dict[int, list[bytes]]]:
    """Speak the Foxglove WebSocket protocol: take the advertised channels, subscribe to all,
    and collect message data until every channel sent twice, or every ``wanted`` topic sent
    once and two seconds passed, or ``until`` (monotonic s)."""
    uri = f"ws://127.0.0.1:{port}"
    async with websockets.connect(uri, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        channels: dict[int, dict] = {}
        data: dict[int, list[bytes]] = {}
        server_info = None
        enough = time.monotonic() + 2.0
        while time.monotonic() < until:
            heard = {channels[c]["topic"] for c in data if c in channels}
            if wanted and wanted <= heard and time.monotonic() > enough:
                break
            try:
                frame = await asyncio.wait_for(ws.recv(), 0.2)
            except asyncio.TimeoutError:
                continue
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "serverInfo":
                    server_info = msg
                channels.update(await _subscribe_advertised(ws, msg))
                continue
            opcode, subscription, _ = struct.unpack_from("<BIQ", frame)
            assert opcode == 1, f"binary opcode {opcode}"
            data.setdefault(subscription, []).append(frame[13:])
            if channels and all(len(data.get(c, ())) >= 2 for c in channels):
                break
        assert server_info is not None and "climbd widowx" in server_info["name"]
        return channels, data


RESUBSCRIBE = 4.0
"""Seconds without a message on a subscribed channel before ``first_on`` subscribes again."""


async def first_on(port: int, topic: str, until: float) -> tuple[dict, dict]:
    """Subscribe to the channel ``topic`` as advertised; the channel and its first message,
    decoded from the channel's protobuf schema, before ``until`` (monotonic s). Only that
    channel: a client subscribed to all that a loaded machine serves slowly may have the server
    drop the big messages it waits for (no /depth, no /truth/joists in 20-30 s, twice in CI
    rehearsals). Subscribed to only, a channel still stayed silent in two CI rehearsals (cause
    unknown): after ``RESUBSCRIBE`` s without a message it subscribes again, and says so."""
    uri = f"ws://127.0.0.1:{port}"
    async with websockets.connect(uri, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        channels: dict[int, dict] = {}
        since: dict[int, float] = {}
        again = 0
        while time.monotonic() < until:
            for cid in [c for c, at in since.items() if time.monotonic() - at > RESUBSCRIBE]:
                await ws.send(json.dumps({"op": "unsubscribe", "subscriptionIds": [cid]}))
                subscription = {"id": cid, "channelId": cid}
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": [subscription]}))
                since[cid] = time.monotonic()
                again += 1
                print(f"first_on: nothing on {topic} in {RESUBSCRIBE:g} s, subscribed again",
                      file=sys.stderr)  # fmt: skip
            try:
                frame = await asyncio.wait_for(ws.recv(), 0.2)
            except asyncio.TimeoutError:
                continue
            if isinstance(frame, str):
                new = await _subscribe_advertised(ws, json.loads(frame), topic)
                channels.update(new)
                since.update(dict.fromkeys(new, time.monotonic()))
                continue
            _, subscription, _ = struct.unpack_from("<BIQ", frame)
            channel = channels[subscription]
            if channel["topic"] == topic:
                schema = base64.b64decode(channel["schema"])
                return channel, proto_dict(channel["schemaName"], schema, frame[13:])
        topics = [c["topic"] for c in channels.values()]
        raise AssertionError(f"no {topic}; channels: {topics}; subscribed again {again} times")


async def _subscribe_advertised(ws, msg: dict, topic: str | None = None) -> dict[int, dict]:
    """For an ``advertise`` op: subscribe to each channel it names (of ``topic`` only, if
    given); the channels subscribed to, by id."""
    if msg["op"] != "advertise":
        return {}
    new = {c["id"]: c for c in msg["channels"] if topic is None or c["topic"] == topic}
    if not new:
        return {}
    subscriptions = [{"id": cid, "channelId": cid} for cid in new]
    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
    return new


def check_payloads(
    channels: dict[int, dict], data: dict[int, list[bytes]], every: bool = True
) -> dict[str, list]:
    """Every advertised channel sent data (unless not ``every``: a run whose world has no such
    map), each payload decodes against its advertised schema; the decoded messages by topic."""
    out: dict[str, list] = {}
    for cid, channel in channels.items():
        payloads = data.get(cid)
        if not every and not payloads:
            continue
        assert payloads, f"nothing on {channel['topic']}"
        if channel["encoding"] == "protobuf":
            assert channel["schemaEncoding"] == "protobuf"
            descriptor_set = base64.b64decode(channel["schema"])
            decoded_all = [proto_dict(channel["schemaName"], descriptor_set, p) for p in payloads]
        else:
            assert (channel["encoding"], channel["schemaEncoding"]) == ("json", "jsonschema")
            schema = json.loads(channel["schema"])
            decoded_all = [json.loads(p) for p in payloads]
            for msg in decoded_all:
                jsonschema.validate(msg, schema)
        out[channel["topic"]] = decoded_all
    return out


MAPS = [
    m.JoistMap(joists=[m.MappedJoist(id=1, confidence=0.7, seen=2, age=0.0, heading=0.0,
                                     offset=0.5, height=0.1,
                                     endpoints=[[0.5, -0.3, 0.0], [0.5, 0.3, 0.0]])]),
    m.HoldMap(holds=[m.MappedHold(id=1, confidence=0.3, seen=1, age=0.0,
                                  position=[0.3, 0.0, 0.0])]),
    m.StairMap(steps=[m.MappedStair(id=1, confidence=1.0, seen=1, age=0.0, height=0.15,
                                    rise=0.15, depth=0.3,
                                    edge=[[0.4, 0.3, 0.15], [0.4, -0.3, 0.15]])]),
    m.TrussMembers(members=[m.TrussMember(p0=[1, 0, 0], p1=[1, 0, 1], radius=0.03,
                                          axis=[0, 0, 1], id=1)],
                   nodes=[m.TrussNode(position=[1, 0, 1], members=[1])]),
    m.ElevationGrid(rows=4, cols=4, resolution=0.05, heights=np.zeros(16, "<f4").tobytes()),
]  # fmt: skip
"""One of each map the view draws, as the perception role's world model publishes them."""


class MapPublisher:
    """A Zenoh peer listening on ``endpoint`` that publishes MAPS every ``period`` s until
    closed (the robot's own peers do not route a third party's maps)."""

    def __init__(self, endpoint: str, period: float = 0.5) -> None:
        self.period = period
        cfg = zenoh.Config()
        cfg.insert_json5("scouting/multicast/enabled", "false")
        cfg.insert_json5("listen/endpoints", json.dumps([endpoint]))
        self.session = zenoh.open(cfg)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            for msg in MAPS:
                self.session.put(m.key("widowx", type(msg)), m.encode(msg))
            self.stop.wait(self.period)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        self.session.close()
