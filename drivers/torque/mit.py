"""The MIT-mode actuator protocol on CAN: packed 8-byte commands and 6-byte replies.

The de-facto protocol of torque-controlled legged-robot actuators (mini-cheetah firmware
and its descendants). A command to motor ``id`` (standard 11-bit id) carries
position (16 bits), velocity, kp, kd and feed-forward torque (12 bits each), each mapped
linearly onto its configured range; the motor applies
``tau = kp (p_des - p) + kd (v_des - v) + tau_ff`` and answers to the master id with
``[id, position 16, velocity 12, torque 12]``. Three special frames switch modes.
"""

from __future__ import annotations

from dataclasses import dataclass

from daemon.profile import ActuatorRanges

ENTER_MOTOR_MODE = bytes([0xFF] * 7 + [0xFC])
EXIT_MOTOR_MODE = bytes([0xFF] * 7 + [0xFD])
SET_ZERO = bytes([0xFF] * 7 + [0xFE])
CAN_ERR_BUSOFF = 0x40
"""Error-frame class bit of Linux SocketCAN for bus-off (linux/can/error.h)."""


class ProtocolError(ValueError):
    """A frame that does not decode: wrong length or a value outside the actuator's range."""


def to_uint(x: float, lo: float, hi: float, bits: int) -> int:
    """Map ``x`` in [lo, hi] onto an unsigned ``bits`` integer, saturating outside."""
    x = min(max(x, lo), hi)
    return int((x - lo) * ((1 << bits) - 1) / (hi - lo))


def to_float(u: int, lo: float, hi: float, bits: int) -> float:
    """Inverse of ``to_uint``."""
    return u * (hi - lo) / ((1 << bits) - 1) + lo


@dataclass(frozen=True)
class Command:
    """One motor's impedance command: desired position, velocity, gains, feed-forward torque."""

    position: float
    velocity: float = 0.0
    kp: float = 0.0
    kd: float = 0.0
    torque: float = 0.0


@dataclass(frozen=True)
class Reply:
    """One motor's state as it reports it: id, position (rad), velocity (rad/s), torque (N·m)."""

    motor: int
    position: float
    velocity: float
    torque: float


def pack_command(c: Command, r: ActuatorRanges) -> bytes:
    """The 8 data bytes of a command; out-of-range values saturate as the firmware does."""
    p = to_uint(c.position, -r.position, r.position, 16)
    v = to_uint(c.velocity, -r.velocity, r.velocity, 12)
    kp = to_uint(c.kp, 0.0, r.kp, 12)
    kd = to_uint(c.kd, 0.0, r.kd, 12)
    t = to_uint(c.torque, -r.torque, r.torque, 12)
    return bytes(
        [
            p >> 8,
            p & 0xFF,
            v >> 4,
            ((v & 0xF) << 4) | (kp >> 8),
            kp & 0xFF,
            kd >> 4,
            ((kd & 0xF) << 4) | (t >> 8),
            t & 0xFF,
        ]
    )


def unpack_command(data: bytes, r: ActuatorRanges) -> Command:
    """Decode a command frame (what a motor does with what it receives)."""
    if len(data) != 8:
        raise ProtocolError(f"command frame has {len(data)} bytes, expected 8")
    p = (data[0] << 8) | data[1]
    v = (data[2] << 4) | (data[3] >> 4)
    kp = ((data[3] & 0xF) << 8) | data[4]
    kd = (data[5] << 4) | (data[6] >> 4)
    t = ((data[6] & 0xF) << 8) | data[7]
    return Command(
        position=to_float(p, -r.position, r.position, 16),
        velocity=to_float(v, -r.velocity, r.velocity, 12),
        kp=to_float(kp, 0.0, r.kp, 12),
        kd=to_float(kd, 0.0, r.kd, 12),
        torque=to_float(t, -r.torque, r.torque, 12),
    )


def pack_reply(s: Reply, r: ActuatorRanges) -> bytes:
    """The 6 data bytes of a motor's reply."""
    p = to_uint(s.position, -r.position, r.position, 16)
    v = to_uint(s.velocity, -r.velocity, r.velocity, 12)
    t = to_uint(s.torque, -r.torque, r.torque, 12)
    return bytes([s.motor & 0xFF, p >> 8, p & 0xFF, v >> 4, ((v & 0xF) << 4) | (t >> 8), t & 0xFF])


def unpack_reply(data: bytes, r: ActuatorRanges) -> Reply:
    """Decode a reply; a wrong length is a ProtocolError naming what arrived."""
    if len(data) != 6:
        raise ProtocolError(f"reply frame has {len(data)} bytes, expected 6: {data.hex()}")
    p = (data[1] << 8) | data[2]
    v = (data[3] << 4) | (data[4] >> 4)
    t = ((data[4] & 0xF) << 8) | data[5]
    return Reply(
        motor=data[0],
        position=to_float(p, -r.position, r.position, 16),
        velocity=to_float(v, -r.velocity, r.velocity, 12),
        torque=to_float(t, -r.torque, r.torque, 12),
    )
