"""An FTDI-style USB serial adapter (U2D2, USB2Dynamixel) between the host and the bus.

A real Dynamixel bus hangs off a USB adapter, and its timing, not the wire's, sets the cost of
a round trip: the chip holds the bytes it receives from the bus until its latency timer
expires (16 ms by default, 1 ms at best) or a USB packet's worth has gathered, and what the
host writes leaves on the next USB frame. Modelling it lets the driver be tested against the
≥ 1 ms (or ≥ 16 ms) a single read costs on a robot, not the tens of µs of a bare pty.
"""

from __future__ import annotations

import math
from collections import deque

FTDI_RX_PAYLOAD = 62
"""Bytes from the bus an FTDI chip sends in one USB packet: a 64-byte full-speed bulk packet
less the 2 modem-status bytes at its head. A buffer this full goes to the host at once, without
waiting for the latency timer."""

USB_FRAME = 1e-3
"""Full-speed USB frame period (s). The host controller schedules bulk OUT transfers per frame,
so bytes the host writes reach the adapter, and the bus, on the next frame boundary."""


class UsbSerialAdapter:
    """The adapter's timing: host → bus on frame boundaries, bus → host held by the timer.

    Bytes off the bus wait in the chip's receive buffer; the host gets them when ``latency`` s
    have passed since the last byte came in, or at once when the buffer holds
    ``buffer_size`` bytes. A short status packet therefore costs at least the latency timer:
    why reading 18 servos one by one takes 18 × the timer. Times are ``time.monotonic()``
    seconds; replies must be fed in the order they come off the wire.
    """

    def __init__(
        self, latency: float, frame: float = USB_FRAME, buffer_size: int = FTDI_RX_PAYLOAD
    ) -> None:
        if latency <= 0:
            raise ValueError(f"latency timer must be positive, got {latency} s")
        self.latency = latency
        self.frame = frame
        self.buffer_size = buffer_size
        self._held = bytearray()
        self._last = 0.0
        """When the last held byte came in."""
        self._arriving: deque[tuple[float, int]] = deque()
        """Bytes still on the wire: (when the adapter has it, byte)."""

    def to_bus(self, written: float) -> float:
        """When bytes the host wrote at ``written`` reach the bus: the next frame boundary."""
        return math.ceil(written / self.frame) * self.frame

    def from_bus(self, data: bytes, end: float, byte_time: float) -> None:
        """A reply whose last byte comes off the wire at ``end``, one byte per ``byte_time``."""
        n = len(data)
        self._arriving.extend((end - (n - 1 - i) * byte_time, b) for i, b in enumerate(data))

    def due(self) -> float | None:
        """When the host next gets bytes (the timer expires or the buffer fills); None: never."""
        held, last = len(self._held), self._last
        for when, _ in self._arriving:
            if held and when > last + self.latency:
                return last + self.latency
            held, last = held + 1, when
            if held == self.buffer_size:
                return when
        return last + self.latency if held else None

    def release(self, now: float) -> bytes:
        """Everything the adapter has sent the host by ``now``, in order."""
        out = bytearray()
        while self._held or self._arriving:
            expiry = self._last + self.latency
            if self._held and expiry <= now and not self._next_before(expiry):
                out += self._held
                self._held.clear()
                continue
            if not self._next_before(now):
                break
            self._last, byte = self._arriving.popleft()
            self._held.append(byte)
            if len(self._held) == self.buffer_size:
                out += self._held
                self._held.clear()
        return bytes(out)

    def _next_before(self, t: float) -> bool:
        """Whether the next byte on the wire reaches the adapter by ``t``."""
        return bool(self._arriving) and self._arriving[0][0] <= t
