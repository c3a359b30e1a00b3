"""Confirmation of an operator's e-stop and reset by the robot's own mode (issue #33).

Nothing counts as done until the robot says so: an operator tool watches the robot's ModeState
(``state/mode``, on change and at 2 Hz) for ESTOP naming its source in ``estop_by``, or for a
mode out of ESTOP/FAULT naming its session in ``reset_by``. Otherwise it raises an Unconfirmed
naming what happened: no robot answered, the robot refused (its mode unchanged, with its
reason), or nothing was confirmed within the timeout. ``climbd estop`` and ``TeleopClient``
(daemon/cli/teleop.py) share it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

from climbd.daemon.contract.messages import EStop, Health, Mode, ModeState
from climbd.daemon.runtime.network import Network, Publisher

REPEAT_HZ = 10.0
"""Rate the e-stop is repeated at until the robot confirms it."""

DEFAULT_TIMEOUT = 2.0
"""Seconds to wait for the robot's confirmation (four of its 2 Hz ModeState messages)."""

CONNECT_PROBE = 1.0
"""Seconds after which a session connected to no peer at all means nothing listens there."""

LATCHED = (Mode.ESTOP, Mode.FAULT)


class Unconfirmed(RuntimeError):
    """An e-stop or reset the robot did not confirm; the message says what happened."""


class NoRobot(Unconfirmed):
    """Nothing was heard from the robot at all: wrong endpoint, wrong name, or no daemon."""


class Refused(Unconfirmed):
    """The robot answered but its mode did not change as asked; the message gives its reason."""


class NotConfirmed(Unconfirmed):
    """The robot answered, but not with this command's confirmation in time."""


def engaged_by(source: str) -> Callable[[ModeState], bool]:
    """Whether a ModeState shows the e-stop latched with ``source`` among its engagers."""
    return lambda state: state.mode == Mode.ESTOP and source in state.estop_by


def reset_by(session: str) -> Callable[[ModeState], bool]:
    """Whether a ModeState shows ESTOP/FAULT left by a reset of ``session``."""
    return lambda state: state.mode not in LATCHED and state.reset_by == session


class ModeWatch:
    """The robot's mode as an operator tool hears it (ModeState), with the control session's
    holder (Health), to wait for a confirmation and to say why none came."""

    def __init__(
        self, net: Network, endpoints: Sequence[str], timeout: float = DEFAULT_TIMEOUT
    ) -> None:
        self.net = net
        self.robot = net.robot
        self.endpoints = list(endpoints)
        self.timeout = timeout
        self.latest: ModeState | None = None
        self.heard_at = 0.0
        self.holder = ""
        self._news = threading.Event()
        self._lock = threading.Lock()
        net.subscribe(ModeState, self._on_mode)
        net.subscribe(Health, self._on_health)

    def _on_mode(self, state: ModeState) -> None:
        """Record the newest mode (on Zenoh's thread) and wake a waiter."""
        with self._lock:
            self.latest, self.heard_at = state, time.monotonic()
        self._news.set()

    def _on_health(self, health: Health) -> None:
        """Record who holds the control session (only its holder may reset) and wake a waiter."""
        if health.role == "control":
            self.holder = health.session
            self._news.set()

    def _connected(self) -> bool:
        """Whether this session reached any peer or router at all."""
        info = self.net.session.info
        return bool(list(info.peers_zid()) or list(info.routers_zid()))

    def wait(
        self,
        done: Callable[[ModeState], bool],
        deadline: float,
        what: str,
        resend: Callable[[], None] | None = None,
    ) -> ModeState:
        """The first ModeState for which ``done`` holds, before ``deadline`` (monotonic s);
        ``resend`` is repeated at REPEAT_HZ meanwhile. Raises an Unconfirmed naming ``what``.
        A session that reached no peer within CONNECT_PROBE fails at once: nothing listens."""
        start = time.monotonic()
        probe, next_send = start + CONNECT_PROBE, start
        before = self.latest
        while (now := time.monotonic()) < deadline:
            self._news.clear()
            state = self.latest
            before = before or state
            if state is not None and done(state):
                return state
            if state is None and now >= probe and not self._connected():
                raise NoRobot(f"no robot {self.robot} answered on {self._where()}: no connection")
            wake = deadline if now >= probe else min(deadline, probe)
            if resend is not None:
                if now >= next_send:
                    resend()
                    next_send = now + 1.0 / REPEAT_HZ
                wake = min(wake, next_send)
            self._news.wait(max(0.0, wake - now))
        state = self.latest
        if state is not None and done(state):
            return state
        raise self.failure(what, start, before)

    def wait_holder(self, client: str, deadline: float, what: str) -> None:
        """Wait for the robot's Health to show ``client`` holding the control session: a reset
        sent with the claim may overtake it and be refused. Raises Refused naming the holder
        when another one keeps it, NotConfirmed when no Health shows ``client`` in time."""
        while self.holder != client and (now := time.monotonic()) < deadline:
            self._news.clear()
            if self.holder != client:
                self._news.wait(deadline - now)
        if self.holder == client:
            return
        if self.holder:
            raise Refused(
                f"refused: {what}: {self.robot}{self._stays()}; session held by {self.holder}"
            )
        raise NotConfirmed(
            f"{what} not confirmed within {self.timeout:g} s: {self.robot} never showed "
            f"{client} holding its session"
        )

    def _stays(self) -> str:
        """ " stays in MODE (reason)" of the mode last heard, "" before any."""
        state = self.latest
        return f" stays in {state.mode.value} ({state.reason})" if state is not None else ""

    def failure(self, what: str, sent_at: float, before: ModeState | None) -> Unconfirmed:
        """Why ``what`` (sent at ``sent_at``, the robot then in ``before``) was not confirmed:
        no robot, refused (mode unchanged), or not in time, with the robot's mode and reason."""
        with self._lock:
            last, heard_at = self.latest, self.heard_at
        timeout = self.timeout
        if last is None:
            return NoRobot(
                f"no robot {self.robot} answered on {self._where()} within {timeout:g} s"
                f"{self._others()}"
            )
        mode = f"{last.mode.value} ({last.reason})"
        if heard_at < sent_at:
            return NotConfirmed(
                f"{what} not confirmed within {timeout:g} s: {self.robot} went silent, "
                f"last heard in {mode}"
            )
        if before is not None and last.mode != before.mode:
            return NotConfirmed(
                f"{what} not confirmed within {timeout:g} s: {self.robot} is in {mode}"
            )
        return Refused(f"refused: {what}: {self.robot} stays in {mode}")

    def _where(self) -> str:
        return ", ".join(self.endpoints) or "this network (no --connect endpoint)"

    def _others(self) -> str:
        """The robots that do answer there, which names a misspelt robot."""
        others = sorted({robot for robot, _ in self.net.alive_roles("*", timeout=0.5)})
        return f" (robots there: {', '.join(others)})" if others else ""


def engage(watch: ModeWatch, pub: Publisher, source: str, reason: str) -> ModeState:
    """Engage the e-stop, repeated at REPEAT_HZ until the robot's mode confirms it is latched
    by ``source``; returns that ModeState or raises Unconfirmed."""

    def send() -> None:
        pub.put(EStop(stamp=time.monotonic(), engage=True, source=source, reason=reason))

    deadline = time.monotonic() + watch.timeout
    return watch.wait(engaged_by(source), deadline, "e-stop", resend=send)


def latched(watch: ModeWatch) -> ModeState:
    """The robot's mode once heard, when it is ESTOP or FAULT; else Refused: nothing to reset
    (a reset tool must not claim, and on release hold, a robot that needs none)."""
    state = watch.wait(lambda _: True, time.monotonic() + watch.timeout, "reset")
    if state.mode not in LATCHED:
        raise Refused(
            f"refused: nothing to reset: {watch.robot} is in {state.mode.value} ({state.reason})"
        )
    return state


def reset(watch: ModeWatch, send: Callable[[], None], session: str, holder: str) -> ModeState:
    """Reset a latched robot as ``holder`` of ``session``: once the robot shows it holding the
    session, ``send`` the reset and wait for the mode to confirm it; returns that ModeState or
    raises Unconfirmed."""
    latched(watch)
    deadline = time.monotonic() + watch.timeout
    watch.wait_holder(holder, deadline, "reset")
    send()
    try:
        return watch.wait(reset_by(session), deadline, "reset")
    except Refused as e:
        if watch.holder in ("", holder):
            raise
        raise Refused(f"{e}; session held by {watch.holder}") from None
