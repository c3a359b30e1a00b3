"""``climbd view`` with a slow client: one that subscribes to everything and then stops reading.

The view (a subprocess) is fed a robot's joints at 100 Hz and a 1 MB elevation grid at 30 Hz
over Zenoh. A raw-socket WebSocket client with a small receive buffer subscribes to every
channel and stops reading: the view's memory stays bounded (the SDK keeps ``--backlog``
messages for it and drops the rest) while it is offered far more than that, a second, normal
client keeps receiving the transforms at ``--rate``, and the slow client, reading again, is
still connected and served.
"""

from __future__ import annotations

import asyncio
import base64
import json
import math
import os
import socket
import struct
import threading
import time

import numpy as np
import websockets
import zenoh
from support.foxglove_ws import SUBPROTOCOLS, Proc

from climbd.daemon.contract import messages as m
from climbd.daemon.contract import profile as profiles

RATE = 30.0
BACKLOG = 16
GRID = 512
"""Cells a side of the elevation grid fed to the view: 1 MB a message."""
STALL = 8.0
"""Seconds the slow client stops reading."""


class Feed:
    """A Zenoh peer on ``endpoint`` publishing the WidowX's joints at 100 Hz and a GRID×GRID
    elevation grid at 30 Hz until closed."""

    def __init__(self, endpoint: str) -> None:
        cfg = zenoh.Config()
        cfg.insert_json5("scouting/multicast/enabled", "false")
        cfg.insert_json5("listen/endpoints", json.dumps([endpoint]))
        self.session = zenoh.open(cfg)
        names = [j.name for j in profiles.load(profiles.stock_profiles()["widowx"]).joints]
        self.joints = m.JointState(names=names, position=[0.0] * len(names))
        grid = m.ElevationGrid(
            rows=GRID, cols=GRID, resolution=0.01, heights=np.zeros(GRID * GRID, "<f4").tobytes()
        )
        self.grid = m.encode(grid)
        self.grids = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        k = 0
        while not self.stop.is_set():
            self.joints.position[0] = 0.1 * math.sin(k / 100)
            self.session.put(m.key("widowx", m.JointState), m.encode(self.joints))
            if k % 3 == 0:
                self.session.put(m.key("widowx", m.ElevationGrid), self.grid)
                self.grids += 1
            k += 1
            self.stop.wait(0.01)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        self.session.close()


class RawClient:
    """The Foxglove WebSocket protocol over a plain socket, read only when asked."""

    def __init__(self, port: int, receive_buffer: int = 32 * 1024) -> None:
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
        self.sock.connect(("127.0.0.1", port))
        self.sock.settimeout(10)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            (
                f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                f"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {', '.join(SUBPROTOCOLS)}"
                "\r\n\r\n"
            ).encode()
        )
        self.buffer = b""
        while b"\r\n\r\n" not in self.buffer:
            self.buffer += self.sock.recv(4096)
        head, self.buffer = self.buffer.split(b"\r\n\r\n", 1)
        assert head.startswith(b"HTTP/1.1 101"), head

    def _take(self, n: int) -> bytes:
        while len(self.buffer) < n:
            chunk = self.sock.recv(1 << 16)
            if not chunk:
                raise ConnectionError("closed by the view")
            self.buffer += chunk
        out, self.buffer = self.buffer[:n], self.buffer[n:]
        return out

    def frame(self) -> tuple[int, bytes]:
        """The next frame's opcode and payload (the server's frames are not masked)."""
        b0, b1 = self._take(2)
        n = b1 & 0x7F
        if n == 126:
            (n,) = struct.unpack(">H", self._take(2))
        elif n == 127:
            (n,) = struct.unpack(">Q", self._take(8))
        return b0 & 0x0F, self._take(n)

    def send_text(self, text: str) -> None:
        data, mask = text.encode(), os.urandom(4)
        n = len(data)
        head = bytes([0x81]) + (
            bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + struct.pack(">H", n)
        )
        self.sock.sendall(head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data)))

    def subscribe_all(self) -> dict[int, str]:
        """Wait for the advertised channels and subscribe to all; their topics by id."""
        while True:
            opcode, payload = self.frame()
            if opcode == 1 and json.loads(payload)["op"] == "advertise":
                channels = {c["id"]: c["topic"] for c in json.loads(payload)["channels"]}
                subscriptions = [{"id": cid, "channelId": cid} for cid in channels]
                self.send_text(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
                return channels


def rss(pid: int) -> int:
    """Resident memory of process ``pid`` (bytes)."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise AssertionError("no VmRSS")


async def transforms_per_second(port: int, seconds: float) -> float:
    """A normal client subscribed to /tf alone: the transforms it receives per second."""
    uri = f"ws://127.0.0.1:{port}"
    async with websockets.connect(uri, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        tf = None
        while tf is None:
            msg = json.loads(await ws.recv())
            if msg["op"] == "advertise":
                tf = next((c["id"] for c in msg["channels"] if c["topic"] == "/tf"), None)
        await ws.send(
            json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": tf}]})
        )
        while isinstance(await ws.recv(), str):  # the first transforms
            pass
        count, start = 0, time.monotonic()
        while time.monotonic() - start < seconds:
            if not isinstance(await ws.recv(), str):
                count += 1
        return count / (time.monotonic() - start)


def test_a_client_that_stops_reading_costs_bounded_memory_and_slows_no_one(endpoint) -> None:
    feed = Feed(endpoint)
    view = Proc(
        "view", "--robot", "widowx", "--connect", endpoint, "--port", "0",
        "--rate", str(RATE), "--backlog", str(BACKLOG), "--cloud-rate", "0",
    )  # fmt: skip
    slow = None
    try:
        port = int(view.wait_for("to Foxglove on ws://").split("ws://127.0.0.1:")[1].split()[0])
        view.wait_for("robot 'widowx' heard")
        slow = RawClient(port)
        topics = slow.subscribe_all()
        assert "/elevation" in topics.values()
        time.sleep(1.0)  # the socket's buffers and the client's backlog fill
        before, grids_before = rss(view.proc.pid), feed.grids
        peak = before
        rate = asyncio.run(transforms_per_second(port, 3.0))
        end = time.monotonic() + STALL - 3.0
        while time.monotonic() < end:
            peak = max(peak, rss(view.proc.pid))
            time.sleep(0.1)
        peak = max(peak, rss(view.proc.pid))
        offered = (feed.grids - grids_before) * GRID * GRID * 4
        assert offered > 100e6, f"the stalled client was offered only {offered / 1e6:.0f} MB"
        grown = peak - before
        assert grown < 40e6, f"view grew {grown / 1e6:.0f} MB while {offered / 1e6:.0f} MB waited"
        assert rate > 0.7 * RATE, f"the normal client got transforms at {rate:.1f}/s"

        # reading again, the slow client is still connected and gets recent messages
        got = set()
        end = time.monotonic() + 5
        while time.monotonic() < end and not {"/tf", "/elevation"} <= got:
            opcode, payload = slow.frame()
            assert opcode != 8, "the view closed the slow client instead of dropping its messages"
            if opcode == 2:
                got.add(topics[struct.unpack_from("<I", payload, 1)[0]])
        assert {"/tf", "/elevation"} <= got
    finally:
        if slow is not None:
            slow.sock.close()
        feed.close()
        code = view.stop()
    assert code == 0, "".join(view.lines)
    assert "Traceback" not in "".join(view.lines)
