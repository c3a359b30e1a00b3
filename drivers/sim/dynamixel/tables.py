"""Control tables and physical constants of the emulated servo models (ROBOTIS e-Manual).

These are the device's view (every field the models answer for, defaults, access), kept apart
from the driver's own tables on purpose: the conformance tests check one against the
published documents and the other against the emulator, so neither can quietly copy a
mistake from the other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

RPM = 2.0 * math.pi / 60.0


@dataclass(frozen=True)
class Field:
    """One control-table item: address, size (bytes), default, read-only, EEPROM, signed."""

    address: int
    size: int
    default: int = 0
    read_only: bool = False
    eeprom: bool = False
    signed: bool = False


@dataclass(frozen=True)
class ServoSpec:
    """A servo model: protocol, model number, control table, and its motor's physics (SI)."""

    name: str
    protocol: int
    model_number: int
    firmware: int
    table_size: int
    fields: dict[str, Field]
    rad_per_tick: float
    center_tick: int
    max_tick: int
    velocity_unit: float  # rad/s per unit of present speed/velocity
    effort_unit: float  # N·m per unit of present load/current
    no_load_speed: float  # rad/s at 12 V
    stall_torque: float  # N·m at 12 V


def _ro(address: int, size: int, default: int = 0, signed: bool = False) -> Field:
    return Field(address, size, default, read_only=True, signed=signed)


def _ee(address: int, size: int, default: int = 0, read_only: bool = False) -> Field:
    return Field(address, size, default, read_only=read_only, eeprom=True)


AX_18A = ServoSpec(
    name="AX-18A",
    protocol=1,
    model_number=18,
    firmware=41,
    table_size=50,
    fields={
        "model_number": _ee(0, 2, 18, read_only=True),
        "firmware_version": _ee(2, 1, 41, read_only=True),
        "id": _ee(3, 1, 1),
        "baud_rate": _ee(4, 1, 1),
        "return_delay_time": _ee(5, 1, 250),
        "cw_angle_limit": _ee(6, 2, 0),
        "ccw_angle_limit": _ee(8, 2, 1023),
        "temperature_limit": _ee(11, 1, 75),
        "min_voltage_limit": _ee(12, 1, 60),
        "max_voltage_limit": _ee(13, 1, 140),
        "max_torque": _ee(14, 2, 1023),
        "status_return_level": _ee(16, 1, 2),
        "alarm_led": _ee(17, 1, 36),
        "shutdown": _ee(18, 1, 36),
        "torque_enable": Field(24, 1),
        "led": Field(25, 1),
        "cw_compliance_margin": Field(26, 1, 1),
        "ccw_compliance_margin": Field(27, 1, 1),
        "cw_compliance_slope": Field(28, 1, 32),
        "ccw_compliance_slope": Field(29, 1, 32),
        "goal_position": Field(30, 2, 512),
        "moving_speed": Field(32, 2, 0),
        "torque_limit": Field(34, 2, 1023),
        "present_position": _ro(36, 2, 512),
        "present_speed": _ro(38, 2),
        "present_load": _ro(40, 2),
        "present_voltage": _ro(42, 1, 120),
        "present_temperature": _ro(43, 1, 35),
        "registered": _ro(44, 1),
        "moving": _ro(46, 1),
        "lock": Field(47, 1),
        "punch": Field(48, 2, 32),
    },
    rad_per_tick=math.radians(300.0) / 1023.0,
    center_tick=512,
    max_tick=1023,
    velocity_unit=0.111 * RPM,
    effort_unit=0.001 * 1.8,
    no_load_speed=97.0 * RPM,
    stall_torque=1.8,
)


def _x_series(
    name: str, model_number: int, load_field: str, effort_unit: float, rpm: float, stall: float
) -> ServoSpec:
    """XL430/XM430 share one Protocol 2.0 table; they differ in load vs current at 126."""
    return ServoSpec(
        name=name,
        protocol=2,
        model_number=model_number,
        firmware=46,
        table_size=147,
        fields={
            "model_number": _ee(0, 2, model_number, read_only=True),
            "model_information": _ee(2, 4, 0, read_only=True),
            "firmware_version": _ee(6, 1, 46, read_only=True),
            "id": _ee(7, 1, 1),
            "baud_rate": _ee(8, 1, 1),
            "return_delay_time": _ee(9, 1, 250),
            "drive_mode": _ee(10, 1, 0),
            "operating_mode": _ee(11, 1, 3),
            "secondary_id": _ee(12, 1, 255),
            "protocol_type": _ee(13, 1, 2),
            "homing_offset": _ee(20, 4, 0),
            "moving_threshold": _ee(24, 4, 10),
            "temperature_limit": _ee(31, 1, 72 if name.startswith("XL") else 80),
            "max_voltage_limit": _ee(32, 2, 140),
            "min_voltage_limit": _ee(34, 2, 60),
            "pwm_limit": _ee(36, 2, 885),
            "velocity_limit": _ee(44, 4, round(rpm / 0.229)),
            "max_position_limit": _ee(48, 4, 4095),
            "min_position_limit": _ee(52, 4, 0),
            "shutdown": _ee(63, 1, 52),
            "torque_enable": Field(64, 1),
            "led": Field(65, 1),
            "status_return_level": Field(68, 1, 2),
            "registered_instruction": _ro(69, 1),
            "hardware_error_status": _ro(70, 1),
            "velocity_i_gain": Field(76, 2, 1000),
            "velocity_p_gain": Field(78, 2, 100),
            "position_d_gain": Field(80, 2, 0),
            "position_i_gain": Field(82, 2, 0),
            "position_p_gain": Field(84, 2, 640),
            "bus_watchdog": Field(98, 1),
            "goal_pwm": Field(100, 2, 885),
            "goal_velocity": Field(104, 4, signed=True),
            "profile_acceleration": Field(108, 4),
            "profile_velocity": Field(112, 4),
            "goal_position": Field(116, 4, 2048, signed=True),
            "realtime_tick": _ro(120, 2),
            "moving": _ro(122, 1),
            "moving_status": _ro(123, 1),
            "present_pwm": _ro(124, 2, signed=True),
            load_field: _ro(126, 2, signed=True),
            "present_velocity": _ro(128, 4, signed=True),
            "present_position": _ro(132, 4, 2048, signed=True),
            "velocity_trajectory": _ro(136, 4, signed=True),
            "position_trajectory": _ro(140, 4, 2048, signed=True),
            "present_input_voltage": _ro(144, 2, 120),
            "present_temperature": _ro(146, 1, 35),
        },
        rad_per_tick=2.0 * math.pi / 4096.0,
        center_tick=2048,
        max_tick=4095,
        velocity_unit=0.229 * RPM,
        effort_unit=effort_unit,
        no_load_speed=rpm * RPM,
        stall_torque=stall,
    )


XL430_W250 = _x_series("XL430-W250", 1060, "present_load", 0.001 * 1.5, 57.0, 1.5)
XM430_W350 = _x_series("XM430-W350", 1020, "present_current", 0.00269 * 4.1 / 2.3, 46.0, 4.1)
XM430_W210 = _x_series("XM430-W210", 1030, "present_current", 0.00269 * 3.0 / 2.3, 77.0, 3.0)

SPECS: dict[str, ServoSpec] = {s.name: s for s in (AX_18A, XL430_W250, XM430_W350, XM430_W210)}


def spec(model: str) -> ServoSpec:
    """The emulated model named ``model`` (e.g. "AX-18A"); ValueError lists the known ones."""
    try:
        return SPECS[model]
    except KeyError:
        raise ValueError(
            f"no emulated Dynamixel model {model!r}; known: {', '.join(SPECS)}"
        ) from None
