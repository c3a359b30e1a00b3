"""One emulated Dynamixel: its control-table memory, error state and a first-order motor model.

Angles are about the servo's centre tick (rad, counter-clockwise positive), velocities rad/s,
effort N·m. Until something external drives it (``external = True`` and ``set_present``),
``step(dt)`` moves the horn toward the goal with a first-order lag ``tau``, limited by the
configured speed (moving speed / profile velocity, else the no-load speed) and by the torque limit.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

from climbd.drivers.sim.dynamixel.tables import Field, ServoSpec

# Protocol 1.0 status error bits and Protocol 2.0 hardware error status bits (e-Manual).
P1_VOLTAGE, P1_ANGLE, P1_OVERHEAT, P1_RANGE = 0x01, 0x02, 0x04, 0x08
P1_CHECKSUM, P1_OVERLOAD, P1_INSTRUCTION = 0x10, 0x20, 0x40
HW_VOLTAGE, HW_OVERHEAT, HW_ENCODER, HW_SHOCK, HW_OVERLOAD = 0x01, 0x04, 0x08, 0x10, 0x20
# Protocol 2.0 status error numbers and the alert bit.
P2_RESULT_FAIL, P2_INSTRUCTION, P2_CRC, P2_DATA_RANGE = 1, 2, 3, 4
P2_DATA_LENGTH, P2_DATA_LIMIT, P2_ACCESS, P2_ALERT = 5, 6, 7, 0x80


@dataclass
class MotorState:
    """Horn state in SI units plus the conditions a physics model or a test sets."""

    angle: float = 0.0
    velocity: float = 0.0
    effort: float = 0.0
    temperature: float = 35.0
    voltage: float = 12.0
    overload: bool = False


class EmulatedServo:
    """A servo of model ``spec`` with id ``ident``; thread-safe through the chain's ``lock``."""

    def __init__(
        self,
        spec: ServoSpec,
        ident: int,
        *,
        angle: float = 0.0,
        tau: float = 0.02,
        lock: threading.RLock | None = None,
    ) -> None:
        self.spec = spec
        self.lock = lock or threading.RLock()
        self.tau = tau
        self.external = False
        self.pending: tuple[int, bytes] | None = None
        self.goals = 0
        """Goal positions received (written and accepted) since power-up."""
        self.t: float | None = None
        self.state = MotorState(angle=angle)
        self.memory = bytearray(spec.table_size)
        self._touched_cache: dict[tuple[int, int], tuple[Field, ...]] = {}
        for f in spec.fields.values():
            self._put(f, f.default)
        self._put(spec.fields["id"], ident)
        self._put(spec.fields["goal_position"], self.tick(angle))
        self._sync_present()

    # --- raw control table ------------------------------------------------------------

    @property
    def ident(self) -> int:
        return self.get("id")

    def _put(self, f: Field, value: int) -> None:
        self.memory[f.address : f.address + f.size] = (value & ((1 << 8 * f.size) - 1)).to_bytes(
            f.size, "little"
        )

    def _take(self, f: Field) -> int:
        raw = int.from_bytes(self.memory[f.address : f.address + f.size], "little")
        if f.signed and raw >= 1 << (8 * f.size - 1):
            raw -= 1 << (8 * f.size)
        return raw

    def get(self, name: str) -> int:
        """Raw value of control-table field ``name``."""
        with self.lock:
            return self._take(self.spec.fields[name])

    def set(self, name: str, value: int) -> None:
        """Set a raw field directly (test and twin set-up; no access checks)."""
        with self.lock:
            self._put(self.spec.fields[name], value)

    def read_bytes(self, address: int, length: int) -> bytes | None:
        """Bytes at ``address``; None if the range leaves the table."""
        if address < 0 or length < 0 or address + length > self.spec.table_size:
            return None
        with self.lock:
            return bytes(self.memory[address : address + length])

    def write_bytes(self, address: int, data: bytes) -> int:
        """Apply an instruction's write; returns the error (1.0: bits, 2.0: number), 0 if none."""
        p1 = self.spec.protocol == 1
        if address < 0 or address + len(data) > self.spec.table_size:
            return P1_RANGE if p1 else P2_ACCESS
        end = address + len(data)
        with self.lock:
            touched = self._touched(address, end)
            if any(f.read_only for f in touched):
                return P1_RANGE if p1 else P2_ACCESS
            if (
                not p1
                and self._take(self.spec.fields["torque_enable"])
                and any(f.eeprom for f in touched)
            ):
                return P2_ACCESS
            before = bytes(self.memory)
            self.memory[address:end] = data
            goal = self.spec.fields["goal_position"] in touched
            error = self._check_goal() if goal else 0
            if error:
                self.memory[:] = before
            elif goal:
                self.goals += 1
            return error

    def _touched(self, address: int, end: int) -> tuple[Field, ...]:
        """Fields overlapping ``[address, end)``; remembered, a servo is written the same way
        every cycle."""
        key = (address, end)
        touched = self._touched_cache.get(key)
        if touched is None:
            touched = tuple(
                f
                for f in self.spec.fields.values()
                if f.address < end and address < f.address + f.size
            )
            self._touched_cache[key] = touched
        return touched

    def _check_goal(self) -> int:
        f = self.spec.fields
        goal = self._take(f["goal_position"])
        if self.spec.protocol == 1:
            lo, hi = self._take(f["cw_angle_limit"]), self._take(f["ccw_angle_limit"])
            return P1_ANGLE if not lo <= goal <= hi else 0
        lo, hi = self._take(f["min_position_limit"]), self._take(f["max_position_limit"])
        return P2_DATA_LIMIT if not lo <= goal <= hi else 0

    # --- SI view ----------------------------------------------------------------------

    def tick(self, angle: float) -> int:
        """Position tick of a horn angle (rad about the centre), clipped to the tick range."""
        s = self.spec
        return min(max(round(s.center_tick + angle / s.rad_per_tick), 0), s.max_tick)

    @property
    def goal_angle(self) -> float:
        """Goal position (rad about the centre) as last written by the host."""
        s = self.spec
        return (self.get("goal_position") - s.center_tick) * s.rad_per_tick

    @property
    def torque_enabled(self) -> bool:
        return bool(self.get("torque_enable"))

    @property
    def speed_limit(self) -> float:
        """Speed cap (rad/s) from moving speed (1.0) or profile velocity (2.0); 0 means none."""
        s = self.spec
        raw = self.get("moving_speed" if s.protocol == 1 else "profile_velocity")
        if s.protocol == 2 and raw == 0:
            raw = self.get("velocity_limit")
        return min(raw * s.velocity_unit, s.no_load_speed) if raw else s.no_load_speed

    def set_present(
        self,
        angle: float | None = None,
        velocity: float | None = None,
        effort: float | None = None,
        temperature: float | None = None,
        voltage: float | None = None,
    ) -> None:
        """Set measured quantities (SI) from an external model or a test; refreshes the table."""
        with self.lock:
            st = self.state
            for name, value in (
                ("angle", angle),
                ("velocity", velocity),
                ("effort", effort),
                ("temperature", temperature),
                ("voltage", voltage),
            ):
                if value is not None:
                    setattr(st, name, float(value))
            self._sync_present()

    def inject_overload(self, on: bool = True) -> None:
        """Raise (or clear) the overload condition, as a stalled horn would."""
        with self.lock:
            self.state.overload = on
            self._sync_present()

    def reboot(self) -> None:
        """Protocol 2.0 REBOOT: the RAM area back to its power-on values (torque off, latched
        hardware errors cleared, goal = present position, nothing registered); EEPROM kept.

        A condition still present (a stalled horn, a hot motor) latches again at once."""
        with self.lock:
            for f in self.spec.fields.values():
                if not f.eeprom:
                    self._put(f, f.default)
            self._put(self.spec.fields["goal_position"], self.tick(self.state.angle))
            self.pending = None
            self._sync_present()

    # --- motor model ------------------------------------------------------------------

    def advance_to(self, t: float) -> None:
        """Step the motor model from the last call's time to ``t`` (s, any monotonic clock)."""
        last, self.t = self.t, t
        if last is not None:
            self.step(t - last)

    def step(self, dt: float) -> None:
        """Advance the built-in motor model by ``dt`` seconds (no-op when driven externally)."""
        if dt <= 0 or self.external:
            return
        with self.lock:
            st = self.state
            if not self.torque_enabled:
                st.velocity = st.effort = 0.0
                self._sync_present()
                return
            goal, vmax = self.goal_angle, self.speed_limit
            f = self.spec.fields
            limit = f["torque_limit" if self.spec.protocol == 1 else "pwm_limit"]
            torque_max = self.spec.stall_torque * self._take(limit) / limit.default
            n = max(1, math.ceil(dt / 1e-3))
            h = dt / n
            for _ in range(n):
                v = min(max((goal - st.angle) / self.tau, -vmax), vmax)
                st.angle += v * h
                st.velocity = v
            st.effort = min(max(torque_max * (goal - st.angle) / 0.1, -torque_max), torque_max)
            self._sync_present()

    # --- error state ------------------------------------------------------------------

    def _conditions(self) -> int:
        """Live fault conditions as Protocol 2.0 hardware error bits."""
        st, f = self.state, self.spec.fields
        bits = 0
        lo = self._take(f["min_voltage_limit"]) / 10.0
        hi = self._take(f["max_voltage_limit"]) / 10.0
        if not lo <= st.voltage <= hi:
            bits |= HW_VOLTAGE
        if st.temperature > self._take(f["temperature_limit"]):
            bits |= HW_OVERHEAT
        if st.overload:
            bits |= HW_OVERLOAD
        return bits

    def status_error(self, instruction_error: int = 0) -> int:
        """Error byte of a status packet: live bits (1.0) or alert + error number (2.0)."""
        with self.lock:
            if self.spec.protocol == 2:
                alert = P2_ALERT if self._take(self.spec.fields["hardware_error_status"]) else 0
                return alert | instruction_error
            c = self._conditions()
            bits = instruction_error
            bits |= P1_VOLTAGE if c & HW_VOLTAGE else 0
            bits |= P1_OVERHEAT if c & HW_OVERHEAT else 0
            bits |= P1_OVERLOAD if c & HW_OVERLOAD else 0
            return bits

    def _sync_present(self) -> None:
        """Write the motor state into the present-value fields; apply shutdown on faults."""
        s, st, f = self.spec, self.state, self.spec.fields
        conditions = self._conditions()
        if s.protocol == 1:
            p1 = (
                (P1_VOLTAGE if conditions & HW_VOLTAGE else 0)
                | (P1_OVERHEAT if conditions & HW_OVERHEAT else 0)
                | (P1_OVERLOAD if conditions & HW_OVERLOAD else 0)
            )
            if p1 & self._take(f["shutdown"]):
                self._put(f["torque_enable"], 0)
            self._put(f["present_speed"], _sign_magnitude(st.velocity / s.velocity_unit))
            self._put(f["present_load"], _sign_magnitude(st.effort / s.effort_unit))
            self._put(f["present_voltage"], round(st.voltage * 10))
        else:
            latched = self._take(f["hardware_error_status"]) | conditions
            self._put(f["hardware_error_status"], latched)
            if latched & self._take(f["shutdown"]):
                self._put(f["torque_enable"], 0)
            load = "present_load" if "present_load" in f else "present_current"
            self._put(f[load], round(st.effort / s.effort_unit))
            self._put(f["present_velocity"], round(st.velocity / s.velocity_unit))
            self._put(f["present_input_voltage"], round(st.voltage * 10))
        self._put(f["present_position"], self.tick(st.angle))
        self._put(f["present_temperature"], max(0, min(255, round(st.temperature))))
        self._put(f["moving"], int(abs(st.velocity) > s.velocity_unit))


def _sign_magnitude(units: float) -> int:
    """Protocol 1.0 speed/load encoding: magnitude in bits 0–9, bit 10 set for clockwise."""
    magnitude = min(round(abs(units)), 1023)
    return magnitude | (1024 if units < 0 and magnitude else 0)
