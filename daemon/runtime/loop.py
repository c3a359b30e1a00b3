"""Fixed-rate control loop with absolute deadlines, a pluggable clock and timing statistics.

Deadlines are ``start + k * period``: a late tick never shifts the ones after it (no drift).
A tick that finds its deadline already a whole period gone counts an overrun and the
schedule skips ahead instead of bursting to catch up. The clock is a parameter: a real-time
clock in production, a stepped clock for deterministic tests and lock-step simulation.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import threading
import time
from collections.abc import Callable
from typing import Protocol

import numpy as np

from climbd.daemon.contract.messages import LoopStats


class Clock(Protocol):
    """Time source of the loop (s): ``now`` and a blocking ``sleep_until`` an absolute time."""

    def now(self) -> float: ...

    def sleep_until(self, deadline: float) -> None: ...


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


_CLOCK_MONOTONIC = 1
_TIMER_ABSTIME = 1


def _load_clock_nanosleep() -> Callable | None:
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        fn = ctypes.CDLL(name, use_errno=True).clock_nanosleep
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.POINTER(_Timespec), ctypes.c_void_p]
    fn.restype = ctypes.c_int
    return fn


class MonotonicClock:
    """CLOCK_MONOTONIC with absolute-deadline sleeps via ``clock_nanosleep(TIMER_ABSTIME)``.

    The same call a C real-time loop makes; ctypes releases the GIL while it sleeps. Falls
    back to ``time.sleep`` of the remaining interval where libc has no clock_nanosleep.
    """

    def __init__(self) -> None:
        self._sleep = _load_clock_nanosleep()
        self._ts = _Timespec()

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, deadline: float) -> None:
        if self._sleep is None:
            remaining = deadline - time.monotonic()
            if remaining > 0:
                time.sleep(remaining)
            return
        frac, whole = math.modf(deadline)
        self._ts.tv_sec = int(whole)
        self._ts.tv_nsec = int(frac * 1e9)
        while self._sleep(_CLOCK_MONOTONIC, _TIMER_ABSTIME, ctypes.byref(self._ts), None) == 4:
            pass  # EINTR: a signal arrived; the deadline is absolute, so sleep again.


class SteppedClock:
    """Simulated time: ``sleep_until`` jumps to the deadline at once, after ``on_advance``.

    ``on_advance(t0, t1)`` lets a physics twin step from t0 to t1 in lock-step with the loop.
    """

    def __init__(
        self,
        start: float = 0.0,
        on_advance: Callable[[float, float], None] | None = None,
    ) -> None:
        self.t = start
        self.on_advance = on_advance

    def now(self) -> float:
        return self.t

    def advance(self, dt: float) -> None:
        """Move time forward by ``dt`` (e.g. to model the cost of a tick in a test)."""
        self.sleep_until(self.t + dt)

    def sleep_until(self, deadline: float) -> None:
        if deadline <= self.t:
            return
        if self.on_advance is not None:
            self.on_advance(self.t, deadline)
        self.t = deadline


class TimingWindow:
    """Ring buffers of recent lateness and compute times; percentiles computed off the hot path."""

    def __init__(self, size: int = 4096) -> None:
        self.lateness = np.zeros(size)
        self.compute = np.zeros(size)
        self.count = 0
        self.overruns = 0

    def add(self, lateness: float, compute: float) -> None:
        i = self.count % self.lateness.size
        self.lateness[i] = lateness
        self.compute[i] = compute
        self.count += 1

    def stats(self, rate_hz: float) -> LoopStats:
        n = min(self.count, self.lateness.size)
        if n == 0:
            return LoopStats(rate_hz=rate_hz)
        late = self.lateness[:n]
        comp = self.compute[:n]
        p_late = np.percentile(late, [50, 99])
        p_comp = np.percentile(comp, [50, 99])
        return LoopStats(
            rate_hz=rate_hz,
            ticks=self.count,
            overruns=self.overruns,
            lateness_p50=float(p_late[0]),
            lateness_p99=float(p_late[1]),
            lateness_max=float(late.max()),
            compute_p50=float(p_comp[0]),
            compute_p99=float(p_comp[1]),
        )


Tick = Callable[[float, float], None]


class ControlLoop:
    """Calls ``tick(t, dt)`` at ``rate_hz`` on absolute deadlines of ``clock``.

    ``t`` is the tick's deadline (scheduled time), ``dt`` the period; the tick itself does
    read → estimate → behave → write. ``idle(deadline)``, if given, does work that need not
    wait for the tick before the sleep (the joint bus taking its replies) and returns before
    the deadline. ``run`` blocks until ``stop()`` or ``max_ticks``.
    """

    def __init__(
        self, rate_hz: float, clock: Clock, tick: Tick, idle: Callable[[float], None] | None = None
    ) -> None:
        if rate_hz <= 0:
            raise ValueError(f"control rate must be > 0 Hz, got {rate_hz}")
        self.rate_hz = rate_hz
        self.period = 1.0 / rate_hz
        self.clock = clock
        self.tick = tick
        self.idle = idle
        self.timing = TimingWindow()
        self.ticks = 0
        self._start: float | None = None
        self._k = 0
        self._stop = threading.Event()

    def stop(self) -> None:
        self._stop.set()

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    def stats(self) -> LoopStats:
        return self.timing.stats(self.rate_hz)

    def run(self, max_ticks: int | None = None) -> None:
        """Run ticks until stopped; each waits for its absolute deadline first. The schedule
        starts at the first call and carries on across calls, so a rig running the loop in
        chunks ticks once a period (restarting it at each call's present time ticked n times
        in n - 1 periods: bench/stepped_chunks.py)."""
        clock, period, tick, timing = self.clock, self.period, self.tick, self.timing
        idle = self.idle
        if self._start is None:
            self._start = clock.now()
        start, k = self._start, self._k
        try:
            while not self._stop.is_set() and (max_ticks is None or self.ticks < max_ticks):
                deadline = start + k * period
                if idle is not None:
                    idle(deadline)
                clock.sleep_until(deadline)
                woke = clock.now()
                tick(deadline, period)
                done = clock.now()
                timing.add(woke - deadline, done - woke)
                self.ticks += 1
                k += 1
                if done > start + k * period:
                    timing.overruns += 1
                    k = max(k, int((done - start) / period))
        finally:
            self._k = k
