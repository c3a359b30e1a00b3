"""The gait's plan, graspable points and the operator channels in the scene (``climbd view``,
``climbd record --scene``): foot targets and swing paths on /plan, graspable points on /grasp,
the control loop's statistics on /loop and the e-stop on /estop, each decoded against the
schema its channel declares."""

from __future__ import annotations

import json
import math

import foxglove
import jsonschema
import numpy as np
import pytest
from support.scene_decode import decoded
from test_view import two_legs, xyz

from climbd.daemon.cli.view import Viewer
from climbd.daemon.contract import messages as m
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.runtime import scene

STANDING = m.JointState(
    names=["l_a", "l_b", "l_c", "r_a", "r_b", "r_c"],
    position=[0.0, 0.0, -math.pi / 2, 0.0, math.pi / 2, math.pi / 2],
)
"""Both feet under their knees (test_view: l_foot at (0.1, 0.2, -0.2), r_foot (0, -0.14, -0.2))."""


def rgba(primitive: dict) -> list[float]:
    return [primitive["color"][c] for c in "rgba"]


def test_foot_targets_are_spheres_and_a_swinging_foot_a_line_from_where_it_is() -> None:
    robot = scene.RobotScene(two_legs())
    targets = m.FootTargets(
        positions=[[0.1, 0.2, -0.2], [0.05, -0.2, -0.15]], stance=[True, False], grip=[True, False]
    )
    update = decoded(robot.plan(targets, STANDING, now=5))
    assert [d["type"] for d in update["deletions"]] == ["ALL"]
    by_id = {e["id"]: e for e in update["entities"]}
    assert set(by_id) == {"target/l", "target/r"}
    assert all(e["frame_id"] == "body" and e["frame_locked"] for e in by_id.values())
    (stance,), (swing,) = by_id["target/l"]["spheres"], by_id["target/r"]["spheres"]
    assert xyz(stance["pose"]["position"]) == pytest.approx([0.1, 0.2, -0.2])
    assert rgba(stance) == pytest.approx(scene.STANCE_COLOR)
    assert rgba(swing) == pytest.approx(scene.SWING_COLOR)
    assert by_id["target/l"]["lines"] == [], "a stance foot has no path"
    (path,) = by_id["target/r"]["lines"]
    assert path["type"] == "LINE_STRIP"
    ends = [xyz(p) for p in path["points"]]
    np.testing.assert_allclose(ends, [[0.0, -0.14, -0.2], [0.05, -0.2, -0.15]], atol=1e-12)
    meta = {kv["key"]: kv["value"] for kv in by_id["target/r"]["metadata"]}
    assert meta == {"phase": "swing", "grip": "false"}

    # a leg with a lost joint keeps its target but has no path; a NaN target is left out
    lost = m.JointState(names=STANDING.names, position=[*STANDING.position[:5], math.nan])
    update = decoded(robot.plan(targets, lost, now=6))
    assert [e["lines"] for e in update["entities"]] == [[], []]
    targets.positions[0] = [math.nan, 0.0, 0.0]
    assert [e["id"] for e in decoded(robot.plan(targets, None, now=7))["entities"]] == ["target/r"]


def test_the_plan_goes_out_with_the_transforms_and_is_cleared_out_of_active() -> None:
    stream = scene.SceneStream(scene.RobotScene(two_legs()), tf_period=0.095)
    targets = m.FootTargets(positions=[[0.1, 0.2, -0.2], [0.0, -0.14, -0.2]], stance=[True, True])
    topics = []
    for k in range(100):  # 100 Hz of joints and foot targets for 1 s
        topics += [t for t, _ in stream.update([STANDING, targets], k * 10_000_000, k / 100)]
    assert topics.count("/plan") == topics.count("/tf") == 10
    out = stream.update([m.ModeState(mode=m.Mode.HOLD)], 2_000_000_000, 2.0)
    cleared = decoded(dict(out)["/plan"])
    assert cleared["entities"] == [] and [d["type"] for d in cleared["deletions"]] == ["ALL"]
    later = stream.update([STANDING, m.ModeState(mode=m.Mode.HOLD)], 3_000_000_000, 3.0)
    assert "/plan" not in dict(later), "no plan until foot targets come again, cleared once"


def test_graspable_points_are_placed_with_their_frames_body_pose_and_thinned() -> None:
    yaw = [math.cos(0.5), 0.0, 0.0, math.sin(0.5)]  # 1 rad about z
    points = m.GraspablePoints(
        frame_position=[1.0, 2.0, 0.3],
        frame_orientation=yaw,
        points=[[0.2, 0.0, -0.1], [math.nan, 0.0, 0.0], [0.0, 0.1, -0.1]],
    )
    update = decoded(scene.grasp(points, now=0))
    (entity,) = update["entities"]
    assert entity["frame_id"] == "odom"
    placed = [xyz(s["pose"]["position"]) for s in entity["spheres"]]
    expected = [rotation(yaw) @ p + [1.0, 2.0, 0.3] for p in ([0.2, 0, -0.1], [0, 0.1, -0.1])]
    np.testing.assert_allclose(placed, expected, atol=1e-12)
    assert rgba(entity["spheres"][0]) == pytest.approx(scene.GRASP_COLOR)

    many = m.GraspablePoints(points=[[0.001 * k, 0.0, 0.0] for k in range(2000)])
    (entity,) = decoded(scene.grasp(many, now=0, max_points=100))["entities"]
    xs = [s["pose"]["position"]["x"] for s in entity["spheres"]]
    assert len(xs) == 100 and xs[0] == 0.0 and xs[-1] == pytest.approx(1.999)

    stream = scene.SceneStream(scene.RobotScene(two_legs()), grasp_period=0.45)
    drawn = [t for k in range(30) for t, _ in stream.update([points], k * 100_000_000, k / 10)]
    assert drawn.count("/grasp") == 6, "at most once per grasp_period"


def test_loop_and_estop_are_flat_json_matching_their_schemas() -> None:
    stream = scene.SceneStream(scene.RobotScene(two_legs()))
    loop = m.LoopStats(rate_hz=99.5, ticks=199, overruns=2, lateness_p50=1e-4,
                       lateness_p99=4e-4, compute_p50=2e-4, compute_p99=6e-4)  # fmt: skip
    fresh = [
        m.Health(stamp=12.5, role="perception"),
        m.Health(stamp=12.0, role="control", loop=loop),
        m.ModeState(stamp=13.0, mode=m.Mode.ESTOP, reason="e-stop", estop_by=["laptop", "pad"]),
    ]
    out = stream.update(fresh, 0, 0.0)
    by_topic: dict[str, list] = {}
    for topic, payload in out:
        if topic in ("/loop", "/estop", "/health", "/mode"):
            value = json.loads(scene.payload(payload))
            jsonschema.validate(value, scene.json_schema(scene.TOPICS[topic]))
            by_topic.setdefault(topic, []).append(value)
    assert len(by_topic["/health"]) == 2
    (flat,) = by_topic["/loop"]  # the control role's only
    assert flat == {
        "stamp": 12.0, "rate_hz": 99.5, "ticks": 199, "overruns": 2, "lateness_p50": 1e-4,
        "lateness_p99": 4e-4, "lateness_max": 0.0, "compute_p50": 2e-4, "compute_p99": 6e-4,
    }  # fmt: skip
    (estop,) = by_topic["/estop"]
    assert estop["engaged"] is True and estop["by"] == ["laptop", "pad"]
    assert estop["mode"] == "ESTOP" and estop["stamp"] == 13.0
    released = dict(stream.update([m.ModeState(mode=m.Mode.HOLD, reset_by="op")], 1, 1.0))
    assert json.loads(released["/estop"])["engaged"] is False


def test_the_view_advertises_the_plan_when_a_gait_steps() -> None:
    viewer = Viewer(scene.RobotScene(two_legs()), foxglove.Context())
    assert {"/loop", "/estop"} <= set(viewer.channels) and "/plan" not in viewer.channels
    declared = scene.channel_schema("/loop")
    assert (declared.name, declared.encoding, declared.message_encoding) == (
        "climbd.Loop", "jsonschema", "json",
    )  # fmt: skip
    targets = m.FootTargets(positions=[[0.1, 0.2, -0.2], [0.0, -0.14, -0.2]], stance=[True, False])
    viewer.publish({m.JointState: STANDING, m.FootTargets: targets}, 0, 0.0)
    assert "/plan" in viewer.channels
