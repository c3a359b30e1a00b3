"""The CAN channels MIT-mode motors are reached over: any python-can interface, or UDP datagrams.

``FrameLink`` is what the driver and the emulated motors need of a channel: send a batch of
standard frames, take every frame waiting. ``PythonCanLink`` puts a python-can interface behind
it (socketcan, virtual, udp_multicast, vendor adapters). ``UdpLink`` carries SocketCAN's
``struct can_frame``, one frame a datagram, between two UDP endpoints, for hardware-in-loop
across processes or hosts: one syscall per frame each way like SocketCAN, but no
``can.Message`` per frame, no msgpack and no echo of its own frames (python-can's
``udp_multicast`` has all three, which cost a 1 kHz tick more than its compute).
"""

from __future__ import annotations

import select
import socket
import struct
from collections.abc import Sequence
from typing import NamedTuple, Protocol

import can

CAN_ERR_FLAG = 0x20000000
CAN_EFF_MASK = 0x1FFFFFFF
CAN_FRAME = struct.Struct("=IB3x8s")
"""Linux ``struct can_frame``: id with flags, length, three pad bytes, eight data bytes."""
UDP_INTERFACE = "udp_can"


class Frame(NamedTuple):
    """One received frame: its id (flags masked off), data, and whether it is an error frame."""

    can_id: int
    data: bytes
    error: bool = False


class FrameLink(Protocol):
    """One CAN channel; failures are python-can's ``CanError``s (the caller names the channel)."""

    channel: str

    def send(self, ids: Sequence[int], payloads: Sequence[bytes]) -> None:
        """Put one standard data frame per id on the channel, in order."""

    def send_error(self, error_class: int) -> None:
        """Put an error frame of ``error_class`` (SocketCAN's bits) on the channel."""

    def receive(self, timeout: float) -> list[Frame]:
        """Every frame waiting, after waiting up to ``timeout`` s for the first ([] if none)."""

    def fileno(self) -> int | None:
        """A descriptor ``select`` finds readable when frames wait, or None if there is none."""

    def close(self) -> None: ...


def open_link(interface: str, channel: str) -> FrameLink:
    """The link for ``interface``: ``udp_can`` is ``UdpLink``, anything else python-can's."""
    if interface == UDP_INTERFACE:
        return UdpLink(channel)
    return PythonCanLink(interface, channel)


class PythonCanLink:
    """A python-can bus as a ``FrameLink``: a ``can.Message`` per frame each way."""

    def __init__(self, interface: str, channel: str) -> None:
        self.channel = channel
        self.bus = can.Bus(interface=interface, channel=channel)

    def send(self, ids: Sequence[int], payloads: Sequence[bytes]) -> None:
        for can_id, data in zip(ids, payloads, strict=True):
            self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))

    def send_error(self, error_class: int) -> None:
        self.bus.send(can.Message(arbitration_id=error_class, is_error_frame=True, dlc=8))

    def receive(self, timeout: float) -> list[Frame]:
        frames = []
        msg = self.bus.recv(timeout)
        while msg is not None:
            frames.append(Frame(msg.arbitration_id, bytes(msg.data), msg.is_error_frame))
            msg = self.bus.recv(0.0)
        return frames

    def fileno(self) -> int | None:
        try:
            return self.bus.fileno()
        except NotImplementedError:  # python-can's virtual bus, some vendor adapters
            return None

    def close(self) -> None:
        self.bus.shutdown()


def endpoints(channel: str) -> tuple[tuple[str, int], tuple[str, int]]:
    """The local and peer (host, port) of a ``"HOST:PORT/HOST:PORT"`` channel."""
    ends = [end.rpartition(":") for end in channel.split("/")]
    if len(ends) != 2 or not all(host and sep and port.isdigit() for host, sep, port in ends):
        raise can.CanInitializationError(
            f"{UDP_INTERFACE} channel {channel!r} is not LOCAL_HOST:PORT/PEER_HOST:PORT"
        )
    (local, _, local_port), (peer, _, peer_port) = ends
    return (local, int(local_port)), (peer, int(peer_port))


def peer_channel(channel: str) -> str:
    """The channel of the link at the other end of ``channel``."""
    local, peer = channel.split("/")
    return f"{peer}/{local}"


def udp_socket(channel: str) -> socket.socket:
    """A non-blocking UDP socket bound to the ``"LOCAL/PEER"`` channel's local end, connected
    to its peer; a malformed channel is a CanInitializationError, a taken port an OSError."""
    local, peer = endpoints(channel)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind(local)
        sock.connect(peer)
    except OSError:
        sock.close()
        raise
    sock.setblocking(False)
    return sock


class UdpLink:
    """One end of a point-to-point CAN channel in UDP datagrams (``"LOCAL/PEER"`` endpoints)."""

    def __init__(self, channel: str) -> None:
        self.channel = channel
        try:
            self.socket = udp_socket(channel)
        except OSError as e:
            raise can.CanInitializationError(f"{UDP_INTERFACE} channel {channel!r}: {e}") from e
        self._buffer = bytearray(CAN_FRAME.size)

    def _send(self, frames: list[bytes]) -> None:
        try:
            for frame in frames:
                self.socket.send(frame)
        except OSError as e:
            raise can.CanOperationError(f"{UDP_INTERFACE}: {e.strerror}", e.errno) from e

    def send(self, ids: Sequence[int], payloads: Sequence[bytes]) -> None:
        pack = CAN_FRAME.pack
        self._send([pack(i, len(d), d) for i, d in zip(ids, payloads, strict=True)])

    def send_error(self, error_class: int) -> None:
        self._send([CAN_FRAME.pack(CAN_ERR_FLAG | error_class, 8, bytes(8))])

    def receive(self, timeout: float) -> list[Frame]:
        """Every frame waiting; a refused peer (nothing listening at its port, as ICMP tells)
        or a datagram that is not a ``can_frame`` is a CanOperationError."""
        frames: list[Frame] = []
        buffer, size = self._buffer, CAN_FRAME.size
        while True:
            try:
                n = self.socket.recv_into(buffer)
            except BlockingIOError:
                if frames or timeout <= 0.0:
                    return frames
                if not select.select([self.socket], [], [], timeout)[0]:
                    return frames
                timeout = 0.0
                continue
            except OSError as e:
                raise can.CanOperationError(f"{UDP_INTERFACE}: {e.strerror}", e.errno) from e
            if n != size:
                raise can.CanOperationError(
                    f"{UDP_INTERFACE}: a {n}-byte datagram is not a {size}-byte can_frame"
                )
            can_id, length, data = CAN_FRAME.unpack_from(buffer)
            frames.append(Frame(can_id & CAN_EFF_MASK, data[:length], bool(can_id & CAN_ERR_FLAG)))

    def fileno(self) -> int | None:
        return self.socket.fileno()

    def close(self) -> None:
        self.socket.close()
