"""Crash-safe recordings: a ``climbd record`` killed outright (kill -9) leaves a file that
``climbd replay`` reads and ``climbd record --recover`` seals, message for message as published;
a recording that cannot start (full disk, unwritable path) fails naming the file and leaves none.
"""

from __future__ import annotations

import logging
import random
import resource
import signal
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from conftest import lossless
from mcap.reader import make_reader
from support.recording import ROOT, climbd, one_of_each, same, wait_line

from climbd.daemon.cli import record
from climbd.daemon.cli.record import McapSink, RecordingError, Sample, recover
from climbd.daemon.cli.replay import Recorded, read
from climbd.daemon.contract import messages as m
from climbd.daemon.runtime.network import Endpoints, Network, zenoh_config

ROBOT = "crash"
TYPES = (m.JointState, m.Health, m.Heartbeat, m.ElevationGrid)
"""What the publisher sends each round: a state, a nested one, a command, bytes with a NaN."""

RATE = 100.0
"""Publisher rounds per second."""

KILLS, WORKERS, MAX_DELAY = 8, 4, 2.5
"""Recorders killed, how many run at once, and the latest kill (s after "recording")."""


@dataclass
class Killed:
    """One recorder killed ``delay`` s after it said it was recording; its file."""

    path: Path
    delay: float
    rounds_sent: int = 0
    got: list[Recorded] = field(default_factory=list)


class Publisher:
    """Publishes one message of each of TYPES per round, keeping what it sent as ground truth."""

    def __init__(self, endpoint: str) -> None:
        self.bus = Network(ROBOT, zenoh_config(None, "test", Endpoints([endpoint], [])))
        self.pubs = {t: lossless(self.bus, t) for t in TYPES}
        self.sent: dict[type, list[m.Message]] = {t: [] for t in TYPES}
        self.rounds = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        """Send round after round at RATE until stopped; ``rounds`` counts whole rounds sent."""
        start = time.monotonic()
        while not self.stop.is_set():
            n = self.rounds
            for msg in one_of_each(n):
                if type(msg) in self.pubs:
                    self.sent[type(msg)].append(msg)
                    self.pubs[type(msg)].put(msg)
            self.rounds = n + 1
            self.stop.wait(max(0.0, start + self.rounds / RATE - time.monotonic()))

    def __enter__(self) -> Publisher:
        self.thread.start()
        return self

    def __exit__(self, *_) -> None:
        self.stop.set()
        self.thread.join(timeout=10)
        self.bus.close()


def record_and_kill(endpoint: str, run: Killed, publisher: Publisher) -> None:
    """Start a recorder, SIGKILL it ``run.delay`` s after it started recording."""
    rec = climbd("record", "--robot", ROBOT, "--connect", endpoint, "-o", str(run.path))
    try:
        wait_line(rec, "climbd: recording")
        time.sleep(run.delay)
        rec.send_signal(signal.SIGKILL)
        rec.wait(timeout=30)
        run.rounds_sent = publisher.rounds
    finally:
        if rec.poll() is None:
            rec.kill()
        rec.communicate(timeout=30)
    assert rec.returncode == -signal.SIGKILL


def check_content(run: Killed, publisher: Publisher) -> None:
    """Each topic holds a run of consecutive rounds, each message as published, none sent after
    the kill."""
    for t in TYPES:
        got = [r for r in run.got if r.key == m.key(ROBOT, t)]
        assert all(type(r.message) is t for r in got), t.__name__
        stamps = [int(r.message.stamp) for r in got]
        assert not stamps or stamps == list(range(stamps[0], stamps[0] + len(stamps))), t
        assert all(s < run.rounds_sent for s in stamps), (t.__name__, run)
        assert all(same(publisher.sent[t][int(r.message.stamp)], r.message) for r in got), (
            t.__name__
        )
    assert {r.key for r in run.got} <= {m.key(ROBOT, t) for t in TYPES}


def check_recovered(run: Killed, tmp_path: Path) -> None:
    """``recover`` writes a sealed, indexed file of the same messages; with none, it fails
    naming the file and writes nothing."""
    out = tmp_path / f"{run.path.stem}.recovered.mcap"
    if not run.got:
        with pytest.raises(RecordingError, match=run.path.name):
            recover(run.path, out)
        assert not out.exists() and not list(tmp_path.glob("*.partial"))
        return
    assert recover(run.path, out).count == len(run.got)
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary.statistics.message_count == len(run.got) and summary.chunk_indexes
    again = list(read(out))
    assert [(r.key, r.log_time) for r in again] == [(r.key, r.log_time) for r in run.got]
    assert all(map(same, (r.message for r in run.got), (r.message for r in again)))


def test_recordings_killed_at_random_points_are_read_and_recovered(
    tmp_path: Path, endpoint: str, caplog: pytest.LogCaptureFixture
) -> None:
    """Eight recorders killed with SIGKILL at seeded random points against one live publisher."""
    rng = random.Random(33)
    runs = [Killed(tmp_path / f"k{i:02d}.mcap", rng.uniform(0.0, MAX_DELAY)) for i in range(KILLS)]
    with Publisher(endpoint) as publisher, ThreadPoolExecutor(WORKERS) as pool:
        time.sleep(0.5)
        list(pool.map(lambda run: record_and_kill(endpoint, run, publisher), runs))
    for run in runs:
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="climbd.replay"):
            run.got = list(read(run.path))
        warnings = [r.getMessage() for r in caplog.records]
        assert len(warnings) == 1, warnings
        assert "not closed cleanly" in warnings[0] and run.path.name in warnings[0]
        assert f"recovered {len(run.got)} complete messages" in warnings[0]
        check_content(run, publisher)
        check_recovered(run, tmp_path)
    late = [run for run in runs if run.delay > 1.5]
    assert late and all(run.got for run in late), [(r.delay, len(r.got)) for r in runs]
    for a in runs:
        for b in runs:
            if b.delay - a.delay >= 1.0:
                assert len(b.got) >= len(a.got), [(r.delay, len(r.got)) for r in runs]


def test_replay_and_recover_commands_on_a_killed_recording(tmp_path: Path, endpoint: str) -> None:
    """The commands print one line saying the file was not closed cleanly and the count."""
    run = Killed(tmp_path / "killed.mcap", 1.5)
    with Publisher(endpoint) as publisher:
        time.sleep(0.5)
        record_and_kill(endpoint, run, publisher)
        count = len(list(read(run.path)))
        replayed = len(list(read(run.path, ["state/*", "features/*"])))
        assert count > replayed > 0
        rep = climbd(
            "replay", str(run.path), "--speed", "1000", "--wait", "0", "--connect", endpoint
        )
        stdout, stderr = rep.communicate(timeout=60)
    assert rep.returncode == 0, stderr
    lines = [line for line in stderr.splitlines() if "not closed cleanly" in line]
    assert len(lines) == 1 and f"recovered {count} complete messages" in lines[0], stderr
    assert f"replayed {replayed} of {replayed} messages" in stdout, stdout
    res = subprocess.run(
        [sys.executable, "-m", "climbd.daemon.cli", "record", "--recover", str(run.path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    out = tmp_path / "killed.recovered.mcap"
    assert res.returncode == 0, res.stderr
    assert f"recovered {count} messages from {run.path} to {out}" in res.stdout, res.stdout
    assert "not closed cleanly" in res.stdout
    assert len(list(read(out))) == count


def test_recover_fails_naming_a_file_with_nothing_to_recover(tmp_path: Path) -> None:
    """A recording cut inside its header holds no message: exit 1, file named, nothing written."""
    whole = tmp_path / "whole.mcap"
    McapSink(whole, [m.JointState]).close()
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(whole.read_bytes()[:40])
    res = subprocess.run(
        [sys.executable, "-m", "climbd.daemon.cli", "record", "--recover", str(torn)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr
    assert f"{torn}: no complete message to recover" in res.stderr, res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["torn.mcap", "whole.mcap"]


def test_flush_fsyncs_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every flush reaches the disk (fsync), so a power cut loses at most FLUSH_PERIOD."""
    synced: list[int] = []
    fsync = record.os.fsync
    monkeypatch.setattr(record, "FLUSH_PERIOD", 0.0)
    monkeypatch.setattr(record.os, "fsync", lambda fd: (synced.append(fd), fsync(fd)))
    path = tmp_path / "synced.mcap"
    sink = McapSink(path, [m.JointState])
    fd = sink.file.fileno()
    for n in range(3):
        before = len(synced)
        sink.write(Sample(m.key("x", m.JointState), m.JointState(stamp=n), 10**18 + n))
        assert synced[before:] == [fd] and path.stat().st_size == sink.file.tell()
    sink.close()
    assert [r.message.stamp for r in read(path)] == [0, 1, 2]


def no_file_writes() -> None:
    """preexec_fn: a file size limit of 0, as a disk already full."""
    resource.setrlimit(resource.RLIMIT_FSIZE, (0, 0))


@pytest.mark.parametrize("case", ["disk full", "parent is a file"])
def test_a_recording_that_cannot_start_names_the_file_and_leaves_none(
    tmp_path: Path, case: str
) -> None:
    """A full disk (RLIMIT_FSIZE=0) or an unwritable path: exit 1, file and reason named."""
    (tmp_path / "file").write_text("")
    path = tmp_path / ("rec.mcap" if case == "disk full" else "file/rec.mcap")
    reason = "File too large" if case == "disk full" else "Not a directory"
    res = subprocess.run(
        [sys.executable, "-m", "climbd.daemon.cli", "record", "--robot", ROBOT, "-o", str(path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        preexec_fn=no_file_writes if case == "disk full" else None,
    )
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr
    assert f"error: {path}: " in res.stderr and reason in res.stderr, res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_a_disk_full_before_the_first_message_leaves_no_file(tmp_path: Path) -> None:
    """Room for the schemas but not one message: the recording stops and its file is removed."""
    path = tmp_path / "full.mcap"
    started = McapSink(path, [m.JointState])
    limit = started.file.tell()
    started.close()
    path.unlink()
    code = f"""
import resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit}))
from climbd.daemon.contract import messages as m
from climbd.daemon.cli.record import McapSink, Sample, WriteFailed
sink = McapSink(sys.argv[1], [m.JointState])
try:
    sink.write(Sample("climbd/x/state/joints", m.JointState(stamp=1), 10**18))
    sink.close()
except WriteFailed as e:
    print(e)
"""
    res = subprocess.run(
        [sys.executable, "-c", code, str(path)], cwd=ROOT, capture_output=True, text=True
    )
    assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr
    assert f"{path}: File too large; no message kept, file removed" in res.stdout, res.stdout
    assert not list(tmp_path.iterdir())
