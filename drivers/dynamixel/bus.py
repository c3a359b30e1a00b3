"""Dynamixel joint bus on dynamixel_sdk: Protocol 1.0 (AX-18A) and 2.0 (X series).

Per cycle: one sync write of goal positions; reads of position, speed and load — on 2.0 one
(fast) sync read, on 1.0 (no sync read on the AX) one READ of the contiguous block per servo.
Every ``round(rate_hz / health_rate_hz)`` reads the same transaction reads a longer block that
also holds voltage and temperature (2.0 adds a sync read of Hardware Error Status).
A servo that misses its reads in ``lost_after`` ticks in a row is marked lost, skipped, probed
on health cycles and re-admitted when it answers. Every device problem is a DriverError naming
the port. ``clear_faults()`` is the operator's reset: it REBOOTs X-series servos whose latched
hardware error switched their torque off and torques limp servos again at their present
position. The feet's gripper servos (``Leg.gripper_servo``) ride the same writes and reads
after the joints; a gripper holds when its fingers, told to close, stop short of closed.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import math
import os
import select
import time
from collections import deque
from collections.abc import Callable, Iterator
from pathlib import Path

import dynamixel_sdk as sdk
import numpy as np

from climbd.daemon.contract.hardware import DriverError
from climbd.daemon.contract.messages import BusSchedule, JointCommand, JointHealth, JointState
from climbd.daemon.contract.profile import Profile, gripper_servos
from climbd.drivers.dynamixel.config import DynamixelConfig
from climbd.drivers.dynamixel.models import MODEL_NAMES, Item, Model, error_names, model
from climbd.drivers.dynamixel.packet import packet_handler
from climbd.drivers.dynamixel.pipeline import Parsed, PipelinedPort, Request
from climbd.drivers.dynamixel.schedule import ReadSchedule
from climbd.drivers.dynamixel.units import TickScale, little_endian, little_endian_bytes

log = logging.getLogger(__name__)

STATUS_RETURN_ALL = 2
# What dynamixel_sdk raises when a late status is taken for the reply to the next instruction.
MISPARSE = (IndexError, KeyError, ValueError)
BRING_UP_MARGIN_MS = 50.0  # bring-up is not time-critical: wait long, never misread a late reply
BRING_UP_ATTEMPTS = 8  # a servo just powered up (or a loaded host) may miss the first packets
USB_SERIAL_SYSFS = Path("/sys/bus/usb-serial/devices")
"""Where Linux exposes each USB serial adapter's settings, one directory per tty (ttyUSB0…)."""
USB_FRAME = 1e-3
"""Full-speed USB frame (s): behind an adapter, what the host writes reaches the bus on the
next one, so requests are spaced by a frame more than their wire time."""
BUS_GAP = 50e-6
"""Seconds left between a reply's end on the wire and the next instruction (turnarounds)."""
IDLE_MARGIN = 3e-4
"""Seconds before the next tick by which the last request between ticks must be off the bus."""
MAX_HOLD = 0.032
"""The longest (s) an adapter is taken to hold a reply: twice FTDI's default latency timer."""
ROUND_TRIP_SAMPLES = 5
GRIP_STOP = 0.1
"""rad: fingers stopped this far inside both ends of their travel are closed on something."""
GRIP_STILL = 0.2
"""rad/s: fingers slower than this have stopped (a gripper still closing holds nothing yet)."""
"""Reads timed at open to learn the port's round trip."""


class LatencyPort(sdk.PortHandler):
    """The SDK's port with packet timeouts sized for our adapter latency, and lean I/O.

    The SDK waits ``bytes × tx time + 2 × 16 ms + 2 ms`` for a reply, assuming the FTDI default
    latency timer; we set the timer to ``latency_ms``, so a silent servo costs ~4 ms, not 34.
    Waiting blocks in select() rather than busy-polling: no core burnt on a Raspberry Pi, and
    other threads of the process (an in-process emulator, Zenoh callbacks) get the GIL.
    Reads, writes and flushes go straight to the file descriptor (pyserial adds an ioctl and a
    select per call, and tcflush takes the tty's buffer lock): a round trip costs two system
    calls fewer at each end. Timeouts run on the monotonic clock, not the SDK's wall clock.
    """

    def __init__(self, name: str, latency_ms: float, margin_ms: float = 2.0) -> None:
        super().__init__(name)
        self.latency_ms = latency_ms
        self.margin_ms = margin_ms
        self.written = 0
        """Bytes written since open (``DynamixelBus.sent``)."""

    def getCurrentTime(self) -> float:  # noqa: N802 - SDK override
        return time.monotonic_ns() / 1e6

    def setPacketTimeout(self, packet_length: int) -> None:  # noqa: N802 - SDK override
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = (
            self.tx_time_per_byte * packet_length + 2.0 * self.latency_ms + self.margin_ms
        )

    def _read(self, length: int) -> bytes:
        """What has arrived, up to ``length`` bytes; b"" if nothing (VMIN = VTIME = 0)."""
        try:
            return os.read(self.ser.fd, length)
        except BlockingIOError:
            return b""

    def receive(self) -> bytes:
        """Every byte that has arrived, without waiting."""
        data = bytearray()
        while chunk := self._read(4096):
            data += chunk
        return bytes(data)

    def readPort(self, length: int) -> bytes:  # noqa: N802 - SDK override
        """Bytes already there at once; else wait in select() for them until the deadline."""
        data = self._read(length)
        if data:
            return data
        remaining = (self.packet_timeout - self.getTimeSinceStart()) / 1000.0
        if remaining > 0 and select.select([self.ser.fd], [], [], remaining)[0]:
            data = self._read(length)
            if not data:  # readable yet empty: hung up
                raise OSError(errno.EIO, "the port hung up (device unplugged?)")
        return data

    def writePort(self, packet: list[int]) -> int:  # noqa: N802 - SDK override
        """Write the whole packet (the tty normally takes it in one call)."""
        data = bytes(packet)
        done = os.write(self.ser.fd, data)
        while done < len(data):
            select.select([], [self.ser.fd], [], 0.1)
            done += os.write(self.ser.fd, data[done:])
        self.written += done
        return done

    def clearPort(self) -> None:  # noqa: N802 - SDK override
        """Drop stale received bytes (a late status) by reading them: one call if none."""
        while self._read(4096):
            pass


def latency_timer_path(port: str, sysfs: Path | None = None) -> Path:
    """The latency timer file of the adapter behind ``port`` under ``sysfs`` (default
    ``USB_SERIAL_SYSFS``), named after the tty the port resolves to; only an adapter has one."""
    return (sysfs or USB_SERIAL_SYSFS) / Path(os.path.realpath(port)).name / "latency_timer"


def set_latency_timer(port: str, latency_ms: int) -> None:
    """Set a USB serial adapter's latency timer (sysfs); a pty or native UART is skipped."""
    path = latency_timer_path(port)
    if not path.exists():
        log.debug("%s: not a USB serial device, no latency timer to set", port)
        return
    try:
        if int(path.read_text().strip()) != latency_ms:
            path.write_text(f"{latency_ms}\n")
    except (OSError, ValueError) as e:
        log.warning(
            "%s: cannot set latency timer to %d ms (%s); loops will crawl. "
            "Fix: echo %d | sudo tee %s",
            port,
            latency_ms,
            e,
            latency_ms,
            path,
        )


def check_latency_timer(
    port: str,
    reads_per_cycle: int,
    measure: Callable[[], float | None] = lambda: None,
    sysfs: Path | None = None,
) -> int | None:
    """Warn, with the cost and the fix, when the adapter behind ``port`` holds replies over 1 ms.

    An FTDI adapter returns a status packet only when its latency timer expires, so every read
    waits for it: a cycle of ``reads_per_cycle`` reads costs that many timers, and a loop that
    should run at 100 Hz crawls instead. ``measure`` times one read on the port (ms; None if
    unanswered); it is called only when there is something to warn about. Returns the timer
    (ms), or None for a port without one (a pty, a native UART)."""
    path = latency_timer_path(port, sysfs)
    try:
        timer = int(path.read_text().strip())
    except (OSError, ValueError):
        return None
    if timer > 1:
        round_trip = measure()
        cost = f"{round_trip:.1f} ms measured" if round_trip is not None else f"≥ {timer} ms"
        log.warning(
            "%s: USB serial adapter latency timer is %d ms: a read takes %s, %d read(s) a cycle "
            "≥ %.0f ms. Fix: echo 1 | sudo tee %s (or install the udev rule "
            "systemd/99-climbd.rules with climbd install)",
            port,
            timer,
            cost,
            reads_per_cycle,
            reads_per_cycle * max(timer, round_trip or 0.0),
            path,
        )
    return timer


class DynamixelBus:
    """The joints of a profile on one Dynamixel bus, in profile order and SI units, and the
    servos of its feet's grippers after them (``Leg.gripper_servo``): the commands' ``grip``
    closes or opens them, and the state's ``holding`` says which hold something."""

    compliant = True
    """Position servos: load deflects them from their goals (the controller's sag offset)."""

    Config = DynamixelConfig
    """Its keys of the profile's ``[bus]`` table."""

    def __init__(
        self,
        profile: Profile,
        port: str | None = None,
        baud: int | None = None,
        lost_after: int | None = None,
        fast_sync_read: bool | None = None,
        timeout_margin_ms: float = 2.0,
    ) -> None:
        bus = self.config = DynamixelConfig.from_profile(profile)
        try:
            self.model: Model = model(bus.model)
        except KeyError as e:
            raise DriverError(f"{profile.source or profile.name}: bus.model: {e.args[0]}") from None
        if self.model.protocol != bus.protocol:
            raise DriverError(
                f"{profile.source or profile.name}: bus.model {self.model.name} speaks protocol "
                f"{self.model.protocol}, bus.protocol is {bus.protocol}"
            )
        self.profile = profile
        self.port_name = port or bus.port
        self.baud = baud or bus.baud
        self.lost_after = lost_after or profile.bus.lost_after
        self.fast_sync_read = fast_sync_read
        self.timeout_margin_ms = timeout_margin_ms
        joints = profile.joints
        grippers = gripper_servos(profile)
        self.n_joints = len(joints)
        self.names = [j.name for j in joints] + [name for _, name, _ in grippers]
        self.ids = [j.id for j in joints] + [g.id for _, _, g in grippers]
        self.map = TickScale(self.model, joints)
        speeds = [j.limits.velocity for j in joints] + [g.velocity for _, _, g in grippers]
        self.speed_caps = self.map.speed_ticks(np.array(speeds))
        self.health_every = max(1, round(profile.rate_hz / profile.bus.health_rate_hz))
        self.gripper_legs = [i for i, _, _ in grippers]
        self.grip_open = np.array([g.open for _, _, g in grippers])
        self.grip_closed = np.array([g.closed for _, _, g in grippers])
        self.gripping: np.ndarray | None = None
        """Which grippers the last command closed (None before one said)."""
        n = len(self.ids)
        self.position = np.zeros(n)
        self.velocity = np.zeros(n)
        self.effort = np.zeros(n)
        self.temperature = np.full(n, np.nan)
        self.voltage = np.full(n, np.nan)
        self.errors = np.zeros(n, np.int64)
        self.misses = np.zeros(n, np.int64)
        """Ticks in a row in which each servo missed a read (several misses in one tick: one)."""
        self._missed_in = np.full(n, -np.inf)
        """The tick (its start, monotonic s) of each servo's last counted miss."""
        self.lost = np.zeros(n, bool)
        self.torque_on = False
        self.reads = 0
        self.port: LatencyPort | None = None
        self.ph = packet_handler(self.model.protocol)
        self._groups: dict[int, sdk.GroupSyncRead] = {}
        self._group_ids: tuple[int, ...] = ()
        self._error_group: sdk.GroupSyncRead | None = None
        self.read_schedule = ReadSchedule(
            self.names, profile.rate_hz, profile.bus.max_state_age, 1.0 / profile.bus.health_rate_hz
        )
        self._failure: DriverError | None = None
        """What failed between ticks, raised by the next read."""
        self._served = False
        """Whether the control loop gives the bus its idle time (``serve_until``): reads are
        then sent between ticks and ``read`` takes what has come, never waiting."""
        self._pipe: PipelinedPort | None = None
        self._requests: deque[Request] = deque()
        self._alone = np.zeros(n, bool)
        """Servos read on their own after a sync read that did not come back whole."""
        self._tick = 0.0
        self._bus_free = 0.0
        self._frame = 0.0
        self._hold = 0.0
        """How long (s) the adapter holds a reply: measured at open, followed as replies come."""
        self._told = 0.0
        """The hold last logged."""
        self._doubted: float | None = None
        """The hold before the replies given up since the last reply came: their doubling
        stands only until a reply shows whether the adapter held them or their servos are
        silent."""
        self._sync_reads = 0
        self._errors_due = False
        """2.0: a health block came by sync read; their error status is read next."""
        self._pipe_groups: dict[tuple[Item, tuple[int, ...]], sdk.GroupSyncRead] = {}

    @classmethod
    def from_profile(cls, profile: Profile, **options) -> DynamixelBus:
        """A bus for ``profile``; options: port, baud, lost_after, fast_sync_read."""
        return cls(profile, **options)

    # --- errors ---------------------------------------------------------------------------

    def _where(self, k: int | None = None) -> str:
        if k is None:
            return f"dynamixel bus {self.port_name} ({self.model.name})"
        return f"{self.port_name}: id {self.ids[k]} ({self.names[k]}, {self.model.name})"

    @contextlib.contextmanager
    def _device(self, what: str) -> Iterator[None]:
        """Turn anything the SDK or the serial port raises into a DriverError naming the port."""
        if self.port is None:
            raise DriverError(f"{self._where()}: {what} before open()")
        try:
            yield
        except DriverError:
            raise
        except Exception as e:  # pyserial, termios, OSError, SDK index errors on short packets
            raise DriverError(f"{self._where()}: {what} failed: {type(e).__name__}: {e}") from None

    # --- bring-up -------------------------------------------------------------------------

    def open(self) -> None:
        """Open the port, ping and check every servo, configure it for a fast loop, first read."""
        bus = self.config
        port = LatencyPort(self.port_name, bus.latency_timer_ms, self.timeout_margin_ms)
        try:
            opened = port.openPort()
        except Exception as e:
            raise DriverError(f"{self._where()}: cannot open port: {e}") from None
        if not opened or not port.setBaudRate(self.baud):
            with contextlib.suppress(Exception):
                port.closePort()
            raise DriverError(f"{self._where()}: cannot set {self.baud} baud on this port")
        self.port = port
        self._pipe = PipelinedPort(port, port.receive)
        set_latency_timer(self.port_name, bus.latency_timer_ms)
        try:
            with self._device("bring-up"), self._patience():
                self._check_models()
                self._configure(self.model.status_return_level, STATUS_RETURN_ALL)
                self._configure(self.model.return_delay_time, bus.return_delay_us // 2)
                self._sync_write(self.model.speed_limit, self.speed_caps)
                self._choose_read_mode()
                self._read_blocks(True)
                reads = len(self.ids) if self.model.protocol == 1 else 1
                timer = check_latency_timer(self.port_name, reads, self._read_round_trip)
                self._plan(timer)
        except DriverError:
            self.close()
            raise

    def _read_round_trip(self) -> float | None:
        """One state read of the first servo, timed (ms); None if it went unanswered."""
        start = time.monotonic()
        _, result, _ = self._read_one(self.ids[0], self.model.state)
        return (time.monotonic() - start) * 1e3 if result == sdk.COMM_SUCCESS else None

    def _read_wire(self, size: int) -> float:
        """Seconds a READ of ``size`` bytes and its status take on the wire."""
        frame = (8 + 6) if self.model.protocol == 1 else (14 + 11)
        return (frame + size) * 10.0 / self.baud + self.config.return_delay_us * 1e-6

    def _sync_read_wire(self, size: int, n: int) -> float:
        """Seconds a (fast) sync read of ``size`` bytes from ``n`` servos takes on the wire."""
        status = 8 + n * (size + 4) if self.fast_sync_read else n * (11 + size)
        return (14 + n + status) * 10.0 / self.baud + n * self.config.return_delay_us * 1e-6

    def _plan(self, timer: int | None) -> None:
        """Learn the port's round trip and plan the reads between ticks; say what it gives.

        Behind a USB adapter (a latency timer in sysfs, or round trips a frame longer than
        the wire) requests wait for the next USB frame and replies for the adapter's timer:
        the plan spaces requests by a frame and waits that long for replies."""
        trips = [t for _ in range(ROUND_TRIP_SAMPLES) if (t := self._read_round_trip())]
        trip = float(np.median(trips)) / 1e3 if trips else 0.0
        m = self.model
        wire = self._read_wire(m.health.size)
        adapter = timer is not None or trip > wire + USB_FRAME / 2
        self._frame = USB_FRAME if adapter else 0.0
        self._hold = max(trip - wire - self._frame / 2, (timer or 0) / 1e3) if adapter else 0.0
        self._told = self._hold
        self.port.latency_ms = max(self.port.latency_ms, self._hold * 1e3)
        period, n = 1.0 / self.profile.rate_hz, len(self.ids)
        bound = self.read_schedule.bound
        where = f"adapter holds replies ~{self._hold * 1e3:.0f} ms" if adapter else "no adapter"
        if m.protocol == 1:
            frames = math.ceil(wire / self._frame) * self._frame if adapter else wire
            spacing = frames + BUS_GAP
            per_tick = max(1, int(0.7 * period / spacing))
            oldest = -(-n // per_tick) * period + self._frame + self._hold
            plan = (
                f"a READ every {spacing * 1e3:.2f} ms between ticks ({where}, round trip "
                f"{trip * 1e3:.1f} ms): ~{min(per_tick, n)} of {n} servos a tick, oldest state "
                f"~{oldest * 1e3:.0f} ms"
            )
        else:
            trip_sync = self._frame + self._sync_read_wire(m.state.size, n) + self._hold
            oldest = max(period, -(-trip_sync // period) * period) + trip_sync
            plan = (
                f"a sync read of {n} servos every {max(period, trip_sync) * 1e3:.0f} ms ({where}, "
                f"round trip {trip * 1e3:.1f} ms), oldest state ~{oldest * 1e3:.0f} ms"
            )
        self.read_schedule.plan = plan
        if oldest > bound:
            log.warning(
                "%s: read schedule: %s, over the %.0f ms bound: reads are too slow for this "
                "loop; the e-stop policy applies when a joint's state is older",
                self._where(),
                plan,
                bound * 1e3,
            )
        else:
            log.info("%s: read schedule: %s (bound %.0f ms)", self._where(), plan, bound * 1e3)

    def _patient(self, call, *args) -> tuple:
        """A bring-up SDK call; a late reply the SDK misparses is a corrupt packet (flushed,
        retried by the caller), not a failed bring-up."""
        try:
            return call(self.port, *args)
        except MISPARSE:
            self.port.clearPort()
            return 0, sdk.COMM_RX_CORRUPT, 0

    def _check_models(self) -> None:
        problems = []
        for k, ident in enumerate(self.ids):
            for _ in range(BRING_UP_ATTEMPTS):
                number, result, _ = self._patient(self.ph.ping, ident)
                if result == sdk.COMM_SUCCESS:
                    break
                time.sleep(self.port.packet_timeout / 1000.0)  # let a late status drain
            if result != sdk.COMM_SUCCESS:
                problems.append(f"id {ident} ({self.names[k]}) does not answer")
            elif number != self.model.model_number:
                found = MODEL_NAMES.get(number, f"model number {number}")
                problems.append(
                    f"id {ident} ({self.names[k]}) is {found}, profile expects "
                    f"{self.model.name} ({self.model.model_number})"
                )
        if problems:
            raise DriverError(f"{self._where()}: " + "; ".join(problems))

    def _configure(self, item: Item, value: int, attempts: int = BRING_UP_ATTEMPTS) -> None:
        """Write ``item`` where it differs, answered or not, and verify by reading it back."""
        for k, ident in enumerate(self.ids):
            for _ in range(attempts):
                current, result, _ = self._patient(self.ph.read1ByteTxRx, ident, item.address)
                if result == sdk.COMM_SUCCESS and current == value:
                    break
                level, result, _ = self._patient(
                    self.ph.read1ByteTxRx, ident, self.model.status_return_level.address
                )
                if result == sdk.COMM_SUCCESS and level >= STATUS_RETURN_ALL:
                    written = self._patient(self.ph.write1ByteTxRx, ident, item.address, value)
                    if written == (sdk.COMM_SUCCESS, 0):
                        continue  # answered: no late status to drain, read it back now
                else:
                    self.ph.write1ByteTxOnly(self.port, ident, item.address, value)
                time.sleep(self.port.packet_timeout / 1000.0)  # let a late status drain
            else:
                raise DriverError(
                    f"{self._where(k)}: cannot set address {item.address} to {value} "
                    f"({self.ph.getTxRxResult(result)}, reads {current})"
                )

    def _choose_read_mode(self) -> None:
        if self.model.protocol == 1:
            return
        if self.fast_sync_read is None:
            need = self.model.fast_sync_read_firmware
            versions = [
                self.ph.read1ByteTxRx(self.port, i, self.model.firmware_version.address)[0]
                for i in self.ids
            ]
            self.fast_sync_read = need is not None and min(versions) >= need
        log.debug("%s: fast sync read %s", self._where(), "on" if self.fast_sync_read else "off")

    # --- per-cycle I/O ----------------------------------------------------------------------

    def _sync_write(self, item: Item, values: np.ndarray, only: np.ndarray | None = None) -> float:
        """One SYNC WRITE (no reply); between ticks' reads it goes out without a flush.
        Returns its wire time (s): 0 when every servo is lost and nothing went."""
        port = self._pipe if self._served else self.port
        group = sdk.GroupSyncWrite(port, self.ph, item.address, item.size)
        raw = little_endian_bytes(values, item.size)
        chosen = [True] * len(self.ids) if only is None else only.tolist()
        if not any(chosen):  # every servo lost: nothing to send (an empty sync write is refused)
            return 0.0
        for k, ident in enumerate(self.ids):
            if chosen[k]:
                group.addParam(ident, list(raw[k * item.size : (k + 1) * item.size]))
        result = group.txPacket()
        if result != sdk.COMM_SUCCESS:
            raise DriverError(
                f"{self._where()}: sync write of address {item.address} failed: "
                f"{self.ph.getTxRxResult(result)}"
            )
        return (8 + len(group.param)) * 10.0 / self.baud

    def read(self) -> JointState:
        """Present position, velocity, effort of every joint; lost joints keep their last value.

        Once the loop serves the bus between ticks, this takes the replies that have come,
        never waiting, and every joint's state carries its age; else it reads every servo."""
        self.reads += 1
        now = self._tick = time.monotonic()
        if self._failure is not None:
            failure, self._failure = self._failure, None
            raise failure
        if self._served:
            with self._device("read"):
                self._collect(now, prompt=False)
            self.read_schedule.tick(now, self.lost)
            age = self.read_schedule.ages(now, self.lost)
        else:
            with self._device("read"):
                self._read_blocks(self.reads % self.health_every == 0)
            age = []
        n = self.n_joints
        return JointState(
            names=self.names[:n],
            position=self.position[:n].tolist(),
            velocity=self.velocity[:n].tolist(),
            effort=self.effort[:n].tolist(),
            age=age[:n],
            holding=self.holding() if self.gripper_legs else None,
        )

    def holding(self) -> list[bool]:
        """Per leg, whether its gripper holds: its fingers, told to close, stopped short of
        closed (on a hold) and not at open; a gripper that closed on nothing ends at closed."""
        n = self.n_joints
        at, speed = self.position[n:], self.velocity[n:]
        travel = np.sign(self.grip_closed - self.grip_open)
        inside = ((at - self.grip_open) * travel > GRIP_STOP) & (
            (self.grip_closed - at) * travel > GRIP_STOP
        )
        closing = np.ones(len(at), bool) if self.gripping is None else self.gripping
        held = inside & (np.abs(speed) < GRIP_STILL) & closing & ~self.lost[n:]
        flags = [False] * len(self.profile.legs)
        for leg, h in zip(self.gripper_legs, held.tolist(), strict=True):
            flags[leg] = h
        return flags

    # --- reads between ticks ---------------------------------------------------------------

    def serve_until(self, deadline: float) -> None:
        """The loop's idle time before ``deadline`` (monotonic s): send READs (sync reads on
        2.0) as the bus frees, oldest state first, each finished on the wire before the
        deadline, and take the replies as they come."""
        if self.port is None:
            return
        # never more than a period: a deadline further off is the loop's clock jumping
        end = min(deadline, time.monotonic() + 1.0 / self.profile.rate_hz) - IDLE_MARGIN
        try:
            if not self._served:  # the first: every servo at once, so no state starts old
                with self._device("read"):
                    self._read_blocks(False)
                self._served = True
            self._serve(end)
        except DriverError as e:  # the loop's idle must not raise: the next read does
            self._failure = self._failure or e

    def _serve(self, end: float) -> None:
        with self._device("read between ticks"):
            while True:
                now = time.monotonic()
                self._collect(now)
                if now >= end:
                    return
                if self._bus_free > now:
                    wait = self._bus_free - now
                elif self._send_next(now, end):
                    continue
                elif self._requests:
                    wait = min(end, self._expires(self._requests[0])) - now
                else:
                    return
                if wait > 0:
                    select.select([self.port.ser.fd], [], [], wait)

    def _send_next(self, now: float, end: float, behind: float = 0.0) -> bool:
        """Send the next request if its reply is off the bus by ``end``; whether one went.
        ``behind``: seconds of an instruction without reply just written, that it follows.
        Without an adapter a reply is back within a wire time: one request at a time.

        First a lost servo due a probe (at the health rate), then READs of their own, oldest
        state first: every 1.0 servo, and the 2.0 servos a sync read missed. Then, on 2.0, a
        sync read of the others (the health block at the health rate, then their error
        status), once a tick and again while one comes back before the next tick (the tick
        then takes the freshest)."""
        if not self._frame and self._requests:  # no adapter: the reply is due at once
            return False
        m, lost = self.model, self.lost
        single = ~lost & self._alone if m.protocol == 2 else ~lost
        k = self.read_schedule.probe(now, lost)
        if k is None:
            k = self.read_schedule.next(self._tick, ~single)
        if k is not None:
            item = m.health if m.protocol == 1 else m.state
            wire = behind + self._read_wire(item.size)
            if now + self._frame + wire > end:
                return False
            self.ph.readTx(self._pipe, self.ids[k], item.address, item.size)
            self._expect((k,), item, now, wire, self._parser(k, item))
            return True
        joints = tuple(np.flatnonzero(~lost & ~self._alone).tolist())
        if m.protocol == 1 or not joints or self.read_schedule.pending[list(joints)].any():
            return False
        stale = self.read_schedule.sampled[list(joints)].min() < self._tick
        trip = self._frame + self._sync_read_wire(m.state.size, len(joints)) + self._hold
        fresher = now + trip < end  # another comes back before the tick: fresher state
        if not (self._errors_due or stale or fresher):
            return False
        if self._errors_due:
            item = m.hardware_error_status
        else:
            health = (self._sync_reads + 1) % self.health_every == 0
            item = m.health if health else m.state
        wire = behind + self._sync_read_wire(item.size, len(joints))
        if now + self._frame + wire > end:
            return False
        self._sync_reads += item != m.hardware_error_status
        self._errors_due = item == m.health
        self._send_sync(joints, item, now, wire)
        return True

    def _send_sync(self, joints: tuple[int, ...], item: Item, now: float, wire: float) -> None:
        key = (item, tuple(self.ids[k] for k in joints))
        group = self._pipe_groups.get(key)
        if group is None:
            if len(self._pipe_groups) > 8:
                self._pipe_groups.clear()
            group = self._pipe_groups[key] = sdk.GroupSyncRead(
                self._pipe, self.ph, item.address, item.size
            )
            for ident in key[1]:
                group.addParam(ident)
        if self.fast_sync_read:
            group.fastSyncReadTxPacket()
            self._expect(joints, item, now, wire, lambda: self._parse_fast(group, joints))
        else:
            group.txPacket()
            for k in joints:
                self._expect((k,), item, now, wire, self._parser(k, item))

    def _expect(self, joints: tuple[int, ...], item: Item, now: float, wire: float, parse) -> None:
        """Note a request sent at ``now`` that keeps the bus ``wire`` s (its instruction, any
        instruction just before it without a reply, its replies). Behind an adapter every
        write leaves on the next USB frame boundary, so a write ``k`` frames later (``k``
        frames ≥ ``wire``) cannot meet it on the bus."""
        if self._frame:  # it leaves on a frame boundary; a write a frame later leaves after it
            self._bus_free = now + math.ceil(wire / self._frame) * self._frame + BUS_GAP
        else:
            self._bus_free = now + wire + BUS_GAP
        self._requests.append(Request(joints, item, now, wire, parse))
        self.read_schedule.pending[list(joints)] = True

    def _expires(self, request: Request) -> float:
        """When a reply is given up: off the wire, released by the adapter (twice the hold
        it is seen to have now), plus the timeout margin."""
        late = self._frame + request.wire + 2.0 * self._hold + self.timeout_margin_ms / 1e3
        return request.sent + late

    def _seen_hold(self, request: Request, now: float, answered: bool) -> None:
        """Follow the adapter's hold: a reply shows it (it decays slowly to what replies
        show), a reply given up doubles it (a latency timer raised under load), up to
        ``MAX_HOLD``; a change of over 2× is said (a rise as a warning), with what it does to
        the schedule."""
        if answered:
            shown = now - request.sent - self._frame - request.wire
            self._hold = max(0.9 * self._hold, min(shown, MAX_HOLD))
        else:
            self._hold = min(max(2.0 * self._hold, USB_FRAME), MAX_HOLD)
        if self._hold > 2.0 * self._told or self._hold < 0.5 * self._told:
            before, self._told = self._told, self._hold
            log.log(
                logging.WARNING if self._hold > before else logging.INFO,
                "%s: replies now held ~%.0f ms (was ~%.0f ms): the oldest joint state ages "
                "by as much",
                self._where(),
                self._hold * 1e3,
                before * 1e3,
            )

    def _follow_hold(
        self, request: Request, now: float, parsed: Parsed | None, prompt: bool, behind: bool
    ) -> None:
        """Follow the adapter's hold from a request settled in the order owed. One given up
        (``parsed`` None) doubles it, provisionally: the adapter passes replies in order, so
        a reply that comes after it shows whether it was held longer or never sent (a silent
        servo not yet lost, which must not stretch every request's expiry, and so its own
        detection, to ``MAX_HOLD``). ``behind``: requests were given up before it in this
        call, so its reply was in already: theirs never came, and it waited, showing no hold.
        ``prompt``: the reply has just come, so it shows the hold."""
        if parsed is None:
            if self._doubted is None:
                self._doubted = self._hold
            self._seen_hold(request, now, False)
            return
        answered = parsed[0] == sdk.COMM_SUCCESS
        if self._doubted is not None and (behind or (prompt and answered)):
            self._hold, self._doubted = self._doubted, None
        if prompt and answered and not behind:
            self._seen_hold(request, now, True)

    def _parser(self, k: int, item: Item) -> Callable[[], Parsed]:
        """What parses the status of one servo's READ of ``item``."""

        def parse() -> Parsed:
            data, result, error = self.ph.readRx(self._pipe, self.ids[k], item.size)
            ok = result == sdk.COMM_SUCCESS and len(data) == item.size
            code = result if ok else sdk.COMM_RX_CORRUPT
            return code, ({k: bytes(data)} if ok else {}), error

        return parse

    def _parse_fast(self, group: sdk.GroupSyncRead, joints: tuple[int, ...]) -> Parsed:
        """A fast sync read's one status; one of another size (the late reply to a request
        given up, of another item: its status carries no item) is corrupt."""
        result = group.fastSyncReadRxPacket()
        if result != sdk.COMM_SUCCESS:
            return result, {}, 0
        data = {k: bytes(group.data_dict[self.ids[k]]) for k in joints}
        if any(len(d) != group.data_length for d in data.values()):
            return sdk.COMM_RX_CORRUPT, {}, 0
        return result, data, 0

    def _collect(self, now: float, prompt: bool = True) -> None:
        """Take every reply that has come and file it: state, health, error status, and
        which servos answered or missed (lost after ``lost_after`` misses in a row).
        ``prompt``: called as bytes arrive (not at a tick), so replies show the hold."""
        answered, got, missed = self._gather(now, prompt)
        for item, data in answered.items():
            self._apply(item, data)
        if got.any() or missed.any():
            back = self._account(got, got | missed)
            if self.torque_on and back.any():
                self._repower(back)

    def _gather(
        self, now: float, prompt: bool = True
    ) -> tuple[dict[Item, dict[int, bytes]], np.ndarray, np.ndarray]:
        """Parse every reply that has come, in the order owed; a request past its expiry is
        a miss for its servos (a failed sync read sends them to be read alone). Returns the
        data read of each item by joint, and which joints answered and which missed."""
        pipe = self._pipe
        pipe.receive()
        answered: dict[Item, dict[int, bytes]] = {}
        got = np.zeros(len(self.ids), bool)
        missed = np.zeros(len(self.ids), bool)
        states = (self.model.state, self.model.health)
        given_up = False
        while self._requests:
            request = self._requests[0]
            try:
                parsed = pipe.attempt(request.parse)
            except MISPARSE:  # bytes the SDK cannot make sense of: corrupt, dropped
                pipe.drop()
                parsed = (sdk.COMM_RX_CORRUPT, {}, 0)
            if parsed is None and now < self._expires(request):
                break
            self._requests.popleft()
            joints = list(request.joints)
            self.read_schedule.pending[joints] = False
            if self._frame:
                self._follow_hold(request, now, parsed, prompt, given_up)
                given_up |= parsed is None
            result, data, error = parsed or (sdk.COMM_RX_TIMEOUT, {}, 0)
            if result != sdk.COMM_SUCCESS:
                missed[joints] = True
                if len(joints) > 1:
                    self._alone[joints] = True
                continue
            answered.setdefault(request.item, {}).update(data)
            if request.item in states:
                self.read_schedule.read(request.joints, request.sent)
            got[joints] = True
            if self.model.protocol == 1:
                self.errors[joints] = error
            elif len(joints) == 1:
                self._alone[joints] = False
        if not self._requests:
            pipe.drop()
        missed &= ~got
        self.read_schedule.miss(missed)
        return answered, got, missed

    def _read_pipelined(self, item: Item, joints: list[int]) -> dict[int, bytes]:
        """READ ``item`` from each of ``joints`` behind an adapter, now: each sent as the bus
        frees, the replies taken as they come, so the adapter's hold is paid once, not once
        a servo (18 AX-18A behind a 16 ms timer: ~35 ms, not ~300); those whose reply
        missed are asked once more. Data by joint."""
        self._quiesce()
        out: dict[int, bytes] = {}
        todo = deque(joints)
        retried = False
        while todo or self._requests or not retried:
            if not todo and not self._requests:  # once more for those a reply missed
                retried = True
                todo.extend(k for k in joints if k not in out)
                continue
            now = time.monotonic()
            answered, _, _ = self._gather(now)
            out.update(answered.get(item, {}))
            if todo and now >= self._bus_free:
                k = todo.popleft()
                self.ph.readTx(self._pipe, self.ids[k], item.address, item.size)
                self._expect((k,), item, now, self._read_wire(item.size), self._parser(k, item))
                continue
            if not todo and not self._requests:
                continue
            until = self._bus_free if todo else self._expires(self._requests[0])
            select.select([self.port.ser.fd], [], [], max(until - now, 0.0))
        return out

    def _apply(self, item: Item, data: dict[int, bytes]) -> None:
        """Decode the blocks read of ``item`` (state, health or hardware error status)."""
        m = self.model
        idx = np.array(sorted(data))
        if item == m.hardware_error_status:
            self.errors[idx] = [data[k][0] for k in idx]
            return
        rows = np.frombuffer(b"".join(data[k] for k in idx), np.uint8).reshape(idx.size, -1)
        self._decode(rows, idx)
        if item == m.health:
            base = m.state.address
            self.voltage[idx] = little_endian(rows, m.voltage.address - base, m.voltage.size) / 10.0
            self.temperature[idx] = rows[:, m.temperature.address - base]

    def _quiesce(self) -> None:
        """Before a blocking exchange (torque, fault reset): take or give up every reply
        still owed, so a flush drops nothing anybody waits for."""
        while self._requests:
            now = time.monotonic()
            self._collect(now)
            if self._requests:
                wait = self._expires(self._requests[0]) - now
                select.select([self.port.ser.fd], [], [], max(wait, 0.0))

    def schedule(self) -> BusSchedule:
        """How the reads between ticks keep up (Health.bus); the plan made at open."""
        return self.read_schedule.report()

    def read_health(self) -> None:
        """A read cycle including voltage, temperature and error status (bring-up, tests)."""
        with self._device("health read"):
            self._quiesce()
            self._read_blocks(True)

    def _read_blocks(self, health: bool) -> None:
        """Read every servo now, waiting for each reply (bring-up, torque, a stepped loop)."""
        m = self.model
        start = time.monotonic()
        item = m.health if health else m.state
        want = ~self.lost | health  # lost servos are probed on health cycles only
        blocks = self._read_each(item, want) if m.protocol == 1 else self._read_sync(item, want)
        got = np.array([b is not None for b in blocks])
        if not (self._frame and m.protocol == 1):  # pipelined READs are stamped one by one
            self.read_schedule.read_all(got, start)
        back = self._account(got, want)
        if not got.any():
            return
        idx = np.flatnonzero(got)
        rows = np.frombuffer(b"".join(blocks[k] for k in idx), np.uint8).reshape(idx.size, -1)
        self._decode(rows, idx)
        if self.torque_on and back.any():
            self._repower(back)
        if health:
            base = m.state.address
            self.voltage[idx] = little_endian(rows, m.voltage.address - base, m.voltage.size) / 10.0
            self.temperature[idx] = rows[:, m.temperature.address - base]
            if m.protocol == 2:
                self._read_hardware_errors(idx)

    def _decode(self, rows: np.ndarray, idx: np.ndarray) -> None:
        m = self.model
        size = m.goal_position.size
        full = np.zeros(len(self.ids), np.int64)
        full[idx] = little_endian(rows, m.position_offset, size)
        self.position[idx] = self.map.position(full)[idx]
        full[idx] = little_endian(rows, m.velocity_offset, size)
        self.velocity[idx] = self.map.velocity(full)[idx]
        full[idx] = little_endian(rows, m.load_offset, 2)
        self.effort[idx] = self.map.effort(full)[idx]

    def _read_each(self, item: Item, want: np.ndarray) -> list[bytes | None]:
        """Protocol 1.0: one READ of the block per servo (pipelined behind an adapter);
        keeps the status error byte."""
        if self._frame:
            data = self._read_pipelined(item, np.flatnonzero(want).tolist())
            return [data.get(k) for k in range(len(self.ids))]
        out: list[bytes | None] = []
        for k, ident in enumerate(self.ids):
            if not want[k]:
                out.append(None)
                continue
            data, result, error = self._read_one(ident, item)
            if result == sdk.COMM_SUCCESS and len(data) == item.size:
                self.errors[k] = error
                out.append(bytes(data))
            else:
                out.append(None)
        return out

    def _group(self, item: Item, ids: tuple[int, ...]) -> sdk.GroupSyncRead:
        if ids != self._group_ids:
            self._groups.clear()
            self._group_ids = ids
        group = self._groups.get(item.size)
        if group is None:
            group = sdk.GroupSyncRead(self.port, self.ph, item.address, item.size)
            for ident in ids:
                group.addParam(ident)
            self._groups[item.size] = group
        return group

    def _sync_read(self, group: sdk.GroupSyncRead) -> int:
        try:
            return group.fastSyncRead() if self.fast_sync_read else group.txRxPacket()
        except MISPARSE:
            self.port.clearPort()
            return sdk.COMM_RX_CORRUPT

    def _read_one(self, ident: int, item: Item) -> tuple[list[int], int, int]:
        """One READ; a late reply the SDK misparses counts as a corrupt packet, not a fault."""
        try:
            return self.ph.readTxRx(self.port, ident, item.address, item.size)
        except MISPARSE:
            self.port.clearPort()
            return [], sdk.COMM_RX_CORRUPT, 0

    def _read_sync(self, item: Item, want: np.ndarray) -> list[bytes | None]:
        """Protocol 2.0: one (fast) sync read of the answering servos; on failure, each alone."""
        out: list[bytes | None] = [None] * len(self.ids)
        want_l, lost_l = want.tolist(), self.lost.tolist()  # lists: cheap to index one by one
        active = [k for k, w in enumerate(want_l) if w and not lost_l[k]]
        if active:
            group = self._group(item, tuple(self.ids[k] for k in active))
            if self._sync_read(group) == sdk.COMM_SUCCESS:
                for k in active:
                    out[k] = bytes(group.data_dict[self.ids[k]])
                active = []
        for k in range(len(self.ids)):
            if want_l[k] and (lost_l[k] or k in active):
                data, result, _ = self._read_one(self.ids[k], item)
                if result == sdk.COMM_SUCCESS and len(data) == item.size:
                    out[k] = bytes(data)
        return out

    def _read_hardware_errors(self, idx: np.ndarray) -> None:
        item = self.model.hardware_error_status
        ids = tuple(self.ids[k] for k in idx)
        group = sdk.GroupSyncRead(self.port, self.ph, item.address, item.size)
        for ident in ids:
            group.addParam(ident)
        if self._sync_read(group) == sdk.COMM_SUCCESS:
            for k in idx:
                self.errors[k] = group.data_dict[self.ids[k]][0]

    def _repower(self, back: np.ndarray) -> None:
        """Re-admitted servos may have been power-cycled (torque off): hold them where they are
        now (goal = present position, so nothing jumps), then torque on again."""
        ticks = self.map.goal_ticks(self.position)
        self._sync_write(self.model.goal_position, ticks, back)
        self._sync_write(self.model.torque_enable, np.ones(len(self.ids), np.int64), back)
        for k in np.flatnonzero(back):
            log.warning("%s: torque on again at its present position", self._where(k))

    def _account(self, got: np.ndarray, want: np.ndarray) -> np.ndarray:
        """Count ticks with misses in a row; mark lost after ``lost_after``; re-admit on an
        answer. Reads between ticks retry the oldest state at once, so a bus silent for a few
        ms (a starved host or emulator, a noise burst) would miss five in one tick: the count is
        of ticks, so a servo is lost after ``lost_after`` periods of silence, not ~12 ms.

        Returns the servos re-admitted by this read."""
        if got.all() and not self.lost.any():  # the usual cycle: every servo answered
            self.misses[:] = 0
            return ~got
        back = got & self.lost
        for k in np.flatnonzero(back):
            log.warning("%s: answers again, re-admitted", self._where(k))
        self.lost &= ~got
        self.misses[got] = 0
        missed = want & ~got
        counted = missed & (self._missed_in != self._tick)
        self.misses[counted] += 1
        self._missed_in[counted] = self._tick
        newly = missed & ~self.lost & (self.misses >= self.lost_after)
        for k in np.flatnonzero(newly):
            log.error("%s: lost after missed reads in %d ticks", self._where(k), self.misses[k])
        self.lost |= newly
        return back

    def write(self, command: JointCommand) -> None:
        """One sync write of goal positions (rad, profile order) to every servo not lost, the
        grippers' goals after the joints' (open or closed as ``command.grip`` says; without
        it, as the last command said, or where they are)."""
        q = np.asarray(command.position, float)
        if q.shape != (self.n_joints,):
            raise DriverError(
                f"{self._where()}: command has {q.size} positions, bus has {self.n_joints} joints"
            )
        if not np.all(np.isfinite(q)):
            bad = [self.names[k] for k in np.flatnonzero(~np.isfinite(q))]
            raise DriverError(f"{self._where()}: non-finite goal for {', '.join(bad)}")
        if self.gripper_legs:
            q = np.concatenate([q, self._grip_goals(command.grip)])
        with self._device("write"):
            wire = self._sync_write(self.model.goal_position, self.map.goal_ticks(q), ~self.lost)
        if self._served:  # the first request rides behind the goals: no reply stands between
            now = time.monotonic()
            self.read_schedule.error = np.abs(q - self.position)
            self.read_schedule.wrote(now)
            with self._device("read after write"):
                end = self._tick + 1.0 / self.profile.rate_hz - IDLE_MARGIN
                self._send_next(now, end, wire)

    def _grip_goals(self, grip: list[bool] | None) -> np.ndarray:
        """The grippers' goal angles (rad) for a command's per-leg ``grip`` flags."""
        if grip is not None:
            if len(grip) != len(self.profile.legs):
                raise DriverError(
                    f"{self._where()}: command has {len(grip)} grip flags, "
                    f"robot has {len(self.profile.legs)} legs"
                )
            self.gripping = np.array([grip[leg] for leg in self.gripper_legs], bool)
        if self.gripping is None:
            return self.position[self.n_joints :].copy()
        return np.where(self.gripping, self.grip_closed, self.grip_open)

    def torque(self, on: bool) -> None:
        """Torque on (goal = present position first, so nothing jumps) or off, all joints."""
        with self._device(f"torque {'on' if on else 'off'}"):
            self._quiesce()
            if on:
                self._read_blocks(False)
                ticks = self.map.goal_ticks(self.position)
                self._sync_write(self.model.goal_position, ticks, ~self.lost)
            self._sync_write(self.model.torque_enable, np.full(len(self.ids), int(on)), ~self.lost)
            self.torque_on = on
            refused = [
                f"id {self.ids[k]} ({self.names[k]})"
                for k, value in self._torque_enabled().items()
                if value != int(on)
            ]
            if self._served:  # the state read above is now as old as this exchange
                self._read_blocks(False)
            if refused:
                raise DriverError(
                    f"{self._where()}: torque {'on' if on else 'off'} refused by "
                    + ", ".join(refused)
                )

    def _torque_enabled(self) -> dict[int, int]:
        """Torque Enable of every servo not lost that answered, by joint."""
        item = self.model.torque_enable
        joints = np.flatnonzero(~self.lost).tolist()
        if self._frame:
            return {k: data[0] for k, data in self._read_pipelined(item, joints).items()}
        values = {}
        for k in joints:
            value, result, _ = self.ph.read1ByteTxRx(self.port, self.ids[k], item.address)
            if result == sdk.COMM_SUCCESS:
                values[k] = value
        return values

    def clear_faults(self) -> list[str]:
        """The operator's fault reset: bring back the servos a fault switched off; their names.

        Only servos whose torque is already off are touched, never one carrying the robot.
        An X-series servo with latched hardware errors gets a REBOOT (Protocol 2.0, 0x08): it
        is marked lost while it boots, and the read path re-admits it when it answers, holding
        it at its present position with torque on. Any other limp servo (an AX-18A's alarm
        shutdown) is held at its present position and torqued again at once."""
        m = self.model
        last = m.hardware_error_status or m.torque_enable
        span = Item(m.torque_enable.address, last.address + last.size - m.torque_enable.address)
        limp = np.zeros(len(self.ids), bool)
        latched = np.zeros(len(self.ids), bool)
        with self._device("fault reset"), self._patience():
            self._quiesce()
            for k, ident in enumerate(self.ids):
                if self.lost[k]:
                    continue
                for _ in range(3):
                    data, result, _ = self._read_one(ident, span)
                    if result == sdk.COMM_SUCCESS and len(data) == span.size:
                        break
                else:
                    log.warning("%s: no answer to the fault reset, not reset", self._where(k))
                    continue
                if data[0]:
                    continue
                limp[k] = True
                if m.hardware_error_status is not None and data[-1]:
                    latched[k] = True
                    self.errors[k] = data[-1]
            for k in np.flatnonzero(latched):
                self._reboot(k)
            if self.torque_on and (limp & ~latched).any():
                self._read_blocks(False)  # where the limp horns are now
                self._repower(limp & ~latched)
        return [self.names[k] for k in np.flatnonzero(limp)]

    @contextlib.contextmanager
    def _patience(self) -> Iterator[None]:
        """Wait long for replies: bring-up and the operator's reset are not time-critical."""
        self.port.margin_ms = max(self.timeout_margin_ms, BRING_UP_MARGIN_MS)
        try:
            yield
        finally:
            self.port.margin_ms = self.timeout_margin_ms

    def _reboot(self, k: int) -> None:
        """REBOOT servo ``k`` and count it lost until it has booted and answers again."""
        try:
            result = self.ph.reboot(self.port, self.ids[k])[0]
        except MISPARSE:
            self.port.clearPort()
            result = sdk.COMM_RX_CORRUPT
        log.warning(
            "%s: rebooted to clear %s (%s); re-admitted once it answers",
            self._where(k),
            ", ".join(error_names(self.model, int(self.errors[k]))) or "latched errors",
            self.ph.getTxRxResult(result),
        )
        self.lost[k] = True
        self.misses[k] = self.lost_after

    def health(self) -> list[JointHealth]:
        """Temperature, voltage, error bits (decoded) and lost flag of every joint."""
        return [
            JointHealth(
                name=name,
                temperature=float(self.temperature[k]),
                voltage=float(self.voltage[k]),
                error=int(self.errors[k]),
                errors=error_names(self.model, int(self.errors[k])),
                lost=bool(self.lost[k]),
            )
            for k, name in enumerate(self.names)
        ]

    @property
    def sent(self) -> int:
        """Bytes written to the port since open (a lock-step twin waits for them)."""
        return self.port.written if self.port is not None else 0

    def close(self) -> None:
        """Close the port (idempotent); torque is left as it is — the e-stop policy decides."""
        self._requests.clear()
        self._served = False
        if self.port is not None:
            with contextlib.suppress(Exception):
                self.port.closePort()
            self.port = None
