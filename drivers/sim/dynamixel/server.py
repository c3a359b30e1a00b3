"""Serve a ServoChain on a pseudo-terminal with modelled wire timing.

An instruction of n bytes starts on the wire when it arrives or when the bus frees up, ends
n × 10 / baud later and is acted on then (as a servo acts on a packet once it is all in; the
emulator stays free meanwhile to note when the next one arrives); each reply follows after
its servo's return delay and its own bytes × 10 / baud, and is written to the pty when its
last byte would have arrived. The host opens ``.port`` with dynamixel_sdk exactly as it opens
/dev/ttyUSB0. With a latency timer set, a USB serial adapter sits between the pty and the bus
(adapter.py): instructions reach the bus on the next USB frame, replies wait in the adapter
until its timer expires or its buffer fills.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import logging
import os
import select
import threading
import time
import tty
from collections import deque

from climbd.drivers.sim.dynamixel.adapter import UsbSerialAdapter
from climbd.drivers.sim.dynamixel.chain import ServoChain
from climbd.drivers.sim.dynamixel.wire import Framer, Instruction

log = logging.getLogger(__name__)

_PR_SET_TIMERSLACK = 29


def _tight_timer_slack() -> None:
    """Ask Linux for 1 ns timer slack on this thread (default 50 µs) so reply times are sharp."""
    name = ctypes.util.find_library("c")
    if name is None:
        return
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(name).prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0)


class DynamixelEmulator:
    """Background thread answering for ``chain`` on a pty; ``.port`` is the slave tty path.

    ``realtime_motor`` steps the built-in motor model of each servo an instruction addresses
    up to wall-clock time (turn it off when a physics twin drives them). ``spin`` (s) busy-waits
    the last stretch before a reply (and before acting on an instruction) instead of sleeping,
    for benchmark-grade timing. ``latency_ms`` puts an FTDI-style USB serial adapter with that
    latency timer between the host and the bus (0 or None: the pty is wired to the bus).
    ``vanish()`` makes the port disappear under the host, as an unplugged USB adapter does.

    In the host's process, a client that busy-polls the port (dynamixel_sdk's stock
    PortHandler) starves this thread of the GIL for tens of ms: select(0) releases and retakes
    it before the waiter runs. Clients that block in select
    (climbd.drivers.dynamixel.bus.LatencyPort) are served at once; for a busy-polling client run
    ``python -m climbd.drivers.sim.dynamixel``."""

    def __init__(
        self,
        chain: ServoChain,
        *,
        realtime_motor: bool = True,
        spin: float = 0.0,
        inter_byte_timeout: float = 0.01,
        latency_ms: float | None = None,
    ) -> None:
        self.chain = chain
        self.realtime_motor = realtime_motor
        self.spin = spin
        self.inter_byte_timeout = inter_byte_timeout
        self.latency_ms = latency_ms
        self.port = ""
        self.bytes_handled = 0
        """Bytes read from the bus and acted on (replies queued, goals applied)."""
        self._master = -1
        self._slave = -1
        self._wake_r = self._wake_w = -1
        self._thread: threading.Thread | None = None
        self._adapter: UsbSerialAdapter | None = None
        self._stop = threading.Event()

    def start(self) -> DynamixelEmulator:
        """Open the pty and start serving; returns self."""
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self._wake_r, self._wake_w = os.pipe()
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name="dxl-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the pty (idempotent)."""
        self._stop.set()
        if self._wake_w >= 0:
            with contextlib.suppress(OSError):
                os.write(self._wake_w, b"x")
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = self._wake_r = self._wake_w = -1

    def retime(self, latency_ms: float) -> None:
        """Change the adapter's latency timer while serving (a user's echo, or udev, under
        load); there must be an adapter."""
        if self._adapter is None:
            raise ValueError("no USB adapter to retime: start with latency_ms")
        self._adapter.latency = latency_ms * 1e-3

    def vanish(self) -> None:
        """The port disappears: the pty closes under the host (reads and writes fail with EIO)."""
        self.stop()

    def __enter__(self) -> DynamixelEmulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _serve(self) -> None:
        _tight_timer_slack()
        chain = self.chain
        if self.realtime_motor:
            chain.clock = time.monotonic
        framer = Framer(chain.protocol)
        adapter = self._adapter = (
            UsbSerialAdapter(self.latency_ms * 1e-3) if self.latency_ms else None
        )
        inbox: deque[tuple[float, Instruction]] = deque()  # (arrival, instruction)
        pending: deque[tuple[float, bytes]] = deque()
        bus_free = last_rx = time.monotonic()
        received = 0
        master, wake = self._master, self._wake_r

        def acted_on() -> float:
            """When the first instruction of the inbox has fully arrived on the wire."""
            arrival, instr = inbox[0]
            return max(arrival, bus_free) + chain.wire_time(instr.size)

        while not self._stop.is_set():
            now = time.monotonic()
            due = [pending[0][0] - self.spin] if pending else []
            due += [acted_on() - self.spin] if inbox else []
            if adapter is not None and (released := adapter.due()) is not None:
                due.append(released - self.spin)
            timeout = max(0.0, min(due) - now) if due else 0.1
            try:
                ready, _, _ = select.select([master, wake], [], [], timeout)
            except (OSError, ValueError):
                return
            if wake in ready:
                return
            now = time.monotonic()
            if master in ready:
                try:
                    data = os.read(master, 4096)
                except OSError:
                    data = b""
                if not data:
                    time.sleep(0.001)  # no slave open yet: nothing to serve
                    continue
                if framer.buffer and now - last_rx > self.inter_byte_timeout:
                    framer.reset()
                last_rx = now
                arrival = now if adapter is None else adapter.to_bus(now)
                inbox.extend((arrival, instr) for instr in framer.feed(data))
                received += len(data)
            while inbox and (t := acted_on()) - time.monotonic() <= self.spin:
                while time.monotonic() < t:
                    pass
                instr = inbox.popleft()[1]
                for reply in chain.handle(instr):
                    t += reply.delay + chain.wire_time(len(reply.data))
                    if adapter is None:
                        pending.append((t, reply.data))
                    else:
                        adapter.from_bus(reply.data, t, chain.wire_time(1))
                bus_free = t
            if not inbox:
                self.bytes_handled = received
            while pending:
                due, data = pending[0]
                now = time.monotonic()
                if due - now > self.spin:
                    break
                while time.monotonic() < due:
                    pass
                pending.popleft()
                try:
                    os.write(master, data)
                except OSError:
                    return
            if adapter is not None:
                released = adapter.due()
                if released is not None and released - time.monotonic() <= self.spin:
                    while time.monotonic() < released:
                        pass
                    try:
                        os.write(master, adapter.release(time.monotonic()))
                    except OSError:
                        return
