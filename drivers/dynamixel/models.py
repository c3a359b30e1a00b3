"""Control tables of the supported Dynamixel models, as data (ROBOTIS e-Manual).

Only what the driver touches: the per-cycle block (position, speed, load), the health block
(plus voltage and temperature), configuration items, units and error-bit names. AX-18A speaks
Protocol 1.0; the X series (XL430/XM430) Protocol 2.0 with one table layout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

RPM = 2.0 * math.pi / 60.0


@dataclass(frozen=True)
class Item:
    """A control-table item: address and size in bytes."""

    address: int
    size: int


@dataclass(frozen=True)
class Model:
    """One servo model: protocol, model number, items, block layout and SI units.

    ``state`` is read every cycle (``state_length`` bytes) and on health cycles the longer
    ``health_length`` from the same start; offsets are relative to ``state.address``.
    ``speed_goal`` is the contiguous span holding the speed cap and the goal position.
    """

    name: str
    protocol: int
    model_number: int
    torque_enable: Item
    goal_position: Item
    speed_limit: Item
    return_delay_time: Item
    status_return_level: Item
    firmware_version: Item
    hardware_error_status: Item | None
    state: Item
    health_length: int
    position_offset: int
    velocity_offset: int
    load_offset: int
    voltage: Item
    temperature: Item
    rad_per_tick: float
    center_tick: int
    max_tick: int
    velocity_unit: float  # rad/s per unit
    effort_unit: float  # N·m per unit of load/current
    sign_magnitude: bool  # 1.0 speed/load: bit 10 = clockwise; 2.0: two's complement
    error_names: dict[int, str]
    fast_sync_read_firmware: int | None = None

    @property
    def health(self) -> Item:
        return Item(self.state.address, self.health_length)


# Protocol 1.0 status error bits; Protocol 2.0 Hardware Error Status bits (address 70).
P1_ERRORS = {
    0x01: "voltage",
    0x02: "angle",
    0x04: "overheat",
    0x08: "range",
    0x10: "checksum",
    0x20: "overload",
    0x40: "instruction",
}
X_HARDWARE_ERRORS = {
    0x01: "voltage",
    0x04: "overheat",
    0x08: "encoder",
    0x10: "electrical_shock",
    0x20: "overload",
}

AX_18A = Model(
    name="AX-18A",
    protocol=1,
    model_number=18,
    torque_enable=Item(24, 1),
    goal_position=Item(30, 2),
    speed_limit=Item(32, 2),
    return_delay_time=Item(5, 1),
    status_return_level=Item(16, 1),
    firmware_version=Item(2, 1),
    hardware_error_status=None,
    state=Item(36, 6),
    health_length=8,
    position_offset=0,
    velocity_offset=2,
    load_offset=4,
    voltage=Item(42, 1),
    temperature=Item(43, 1),
    rad_per_tick=math.radians(300.0) / 1023.0,
    center_tick=512,
    max_tick=1023,
    velocity_unit=0.111 * RPM,
    effort_unit=0.001 * 1.8,
    sign_magnitude=True,
    error_names=P1_ERRORS,
)


def _x_series(name: str, model_number: int, effort_unit: float) -> Model:
    """XL430/XM430 (Protocol 2.0): load (XL) or current (XM) at 126, velocity, position."""
    return Model(
        name=name,
        protocol=2,
        model_number=model_number,
        torque_enable=Item(64, 1),
        goal_position=Item(116, 4),
        speed_limit=Item(112, 4),
        return_delay_time=Item(9, 1),
        status_return_level=Item(68, 1),
        firmware_version=Item(6, 1),
        hardware_error_status=Item(70, 1),
        state=Item(126, 10),
        health_length=21,
        position_offset=6,
        velocity_offset=2,
        load_offset=0,
        voltage=Item(144, 2),
        temperature=Item(146, 1),
        rad_per_tick=2.0 * math.pi / 4096.0,
        center_tick=2048,
        max_tick=4095,
        velocity_unit=0.229 * RPM,
        effort_unit=effort_unit,
        sign_magnitude=False,
        error_names=X_HARDWARE_ERRORS,
        fast_sync_read_firmware=45,
    )


XL430_W250 = _x_series("XL430-W250", 1060, 0.001 * 1.5)
# XM430: present current 2.69 mA/unit × torque constant (stall torque / stall current at 12 V).
XM430_W350 = _x_series("XM430-W350", 1020, 0.00269 * 4.1 / 2.3)
XM430_W210 = _x_series("XM430-W210", 1030, 0.00269 * 3.0 / 2.3)

MODELS: dict[str, Model] = {m.name: m for m in (AX_18A, XL430_W250, XM430_W350, XM430_W210)}
MODEL_NAMES: dict[int, str] = {m.model_number: m.name for m in MODELS.values()}


def model(name: str) -> Model:
    """The model called ``name`` (profile ``bus.model``); KeyError lists the supported ones."""
    try:
        return MODELS[name]
    except KeyError:
        raise KeyError(
            f"unsupported Dynamixel model {name!r}; supported: {', '.join(MODELS)}"
        ) from None


def error_names(m: Model, bits: int) -> list[str]:
    """Names of the set bits of a status error byte (1.0) or hardware error status (2.0)."""
    return [n for bit, n in m.error_names.items() if bits & bit]
