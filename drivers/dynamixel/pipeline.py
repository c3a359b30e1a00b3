"""Requests in flight on a Dynamixel bus: sent now, their replies parsed when they have come.

Behind a USB serial adapter a reply reaches the host only when the adapter's latency timer
expires (1 ms at best, 16 ms by default), long after it left the bus. Waiting for it blocks
the host for that long; instead the driver sends the next request as soon as the bus is free
and parses each reply once it is in. ``PipelinedPort`` is the port as dynamixel_sdk sees it
then: what the SDK writes goes out at once, what it reads comes from bytes already received,
it never waits and never flushes (a flush would drop replies still owed to earlier requests).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import dynamixel_sdk as sdk

from climbd.drivers.dynamixel.models import Item

Parsed = tuple[int, dict[int, bytes], int]
"""A parsed reply: the SDK's result code, the data of each joint read (joint index → bytes)
and the status error byte (Protocol 1.0's alarms; 0 when not kept)."""


class PipelinedPort:
    """dynamixel_sdk's port, for requests whose replies are parsed later from received bytes.

    ``receive()`` takes what the OS has; ``attempt(parse)`` runs an SDK parse over it and
    keeps the bytes it consumed only if the parse did not run out of them (an incomplete
    reply stays for later, whole)."""

    def __init__(self, port: sdk.PortHandler, receive: Callable[[], bytes]) -> None:
        self.port = port
        self._receive = receive
        self.buffer = bytearray()
        self._pos = 0
        self._starved = False

    # --- what the SDK calls ------------------------------------------------------------

    @property
    def is_using(self) -> bool:
        """Never busy: requests overlap by design (the SDK would refuse a second one)."""
        return False

    @is_using.setter
    def is_using(self, value: bool) -> None:
        pass

    def writePort(self, packet: list[int]) -> int:  # noqa: N802 - SDK interface
        return self.port.writePort(packet)

    def readPort(self, length: int) -> bytes:  # noqa: N802 - SDK interface
        data = self.buffer[self._pos : self._pos + length]
        self._pos += len(data)
        if len(data) < length:
            self._starved = True
        return bytes(data)

    def isPacketTimeout(self) -> bool:  # noqa: N802 - SDK interface
        """The SDK asks only when it wants more than there is: the bytes have run out."""
        self._starved = True
        return True

    def clearPort(self) -> None:  # noqa: N802 - SDK interface
        """Not a flush: received bytes may be replies to requests still in flight."""

    def setPacketTimeout(self, packet_length: int) -> None:  # noqa: N802 - SDK interface
        pass

    def setPacketTimeoutMillis(self, msec: float) -> None:  # noqa: N802 - SDK interface
        pass

    # --- what the driver calls ---------------------------------------------------------

    def receive(self) -> int:
        """Append every byte the OS has received; how many came."""
        data = self._receive()
        self.buffer += data
        return len(data)

    def attempt(self, parse: Callable[[], Parsed]) -> Parsed | None:
        """Run ``parse`` (SDK rx calls) over the received bytes: what it returns, consuming
        what it read; None when the reply is not all in yet (nothing consumed)."""
        self._pos, self._starved = 0, False
        parsed = parse()
        if parsed[0] != sdk.COMM_SUCCESS and self._starved:
            return None
        del self.buffer[: self._pos]
        return parsed

    def drop(self) -> None:
        """Forget every received byte (nothing is owed any more)."""
        self.buffer.clear()


@dataclass
class Request:
    """A request on the bus whose reply has not been parsed: a READ of ``item`` from the
    servos at ``joints`` (one for a READ, all of a sync read), sent at ``sent`` (monotonic
    s), keeping the bus ``wire`` s. ``parse`` takes its reply from the pipelined port."""

    joints: tuple[int, ...]
    item: Item
    sent: float
    wire: float
    parse: Callable[[], Parsed]
