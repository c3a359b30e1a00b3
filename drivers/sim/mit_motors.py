"""Emulated MIT-mode actuators answering CAN frames on a ``FrameLink`` (python-can's ``virtual``
bus in tests, ``udp_can`` between processes).

Each motor behaves as the firmware does: special frames enter/leave motor mode or zero the
encoder; every command frame is answered with the motor's state; commands act only in motor
mode. A built-in rigid-rotor model (inertia, viscous damping, torque limit) moves the motors
between frames unless an external model (the physics twin) sets their state instead:

    chain = MitMotorChain([1, 2, 3], ranges, channel="qz")   # serves in a thread
    chain.start()
    chain.motors[1].command          # last Command received (for the twin's actuator)
    chain.set_state(1, position=.., velocity=.., torque=..)  # from the twin, each step
    chain.silence(2); chain.corrupt(3); chain.bus_off()      # fault injection
    chain.stop()

``python -m climbd.drivers.sim.mit_motors --profile robots/qingzhui.toml --channel
127.0.0.1:47002/127.0.0.1:47001`` serves a profile's motors from a process of their own
(``udp_can`` by default, the driver on the reversed channel; any python-can interface with
``--interface``, e.g. ``socketcan --channel vcan0`` where there is vcan), so a driver is
measured without emulated motors taking its interpreter's time.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from dataclasses import dataclass, field

import can

from climbd.daemon.contract.profile import ProfileError, load
from climbd.drivers.torque.bus import joint_channels
from climbd.drivers.torque.config import ActuatorRanges, TorqueConfig
from climbd.drivers.torque.links import UDP_INTERFACE, FrameLink, open_link
from climbd.drivers.torque.mit import (
    CAN_ERR_BUSOFF,
    ENTER_MOTOR_MODE,
    EXIT_MOTOR_MODE,
    SET_ZERO,
    Command,
    Reply,
    pack_reply,
    unpack_command,
)


@dataclass
class EmulatedMotor:
    """One actuator: state at the output shaft (SI), mode, last command, injected faults."""

    motor: int
    position: float = 0.0
    velocity: float = 0.0
    torque: float = 0.0
    inertia: float = 0.02
    damping: float = 0.05
    load: float = 0.0
    motor_mode: bool = False
    command: Command | None = None
    silent: bool = False
    corrupt: bool = False
    frames: int = 0
    last_step: float | None = field(default=None, repr=False)

    def step(self, dt: float, limit: float) -> None:
        """Advance the built-in rotor model by ``dt`` under the impedance law."""
        c = self.command
        tau = 0.0
        if self.motor_mode and c is not None:
            tau = c.kp * (c.position - self.position) + c.kd * (c.velocity - self.velocity)
            tau = max(-limit, min(limit, tau + c.torque))
        self.torque = tau
        n = max(1, int(dt / 2e-4))
        h = dt / n
        for _ in range(n):
            acc = (tau - self.damping * self.velocity - self.load) / self.inertia
            self.velocity += acc * h
            self.position += self.velocity * h


class MitMotorChain:
    """A set of emulated MIT-mode motors on one CAN channel, served by a background thread."""

    def __init__(
        self,
        motors: list[int],
        ranges: ActuatorRanges,
        channel: str,
        interface: str = "virtual",
        master_id: int = 0,
        external_model: bool = False,
    ) -> None:
        self.ranges = ranges
        self.channel = channel
        self.interface = interface
        self.master_id = master_id
        self.external_model = external_model
        self.motors = {m: EmulatedMotor(m) for m in motors}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._link: FrameLink | None = None

    def start(self) -> MitMotorChain:
        self._link = open_link(self.interface, self.channel)
        self._thread = threading.Thread(target=self._serve, name=f"mit-{self.channel}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2)
        if self._link is not None:
            self._link.close()

    # --- in-process API for the twin and tests ----------------------------------------

    def set_state(self, motor: int, position: float, velocity: float, torque: float) -> None:
        """Set a motor's measured state from an external model (the physics twin)."""
        with self._lock:
            m = self.motors[motor]
            m.position, m.velocity, m.torque = position, velocity, torque

    def silence(self, motor: int, silent: bool = True) -> None:
        """The motor stops (or resumes) answering."""
        self.motors[motor].silent = silent

    def corrupt(self, motor: int, corrupt: bool = True) -> None:
        """The motor answers with a truncated (5-byte) reply."""
        self.motors[motor].corrupt = corrupt

    def bus_off(self) -> None:
        """Put an error frame with the bus-off class on the bus, as a SocketCAN controller does."""
        self._link.send_error(CAN_ERR_BUSOFF)

    # --- the wire ---------------------------------------------------------------------

    def _serve(self) -> None:
        """Answer the frames waiting, all at once, as motors on one bus answer in turn."""
        link = self._link
        while not self._stop.is_set():
            try:
                replies = []
                for frame in link.receive(0.05):
                    m = None if frame.error else self.motors.get(frame.can_id)
                    reply = None if m is None else self._handle(m, frame.data)
                    if reply is not None:
                        replies.append(reply)
                link.send([self.master_id] * len(replies), replies)
            except can.CanOperationError:  # a udp_can driver that went away: wait for the next
                continue

    def _handle(self, m: EmulatedMotor, data: bytes) -> bytes | None:
        now = time.monotonic()
        with self._lock:
            if not self.external_model and m.last_step is not None:
                m.step(min(now - m.last_step, 0.05), self.ranges.torque)
            m.last_step = now
            known = True
            if data == ENTER_MOTOR_MODE:
                m.motor_mode = True
            elif data == EXIT_MOTOR_MODE:
                m.motor_mode = False
                m.command = None
            elif data == SET_ZERO:
                m.position = 0.0
            elif len(data) == 8:
                command = unpack_command(data, self.ranges)
                if m.motor_mode:
                    m.command = command
            else:
                known = False
            reply = pack_reply(Reply(m.motor, m.position, m.velocity, m.torque), self.ranges)
            m.frames += 1  # last: a counted frame's command and reply are both settled
        if not known or m.silent:
            return None
        return reply[:5] if m.corrupt else reply


def main(argv: list[str] | None = None) -> int:
    """Serve a profile's motors on its CAN channels until SIGTERM/SIGINT; the channels' names
    on stdout once they answer."""
    parser = argparse.ArgumentParser(
        prog="python -m climbd.drivers.sim.mit_motors", description=__doc__
    )
    parser.add_argument("--profile", required=True, help="robot profile (robots/*.toml)")
    parser.add_argument(
        "--channel",
        nargs="+",
        required=True,
        help="CAN channels (LOCAL/PEER UDP endpoints, vcan0 ...): leg i's motors on channel "
        "i mod n",
    )
    parser.add_argument(
        "--interface", default=UDP_INTERFACE, help=f"{UDP_INTERFACE} or a python-can interface"
    )
    args = parser.parse_args(argv)
    chains: list[MitMotorChain] = []
    try:
        profile = load(args.profile)
        bus = TorqueConfig.from_profile(profile)
        placed = joint_channels(profile, args.channel)
        for channel in args.channel:
            ids = [j.id for j, c in zip(profile.joints, placed, strict=True) if c == channel]
            chain = MitMotorChain(ids, bus.actuator, channel, args.interface, bus.master_id)
            chains.append(chain.start())
    except (ProfileError, can.CanError, OSError, ValueError) as e:
        for chain in chains:
            chain.stop()
        print(f"error: {e}", file=sys.stderr)
        return 2
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    print(" ".join(args.channel), flush=True)
    done.wait()
    for chain in chains:
        chain.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
