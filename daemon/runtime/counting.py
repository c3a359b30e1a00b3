"""Bounded, thread-safe counts by key (topic, or topic and peer) for the roles' Health.

A sender choosing its keys (many topics of another robot, made-up peer ids) must not grow a
role's memory or its Health message: past ``MAX_KEYS`` keys, new ones are summed under
``OTHER``, while the total stays exact.
"""

from __future__ import annotations

import threading

MAX_KEYS = 64
"""Most keys a Tally holds, ``OTHER`` included."""

OTHER = "other"
"""The key new keys are counted under once a Tally is full."""


class Tally:
    """Counts by key with an exact total; thread-safe (Zenoh's threads and asyncio add)."""

    def __init__(self, limit: int = MAX_KEYS) -> None:
        self._limit = limit
        self._counts: dict[str, int] = {}
        self._lock = threading.Lock()
        self.total = 0

    def add(self, key: str, n: int = 1) -> None:
        """Count ``n`` under ``key``, or under OTHER when ``key`` is new and the tally is full
        (one slot is kept for OTHER)."""
        with self._lock:
            self.total += n
            if key not in self._counts and len(self._counts) >= self._limit - 1:
                key = OTHER
            self._counts[key] = self._counts.get(key, 0) + n

    def counts(self) -> dict[str, int]:
        """A copy of the counts by key, for a Health message."""
        with self._lock:
            return dict(self._counts)
