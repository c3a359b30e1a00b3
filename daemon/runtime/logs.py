"""Logging for a daemon under systemd: journald priority prefixes and rate-limited repeats.

Under systemd (``JOURNAL_STREAM`` set) each line starts with ``<N>``, the syslog priority
journald reads, so ``journalctl -p warning`` works. A message repeating from the same place
(a servo faulting every tick) is logged ``burst`` times per ``interval`` and then counted; the
count is reported with the next one let through.
"""

from __future__ import annotations

import logging
import os
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


class RateLimit(logging.Filter):
    """Let at most ``burst`` records from one call site through per ``interval`` seconds."""

    def __init__(self, burst: int = 5, interval: float = 10.0, clock=time.monotonic) -> None:
        super().__init__()
        self.burst, self.interval, self.clock = burst, interval, clock
        self._windows: dict[tuple[str, int], list] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        site = (record.pathname, record.lineno)
        now = self.clock()
        window = self._windows.setdefault(site, [now, 0, 0])
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


def setup(verbose: bool = False) -> None:
    """Configure the root logger for the CLI and the daemon."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JournalFormatter(journal=bool(os.environ.get("JOURNAL_STREAM"))))
    handler.addFilter(RateLimit())
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(logging.DEBUG if verbose else logging.INFO)
