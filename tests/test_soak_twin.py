"""bench/soak.py's twin-soak table: the figures BENCHMARKS.md quotes, against a run this test
constructs (Health reports, RSS samples, a circular odometry path, Joists messages)."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import pytest

from climbd.daemon.contract.messages import Health, LoopStats, Mode

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def soak():
    spec = importlib.util.spec_from_file_location("bench_soak", ROOT / "bench" / "soak.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def health(t: float, ticks: int, overruns: int, p99: float, mode=Mode.ACTIVE, **kw) -> Health:
    loop = LoopStats(rate_hz=100.0, ticks=ticks, overruns=overruns, lateness_p99=p99)
    loop.lateness_p50 = p99 / 4
    return Health(stamp=t, mode=mode, loop=loop, **kw)


def cells(row: str) -> list[str]:
    return [c.strip() for c in row.strip("|").split("|")]


def test_loop_counts_skip_the_pair_across_a_control_role_restart(soak):
    reports = [health(0.0, 0, 0, 1e-3), health(1.0, 80, 5, 1e-3), health(2.0, 160, 9, 1e-3)]
    reports += [health(3.0, 30, 0, 1e-3), health(4.0, 120, 2, 1e-3)]  # restarted: counters reset
    ticks, overruns, expected = soak._loop_counts(reports)
    assert (ticks, overruns) == (80 + 80 + 90, 5 + 4 + 2)
    assert expected == pytest.approx(300.0)


def test_window_table_reports_memory_lateness_missed_ticks_path_and_features(soak):
    """Two 60 s windows: 80 of 100 ticks/s done, RSS 100 → 110 MiB, a 1 m-radius circle walked
    at 0.05 m/s (3 m per window), perception at 2 Hz with one false joist in the second window."""
    rec = soak.TwinRecorder()
    start = 1000.0
    for k in range(241):  # Health at 2 Hz for 120 s
        t = start + 0.5 * k
        p99 = 2e-3 if t < start + 60 else 3e-3
        rec.health.append((t, health(t, 40 * k, k, p99)))
        rec.perception.append((t, health(t, 0, 0, 0.0, role="perception", dropped_frames=k // 10)))
        rec.features.append((t, int(k == 150)))
    for k in range(601):  # odometry at 5 Hz
        t = start + 0.2 * k
        angle = 0.05 * (t - start)
        rec.body.append((t, math.sin(angle), 1 - math.cos(angle)))
    rec.modes = [(start - 5, "STAND", "start-up"), (start + 70, "ACTIVE", "requested")]
    rss = [(start + 5 * k, {"control": 100.0 + 10 * (k >= 12)}) for k in range(24)]
    rss.append((start + 119.9, {"control": 110.0}))

    head, _, first, second = soak._twin_windows(rec, rss, start, 60.0)
    columns = cells(head)
    first, second = (dict(zip(columns, cells(row), strict=True)) for row in (first, second))
    assert first["window (min)"] == "0-1" and second["window (min)"] == "1-2"
    assert (first["RSS control (MiB)"], second["RSS control (MiB)"]) == ("100.0", "110.0")
    assert (first["RSS ratio"], second["RSS ratio"]) == ("1.000", "1.100")
    assert (first["p99 (µs)"], second["p99 (µs)"], second["p99 ratio"]) == ("2000", "3000", "1.50")
    assert first["lateness p50 (µs)"] == "500"
    assert first["ticks (missed)"] == "4760 (20 %)"  # 119 half-second pairs of 40 ticks
    assert first["overruns"] == "119" and first["ACTIVE"] == "100 %"
    assert (first["mode changes"], second["mode changes"]) == ("0", "1")
    for row in (first, second):  # chords of a 0.01 m arc: the path is the arc to 1e-5
        assert float(row["walked (m)"]) == pytest.approx(3.0 - 0.01, abs=0.01)
    assert first["Joists msgs /s"] == "2.0"
    assert (first["with a joist"], second["with a joist"]) == ("0", "1")
    assert first["frames dropped"] == "11"
