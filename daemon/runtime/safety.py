"""Modes, e-stop, teleop sessions with heartbeats, and servo-health policy
(docs/architecture.md, Safety).

A pure state machine: every method takes the current time, nothing here reads a clock or
touches a device. The control tick asks it what to do; the bus feeds it requests.

Modes: OFF → STAND → ACTIVE ⇄ HOLD; any → ESTOP (engaged by anyone authorised, left only
by an explicit reset) and any → FAULT (a device or health fault, left only by a reset).
Releasing the session means HOLD, unless its holder hands the robot to autonomy.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field

from climbd.daemon.contract.messages import EstopPolicy, JointHealth, JointState, Mode, ModeState
from climbd.daemon.contract.profile import Profile

log = logging.getLogger("climbd.safety")

_ALLOWED: dict[Mode, set[Mode]] = {
    Mode.OFF: {Mode.STAND},
    Mode.STAND: {Mode.ACTIVE, Mode.HOLD, Mode.OFF},
    Mode.ACTIVE: {Mode.HOLD},
    Mode.HOLD: {Mode.STAND, Mode.ACTIVE, Mode.OFF},
    Mode.ESTOP: set(),
    Mode.FAULT: set(),
}

DERATE_SCALE = 0.5

MAX_ESTOP_SOURCES = 8
"""Sources of one e-stop latch kept for ModeState.estop_by (the newest): a flood of e-stops
from many sources cannot grow the mode message."""

MAX_HEARTBEAT_SESSIONS = 64
"""Sessions whose last accepted heartbeat (seq, stamp) is remembered (the most recently beating
ones): a session claimed again after it lapsed keeps its watermark, so its captured heartbeats
stay refused."""

REFUSAL_LOG_PERIOD = 5.0
"""Seconds between log lines about refused heartbeats (the others are only counted)."""


@dataclass
class Beat:
    """The last heartbeat accepted for a session: its sequence number and sender stamp."""

    seq: int
    stamp: float


@dataclass
class Session:
    """The controlling teleop/override session and when its holder was last heard."""

    session: str
    client: str
    last_heartbeat: float
    override: bool = False


@dataclass
class Transition:
    """A mode change, for logs and the ModeState topic."""

    mode: Mode
    previous: Mode
    reason: str
    at: float


@dataclass
class Safety:
    """The safety supervisor of one robot: mode, e-stop, session, health verdicts."""

    profile: Profile
    mode: Mode = Mode.OFF
    reason: str = "start"
    session: Session | None = None
    refused: int = 0
    refused_heartbeats: int = 0
    speed_scale: float = 1.0
    torque_on: bool = False
    estop_by: list[str] = field(default_factory=list)
    reset_by: str = ""
    history: list[Transition] = field(default_factory=list)
    _beats: dict[str, Beat] = field(default_factory=dict, repr=False)
    _refusal_logged: float = field(default=-1e9, repr=False)
    _lock: threading.RLock = field(default_factory=threading.RLock, repr=False)

    @property
    def policy(self) -> EstopPolicy:
        return self.profile.safety.estop_policy

    def _enter(self, mode: Mode, reason: str, now: float) -> None:
        if mode == self.mode:
            return
        t = Transition(mode, self.mode, reason, now)
        self.history.append(t)
        del self.history[:-100]
        log.log(
            logging.WARNING if mode in (Mode.ESTOP, Mode.FAULT) else logging.INFO,
            "mode %s → %s: %s",
            self.mode.value,
            mode.value,
            reason,
        )
        self.mode, self.reason = mode, reason
        if mode in (Mode.ESTOP, Mode.FAULT):
            self.reset_by = ""
        if mode != Mode.ESTOP:
            self.estop_by = []

    def mode_state(self, now: float) -> ModeState:
        """The ModeState to publish: mode, reason, and who engaged or reset the latch, so an
        operator tool can confirm its own e-stop or reset."""
        with self._lock:
            return ModeState(
                stamp=now,
                mode=self.mode,
                reason=self.reason,
                estop_by=list(self.estop_by),
                reset_by=self.reset_by,
            )

    # --- requests ---------------------------------------------------------------------

    def request(self, mode: Mode, now: float, session: str | None = None, reason: str = "") -> bool:
        """A mode request; ``session=None`` is local (the daemon itself), else it must hold it."""
        with self._lock:
            if session is not None and not self.accepts(session):
                return False
            if mode == self.mode:
                return True
            if mode not in _ALLOWED[self.mode]:
                log.warning("refused mode request %s → %s", self.mode.value, mode.value)
                return False
            self._enter(mode, reason or f"requested by {session or 'daemon'}", now)
            return True

    def estop(self, now: float, source: str, reason: str = "") -> None:
        """Engage the e-stop: from any mode, at once; only ``reset`` leaves it. Each source is
        named in ``estop_by`` (also one engaging an e-stop already latched), so it can confirm."""
        source = source or "unknown"
        with self._lock:
            self._enter(Mode.ESTOP, f"e-stop by {source}: {reason}".rstrip(": "), now)
            if source not in self.estop_by:
                if self.estop_by:
                    log.warning("e-stop also engaged by %s: %s", source, reason)
                self.estop_by = [*self.estop_by, source][-MAX_ESTOP_SOURCES:]

    def fault(self, now: float, reason: str) -> None:
        """A device or health fault: FAULT applies the e-stop policy and needs a reset."""
        with self._lock:
            if self.mode != Mode.ESTOP:
                self._enter(Mode.FAULT, reason, now)

    def hold(self, now: float, reason: str) -> None:
        """Freeze at the commanded pose (from STAND or ACTIVE); other modes are left alone."""
        with self._lock:
            if self.mode in (Mode.STAND, Mode.ACTIVE):
                self._enter(Mode.HOLD, reason, now)

    def reset(self, now: float, session: str | None = None) -> bool:
        """Leave ESTOP/FAULT explicitly: to HOLD when the joints are powered, else OFF."""
        with self._lock:
            if session is not None and not self.accepts(session):
                return False
            if self.mode not in (Mode.ESTOP, Mode.FAULT):
                return False
            target = Mode.HOLD if self.torque_on else Mode.OFF
            self._enter(target, f"reset by {session or 'daemon'}", now)
            self.reset_by = session or "daemon"
            return True

    # --- sessions ---------------------------------------------------------------------

    def claim(
        self, session: str, client: str, now: float, override: bool = False
    ) -> tuple[bool, str]:
        """Claim the controlling session: free, expired, or taken over with ``override``."""
        with self._lock:
            held = self.session
            taken = held is not None and held.session != session
            if taken and not override and not self._expired(held, now):
                self.refused += 1
                return False, f"session held by {held.client}"
            if held is not None and held.session != session:
                log.warning("session of %s preempted by %s", held.client, client)
            self.session = Session(session, client, now, override)
            return True, "claimed"

    def release(self, session: str, now: float, handoff: bool = False) -> bool:
        """Release the session held by ``session``: the robot holds (release means hold), unless
        ``handoff`` hands it to autonomy, which is logged and named in the mode's reason. Returns
        whether ``session`` held it (another session's release changes nothing)."""
        with self._lock:
            held = self.session
            if held is None or held.session != session:
                return False
            self.session = None
            if not handoff:
                self.hold(now, f"session of {held.client} released")
                return True
            log.warning(
                "session of %s released: robot handed to autonomy in %s",
                held.client,
                self.mode.value,
            )
            if self.mode == Mode.ACTIVE:
                self.reason = f"handed to autonomy by {held.client}"
            return True

    def heartbeat(self, session: str, now: float, seq: int, stamp: float) -> bool:
        """Renew the session's heartbeat if its ``seq`` and sender ``stamp`` both advanced past
        the last accepted for that session: a replayed or stale one is refused and counted, so a
        captured heartbeat cannot keep the dead-man alive. Another session's is ignored, not
        counted: heartbeats are express and overtake a claim or release sent around them."""
        with self._lock:
            held = self.session
            if held is None or held.session != session:
                return False
            last = self._beats.get(session)
            if last is not None and (seq <= last.seq or stamp <= last.stamp):
                self._refuse_heartbeat(held, seq, stamp, last, now)
                return False
            self._beats.pop(session, None)
            self._beats[session] = Beat(seq, stamp)
            while len(self._beats) > MAX_HEARTBEAT_SESSIONS:
                del self._beats[next(iter(self._beats))]
            held.last_heartbeat = now
            return True

    def _refuse_heartbeat(
        self, held: Session, seq: int, stamp: float, last: Beat, now: float
    ) -> None:
        """Count a replayed or stale heartbeat; log it at most every REFUSAL_LOG_PERIOD."""
        self.refused_heartbeats += 1
        if now - self._refusal_logged < REFUSAL_LOG_PERIOD:
            return
        self._refusal_logged = now
        log.warning(
            "refused heartbeat of session %s (%s): seq %d stamp %.3f not after seq %d stamp %.3f "
            "(replayed or stale; %d refused so far, more only counted for %.0f s)",
            held.session,
            held.client,
            seq,
            stamp,
            last.seq,
            last.stamp,
            self.refused_heartbeats,
            REFUSAL_LOG_PERIOD,
        )

    def accepts(self, session: str) -> bool:
        """Whether a command from ``session`` may act; a refusal is counted."""
        with self._lock:
            if self.session is not None and self.session.session == session:
                return True
            self.refused += 1
            return False

    def _expired(self, held: Session, now: float) -> bool:
        return now - held.last_heartbeat > self.profile.safety.heartbeat_window

    def check_heartbeat(self, now: float) -> None:
        """A session whose heartbeat is older than the profile's window puts the robot in HOLD."""
        with self._lock:
            held = self.session
            if held is None or not self._expired(held, now):
                return
            self.session = None
            self.hold(now, f"heartbeat of {held.client} lost")

    # --- health -----------------------------------------------------------------------

    def check_state_age(self, state: JointState, now: float) -> None:
        """A joint whose state is older than the profile's bound is a fault (the e-stop
        policy applies): the legs would move on where a joint was, not where it is. Lost
        joints (age NaN) are the health policy's; a robot not on its legs has nothing to fault."""
        if self.mode not in (Mode.STAND, Mode.ACTIVE, Mode.HOLD) or not state.age:
            return
        bound = self.profile.bus.max_state_age
        stale = [(n, a) for n, a in zip(state.names, state.age, strict=False) if a > bound]
        if stale:
            old = ", ".join(f"{n} {a * 1e3:.0f} ms" for n, a in stale)
            self.fault(now, f"joint state older than {bound * 1e3:.0f} ms: {old}")

    def judge(self, joints: list[JointHealth], now: float) -> None:
        """Apply the profile's health policy: lost/voltage → HOLD, derate, overheat → FAULT."""
        s = self.profile.safety
        hot = [j.name for j in joints if j.temperature >= s.max_temperature]
        warm = [j for j in joints if j.temperature >= s.derate_temperature]
        lost = [j.name for j in joints if j.lost]
        volts = [
            j.name
            for j in joints
            if j.voltage == j.voltage and not s.min_voltage <= j.voltage <= s.max_voltage
        ]
        overload = [j.name for j in joints if "overload" in j.errors]
        for j in warm:
            j.derated = True
        self.speed_scale = DERATE_SCALE if warm else 1.0
        if hot:
            self.fault(now, f"overheat ≥ {s.max_temperature} °C: {', '.join(hot)}")
        elif lost:
            self.hold(now, f"servo lost: {', '.join(lost)}")
        elif overload:
            self.hold(now, f"overload: {', '.join(overload)}")
        elif volts:
            self.hold(now, f"voltage outside {s.min_voltage}–{s.max_voltage} V: {', '.join(volts)}")
