"""``climbd record --scene``: a recording that opens in Foxglove as the 3-D scene.

A robot runs with the fake driver and a second peer publishes one of each map; ``climbd record
--scene`` records them. The MCAP is read with the ``mcap`` library and decoded as Foxglove
does, from the schemas in the file (protobuf from the FileDescriptorSet, JSON against the JSON
Schema; no climbd code): the scene's channels are those ``climbd view`` serves, with the same
schemas, every message decodes, and the transforms form one tree rooted at the odometry frame.
``climbd replay`` reads the same file as the raw topics alone, and ``climbd view`` draws
them again.
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

import jsonschema
import pytest
from conftest import free_port
from mcap.reader import make_reader
from support.foxglove_ws import MAPS, MapPublisher, Proc, check_payloads, foxglove_client
from support.recording import climbd, wait_line
from support.scene_decode import in_frame, proto_dict, tree

from climbd.daemon.cli.record import RecordingFile
from climbd.daemon.cli.replay import read
from climbd.daemon.contract import messages as m
from climbd.daemon.contract import profile as profiles
from climbd.daemon.runtime import scene

ROOT = Path(__file__).resolve().parent.parent


def test_transforms_follow_the_joints_at_the_scene_rate_and_maps_on_arrival() -> None:
    stream = scene.SceneStream(
        scene.RobotScene(profiles.load(ROOT / "robots/widowx.toml")), tf_period=0.1
    )
    names = [j.name for j in stream.robot.profile.joints]
    topics = []
    for k in range(1000):  # 1 kHz of joint states for 1 s
        joints = m.JointState(stamp=k * 1e-3, names=names, position=[0.0] * len(names))
        fresh = [joints] + (MAPS if k == 500 else [])
        topics += [t for t, _ in stream.update(fresh, k * 1_000_000, k * 1e-3)]
    assert topics.count("/tf") == 10, "at most one transform per tf_period"
    assert topics.count("/robot") == 1, "the geometry once per GEOMETRY_PERIOD"
    assert topics.count("/joists") == topics.count("/elevation") == 1
    assert "/mode" not in topics


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """A 4 s ``climbd record --scene`` of the fake-driver WidowX and one of each map; the
    file and the recorder's stdout."""
    out = tmp_path_factory.mktemp("scene") / "scene.mcap"
    endpoint, maps_ep = (f"tcp/127.0.0.1:{free_port()}" for _ in range(2))
    robot = climbd(
        "run", "--profile", "robots/widowx.toml", "--driver", "fake", "--listen", endpoint,
        "--quiet",
    )  # fmt: skip
    maps = MapPublisher(maps_ep, period=0.25)
    rec = None
    try:
        wait_line(robot, "control role")
        rec = climbd(
            "record", "--robot", "widowx", "--connect", endpoint, "--connect", maps_ep,
            "--scene", "--duration", "4", "-o", str(out),
        )  # fmt: skip
        stdout, stderr = rec.communicate(timeout=60)
    finally:
        maps.close()
        for proc in (rec, robot):
            if proc is not None and proc.poll() is None:
                proc.terminate()
                proc.wait(timeout=30)
    assert rec.returncode == 0, stdout + stderr
    return out, stdout


def test_record_scene_writes_the_views_channels_as_one_tree_rooted_at_odom(
    recording: tuple[Path, str],
) -> None:
    out, stdout = recording
    assert "with its scene on 11 channels" in stdout and "scene: " in stdout, stdout

    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        messages = list(reader.iter_messages())
    channels = {c.topic: c for c in summary.channels.values()}
    expected = {
        "/tf": ("protobuf", "foxglove.FrameTransforms"),
        "/robot": ("protobuf", "foxglove.SceneUpdate"),
        "/joists": ("protobuf", "foxglove.SceneUpdate"),
        "/holds": ("protobuf", "foxglove.SceneUpdate"),
        "/stairs": ("protobuf", "foxglove.SceneUpdate"),
        "/truss": ("protobuf", "foxglove.SceneUpdate"),
        "/elevation": ("protobuf", "foxglove.Grid"),
        "/mode": ("json", "climbd.ModeState"),
        "/health": ("json", "climbd.Health"),
        "/loop": ("json", "climbd.Loop"),
        "/estop": ("json", "climbd.EStopState"),
    }
    for topic, (encoding, name) in expected.items():
        channel = channels[topic]
        schema = summary.schemas[channel.schema_id]
        schema_encoding = "jsonschema" if encoding == "json" else "protobuf"
        assert (channel.message_encoding, schema.encoding, schema.name) == (
            encoding, schema_encoding, name,
        ), topic  # fmt: skip
        # the view's schema for the same topic, byte for byte
        assert scene.channel_schema(topic) == (name, schema_encoding, schema.data, encoding)
        assert channel.metadata["scene"] == "foxglove"
    raw = {t for t in channels if t.startswith("climbd/widowx/")}
    assert {m.key("widowx", t) for t in scene.INPUTS} <= raw, "recorded with what they draw"

    # every scene message decodes against its schema in the file
    by_topic: dict[str, list[dict]] = {}
    for schema, channel, msg in messages:
        if channel.topic not in expected:
            continue
        if channel.message_encoding == "protobuf":
            value = proto_dict(schema.name, schema.data, msg.data)
        else:
            value = json.loads(msg.data)
            jsonschema.validate(value, json.loads(schema.data))
        by_topic.setdefault(channel.topic, []).append(value)
    assert set(by_topic) == set(expected), f"nothing on {set(expected) - set(by_topic)}"
    assert len(by_topic["/tf"]) >= 30, "transforms at about --scene-rate for 4 s"

    # the transforms: one tree rooted at odom, every link, foot and the camera in it
    transforms = [t for msg in by_topic["/tf"] for t in msg["transforms"]]
    parents = {}
    for t in transforms:
        child, parent = t["child_frame_id"], t["parent_frame_id"]
        assert parents.setdefault(child, parent) == parent, f"{child} has two parents"
    profile = profiles.load(ROOT / "robots/widowx.toml")
    frames = tree(transforms)
    assert set(frames) == set(scene.RobotScene(profile).frames) - {"odom"}
    for frame in frames:
        seen = set()
        while frame != "odom":
            assert frame not in seen and frame in frames, f"{frame} does not reach odom"
            seen.add(frame)
            frame = frames[frame][0]
    feet = [in_frame(frames, f"{leg.name}_foot", "body")[0] for leg in profile.legs]
    assert all(f[2] < -0.05 for f in feet), "a standing robot's feet are below its body"
    stamps = [t["timestamp"] for t in transforms]
    assert stamps == sorted(stamps), "stamped with the log time"

    ids = {e["id"] for msg in by_topic["/robot"] for e in msg["entities"]}
    assert {"body", "camera_front", "link/rf_femur", "rf_foot"} <= ids
    for topic, kind in (("/joists", "cubes"), ("/holds", "spheres"), ("/stairs", "cubes"),
                        ("/truss", "cylinders")):  # fmt: skip
        assert any(e[kind] for msg in by_topic[topic] for e in msg["entities"]), topic
    assert by_topic["/elevation"][-1]["column_count"] == 4
    assert by_topic["/mode"][-1]["mode"] in {"STAND", "HOLD"}
    assert any(h["role"] == "control" for h in by_topic["/health"])

    # climbd replay reads the raw topics alone; a recovery keeps the scene
    replayed = list(read(out))
    assert replayed and all(r.key.startswith("climbd/widowx/") for r in replayed)
    assert any(isinstance(r.message, m.JointState) for r in replayed)
    with_scene = RecordingFile(out, scene=True)
    assert sum(1 for e in with_scene if e.value is None) == sum(map(len, by_topic.values()))


def test_replay_of_a_scene_recording_feeds_climbd_view(recording: tuple[Path, str]) -> None:
    """The raw topics go back on the bus (the scene's channels stay in the file) and
    ``climbd view`` draws them again."""
    out, _ = recording
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    view = Proc("view", "--robot", "widowx", "--connect", endpoint, "--port", "0")
    replay = None
    try:
        port = int(view.wait_for("to Foxglove on ws://").split("ws://127.0.0.1:")[1].split()[0])
        replay = climbd("replay", str(out), "--listen", endpoint, "--wait", "2")
        view.wait_for("robot 'widowx' heard")
        channels, data = asyncio.run(foxglove_client(port, time.monotonic() + 6))
        topics = check_payloads(channels, data)
        stdout, stderr = replay.communicate(timeout=30)
    finally:
        if replay is not None and replay.poll() is None:
            replay.kill()
        code = view.stop()
    assert replay.returncode == 0, stderr
    assert "replayed" in stdout and "Traceback" not in stderr
    frames = tree([t for msg in topics["/tf"] for t in msg["transforms"]])
    assert frames["body"][0] == "odom" and "rf_foot" in frames
    assert any(e["cubes"] for msg in topics["/joists"] for e in msg["entities"])
    assert code == 0 and "Traceback" not in "".join(view.lines)
