"""The torque driver's keys of the profile's ``[bus]`` table, and the CAN bus-load check."""

from __future__ import annotations

import msgspec

from climbd.daemon.contract.profile import DriverConfig, Profile, ProfileError

MIT_FRAME_BYTES = (8, 6)
"""Data bytes of an MIT-mode command and of the motor's reply: one of each per motor a tick."""


class ActuatorRanges(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Ranges of an MIT-mode actuator's packed fields (SI, at the output shaft).

    The firmware maps each range onto 16 bits (position) or 12 bits (the others); they must
    match the actuator's firmware. Defaults are the common mini-cheetah/AK-series values.
    """

    position: float = 12.5
    velocity: float = 45.0
    kp: float = 500.0
    kd: float = 5.0
    torque: float = 18.0


def can_frame_bits(data_bytes: int) -> int:
    """Bits a classic CAN data frame (11-bit id) holds the bus for: the 34 + 8n bits from start
    of frame to the CRC at worst-case stuffing (a stuff bit after every 4 past the first), then
    CRC delimiter, ACK, end of frame and the 3-bit interframe space (13)."""
    stuffed = 34 + 8 * data_bytes
    return stuffed + (stuffed - 1) // 4 + 13


def can_tick_time(motors: int, baud: int) -> float:
    """Seconds of bus time ``motors`` MIT motors take a tick on one channel at ``baud`` bit/s."""
    return motors * sum(can_frame_bits(n) for n in MIT_FRAME_BYTES) / baud


class TorqueConfig(DriverConfig, forbid_unknown_fields=True, kw_only=True):
    """Torque legs (``kind = "torque"``): MIT-mode actuators on one or more CAN buses.

    ``can_channels`` spreads the legs over several CAN buses (leg i on channel i mod n; empty:
    all on ``can_channel``), each of which must carry its motors' command and reply every tick
    at ``baud`` (the CAN bit rate, bit/s). ``actuator`` holds the ranges of the packed fields;
    ``kp`` (N·m/rad) and ``kd`` (N·m·s/rad) are the position gains of commands without gains.
    ``reply_timeout`` (s) is how long a read waits for motors yet to answer the last write: 0
    takes the replies that have arrived and leaves those still on the wire to the next read, so
    a tick never waits out a channel's bus time (three motors hold a 1 Mbit/s channel 0.75 ms
    after each write). ``model`` names the actuator protocol ("mit").
    """

    model: str = "mit"
    can_interface: str = "socketcan"
    can_channel: str = "can0"
    can_channels: list[str] = []
    baud: int = 1_000_000
    master_id: int = 0
    reply_timeout: float = 0.0
    actuator: ActuatorRanges = msgspec.field(default_factory=ActuatorRanges)
    kp: float = 60.0
    kd: float = 1.5

    @property
    def channels(self) -> list[str]:
        """The CAN channels the legs are spread over (leg i on channel i mod n)."""
        return self.can_channels or [self.can_channel]

    def validate(self, profile: Profile) -> None:
        """Every CAN channel carries its motors' commands and replies within one control period:
        18 motors on one 1 Mbit/s bus take 4.5 ms a tick, which no 1 kHz loop can run on."""
        src = profile.source or profile.name
        if self.baud <= 0:
            raise ProfileError(f"{src}: $.bus.baud: expected > 0 bit/s, found {self.baud}")
        channels = self.channels
        per_leg = [len(leg.joints) for leg in profile.legs]
        motors = {c: sum(per_leg[i :: len(channels)]) for i, c in enumerate(channels)}
        busiest = max(motors, key=motors.get)
        need = can_tick_time(motors[busiest], self.baud)
        period = 1.0 / profile.rate_hz
        if need <= period:
            return
        fits = [
            n
            for n in range(1, len(per_leg) + 1)
            if can_tick_time(max(sum(per_leg[i::n]) for i in range(n)), self.baud) <= period
        ]
        advice = (
            f"spread the legs over {fits[0]} channels or more (leg i on channel i mod n)"
            if fits
            else "one leg a channel does not fit either: lower rate_hz or raise baud"
        )
        raise ProfileError(
            f"{src}: $.bus.can_channels: "
            f"{motors[busiest]} motors on {busiest} need {need * 1e3:.2f} ms of bus time a tick "
            f"(an {MIT_FRAME_BYTES[0]}-byte command and a {MIT_FRAME_BYTES[1]}-byte reply each at "
            f"{self.baud} bit/s), more than the {period * 1e3:g} ms period at "
            f"{profile.rate_hz:g} Hz: {advice}"
        )
