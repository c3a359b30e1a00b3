"""The MIT-mode actuator protocol on CAN: packed 8-byte commands and 6-byte replies.

The de-facto protocol of torque-controlled legged-robot actuators (mini-cheetah firmware
and its descendants). A command to motor ``id`` (standard 11-bit id) carries
position (16 bits), velocity, kp, kd and feed-forward torque (12 bits each), each mapped
linearly onto its configured range; the motor applies
``tau = kp (p_des - p) + kd (v_des - v) + tau_ff`` and answers to the master id with
``[id, position 16, velocity 12, torque 12]``. Three special frames switch modes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from daemon.profile import MIT_FRAME_BYTES, ActuatorRanges

ENTER_MOTOR_MODE = bytes([0xFF] * 7 + [0xFC])
EXIT_MOTOR_MODE = bytes([0xFF] * 7 + [0xFD])
SET_ZERO = bytes([0xFF] * 7 + [0xFE])
COMMAND_BYTES, REPLY_BYTES = MIT_FRAME_BYTES
CAN_ERR_BUSOFF = 0x40
"""Error-frame class bit of Linux SocketCAN for bus-off (linux/can/error.h)."""


class ProtocolError(ValueError):
    """A frame that does not decode: wrong length or a value outside the actuator's range."""


def to_uint(x: ArrayLike, lo: ArrayLike, hi: ArrayLike, bits: ArrayLike) -> np.ndarray | int:
    """Map ``x`` in [lo, hi] onto unsigned ``bits`` integers, saturating outside: an int for a
    float (a motor's one frame, where numpy's call costs more than the arithmetic), else an
    array (``lo``, ``hi`` and ``bits`` broadcast against ``x``)."""
    if isinstance(x, float):
        return int((min(max(x, lo), hi) - lo) * ((1 << bits) - 1) / (hi - lo))
    full = np.left_shift(1, bits) - 1
    return ((np.clip(x, lo, hi) - lo) * full / (np.subtract(hi, lo))).astype(np.int64)


def to_float(u: ArrayLike, lo: float, hi: float, bits: int) -> np.ndarray | float:
    """Inverse of ``to_uint`` (an int gives a float, an array an array)."""
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
COMMAND_BITS = np.array([[16], [12], [12], [12], [12]])
"""Width of each command field on the wire, in ``COMMAND_FIELDS`` order."""


def pack_commands(
    position: ArrayLike,
    velocity: ArrayLike,
    kp: ArrayLike,
    kd: ArrayLike,
    torque: ArrayLike,
    r: ActuatorRanges,
    labels: Sequence[str] = (),
) -> list[bytes]:
    """The 8 data bytes of each motor's command, one value per motor in every argument, all
    packed at once; out-of-range values saturate as the firmware does, non-finite ones raise,
    naming the motor by ``labels`` or index (a NaN would cast to a full-scale command)."""
    values = np.array([position, velocity, kp, kd, torque], float)
    bad = np.argwhere(~np.isfinite(values))
    if len(bad):
        field, i = bad[0]
        motor = labels[i] if labels else f"motor index {i}"
        raise ProtocolError(f"command {COMMAND_FIELDS[field]} of {motor} is not finite")
    lo = np.array([[-r.position], [-r.velocity], [0.0], [0.0], [-r.torque]])
    hi = np.array([[r.position], [r.velocity], [r.kp], [r.kd], [r.torque]])
    p, v, kp_, kd_, t = to_uint(values, lo, hi, COMMAND_BITS)
    frames = np.stack(
        [p >> 8, p, v >> 4, (v << 4) | (kp_ >> 8), kp_, kd_ >> 4, (kd_ << 4) | (t >> 8), t], 1
    ).astype(np.uint8)  # the cast keeps each byte's low 8 bits
    raw = frames.tobytes()
    return [raw[i : i + COMMAND_BYTES] for i in range(0, len(raw), COMMAND_BYTES)]


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


def unpack_replies(data: bytes, r: ActuatorRanges) -> tuple[np.ndarray, ...]:
    """Decode replies laid end to end at once: motor ids, positions (rad), velocities (rad/s)
    and torques (N·m); a buffer that does not split into replies is a ProtocolError."""
    if len(data) % REPLY_BYTES:
        check_reply(data)  # not a whole number of replies, so not one either: name what arrived
    b = np.frombuffer(data, np.uint8).reshape(-1, REPLY_BYTES).astype(np.int64)
    p = (b[:, 1] << 8) | b[:, 2]
    v = (b[:, 3] << 4) | (b[:, 4] >> 4)
    t = ((b[:, 4] & 0xF) << 8) | b[:, 5]
    return (
        b[:, 0],
        to_float(p, -r.position, r.position, 16),
        to_float(v, -r.velocity, r.velocity, 12),
        to_float(t, -r.torque, r.torque, 12),
    )
