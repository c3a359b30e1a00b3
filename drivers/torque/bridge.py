"""The torque-leg driver in a process of its own: one datagram each way per control tick.

In CPython the MIT driver's wire is a third of a 1 kHz tick: a syscall and a frame to file
for each of 18 commands and 18 replies. A thread cannot take it off the tick (it waits on the
GIL while the tick computes, and its forced switches land in the tick), a process can. The
bridge runs ``MitJointBus`` on the CAN channels; the control role's ``BridgeJointBus`` sends
it each tick's command and takes back the state the motors answered it with, a tick later:

    python -m climbd.drivers.torque.bridge --profile robots/qingzhui.toml \\
        --listen 127.0.0.1:47170/127.0.0.1:47171
    climbd run robots/qingzhui.toml --driver torque-bridge --port 127.0.0.1:47171/127.0.0.1:47170

Torque on and off are requests the bridge answers once done. With no request for
``--watchdog`` s (the control role gone), the bridge applies the profile's e-stop policy: torque
off, or hold the last commanded pose (velocity zeroed, gains and feed-forward kept).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import select
import signal
import socket
import sys
import threading
import time

import can
import msgspec

from climbd.daemon.contract.hardware import DriverError
from climbd.daemon.contract.messages import EstopPolicy, JointCommand, JointHealth, JointState
from climbd.daemon.contract.profile import Profile, ProfileError, load
from climbd.drivers.torque.bus import MitJointBus, waiting_for_replies
from climbd.drivers.torque.config import TorqueConfig
from climbd.drivers.torque.links import udp_socket
from climbd.drivers.torque.mit import non_finite

log = logging.getLogger("climbd.torque.bridge")

WATCHDOG = 0.1
"""Seconds without a request before the bridge applies the e-stop policy: a hundred missed
ticks, past a collector's pause or a stalled host, short of a fall."""
REPLY_WAIT = 0.0008
"""Seconds the bridge waits for the motors' replies to a command (it returns once all are in)."""
OPEN_TIMEOUT = 1.0
"""Seconds the control role waits for the bridge's first report at open()."""
TORQUE_TIMEOUT = 0.5
"""Seconds the control role waits for torque on/off to be done."""
DATAGRAM = 65536


class Exchange(msgspec.Struct, tag="exchange"):
    """This tick's command (None: only report the state)."""

    command: JointCommand | None = None


class Torque(msgspec.Struct, tag="torque"):
    """Enter (on) or leave motor mode; answered by ``Done`` with the same ``seq``."""

    on: bool
    seq: int


class Report(msgspec.Struct, tag="report"):
    """The state the motors answered the last command with, their health, and what failed."""

    state: JointState
    health: list[JointHealth]
    error: str = ""


class Done(msgspec.Struct, tag="done"):
    seq: int
    error: str = ""


Request = Exchange | Torque
Answer = Report | Done


class Bridge:
    """Serves one ``MitJointBus`` to one control role over a UDP channel."""

    def __init__(self, bus: MitJointBus, channel: str, watchdog: float = WATCHDOG) -> None:
        self.bus = bus
        self.channel = channel
        self.watchdog = watchdog
        self.policy = bus.profile.safety.estop_policy
        self.sock = udp_socket(channel)
        self._requests = msgspec.msgpack.Decoder(Request)
        self._encode = msgspec.msgpack.Encoder().encode
        self._last: JointCommand | None = None
        self._state: JointState | None = None
        self.stop = threading.Event()
        self.safe = True
        """True while there is nothing to guard: before the first command after torque on (a
        control role's first tick may be slow), with torque off, and once the policy was
        applied for a silent control role."""
        self.tripped = ""
        """What the watchdog did, for the next report (whose command is not written: it comes
        from a control role that went silent and must hear of it first)."""

    def serve(self) -> None:
        """Answer requests until ``stop`` is set."""
        while not self.stop.is_set():
            if not select.select([self.sock], [], [], self.watchdog)[0]:
                if not self.safe:
                    self._control_role_gone()
                continue
            try:
                data = self.sock.recv(DATAGRAM)
            except ConnectionRefusedError:  # the control role's port closed: it went away
                continue
            try:
                request = self._requests.decode(data)
            except msgspec.DecodeError as e:
                log.warning("bridge %s: dropped a malformed request: %s", self.channel, e)
                continue
            self._send(self._answer(request))

    def _answer(self, request: Exchange | Torque) -> Report | Done:
        if isinstance(request, Torque):
            try:
                self.bus.torque(request.on)
            except DriverError as e:
                return Done(request.seq, str(e))
            self.safe = self.safe or not request.on  # armed by the first command, not by torque on
            return Done(request.seq)
        error, self.tripped = self.tripped, ""
        try:
            if request.command is not None and not error:
                self.bus.write(request.command)
                self._last = request.command
                self.safe = not self.bus.torque_on
            self._state = self.bus.read()
        except DriverError as e:
            error = str(e)
        state = self._state or JointState(names=self.bus.names)
        return Report(state=state, health=self.bus.health(), error=error)

    def _control_role_gone(self) -> None:
        """The e-stop policy, for a control role silent for ``watchdog`` s."""
        self.safe = True
        off = self.policy == EstopPolicy.TORQUE_OFF  # armed only after a command: _last is set
        self.tripped = (
            f"no request for {self.watchdog * 1e3:.0f} ms: "
            f"{'torque off' if off else 'holding the last commanded pose'}"
        )
        log.error("bridge %s: %s", self.channel, self.tripped)
        try:
            if off:
                self.bus.torque(False)
            else:
                self.bus.write(msgspec.structs.replace(self._last, velocity=None))
                self.bus.read()
        except DriverError as e:
            log.error("bridge %s: applying the e-stop policy failed: %s", self.channel, e)

    def _send(self, answer: Report | Done) -> None:
        # No control role listening, or its buffer full: the next answer is newer anyway.
        with contextlib.suppress(BlockingIOError, ConnectionRefusedError):
            self.sock.send(self._encode(answer))

    def close(self) -> None:
        self.sock.close()


class BridgeJointBus:
    """The control role's side: the ``JointBus`` of a torque bridge on ``port`` (its UDP
    channel, ``LOCAL_HOST:PORT/BRIDGE_HOST:PORT``)."""

    Config = TorqueConfig
    """The bridge serves torque legs: the torque driver's keys of ``[bus]``."""

    def __init__(self, profile: Profile, channel: str) -> None:
        self.profile = profile
        self.channel = channel
        self.names = [j.name for j in profile.joints]
        self.lost_after = profile.bus.lost_after
        self.sock: socket.socket | None = None
        self._answers = msgspec.msgpack.Decoder(Answer)
        self._encode = msgspec.msgpack.Encoder().encode
        self._report: Report | None = None
        self._error = ""
        """The first error a report carried since the last read (a newer report may follow)."""
        self._silent = 0
        """Reads since the last that found a new report."""
        self._written = False
        self._seq = 0
        self.late_reads = 0
        """Reads that found no report newer than the last (the state is then a tick older)."""

    @classmethod
    def from_profile(cls, profile: Profile, port: str | None = None) -> BridgeJointBus:
        if not port:
            raise DriverError("torque bridge: no channel (--port LOCAL_HOST:PORT/BRIDGE_HOST:PORT)")
        return cls(profile, port)

    def open(self) -> None:
        try:
            self.sock = udp_socket(self.channel)
        except (OSError, can.CanError) as e:
            raise DriverError(f"torque bridge channel {self.channel!r}: {e}") from e
        self._request(Exchange())
        deadline = time.monotonic() + OPEN_TIMEOUT
        while self._report is None and time.monotonic() < deadline:
            self._take(deadline - time.monotonic())
        if self._report is None:
            self.close()
            raise DriverError(
                f"no torque bridge answering on {self.channel} within {OPEN_TIMEOUT:.0f} s"
            )
        if self._report.state.names != self.names:
            names = self._report.state.names
            self.close()
            raise DriverError(
                f"torque bridge on {self.channel} serves joints {names}, "
                f"the profile has {self.names}"
            )

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None

    def torque(self, on: bool) -> None:
        self._seq += 1
        self._request(Torque(on, self._seq))
        deadline = time.monotonic() + TORQUE_TIMEOUT
        while (left := deadline - time.monotonic()) > 0:
            for done in self._take(left):
                if done.seq == self._seq:
                    if done.error:
                        raise DriverError(f"torque bridge on {self.channel}: {done.error}")
                    return
        raise DriverError(
            f"torque bridge on {self.channel}: torque {'on' if on else 'off'} not done "
            f"within {TORQUE_TIMEOUT * 1e3:.0f} ms"
        )

    def write(self, command: JointCommand) -> None:
        if len(command.position) != len(self.names):
            raise DriverError(
                f"command has {len(command.position)} positions, bus has {len(self.names)} joints"
            )
        c = command
        fields = [c.position, c.velocity or (), c.kp or (), c.kd or (), c.effort or ()]
        error = non_finite(fields, self.names)
        if error is not None:
            raise DriverError(f"torque joint bus: {error}")
        self._request(Exchange(command))
        self._written = True

    def read(self) -> JointState:
        if self.sock is None:
            raise DriverError("torque bridge: read before open()")
        self._silent += 1
        if not self._written:
            self._request(Exchange())
        self._written = False
        before = self._report
        self._take(0.0)
        error, self._error = self._error, ""
        if error:
            raise DriverError(f"torque bridge on {self.channel}: {error}")
        if self._report is before:
            self.late_reads += 1
        else:
            self._silent = 0
        return self._report.state

    def health(self) -> list[JointHealth]:
        health = self._report.health if self._report is not None else []
        if self._silent >= self.lost_after:
            return [msgspec.structs.replace(h, lost=True) for h in health]
        return health

    def _request(self, request: Exchange | Torque) -> None:
        try:
            self.sock.send(self._encode(request))
        except OSError as e:
            raise DriverError(f"torque bridge on {self.channel}: {e.strerror}") from e

    def _take(self, timeout: float) -> list[Done]:
        """Keep the newest report waiting (after up to ``timeout`` s for one) and the first
        error any carried; the ``Done``s."""
        done = []
        while True:
            try:
                data = self.sock.recv(DATAGRAM)
            except BlockingIOError:
                if timeout <= 0.0 or not select.select([self.sock], [], [], timeout)[0]:
                    return done
                timeout = 0.0
                continue
            except OSError as e:
                raise DriverError(f"torque bridge on {self.channel}: {e.strerror}") from e
            answer = self._answers.decode(data)
            if isinstance(answer, Done):
                done.append(answer)
            else:
                self._report = answer
                self._error = self._error or answer.error


def main(argv: list[str] | None = None) -> int:
    """Serve a profile's torque legs to one control role until SIGTERM/SIGINT."""
    parser = argparse.ArgumentParser(
        prog="python -m climbd.drivers.torque.bridge", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--profile", required=True, help="robot profile (robots/*.toml)")
    parser.add_argument("--listen", required=True, help="LOCAL_HOST:PORT/CONTROL_HOST:PORT")
    parser.add_argument("--interface", help="CAN interface (default: the profile's)")
    parser.add_argument("--channel", nargs="+", help="CAN channels (default: the profile's)")
    parser.add_argument(
        "--watchdog",
        type=float,
        default=WATCHDOG,
        help="s without a request before the e-stop policy",
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    try:
        profile = load(args.profile)
        if profile.bus.kind != "torque":
            raise ProfileError(f"{args.profile}: bus.kind is {profile.bus.kind!r}, not 'torque'")
        TorqueConfig.check(profile)
        bus = MitJointBus(waiting_for_replies(profile, REPLY_WAIT), args.channel, args.interface)
        bus.open()
    except (ProfileError, DriverError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    try:
        bridge = Bridge(bus, args.listen, args.watchdog)
    except (OSError, can.CanError) as e:
        bus.close()
        print(f"error: --listen {args.listen}: {e}", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda *_: bridge.stop.set())
    signal.signal(signal.SIGINT, lambda *_: bridge.stop.set())
    print(args.listen, flush=True)
    try:
        bridge.serve()
    finally:
        if bus.torque_on:
            bus.torque(False)
        bridge.close()
        bus.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
