"""Logging for a daemon under systemd: journald priority prefixes and rate-limited repeats.

Under systemd (``JOURNAL_STREAM`` set) each line starts with ``<N>``, the syslog priority
journald reads, so ``journalctl -p warning`` works. A message repeating from the same place
(a servo faulting every tick) is logged ``burst`` times per ``interval`` and then counted; the
count is reported with the next one let through. Messages are alike when their text differs in
numbers only, so a decision logged from the same line as a repeating one still gets through.
"""

from __future__ import annotations

import logging
import os
import re
import sys
import time

PRIORITY = {
    logging.CRITICAL: 2,
    logging.ERROR: 3,
    logging.WARNING: 4,
    logging.INFO: 6,
    logging.DEBUG: 7,
}


class JournalFormatter(logging.Formatter):
    """``<priority>logger: message`` for journald; plain ``LEVEL logger: message`` otherwise."""

    def __init__(self, journal: bool) -> None:
        super().__init__(
            "%(name)s: %(message)s" if journal else "%(levelname)s %(name)s: %(message)s"
        )
        self.journal = journal

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        if not self.journal:
            return text
        prefix = f"<{PRIORITY.get(record.levelno, 6)}>"
        return "\n".join(prefix + line for line in text.splitlines())


NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?")
"""A number in a message: alike messages differ in these only (stamps, counts, readings)."""
WINDOWS = 1024
"""Kinds of message whose windows are kept before those idle past their interval go."""


class RateLimit(logging.Filter):
    """Let at most ``burst`` alike records (one call site, the same text but for its numbers)
    through per ``interval`` seconds."""

    def __init__(self, burst: int = 5, interval: float = 10.0, clock=time.monotonic) -> None:
        super().__init__()
        self.burst, self.interval, self.clock = burst, interval, clock
        self._windows: dict[tuple[str, int, str], list] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        kind = (record.pathname, record.lineno, NUMBER.sub("#", record.getMessage()))
        now = self.clock()
        if kind not in self._windows and len(self._windows) >= WINDOWS:
            self._forget(now)
        window = self._windows.setdefault(kind, [now, 0, 0])
        if now - window[0] >= self.interval:
            suppressed = window[2]
            window[:] = [now, 0, 0]
            if suppressed:
                record.msg = f"{record.msg} ({suppressed} similar messages suppressed)"
        window[1] += 1
        if window[1] > self.burst:
            window[2] += 1
            return False
        return True

    def _forget(self, now: float) -> None:
        """Drop the windows idle past their interval (their suppressed counts are lost, as a
        window that never saw its message again would keep them)."""
        idle = [k for k, w in self._windows.items() if now - w[0] >= self.interval]
        for kind in idle:
            del self._windows[kind]


def setup(verbose: bool = False) -> None:
    """Configure the root logger for the CLI and the daemon."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JournalFormatter(journal=bool(os.environ.get("JOURNAL_STREAM"))))
    handler.addFilter(RateLimit())
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(logging.DEBUG if verbose else logging.INFO)
