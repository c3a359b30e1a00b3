"""The Dynamixel driver's keys of the profile's ``[bus]`` table."""

from __future__ import annotations

from typing import Literal

from climbd.daemon.contract.profile import DriverConfig


class DynamixelConfig(DriverConfig, forbid_unknown_fields=True, kw_only=True):
    """One Dynamixel bus: serial ``port``, ``baud`` (bit/s), ``protocol`` (1.0 or 2.0), the
    servos' ``model`` (drivers/dynamixel/models.py), their return delay (µs, set at open) and
    the USB-serial adapter's latency timer (ms)."""

    port: str = "/dev/ttyUSB0"
    baud: int = 1_000_000
    protocol: Literal[1, 2] = 1
    model: str = "AX-18A"
    return_delay_us: int = 0
    latency_timer_ms: int = 1
