"""The wire contract: round trips, schema versions, garbage rejection, JSON Schema."""

from __future__ import annotations

import json
import subprocess
import sys

import msgspec
import pytest

from climbd.daemon.contract import messages as m


def test_every_message_round_trips() -> None:
    samples = [
        m.JointState(
            stamp=1.5,
            names=["a", "b"],
            position=[0.1, -0.2],
            velocity=[0.0, 0.0],
            effort=[0.0, 1.0],
        ),
        m.JointCommand(position=[0.1], kp=[30.0], kd=[1.0]),
        m.Health(
            mode=m.Mode.HOLD,
            joints=[m.JointHealth(name="a", temperature=40.0, errors=["overload"])],
        ),
        m.Joists(
            joists=[
                m.Joist(
                    distance=0.8, yaw=0.5, height=0.1, endpoints=[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]
                )
            ]
        ),
        m.TrussMembers(
            members=[
                m.TrussMember(
                    p0=[0.0, 0.0, 0.0], p1=[1.0, 0.0, 0.0], radius=0.02, axis=[1.0, 0.0, 0.0]
                )
            ]
        ),
        m.EStop(engage=True, source="laptop"),
        m.ElevationGrid(rows=2, cols=2, heights=b"\x00" * 16),
    ]
    for msg in samples:
        back = m.decode(m.encode(msg), type(msg))
        assert type(back) is type(msg) and m.encode(back) == m.encode(msg)


def test_keys_are_namespaced_by_robot() -> None:
    assert m.key("widowx", m.JointState) == "climbd/widowx/state/joints"
    assert m.key("hubrobo", m.EStop) == "climbd/hubrobo/cmd/estop"
    topics = [t.TOPIC for t in m.ALL_MESSAGES]
    assert len(topics) == len(set(topics))
    assert all(t.startswith(("state/", "cmd/", "features/", "sim/")) for t in topics)


def test_wrong_schema_version_is_refused() -> None:
    payload = m.encode(m.JointState(schema=m.SCHEMA_VERSION + 1, position=[1.0]))
    with pytest.raises(m.SchemaMismatch, match="schema 2"):
        m.decode(payload, m.JointState)


@pytest.mark.parametrize(
    "payload",
    [b"", b"\xff\xfe", b"garbage", m.encode(m.EStop()), msgspec.msgpack.encode({"position": "x"})],
)
def test_garbage_is_a_decode_error(payload: bytes) -> None:
    with pytest.raises((msgspec.DecodeError, msgspec.ValidationError)):
        m.decode(payload, m.JointState)


def test_schema_command_lists_every_topic(tmp_path) -> None:
    out = tmp_path / "schema.json"
    subprocess.run(
        [sys.executable, "-m", "climbd.daemon.cli", "schema", "-o", str(out)],
        check=True,
        timeout=60,
    )
    doc = json.loads(out.read_text())
    assert doc["schema_version"] == m.SCHEMA_VERSION
    assert set(doc["topics"]) == {t.TOPIC for t in m.ALL_MESSAGES}
    joint_state = doc["$defs"]["JointState"]["properties"]
    assert {"schema", "stamp", "names", "position", "velocity", "effort"} <= set(joint_state)


def test_topics_doc_lists_every_topic() -> None:
    from pathlib import Path

    doc = (Path(__file__).resolve().parent.parent / "docs" / "topics.md").read_text()
    for t in m.ALL_MESSAGES:
        assert f"`{t.TOPIC}`" in doc and t.__name__ in doc
