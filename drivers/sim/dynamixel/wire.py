"""Dynamixel wire format, written from the published protocol documents (not from the SDK).

Protocol 1.0: ``FF FF ID LEN INST PARAMS… CHECKSUM``, checksum = ~(ID + LEN + INST + PARAMS) & 0xFF.
Protocol 2.0: ``FF FF FD 00 ID LEN_L LEN_H INST PARAMS… CRC_L CRC_H``, CRC-16 (polynomial 0x8005,
initial value 0, not reflected) over everything before the CRC; inside INST+PARAMS every
``FF FF FD`` is followed by a stuffed ``FD`` and LEN counts the stuffed bytes.
"""

from __future__ import annotations

from dataclasses import dataclass

HEADER1 = b"\xff\xff"
HEADER2 = b"\xff\xff\xfd\x00"
BROADCAST = 0xFE
STATUS = 0x55


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray, crc: int = 0) -> int:
    """CRC-16/BUYPASS of Protocol 2.0 (poly 0x8005, init 0), continuing from ``crc``."""
    for b in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


def checksum(body: bytes | bytearray) -> int:
    """Protocol 1.0 checksum of ID, LEN, INST/ERROR and parameters."""
    return ~sum(body) & 0xFF


def stuff(payload: bytes) -> bytes:
    """Insert a 0xFD after every FF FF FD in INST+PARAMS (Protocol 2.0 byte stuffing)."""
    out = bytearray()
    for b in payload:
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(payload: bytes) -> bytes:
    """Remove the 0xFD stuffed after every FF FF FD (inverse of ``stuff``)."""
    out = bytearray()
    i = 0
    while i < len(payload):
        b = payload[i]
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            i += 1  # skip the stuffed FD
        i += 1
    return bytes(out)


def packet1(ident: int, code: int, params: bytes = b"") -> bytes:
    """A Protocol 1.0 packet; ``code`` is the instruction (host) or error byte (servo)."""
    body = bytes([ident, len(params) + 2, code]) + params
    return HEADER1 + body + bytes([checksum(body)])


def packet2(ident: int, inst: int, params: bytes = b"") -> bytes:
    """A Protocol 2.0 packet with byte stuffing and CRC; status params start with the error."""
    payload = stuff(bytes([inst]) + params)
    n = len(payload) + 2
    head = HEADER2 + bytes([ident, n & 0xFF, n >> 8]) + payload
    crc = crc16(head)
    return head + bytes([crc & 0xFF, crc >> 8])


@dataclass(frozen=True)
class Instruction:
    """One instruction packet as received: id, instruction, parameters, wire size, CRC validity."""

    ident: int
    inst: int
    params: bytes
    size: int
    valid: bool = True


class Framer:
    """Cuts a byte stream into instruction packets of one protocol, resynchronising on garbage."""

    def __init__(self, protocol: int) -> None:
        if protocol not in (1, 2):
            raise ValueError(f"Dynamixel protocol must be 1 or 2, got {protocol}")
        self.protocol = protocol
        self.buffer = bytearray()

    def feed(self, data: bytes) -> list[Instruction]:
        """Append ``data`` and return every complete packet now in the buffer."""
        self.buffer += data
        out = []
        while True:
            packet = self._next1() if self.protocol == 1 else self._next2()
            if packet is None:
                return out
            out.append(packet)

    def reset(self) -> None:
        """Drop a partial packet (e.g. after an inter-byte timeout)."""
        self.buffer.clear()

    def _resync(self, header: bytes) -> bool:
        i = self.buffer.find(header)
        if i < 0:
            keep = len(header) - 1
            del self.buffer[: max(0, len(self.buffer) - keep)]
            return False
        del self.buffer[:i]
        return True

    def _next1(self) -> Instruction | None:
        buf = self.buffer
        while True:
            if not self._resync(HEADER1) or len(buf) < 4:
                return None
            if buf[2] == 0xFF:  # FF FF FF…: the header starts one byte later
                del buf[0]
                continue
            break
        n = buf[3]
        if n < 2:
            del buf[:2]
            return self._next1()
        size = n + 4
        if len(buf) < size:
            return None
        raw = bytes(buf[:size])
        del buf[:size]
        valid = checksum(raw[2:-1]) == raw[-1]
        return Instruction(raw[2], raw[4], raw[5:-1], size, valid)

    def _next2(self) -> Instruction | None:
        buf = self.buffer
        if not self._resync(HEADER2[:3]) or len(buf) < 7:
            return None
        if buf[3] != 0x00:
            del buf[:3]
            return self._next2()
        n = buf[5] | buf[6] << 8
        if n < 3:
            del buf[:3]
            return self._next2()
        size = n + 7
        if len(buf) < size:
            return None
        raw = bytes(buf[:size])
        del buf[:size]
        valid = crc16(raw[:-2]) == (raw[-2] | raw[-1] << 8)
        payload = unstuff(raw[7:-2])
        return Instruction(raw[4], payload[0], payload[1:], size, valid)
