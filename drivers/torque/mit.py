"""The MIT-mode actuator protocol on CAN: packed 8-byte commands and 6-byte replies.

The de-facto protocol of torque-controlled legged-robot actuators (mini-cheetah firmware
and its descendants). A command to motor ``id`` (standard 11-bit id) carries
position (16 bits), velocity, kp, kd and feed-forward torque (12 bits each), each mapped
linearly onto its configured range; the motor applies
``tau = kp (p_des - p) + kd (v_des - v) + tau_ff`` and answers to the master id with
``[id, position 16, velocity 12, torque 12]``. Three special frames switch modes.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from math import isfinite

import numpy as np

from climbd.drivers.torque.config import MIT_FRAME_BYTES, ActuatorRanges

ENTER_MOTOR_MODE = bytes([0xFF] * 7 + [0xFC])
EXIT_MOTOR_MODE = bytes([0xFF] * 7 + [0xFD])
SET_ZERO = bytes([0xFF] * 7 + [0xFE])
COMMAND_BYTES, REPLY_BYTES = MIT_FRAME_BYTES
CAN_ERR_BUSOFF = 0x40
"""Error-frame class bit of Linux SocketCAN for bus-off (linux/can/error.h)."""


class ProtocolError(ValueError):
    """A frame that does not decode: wrong length or a value outside the actuator's range."""


def to_uint(x: float, lo: float, hi: float, bits: int) -> int:
    """Map ``x`` in [lo, hi] onto an unsigned ``bits`` integer, saturating outside."""
    return int((min(max(x, lo), hi) - lo) * ((1 << bits) - 1) / (hi - lo))


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


COMMAND_FIELDS = ("position", "velocity", "kp", "kd", "torque")
REPLY = struct.Struct(">BHBBB")
"""A reply: id, position (16 bits), then velocity and torque (12 bits each) in three bytes."""


def pack_commands(
    position: Sequence[float],
    velocity: Sequence[float],
    kp: Sequence[float],
    kd: Sequence[float],
    torque: Sequence[float],
    r: ActuatorRanges,
    labels: Sequence[str] = (),
) -> list[bytes]:
    """The 8 data bytes of each motor's command, one value per motor in every argument;
    out-of-range values saturate as the firmware does, non-finite ones raise, naming the
    motor by ``labels`` or index (a NaN would cast to a full-scale command). Per motor in
    floats: for a robot's 18 joints numpy's per-call cost is more than the arithmetic."""
    fields = [
        f.tolist() if isinstance(f, np.ndarray) else f for f in (position, velocity, kp, kd, torque)
    ]
    pl, ph, vl, vh, tl, th = -r.position, r.position, -r.velocity, r.velocity, -r.torque, r.torque
    kph, kdh = r.kp, r.kd
    frames = []
    for a, b, c, d, e in zip(*fields, strict=True):
        if not (isfinite(a) and isfinite(b) and isfinite(c) and isfinite(d) and isfinite(e)):
            raise non_finite(fields, labels)
        p = int((min(max(a, pl), ph) - pl) * 65535 / (ph - pl))
        v = int((min(max(b, vl), vh) - vl) * 4095 / (vh - vl))
        k = int(min(max(c, 0.0), kph) * 4095 / kph)
        g = int(min(max(d, 0.0), kdh) * 4095 / kdh)
        t = int((min(max(e, tl), th) - tl) * 4095 / (th - tl))
        frames.append(
            bytes(
                (
                    p >> 8,
                    p & 0xFF,
                    v >> 4,
                    (v & 0xF) << 4 | k >> 8,
                    k & 0xFF,
                    g >> 4,
                    (g & 0xF) << 4 | t >> 8,
                    t & 0xFF,
                )
            )
        )
    return frames


def non_finite(fields: Sequence[Sequence[float]], labels: Sequence[str]) -> ProtocolError | None:
    """The error naming the first non-finite value, field by field in ``COMMAND_FIELDS``
    order (an empty field is skipped), or None if all are finite."""
    for name, values in zip(COMMAND_FIELDS, fields, strict=True):
        for i, x in enumerate(values):
            if not isfinite(x):
                motor = labels[i] if labels else f"motor index {i}"
                return ProtocolError(f"command {name} of {motor} is not finite")
    return None


def unpack_command(data: bytes, r: ActuatorRanges) -> Command:
    """Decode a command frame (what a motor does with what it receives)."""
    if len(data) != COMMAND_BYTES:
        raise ProtocolError(f"command frame has {len(data)} bytes, expected {COMMAND_BYTES}")
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


def check_reply(data: bytes) -> None:
    """A ProtocolError naming what arrived unless ``data`` is one reply's length."""
    if len(data) != REPLY_BYTES:
        raise ProtocolError(
            f"reply frame has {len(data)} bytes, expected {REPLY_BYTES}: {data.hex()}"
        )


def unpack_replies(
    data: bytes, r: ActuatorRanges
) -> tuple[list[int], list[float], list[float], list[float]]:
    """Decode replies laid end to end: motor ids, positions (rad), velocities (rad/s) and
    torques (N·m); a buffer that does not split into replies is a ProtocolError."""
    if len(data) % REPLY_BYTES:
        check_reply(data)  # not a whole number of replies, so not one either: name what arrived
    pl, pspan, vl, vspan, tl, tspan = (
        -r.position,
        2 * r.position,
        -r.velocity,
        2 * r.velocity,
        -r.torque,
        2 * r.torque,
    )
    motors, position, velocity, torque = [], [], [], []
    for m, p, b3, b4, b5 in REPLY.iter_unpack(data):
        motors.append(m)
        position.append(p * pspan / 65535 + pl)
        velocity.append((b3 << 4 | b4 >> 4) * vspan / 4095 + vl)
        torque.append(((b4 & 0xF) << 8 | b5) * tspan / 4095 + tl)
    return motors, position, velocity, torque
