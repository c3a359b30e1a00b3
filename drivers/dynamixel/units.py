"""Raw Dynamixel units ↔ SI joint units, vectorised over the joints of a bus.

A joint's position is its servo horn angle about the centre tick (rad), the joint convention
of every driver (daemon/contract/profile.py ``Joint``): zero offsets and directions belong to the
leg's kinematics, not to the bus. This module is the only place where device units exist.
"""

from __future__ import annotations

import numpy as np

from climbd.daemon.contract.profile import Joint
from climbd.drivers.dynamixel.models import Model


class TickScale:
    """Tick ↔ radian conversions of one bus, with the model's unit scales."""

    def __init__(self, model: Model, joints: list[Joint]) -> None:
        self.model = model
        self.n = len(joints)

    def goal_ticks(self, q: np.ndarray) -> np.ndarray:
        """Goal position ticks for joint angles ``q`` (rad), clipped to the servo's range."""
        m = self.model
        ticks = np.rint(m.center_tick + np.asarray(q) / m.rad_per_tick)
        return np.clip(ticks, 0, m.max_tick).astype(np.int64)

    def position(self, ticks: np.ndarray) -> np.ndarray:
        """Joint angles (rad) from present position ticks."""
        m = self.model
        return (np.asarray(ticks) - m.center_tick) * m.rad_per_tick

    def speed_ticks(self, speed: np.ndarray) -> np.ndarray:
        """Moving speed / profile velocity units for speed caps (rad/s); at least 1 (0 = none)."""
        return np.maximum(1, np.rint(np.abs(speed) / self.model.velocity_unit)).astype(np.int64)

    def velocity(self, raw: np.ndarray) -> np.ndarray:
        """Joint velocities (rad/s) from present speed/velocity fields."""
        return _signed(self.model, raw, 4) * self.model.velocity_unit

    def effort(self, raw: np.ndarray) -> np.ndarray:
        """Joint efforts (N·m) from present load/current fields."""
        return _signed(self.model, raw, 2) * self.model.effort_unit


def _signed(model: Model, raw: np.ndarray, size: int) -> np.ndarray:
    """Decode sign-magnitude (1.0: bit 10 = clockwise) or two's complement of ``size`` bytes."""
    raw = np.asarray(raw, np.int64)
    if model.sign_magnitude:
        return np.where(raw & 1024, -(raw & 1023), raw & 1023)
    half = 1 << (8 * size - 1)
    return np.where(raw >= half, raw - 2 * half, raw)


def little_endian(blocks: np.ndarray, offset: int, size: int) -> np.ndarray:
    """Unsigned little-endian integers of ``size`` bytes at ``offset`` in each row of ``blocks``."""
    field = np.ascontiguousarray(blocks[:, offset : offset + size])
    return field.view(_UNSIGNED[size])[:, 0].astype(np.int64)


def little_endian_bytes(values: np.ndarray, size: int) -> bytes:
    """``values`` as unsigned little-endian fields of ``size`` bytes, one after another (the
    parameters of a sync write)."""
    return np.asarray(values).astype(_UNSIGNED[size]).tobytes()


_UNSIGNED = {1: np.dtype("u1"), 2: np.dtype("<u2"), 4: np.dtype("<u4")}
