"""Modes, e-stop, teleop sessions with heartbeats, and servo-health policy
(docs/architecture.md, Safety).

A pure state machine: every method takes the current time, nothing here reads a clock or
touches a device. The control tick asks it what to do; the bus feeds it requests.

Modes: OFF → STAND → ACTIVE ⇄ HOLD; any → ESTOP (engaged by anyone authorised, left only
by an explicit reset) and any → FAULT (a device or health fault, left only by a reset).
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field

from climbd.daemon.contract.messages import EstopPolicy, JointHealth, Mode
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
    speed_scale: float = 1.0
    torque_on: bool = False
    history: list[Transition] = field(default_factory=list)
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
        """Engage the e-stop: from any mode, at once; only ``reset`` leaves it."""
        with self._lock:
            self._enter(Mode.ESTOP, f"e-stop by {source or 'unknown'}: {reason}".rstrip(": "), now)

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

    def release(self, session: str) -> None:
        with self._lock:
            if self.session is not None and self.session.session == session:
                self.session = None

    def heartbeat(self, session: str, now: float) -> bool:
        """Renew the session's heartbeat. Another session's is ignored, not counted as refused:
        heartbeats are express and overtake a claim or release sent just before or after them."""
        with self._lock:
            if self.session is None or self.session.session != session:
                return False
            self.session.last_heartbeat = now
            return True

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
