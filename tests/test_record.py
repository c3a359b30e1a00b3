"""``climbd record`` / ``climbd replay``: MCAP files any MCAP tool opens (JSON + JSON Schema),
replayed on the bus in order at the chosen pace; a twin run replays to the same joists."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgspec
import pytest
from conftest import lossless
from mcap.reader import make_reader
from support.recording import climbd, one_of_each, same, wait_line

from climbd.daemon.cli.record import McapSink, Sample, WriteFailed
from climbd.daemon.cli.replay import RecordingError, pace, read
from climbd.daemon.contract import messages as m
from climbd.daemon.runtime.network import Endpoints, Network, zenoh_config

ROOT = Path(__file__).resolve().parent.parent


def test_recording_lists_every_topic_with_its_schema(tmp_path: Path, endpoint: str) -> None:
    out = tmp_path / "all.mcap"
    bus = Network("rec", zenoh_config(None, "test", Endpoints([endpoint], [])))
    rec = climbd("record", "--robot", "rec", "--connect", endpoint, "-o", str(out))
    try:
        wait_line(rec, f"recording {len(m.ALL_MESSAGES)} topics")
        time.sleep(1.0)  # the recorder's subscriptions reach this session
        pubs = {type(x): lossless(bus, type(x)) for x in one_of_each(0)}
        sent = []
        for n in range(3):
            for msg in one_of_each(n):
                pubs[type(msg)].put(msg)
                sent.append(msg)
            time.sleep(0.05)
        time.sleep(1.0)
        rec.send_signal(signal.SIGINT)
        stdout, stderr = rec.communicate(timeout=30)
    finally:
        if rec.poll() is None:
            rec.kill()
        bus.close()
    assert rec.returncode == 0, stderr
    n = len(m.ALL_MESSAGES)
    assert f"recorded {3 * n} messages on {n} topics" in stdout, stdout + stderr
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary.statistics.message_count == 3 * n
    channels = {c.topic: c for c in summary.channels.values()}
    assert set(channels) == {f"climbd/rec/{t.TOPIC}" for t in m.ALL_MESSAGES}
    for t in m.ALL_MESSAGES:
        c = channels[m.key("rec", t)]
        schema = summary.schemas[c.schema_id]
        assert (c.message_encoding, schema.encoding) == ("json", "jsonschema")
        assert schema.name == f"climbd.{t.__name__}"
        assert json.loads(schema.data) == json.loads(msgspec.json.encode(msgspec.json.schema(t)))
    got = [r.message for r in read(out)]
    for t in m.ALL_MESSAGES:
        mine = [x for x in sent if type(x) is t]
        theirs = [x for x in got if type(x) is t]
        assert len(theirs) == 3 and all(map(same, mine, theirs)), t.__name__
    with open(out, "rb") as f:  # the payload is plain JSON, NaN as null
        _, channel, msg = next(
            x for x in make_reader(f).iter_messages() if x[1].topic.endswith("state/health")
        )
    assert json.loads(msg.data)["joints"][0]["temperature"] is None


def _recording(path: Path, span: float, count: int) -> list[Sample]:
    """Write ``count`` rounds of joints, health and heartbeat over ``span`` seconds; return them."""
    sink = McapSink(path, list(m.ALL_MESSAGES))
    t0 = 1_700_000_000_000_000_000
    samples = []
    for n in range(count):
        at = t0 + int(n * span / (count - 1) * 1e9)
        for msg in (
            m.JointState(stamp=n, names=["a"], position=[0.01 * n]),
            m.Health(stamp=n, loop=m.LoopStats(ticks=n)),
            m.Heartbeat(stamp=n, session="s", seq=n),
        ):
            s = Sample(m.key("rec", type(msg)), msg, at)
            sink.write(s)
            samples.append(s)
    sink.close()
    return samples


def test_pace_divides_recorded_gaps_by_the_speed() -> None:
    t = [0, 1_000_000_000, 1_500_000_000, 4_000_000_000]
    assert pace(t, 1.0) == [0.0, 1.0, 1.5, 4.0]
    assert pace(t, 4.0) == [0.0, 0.25, 0.375, 1.0]
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="--speed"):
            pace(t, bad)


@pytest.mark.parametrize("speed", [4.0])
def test_replay_republishes_in_order_at_the_chosen_speed(
    tmp_path: Path, endpoint: str, speed: float
) -> None:
    span, count = 2.0, 41
    samples = _recording(tmp_path / "r.mcap", span, count)
    got: dict[type, list[tuple[float, m.Message]]] = {}
    lock = threading.Lock()

    def collect(msg: m.Message) -> None:
        with lock:
            got.setdefault(type(msg), []).append((time.monotonic(), msg))

    bus = Network("rec", zenoh_config(None, "test", Endpoints([endpoint], [])))
    replay = climbd(
        "replay", str(tmp_path / "r.mcap"), "--speed", str(speed), "--connect", endpoint,
        "--wait", "1.5",
    )  # fmt: skip
    try:
        for t in (m.JointState, m.Health, m.Heartbeat):
            bus.subscribe(t, collect)
        stdout, stderr = replay.communicate(timeout=60)
    finally:
        if replay.poll() is None:
            replay.kill()
        bus.close()
    assert replay.returncode == 0, stderr
    assert f"replayed {2 * count} of {2 * count} messages" in stdout, stdout
    assert m.Heartbeat not in got, "cmd/** topics stay out of a replay unless --commands"
    for t in (m.JointState, m.Health):
        recorded = [s.message for s in samples if type(s.message) is t]
        replayed = [msg for _, msg in got.get(t, [])]
        assert len(replayed) == count and all(map(same, recorded, replayed)), t.__name__
    times = [at for at, _ in got[m.JointState]]
    assert times[-1] - times[0] >= 0.9 * span / speed  # never faster than asked
    assert times[-1] - times[0] < span  # and not at real time


def test_twin_recording_replays_to_the_same_joist_detections(tmp_path: Path, endpoint: str) -> None:
    """Joists detected live from the twin's ray-cast depth are recorded and replayed unchanged."""
    from climbd.daemon.cli.record import Recorder
    from climbd.daemon.cli.replay import Replayer
    from climbd.daemon.contract.profile import load
    from climbd.drivers.sim.twin import Twin
    from climbd.plugins.perception.joist_perception import JoistPerception

    profile = load(ROOT / "robots" / "widowx.toml")
    twin = Twin(profile, "attic_paper", stepped=True, bus=False)
    plugin = JoistPerception(profile=profile)
    live_bus = Network("widowx", zenoh_config(None, "perception", Endpoints([endpoint], [])))
    rec_bus = Network("widowx", zenoh_config(None, "record", Endpoints([], [endpoint])))
    recorder = Recorder(rec_bus.session, "widowx", [m.Joists, m.BodyState])
    recorder.start()
    time.sleep(1.0)
    live = []
    try:
        pub_j, pub_b = live_bus.publisher(m.Joists), live_bus.publisher(m.BodyState)
        twin.step(200)
        for _ in range(5):
            twin.step(30)
            frame = twin.depth_frame("front")
            pos, quat = twin.body_pose()
            body = m.BodyState(
                stamp=frame.timestamp, position=pos.tolist(), orientation=quat.tolist()
            )
            joists = plugin.process(frame, body)
            pub_b.put(body)
            pub_j.put(joists)
            live.append(joists)
            time.sleep(0.05)
        time.sleep(1.0)
        sink = McapSink(tmp_path / "twin.mcap", [m.Joists, m.BodyState])
        recorder.drain(sink, threading.Event(), time.monotonic() + 0.5)
        sink.close()
    finally:
        recorder.stop()
        live_bus.close()
        rec_bus.close()
    with open(tmp_path / "twin.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    topics = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert topics == {
        "climbd/widowx/features/joists": "climbd.Joists",
        "climbd/widowx/state/body": "climbd.BodyState",
    }
    assert summary.statistics.message_count == 2 * len(live)
    assert all(j.joists for j in live), "the twin's attic shows the 15° joist"
    assert abs(live[0].joists[0].yaw - math.radians(15)) < math.radians(3)

    replayed = []
    sub = Network("widowx", zenoh_config(None, "test", Endpoints([endpoint], [])))
    out = Network("widowx", zenoh_config(None, "replay", Endpoints([], [endpoint])))
    try:
        sub.subscribe(m.Joists, replayed.append)
        time.sleep(1.0)
        replayer = Replayer(out)
        replayer.run(
            list(read(tmp_path / "twin.mcap", ["features/*"])), 10.0, None, threading.Event()
        )
        time.sleep(0.5)
    finally:
        out.close()
        sub.close()
    assert len(replayed) == len(live)
    assert all(map(same, live, replayed))


def test_disk_full_stops_the_recording_cleanly_and_keeps_a_readable_file(tmp_path: Path) -> None:
    """A write that fails (here: the file size limit, as a full disk would) seals what was kept."""
    path = tmp_path / "full.mcap"
    McapSink(path, list(m.ALL_MESSAGES)).close()
    limit = path.stat().st_size + 20_000  # the schemas and some 20 kB of messages
    code = f"""
import resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit}))
from climbd.daemon.contract import messages as m
from climbd.daemon.cli.record import McapSink, Sample, WriteFailed
sink = McapSink(sys.argv[1], list(m.ALL_MESSAGES))
try:
    for n in range(10_000):
        msg = m.JointState(stamp=n, names=["a", "b"], position=[0.1 * n, 0.2])
        sink.write(Sample("climbd/x/state/joints", msg, 10**18 + n))
    sink.close()
except WriteFailed as e:
    print(e)
"""
    res = subprocess.run(
        [sys.executable, "-c", code, str(path)], cwd=ROOT, capture_output=True, text=True
    )
    assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr
    assert "File too large" in res.stdout and "file sealed and readable" in res.stdout
    kept = int(res.stdout.split("; ")[1].split()[0])
    assert 0 < kept < 10_000 and path.stat().st_size <= limit
    got = list(read(path))
    assert len(got) == kept
    assert [r.message.stamp for r in got] == list(range(kept))


def test_unreadable_recordings_are_named(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    with pytest.raises(RecordingError, match="bad.mcap"):
        list(read(bad))
    with pytest.raises(RecordingError, match="missing.mcap"):
        list(read(tmp_path / "missing.mcap"))
    with pytest.raises(WriteFailed, match="nodir"):
        McapSink(tmp_path / "nodir" / "x.mcap", [m.JointState])
