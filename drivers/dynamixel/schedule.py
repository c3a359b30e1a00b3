"""Which joint a Dynamixel bus reads next between ticks, and how well the reads keep up.

A bus that cannot read every servo every tick (Protocol 1.0 has no sync read; a USB adapter
holds each reply for its latency timer) reads them in turn in the loop's idle time: the
oldest state first, sooner for a joint far from its goal (it is moving, its state matters
more). Every joint's state carries the time it was sampled, so the tick knows its age.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from climbd.daemon.contract.messages import BusSchedule

ERROR_SCALE = 0.05
"""Tracking error (rad) at which a joint's claim to the next read is a full tick older than
its age (less in proportion, never more: no joint starves the others)."""

WINDOW = 2.0
"""Seconds of ticks the reported figures cover."""


class ReadSchedule:
    """Sample times of ``n`` joints, the choice of the next to read, and the figures."""

    def __init__(self, names: list[str], rate_hz: float, bound: float, probe_period: float) -> None:
        n = len(names)
        self.names = names
        self.sampled = np.full(n, -np.inf)
        """When each joint's state was sampled (monotonic s): when its READ was sent."""
        self.error = np.zeros(n)
        """Each joint's distance (rad) from its last goal."""
        self.pending = np.zeros(n, bool)
        self.probed = np.full(n, -np.inf)
        self.bound = bound
        self.period = 1.0 / rate_hz
        self.probe_period = probe_period
        self.plan = ""
        self.missed = np.zeros(n, np.int64)
        """Replies given up or corrupt, by joint."""
        self._ticks: deque[tuple[float, int, float]] = deque(maxlen=max(2, int(WINDOW * rate_hz)))
        self._reads = 0
        self.read_count = 0
        """States read since start."""
        self._writes: deque[float] = deque(maxlen=max(2, int(WINDOW * rate_hz)))

    def next(self, since: float, lost: np.ndarray) -> int | None:
        """The joint to read next: not read since ``since`` (the last tick's start), no reply
        owed, not lost; the oldest first, up to a tick sooner for its tracking error. None: all
        are fresh."""
        free = (self.sampled < since) & ~self.pending & ~lost
        if not free.any():
            return None
        score = since - self.sampled + self.period * np.minimum(self.error / ERROR_SCALE, 1.0)
        score[~free] = -np.inf
        return int(np.argmax(score))

    def probe(self, now: float, lost: np.ndarray) -> int | None:
        """A lost joint not asked for ``probe_period`` s (is it back?), or None."""
        due = lost & ~self.pending & (self.probed <= now - self.probe_period)
        if not due.any():
            return None
        k = int(np.argmax(due))
        self.probed[k] = now
        return k

    def miss(self, joints: np.ndarray) -> None:
        """The joints at mask ``joints`` did not answer (given up, or corrupt)."""
        self.missed += joints

    def read_all(self, answered: np.ndarray, sampled: float) -> None:
        """The joints at mask ``answered`` were read together at ``sampled`` (a blocking read
        of every servo)."""
        self.sampled[answered] = sampled
        count = int(answered.sum())
        self._reads += count
        self.read_count += count

    def read(self, joints: tuple[int, ...], sampled: float) -> None:
        """``joints`` answered a request sent at ``sampled``."""
        self.sampled[list(joints)] = sampled
        self._reads += len(joints)
        self.read_count += len(joints)

    def ages(self, now: float, lost: np.ndarray) -> list[float]:
        """Each joint's state age (s) at ``now``; NaN for a lost joint (it is not read)."""
        return np.where(lost, np.nan, now - self.sampled).tolist()

    def tick(self, now: float, lost: np.ndarray) -> None:
        """A tick took the state: note the reads since the last and the oldest joint's age."""
        live = ~lost
        oldest = float(np.max(now - self.sampled[live])) if live.any() else 0.0
        self._ticks.append((now, self._reads, oldest))
        self._reads = 0

    def wrote(self, now: float) -> None:
        """A goal went to every joint."""
        self._writes.append(now)

    def report(self) -> BusSchedule:
        """The figures over the last ``WINDOW`` s (reads: those before each tick but the
        first, whose reads began before the window)."""
        if len(self._ticks) < 2:
            return BusSchedule(age_bound=self.bound, plan=self.plan, **self._misses())
        t = np.array([x[0] for x in self._ticks])
        reads = np.array([x[1] for x in self._ticks])
        oldest = np.array([x[2] for x in self._ticks])
        span = t[-1] - t[0]
        w = np.array(self._writes)
        return BusSchedule(
            reads_per_tick=float(reads[1:].mean()),
            reads_per_s=float(reads[1:].sum() / span) if span > 0 else 0.0,
            writes_per_s=float(((w > t[0]) & (w <= t[-1])).sum() / span) if span > 0 else 0.0,
            oldest_age_p50=float(np.percentile(oldest, 50)),
            oldest_age_p99=float(np.percentile(oldest, 99)),
            oldest_age_max=float(oldest.max()),
            age_bound=self.bound,
            plan=self.plan,
            **self._misses(),
        )

    def _misses(self) -> dict:
        return {
            "missed": int(self.missed.sum()),
            "missed_by": {self.names[k]: int(self.missed[k]) for k in np.flatnonzero(self.missed)},
        }
