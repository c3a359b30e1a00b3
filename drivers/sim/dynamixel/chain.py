"""A chain of emulated servos on one half-duplex bus: instruction in, status packets out.

``handle`` implements the instructions of the published protocols: Protocol 1.0 ping, read,
write, reg write, action, sync write; Protocol 2.0 additionally reboot, sync read, fast sync
read, bulk read, fast bulk read and bulk write. It honours status return level (0: ping only,
1: ping and reads, 2: all) and returns each reply with the return delay its servo waits first,
so the server can model wire timing. Fault injection: ``silence`` (a servo stops answering),
``corrupt`` (its replies carry a bad checksum/CRC), plus the servo's own ``set_present`` /
``inject_overload`` for overheat, voltage and overload conditions. With ``clock`` set, each
servo an instruction addresses first steps its motor model up to ``clock()`` (lazily: a
servo nobody talks to costs nothing). A REBOOT is answered (status of the servo before it
restarts), then the servo is silent for ``boot_time`` s of wall-clock time and comes back
with its RAM at power-on values: torque off, latched errors cleared.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from climbd.daemon.contract.profile import gripper_servos
from climbd.drivers.dynamixel.config import DynamixelConfig
from climbd.drivers.sim.dynamixel import servo as sv
from climbd.drivers.sim.dynamixel.servo import EmulatedServo
from climbd.drivers.sim.dynamixel.tables import spec as model_spec
from climbd.drivers.sim.dynamixel.wire import (
    BROADCAST,
    STATUS,
    Instruction,
    crc16,
    packet1,
    packet2,
)

PING, READ, WRITE, REG_WRITE, ACTION, REBOOT = 0x01, 0x02, 0x03, 0x04, 0x05, 0x08
SYNC_READ, SYNC_WRITE, FAST_SYNC_READ = 0x82, 0x83, 0x8A
BULK_READ, BULK_WRITE, FAST_BULK_READ = 0x92, 0x93, 0x9A
_READS = {READ, SYNC_READ, FAST_SYNC_READ, BULK_READ, FAST_BULK_READ}
BOOT_TIME = 0.1
"""Seconds a rebooting servo stays silent (assumed; the e-Manual gives no figure)."""


@dataclass(frozen=True)
class Reply:
    """A status packet and the answering servo's return delay (s) before it goes on the wire."""

    data: bytes
    delay: float


class ServoChain:
    """Servos sharing one bus of ``protocol`` (1 or 2) at ``baud``; ``servo(id)`` finds one."""

    def __init__(
        self,
        servos: Iterable[EmulatedServo],
        protocol: int,
        baud: int = 1_000_000,
        boot_time: float = BOOT_TIME,
    ):
        self.protocol = protocol
        self.baud = baud
        self.boot_time = boot_time
        self.booting: dict[int, float] = {}
        self.lock = threading.RLock()
        self.servos: dict[int, EmulatedServo] = {}
        for s in servos:
            if s.spec.protocol != protocol:
                raise ValueError(
                    f"servo {s.ident} ({s.spec.name}) speaks protocol {s.spec.protocol}"
                )
            if s.ident in self.servos:
                raise ValueError(f"duplicate servo id {s.ident}")
            s.lock = self.lock
            self.servos[s.ident] = s
        self.silenced: set[int] = set()
        self.corrupting: dict[int, int | None] = {}
        self.joints: list[EmulatedServo] = []
        self.grippers: dict[int, EmulatedServo] = {}
        """The feet's gripper servos by leg index (a profile's ``gripper_servo``s)."""
        self.counts: Counter[int] = Counter()
        self.bytes_in = 0
        self.bytes_out = 0
        self.clock: Callable[[], float] | None = None

    @classmethod
    def from_profile(cls, profile, baud: int | None = None, **servo_options) -> ServoChain:
        """One servo per profile joint (the Dynamixel ``model`` of its ``[bus]``), at kinematic
        zero, and one per foot gripper's servo, open."""
        bus = DynamixelConfig.from_profile(profile)
        model = model_spec(bus.model)
        if model.protocol != bus.protocol:
            raise ValueError(
                f"{profile.source or profile.name}: bus.model {model.name} speaks protocol "
                f"{model.protocol}, bus.protocol is {bus.protocol}"
            )
        joints = profile.joints
        servos = [EmulatedServo(model, j.id, angle=j.zero_offset, **servo_options) for j in joints]
        grippers = {
            leg: EmulatedServo(model, g.id, angle=g.open, **servo_options)
            for leg, _, g in gripper_servos(profile)
        }
        chain = cls([*servos, *grippers.values()], model.protocol, baud or bus.baud)
        chain.joints = servos
        chain.grippers = grippers
        return chain

    def servo(self, ident: int) -> EmulatedServo:
        return self.servos[ident]

    def wire_time(self, nbytes: int) -> float:
        """Seconds ``nbytes`` take on the wire: 10 bits a byte (start, 8 data, stop)."""
        return nbytes * 10.0 / self.baud

    # --- joint-space view for a physics twin ------------------------------------------------

    def joint_goals(self) -> np.ndarray:
        """Goal horn angles about the centre (rad) in profile joint order: joint positions."""
        return np.array([s.goal_angle for s in self.joints])

    def joint_positions(self) -> np.ndarray:
        """Present horn angles about the centre (rad) in profile joint order."""
        return np.array([s.state.angle for s in self.joints])

    def set_joint_state(self, position, velocity=None, effort=None) -> None:
        """Set present horn angle/velocity/effort (profile order) from physics."""
        n = len(self.joints)
        velocity = np.zeros(n) if velocity is None else velocity
        effort = np.zeros(n) if effort is None else effort
        with self.lock:
            for s, q, dq, tau in zip(self.joints, position, velocity, effort, strict=True):
                s.set_present(angle=q, velocity=dq, effort=tau)

    def advance(self, dt: float) -> None:
        """Step every servo's built-in motor model by ``dt`` s (skips externally driven ones)."""
        with self.lock:
            for s in self.servos.values():
                s.step(dt)

    # --- fault injection ------------------------------------------------------------------

    def silence(self, ident: int, on: bool = True) -> None:
        """Servo ``ident`` stops answering (as if its cable came off), or answers again."""
        with self.lock:
            (self.silenced.add if on else self.silenced.discard)(ident)

    def corrupt(self, ident: int, count: int | None = 1) -> None:
        """The next ``count`` replies of ``ident`` carry a bad checksum/CRC (None: until 0)."""
        with self.lock:
            if count == 0:
                self.corrupting.pop(ident, None)
            else:
                self.corrupting[ident] = count

    # --- instruction handling ---------------------------------------------------------------

    def _alive(self, ident: int) -> EmulatedServo | None:
        s = self.servos.get(ident)
        if s is None or ident in self.silenced:
            return None
        if ident in self.booting:
            if time.monotonic() < self.booting[ident]:
                return None
            del self.booting[ident]
        if self.clock is not None:
            s.advance_to(self.clock())
        return s

    def _status(self, s: EmulatedServo, error: int, params: bytes = b"") -> Reply:
        if self.protocol == 1:
            data = packet1(s.ident, s.status_error(error), params)
        else:
            data = packet2(s.ident, STATUS, bytes([s.status_error(error)]) + params)
        left = self.corrupting.get(s.ident, 0)
        if left != 0:
            data = data[:-1] + bytes([data[-1] ^ 0xFF])
            if left is not None:
                self.corrupt(s.ident, left - 1)
        return Reply(data, s.get("return_delay_time") * 2e-6)

    def _answers(self, s: EmulatedServo, inst: int) -> bool:
        level = s.get("status_return_level")
        return inst == PING or level >= 2 or (level == 1 and inst in _READS)

    def handle(self, instr: Instruction) -> list[Reply]:
        """Execute one instruction packet; returns the status packets in bus order."""
        with self.lock:
            self.counts[instr.inst] += 1
            self.bytes_in += instr.size
            replies = self._handle1(instr) if self.protocol == 1 else self._handle2(instr)
            self.bytes_out += sum(len(r.data) for r in replies)
            return replies

    def _unicast(self, instr: Instruction) -> EmulatedServo | None:
        return None if instr.ident == BROADCAST else self._alive(instr.ident)

    def _handle1(self, instr: Instruction) -> list[Reply]:
        s = self._unicast(instr)
        p = instr.params
        if not instr.valid:
            return [self._status(s, sv.P1_CHECKSUM)] if s and self._answers(s, READ) else []
        if instr.inst == SYNC_WRITE and instr.ident == BROADCAST and len(p) >= 2:
            self._sync_write(p[0], p[1], p[2:])
            return []
        if instr.inst == ACTION and instr.ident == BROADCAST:
            for t in self.servos.values():
                if t.ident not in self.silenced:
                    self._action(t)
            return []
        if s is None:
            return []
        answer = self._answers(s, instr.inst)  # the level in force when the packet arrived
        error = 0
        params = b""
        if instr.inst == PING:
            pass
        elif instr.inst == READ and len(p) == 2:
            data = s.read_bytes(p[0], p[1])
            error, params = (sv.P1_RANGE, b"") if data is None else (0, data)
        elif instr.inst in (WRITE, REG_WRITE) and len(p) >= 2:
            error = self._write(s, p[0], p[1:], instr.inst == REG_WRITE)
        elif instr.inst == ACTION:
            self._action(s)
        else:
            error = sv.P1_INSTRUCTION
        return [self._status(s, error, params)] if answer else []

    def _handle2(self, instr: Instruction) -> list[Reply]:
        s = self._unicast(instr)
        p = instr.params
        inst = instr.inst
        if not instr.valid:
            return [self._status(s, sv.P2_CRC)] if s and self._answers(s, READ) else []
        if instr.ident == BROADCAST:
            return self._broadcast2(inst, p)
        if s is None:
            return []
        answer = self._answers(s, inst)
        error = 0
        params = b""
        if inst == PING:
            params = _ping_params(s)
        elif inst == READ and len(p) == 4:
            data = s.read_bytes(_u16(p, 0), _u16(p, 2))
            error, params = (sv.P2_ACCESS, b"") if data is None else (0, data)
        elif inst in (WRITE, REG_WRITE) and len(p) >= 2:
            error = self._write(s, _u16(p, 0), p[2:], inst == REG_WRITE)
        elif inst == ACTION:
            self._action(s)
        elif inst == REBOOT:
            reply = self._status(s, 0)
            self._reboot(s)
            return [reply] if answer else []
        elif inst in (READ, WRITE, REG_WRITE):
            error = sv.P2_DATA_LENGTH
        else:
            error = sv.P2_INSTRUCTION
        return [self._status(s, error, params)] if answer else []

    def _broadcast2(self, inst: int, p: bytes) -> list[Reply]:
        if inst == PING:
            alive = [self._alive(ident) for ident in sorted(self.servos)]
            return [self._status(s, 0, _ping_params(s)) for s in alive if s is not None]
        if inst in (ACTION, REBOOT):
            for ident in list(self.servos):
                s = self._alive(ident)
                if s is not None and inst == ACTION:
                    self._action(s)
                elif s is not None:
                    self._reboot(s)
            return []
        if inst == SYNC_WRITE and len(p) >= 4:
            self._sync_write(_u16(p, 0), _u16(p, 2), p[4:])
            return []
        if inst == BULK_WRITE:
            i = 0
            while i + 5 <= len(p):
                n = _u16(p, i + 3)
                s = self._alive(p[i])
                if s is not None:
                    self._write(s, _u16(p, i + 1), p[i + 5 : i + 5 + n], False)
                i += 5 + n
            return []
        if inst in (SYNC_READ, FAST_SYNC_READ) and len(p) >= 4:
            reads = [(ident, _u16(p, 0), _u16(p, 2)) for ident in p[4:]]
        elif inst in (BULK_READ, FAST_BULK_READ):
            reads = [(p[i], _u16(p, i + 1), _u16(p, i + 3)) for i in range(0, len(p) - 4, 5)]
        else:
            return []
        if inst in (FAST_SYNC_READ, FAST_BULK_READ):
            return self._fast_read(reads)
        out = []
        for ident, address, length in reads:
            s = self._alive(ident)
            if s is None or not self._answers(s, inst):
                continue
            data = s.read_bytes(address, length)
            out.append(self._status(s, sv.P2_ACCESS if data is None else 0, data or b""))
        return out

    def _fast_read(self, reads: list[tuple[int, int, int]]) -> list[Reply]:
        """One status packet chained by every addressed servo: ERR ID DATA CRC per servo.

        Each servo's CRC covers the packet from its header up to that CRC, so the last one is
        the packet's own CRC. A silent servo leaves its segment out and the packet comes up
        short, as on a real bus. The SDK reads this packet without unstuffing, so none is done.
        """
        total = sum(length + 4 for _, _, length in reads)
        n = total + 1
        body = bytearray(b"\xff\xff\xfd\x00" + bytes([BROADCAST, n & 0xFF, n >> 8, STATUS]))
        first = None
        broken = False
        running = crc16(body)  # the CRC of everything chained so far
        for ident, address, length in reads:
            s = self._alive(ident)
            if s is None or not self._answers(s, FAST_SYNC_READ):
                continue
            first = first or s
            data = s.read_bytes(address, length)
            error = sv.P2_ACCESS if data is None else 0
            segment = bytes([s.status_error(error), ident]) + (data or bytes(length))
            crc = crc16(segment, running)
            tail = bytes([crc & 0xFF, crc >> 8])
            body += segment + tail
            running = crc16(tail, crc)
            if self.corrupting.get(ident, 0) != 0:
                broken = True
                left = self.corrupting[ident]
                if left is not None:
                    self.corrupt(ident, left - 1)
        if first is None:
            return []
        if broken:
            body[-1] ^= 0xFF
        return [Reply(bytes(body), first.get("return_delay_time") * 2e-6)]

    def _write(self, s: EmulatedServo, address: int, data: bytes, registered: bool) -> int:
        if registered:
            s.pending = (address, bytes(data))
            s.set("registered" if self.protocol == 1 else "registered_instruction", 1)
            return 0
        id_field = s.spec.fields["id"]
        error = s.write_bytes(address, data)
        if not error and address <= id_field.address < address + len(data):
            self.servos = {t.ident: t for t in self.servos.values()}
        return error

    def _reboot(self, s: EmulatedServo) -> None:
        s.reboot()
        self.booting[s.ident] = time.monotonic() + self.boot_time

    def _action(self, s: EmulatedServo) -> None:
        pending = s.pending
        if pending is not None:
            s.pending = None
            s.set("registered" if self.protocol == 1 else "registered_instruction", 0)
            self._write(s, pending[0], pending[1], False)

    def _sync_write(self, address: int, length: int, block: bytes) -> None:
        step = 1 + length
        for i in range(0, len(block) - step + 1, step):
            s = self._alive(block[i])
            if s is not None:
                self._write(s, address, block[i + 1 : i + step], False)


def _ping_params(s: EmulatedServo) -> bytes:
    """Protocol 2.0 ping status parameters: model number (2 bytes) and firmware version."""
    return s.get("model_number").to_bytes(2, "little") + bytes([s.get("firmware_version")])


def _u16(p: bytes, i: int) -> int:
    return p[i] | p[i + 1] << 8
