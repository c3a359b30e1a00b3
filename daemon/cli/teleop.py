"""``climbd teleop``: drive or override a robot from the keyboard or a timed script.

The client claims the robot's control session (``--override`` preempts autonomy or another
operator; the robot logs it), sends heartbeats at ``--heartbeat-hz`` from its own thread so
the robot holds if this client vanishes, repeats the current motion command at ``--rate``,
and releases the session on exit: the robot then holds, unless ``--handoff`` (or a script's
``release handoff``) hands it to autonomy. E-stop and reset wait for the robot's mode to
confirm them (``--timeout``), as ``climbd estop`` does. Stamps are this machine's monotonic
clock.

Script lines are ``<t> <verb> [args]``, ``t`` in seconds from start, ``#`` comments::

    0.0 claim            # or: claim override
    0.2 mode STAND       # STAND, ACTIVE, HOLD, OFF
    3.0 mode ACTIVE
    3.1 motion vx=0.05 yaw_rate=0.1
    6.0 stop             # zero motion
    6.5 estop reason     # engage the e-stop (no session needed), confirmed
    7.0 reset            # leave ESTOP/FAULT, confirmed
    8.0 release          # the robot holds; or: release handoff (to autonomy)
"""

from __future__ import annotations

import argparse
import os
import select
import socket
import sys
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from climbd.daemon.cli.client import add_credential_arguments, open_client
from climbd.daemon.cli.confirm import (
    DEFAULT_TIMEOUT,
    ModeWatch,
    Refused,
    Unconfirmed,
    engage,
    latched,
    reset,
)
from climbd.daemon.contract.messages import (
    EStop,
    Heartbeat,
    Mode,
    ModeRequest,
    ModeState,
    MotionCommand,
    OverrideClaim,
    ResetRequest,
    SessionClaim,
)
from climbd.daemon.runtime.network import Network

MOTION_FIELDS = ("vx", "vy", "yaw_rate", "body_height", "roll", "pitch")
KEYS = {
    "w": ("vx", +1),
    "s": ("vx", -1),
    "a": ("vy", +1),
    "d": ("vy", -1),
    "q": ("yaw_rate", +1),
    "e": ("yaw_rate", -1),
}
STEP = {"vx": 0.02, "vy": 0.02, "yaw_rate": 0.1}


class ScriptError(ValueError):
    """A script line that cannot be run; the message names file and line."""


@dataclass(frozen=True)
class Step:
    """One timed script command."""

    at: float
    verb: str
    args: tuple[str, ...]
    where: str


def parse_script(text: str, source: str = "<script>") -> list[Step]:
    """Parse a teleop script into time-ordered steps; errors name ``source:line``."""
    steps = []
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        where = f"{source}:{n}"
        words = line.split()
        if len(words) < 2:
            raise ScriptError(f"{where}: expected '<t> <verb> [args]', found {raw!r}")
        try:
            at = float(words[0])
        except ValueError:
            raise ScriptError(f"{where}: time {words[0]!r} is not a number of seconds") from None
        verb, args = words[1], tuple(words[2:])
        if verb == "motion":
            _motion_fields(args, where)
        elif verb == "mode":
            if len(args) != 1 or args[0].upper() not in Mode.__members__:
                raise ScriptError(f"{where}: mode takes one of STAND, ACTIVE, HOLD, OFF")
        elif verb == "claim":
            if args not in ((), ("override",)):
                raise ScriptError(f"{where}: claim takes nothing or 'override'")
        elif verb == "release":
            if args not in ((), ("handoff",)):
                raise ScriptError(f"{where}: release takes nothing or 'handoff'")
        elif verb not in ("stop", "estop", "reset", "wait"):
            raise ScriptError(
                f"{where}: unknown verb {verb!r} "
                "(claim, release, mode, motion, stop, estop, reset, wait)"
            )
        steps.append(Step(at, verb, args, where))
    return sorted(steps, key=lambda s: s.at)


def _motion_fields(args: tuple[str, ...], where: str) -> dict[str, float]:
    out = {}
    for a in args:
        name, _, value = a.partition("=")
        if name not in MOTION_FIELDS:
            raise ScriptError(
                f"{where}: motion field {name!r} unknown ({', '.join(MOTION_FIELDS)})"
            )
        try:
            out[name] = float(value)
        except ValueError:
            raise ScriptError(f"{where}: motion {name}={value!r} is not a number") from None
    return out


class TeleopClient:
    """A controlling session over a climbd Network: claim, heartbeats, motion, modes, release;
    e-stop and reset confirmed by the robot's mode (``endpoints`` name where, in errors)."""

    def __init__(
        self,
        net: Network,
        client: str,
        heartbeat_hz: float = 20.0,
        rate_hz: float = 20.0,
        endpoints: Sequence[str] = (),
        timeout: float = DEFAULT_TIMEOUT,
    ) -> None:
        self.net = net
        self.client = client
        self.session = uuid.uuid4().hex
        self.heartbeat_period = 1.0 / heartbeat_hz
        self.rate_period = 1.0 / rate_hz
        self.motion: dict[str, float] = {}
        self.watch = ModeWatch(net, endpoints, timeout)
        self.claimed = False
        self._pubs = {t: net.publisher(t) for t in (SessionClaim, Heartbeat, MotionCommand)}
        self._pubs[ModeRequest] = net.publisher(ModeRequest)
        self._pubs[EStop] = net.publisher(EStop)
        self._pubs[ResetRequest] = net.publisher(ResetRequest)
        self._pubs[OverrideClaim] = net.publisher(OverrideClaim)
        self._seq = 0
        self._next_beat = 0.0
        self._lock = threading.Lock()  # no heartbeat or motion may follow the release
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="teleop", daemon=True)

    @property
    def mode(self) -> ModeState | None:
        """The robot's mode as last heard, None before the first ModeState."""
        return self.watch.latest

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        """Heartbeats while claimed; the current motion command repeated at its rate."""
        next_motion = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            with self._lock:
                if self.claimed and now >= self._next_beat:
                    self._seq += 1
                    beat = Heartbeat(stamp=now, session=self.session, seq=self._seq)
                    self._pubs[Heartbeat].put(beat)
                    self._next_beat = now + self.heartbeat_period
                if self.claimed and self.motion and now >= next_motion:
                    self._send_motion(now)
                    next_motion = now + self.rate_period
                wake = min(self._next_beat, next_motion)
            self._stop.wait(min(self.heartbeat_period, max(0.0, wake - time.monotonic())))

    def _send_motion(self, now: float) -> None:
        self._pubs[MotionCommand].put(MotionCommand(stamp=now, session=self.session, **self.motion))

    def claim(self, override: bool = False) -> None:
        """Claim the session (``override`` on cmd/override, which needs that right); heartbeats
        follow one period later: the claim and the heartbeats leave on different publishers,
        and one sent at once could reach the robot first."""
        with self._lock:
            now = time.monotonic()
            if override:
                self._pubs[OverrideClaim].put(
                    OverrideClaim(stamp=now, session=self.session, client=self.client)
                )
            else:
                self._pubs[SessionClaim].put(
                    SessionClaim(stamp=now, session=self.session, client=self.client)
                )
            self.claimed = True
            self._next_beat = now + self.heartbeat_period

    def release(self, handoff: bool = False) -> bool:
        """Release the session: the robot holds, unless ``handoff`` hands it to autonomy.
        Returns whether a release was sent (False when nothing was claimed)."""
        with self._lock:
            if not self.claimed:
                return False
            self.claimed = False
            self.motion = {}
            self._pubs[SessionClaim].put(
                SessionClaim(
                    stamp=time.monotonic(),
                    session=self.session,
                    client=self.client,
                    release=True,
                    handoff=handoff,
                )
            )
            return True

    def set_motion(self, **fields: float) -> None:
        """Set (and send at once) the motion command repeated from now on; none means stop."""
        self.motion = dict(fields) if fields else {}
        self._send_motion(time.monotonic())

    def request(self, mode: Mode) -> None:
        self._pubs[ModeRequest].put(
            ModeRequest(stamp=time.monotonic(), session=self.session, mode=mode)
        )

    def reset(self) -> ModeState:
        """Reset a latched e-stop or fault as this session's holder and wait for the robot's mode
        to confirm it; raises confirm.Unconfirmed (no robot, refused, not in time)."""
        if not self.claimed:
            latched(self.watch)  # "nothing to reset" says more than "not claimed"
            raise Refused(
                f"refused: reset: {self.client} holds no session of {self.net.robot}: claim first"
            )

        def send() -> None:
            self._pubs[ResetRequest].put(ResetRequest(stamp=time.monotonic(), session=self.session))

        return reset(self.watch, send, self.session, self.client)

    def estop(self, reason: str = "teleop") -> ModeState:
        """Engage the e-stop, repeated until the robot's mode shows it latched by this client;
        raises confirm.Unconfirmed (no robot, refused, not in time)."""
        return engage(self.watch, self._pubs[EStop], self.client, reason)

    def close(self, handoff: bool = False) -> bool:
        """Release the session (the robot holds unless ``handoff``) and stop the heartbeats;
        returns whether a release was sent."""
        released = self.release(handoff)
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(1.0)
        return released

    def apply(self, step: Step) -> str:
        """Carry out one script step; returns the robot's confirmation of an e-stop or reset
        ("" for other steps). Raises confirm.Unconfirmed when the robot does not confirm."""
        verb, args = step.verb, step.args
        if verb == "claim":
            self.claim(override=args == ("override",))
        elif verb == "release":
            self.release(handoff=args == ("handoff",))
        elif verb == "mode":
            self.request(Mode[args[0].upper()])
        elif verb == "motion":
            self.set_motion(**_motion_fields(args, step.where))
        elif verb == "stop":
            self.set_motion()
        elif verb == "estop":
            return confirmed(self.estop(" ".join(args) or "teleop script"))
        elif verb == "reset":
            return confirmed(self.reset())
        return ""


def confirmed(state: ModeState) -> str:
    """How a confirmed e-stop or reset is reported: the robot's mode and reason."""
    return f"confirmed: {state.mode.value} ({state.reason})"


def run_script(client: TeleopClient, steps: list[Step]) -> None:
    """Run steps at their times (from now), printing each as it goes; an e-stop or reset the
    robot does not confirm ends the script (confirm.Unconfirmed)."""
    start = time.monotonic()
    for step in steps:
        delay = start + step.at - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        outcome = client.apply(step)
        line = f"{time.monotonic() - start:7.3f} s  {step.verb} {' '.join(step.args)}"
        print(f"{line}  {outcome}" if outcome else line, flush=True)


def confirm_key(action: Callable[[], ModeState], what: str) -> str:
    """The keyboard UI's line for an e-stop or reset key: confirmed, or why not."""
    try:
        return f"{what} {confirmed(action())}"
    except Unconfirmed as e:
        return f"{what} FAILED: {e}"


def run_keyboard(client: TeleopClient, override: bool) -> None:
    """The terminal UI: w/s a/d q/e change velocity, space stops, 1/2/3 STAND/ACTIVE/HOLD,
    x e-stop, r reset (each waits for the robot to confirm), Esc or Ctrl-C quits (releasing
    the session: the robot holds unless --handoff)."""
    import termios
    import tty

    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    motion = {"vx": 0.0, "vy": 0.0, "yaw_rate": 0.0}
    client.claim(override)
    print(__doc__.splitlines()[0] + "\r\n" + run_keyboard.__doc__.replace("\n", "\r\n") + "\r")
    try:
        tty.setcbreak(fd)
        while True:
            ready, _, _ = select.select([sys.stdin], [], [], 0.1)
            mode = client.mode.mode.value if client.mode else "?"
            reason = client.mode.reason if client.mode else ""
            sys.stdout.write(
                f"\r{mode:<6} vx {motion['vx']:+.2f} vy {motion['vy']:+.2f} "
                f"yaw {motion['yaw_rate']:+.2f}  {reason[:40]:<40}"
            )
            sys.stdout.flush()
            if not ready:
                continue
            key = sys.stdin.read(1)
            if key in ("\x1b", "\x03"):
                break
            if key in KEYS:
                name, sign = KEYS[key]
                motion[name] = round(motion[name] + sign * STEP[name], 3)
                client.set_motion(**motion)
            elif key == " ":
                motion = dict.fromkeys(motion, 0.0)
                client.set_motion(**motion)
            elif key in "123":
                client.request((Mode.STAND, Mode.ACTIVE, Mode.HOLD)[int(key) - 1])
            elif key == "x":
                print("\r\n" + confirm_key(lambda: client.estop("teleop keyboard"), "e-stop"))
            elif key == "r":
                print("\r\n" + confirm_key(client.reset, "reset"))
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)
        print()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", required=True, help="robot name (profile name)")
    parser.add_argument(
        "--connect", action="append", default=[], help="Zenoh endpoint of the robot (repeatable)"
    )
    parser.add_argument("--script", help="timed commands to run instead of the keyboard UI")
    parser.add_argument("--override", action="store_true", help="preempt the current session")
    parser.add_argument("--name", help="client name the robot logs (default: host:pid)")
    parser.add_argument("--rate", type=float, default=20.0, help="motion command rate (Hz)")
    parser.add_argument("--heartbeat-hz", type=float, default=20.0, help="heartbeat rate (Hz)")
    parser.add_argument(
        "--handoff",
        action="store_true",
        help="on exit, hand the robot to autonomy instead of holding it",
    )
    parser.add_argument(
        "--timeout",
        type=float,
        default=DEFAULT_TIMEOUT,
        help=f"seconds to wait for the robot to confirm an e-stop or reset ({DEFAULT_TIMEOUT:g})",
    )
    add_credential_arguments(parser)


def main(args: argparse.Namespace) -> int:
    import signal

    steps = None
    if args.script:
        try:
            steps = parse_script(Path(args.script).read_text(), args.script)
        except OSError as e:
            print(f"error: {args.script}: {e.strerror}", file=sys.stderr)
            return 2
        except ScriptError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
    elif not sys.stdin.isatty():
        print("error: no terminal for the keyboard UI; give --script FILE", file=sys.stderr)
        return 2
    net = open_client(args, args.robot, "teleop")
    if net is None:
        return 2
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    name = args.name or f"{socket.gethostname()}:{os.getpid()}"
    client = TeleopClient(
        net, name, args.heartbeat_hz, args.rate, endpoints=args.connect, timeout=args.timeout
    )
    client.start()
    try:
        time.sleep(0.3)  # let the session find the robot before the first claim
        if steps is not None:
            if args.override:
                steps = [
                    Step(s.at, s.verb, ("override",), s.where) if s.verb == "claim" else s
                    for s in steps
                ]
            run_script(client, steps)
        else:
            run_keyboard(client, args.override)
        return 0
    except Unconfirmed as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    finally:
        client.close(args.handoff)
        time.sleep(0.1)  # let the release leave before the session closes
        net.close()
