"""Daemon logs: journald priority prefixes and rate-limited repeats."""

from __future__ import annotations

import logging

from climbd.daemon.runtime.logs import JournalFormatter, RateLimit


def record(msg: str, level: int = logging.WARNING, line: int = 10) -> logging.LogRecord:
    return logging.LogRecord("climbd.dxl", level, "bus.py", line, msg, None, None)


def test_journal_prefix_carries_the_syslog_priority() -> None:
    f = JournalFormatter(journal=True)
    assert f.format(record("servo 3 lost")) == "<4>climbd.dxl: servo 3 lost"
    assert f.format(record("a\nb", logging.ERROR)) == "<3>climbd.dxl: a\n<3>b"
    assert JournalFormatter(journal=False).format(record("x")) == "WARNING climbd.dxl: x"


def test_repeats_are_limited_then_counted() -> None:
    now = [0.0]
    limit = RateLimit(burst=3, interval=10.0, clock=lambda: now[0])
    passed = [limit.filter(record("overheat")) for _ in range(100)]
    assert passed.count(True) == 3
    assert limit.filter(record("other site", line=99)), "another call site has its own budget"
    now[0] = 10.5
    r = record("overheat")
    assert limit.filter(r) and "97 similar messages suppressed" in r.msg


def test_a_different_message_from_a_repeating_call_site_gets_through() -> None:
    """One ``log.info("%.2f s %s", t, what)`` line logs a behaviour's every decision: a
    decision that repeats (with new stamps and figures) is limited, a new one is not."""
    now = [0.0]
    limit = RateLimit(burst=2, interval=10.0, clock=lambda: now[0])

    def event(t: float, what: str) -> logging.LogRecord:
        return logging.LogRecord("g", logging.INFO, "gait.py", 7, "%.2f s %s", (t, what), None)

    stuck = [limit.filter(event(t, f"no plan: stuck at x {t / 100:.3f} m")) for t in range(50)]
    assert stuck.count(True) == 2
    assert limit.filter(event(51.0, "walk: joist crossed"))
    assert not limit.filter(event(52.0, "no plan: stuck at x 0.520 m"))


def test_windows_stay_bounded_over_many_kinds_of_message() -> None:
    now = [0.0]
    limit = RateLimit(burst=1, interval=1.0, clock=lambda: now[0])
    for k in range(5000):
        now[0] = k * 0.01
        letters = "".join(chr(65 + k // 26**i % 26) for i in range(3))  # 5000 kinds
        limit.filter(record(f"kind {letters}"))
    assert len(limit._windows) <= 1024
