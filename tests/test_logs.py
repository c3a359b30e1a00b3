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
