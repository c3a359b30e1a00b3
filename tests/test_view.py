"""``climbd view``: climbd's messages as Foxglove schemas, served live over Foxglove's WebSocket.

The translation is checked against geometry built here, decoded with protobuf from the schema
each foxglove-sdk message type advertises (as a Foxglove client does). The end-to-end test
starts the view before the robot, the robot with the fake driver, and speaks the Foxglove
WebSocket protocol with the ``websockets`` package (no climbd code on the client side): every
advertised channel decodes against its advertised schema, the transforms form one tree rooted
at the odometry frame, and the view says when the robot is not heard and when it comes back.
"""

from __future__ import annotations

import asyncio
import base64
import json
import math
import time
import zlib
from pathlib import Path

import foxglove
import jsonschema
import msgspec
import numpy as np
import pytest
from conftest import free_port
from support.foxglove_ws import MapPublisher, Proc, check_payloads, foxglove_client
from support.scene_decode import decoded, in_frame, tree

from climbd.daemon.cli.view import Latest, Presence, Viewer
from climbd.daemon.contract import messages as m
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.runtime import scene

ROOT = Path(__file__).resolve().parent.parent


def xyz(v: dict) -> list[float]:
    return [v["x"], v["y"], v["z"]]


def quat_of(pose: dict) -> list[float]:
    o = pose["orientation"]
    return [o["w"], o["x"], o["y"], o["z"]]


# --- the robot's frames ---------------------------------------------------------------------


def two_legs() -> profiles.Profile:
    """A robot of two legs with round numbers: a coxa-femur-tibia leg pointing left and an
    abduction-thigh-shank leg pointing right, joints in the kinematic convention."""
    data = msgspec.to_builtins(profiles.load(ROOT / "robots/widowx.toml"))
    left, right = data["legs"][3], data["legs"][0]
    left.update(name="l", mount=[0.1, 0.05, 0.0], yaw=math.pi / 2, links=[0.05, 0.1, 0.2])
    right.update(name="r", mount=[0.0, -0.1, 0.0], yaw=-math.pi / 2, links=[0.04, 0.1, 0.1])
    right["kind"] = "abduction_thigh_shank"
    for leg in (left, right):
        for joint, part in zip(leg["joints"], ("a", "b", "c"), strict=True):
            joint.update(name=f"{leg['name']}_{part}", direction=1, zero_offset=0.0)
            joint["limits"].update(lower=-4.0, upper=4.0)
    data["legs"] = [left, right]
    data["cameras"][0]["mount"] = {"position": [0.2, 0.0, 0.1], "tilt_deg": 90.0}
    data["stand"] = {"body_height": 0.1, "foot_reach": 0.15}
    return profiles.from_dict(data, "two-legs")


def test_link_frames_put_each_joint_and_foot_where_the_geometry_says() -> None:
    robot = scene.RobotScene(two_legs())
    # l: coxa 0, femur level, tibia straight down; r: no abduction, thigh and shank down
    joints = m.JointState(
        names=["r_a", "r_b", "r_c", "l_a", "l_b", "l_c"],  # any order: matched by name
        position=[0.0, math.pi / 2, math.pi / 2, 0.0, 0.0, -math.pi / 2],
    )
    body = m.BodyState(position=[1.0, 2.0, 0.3], orientation=[math.cos(0.25), 0, 0, math.sin(0.25)])
    out = decoded(robot.transforms(body, joints, now=1_700_000_000_123_456_789))
    assert {t["timestamp"] for t in out["transforms"]} == {"2023-11-14T22:13:20.123456789Z"}
    frames = tree(out["transforms"])
    expected = {
        "l_a": [0.1, 0.05, 0.0],
        "l_b": [0.1, 0.1, 0.0],
        "l_c": [0.1, 0.2, 0.0],
        "l_foot": [0.1, 0.2, -0.2],
        "r_a": [0.0, -0.1, 0.0],
        "r_b": [0.0, -0.14, 0.0],
        "r_c": [0.0, -0.14, -0.1],
        "r_foot": [0.0, -0.14, -0.2],
    }
    for frame, position in expected.items():
        np.testing.assert_allclose(in_frame(frames, frame, "body")[0], position, atol=1e-12)
    np.testing.assert_allclose(
        [in_frame(frames, f"{leg}_foot", "body")[0] for leg in "lr"],
        robot.kinematics.fk(robot.joint_vector(joints)),
        atol=1e-12,
    )
    # the body pose: yaw 0.5 rad at (1, 2, 0.3) in odom
    p, r = in_frame(frames, "l_foot", "odom")
    yaw = rotation(body.orientation)
    np.testing.assert_allclose(p, yaw @ [0.1, 0.2, -0.2] + [1.0, 2.0, 0.3], atol=1e-12)
    # the camera looks straight down (tilt 90°): its optical z is the body's -z
    p, r = in_frame(frames, "camera_front", "body")
    np.testing.assert_allclose(p, [0.2, 0.0, 0.1], atol=1e-12)
    np.testing.assert_allclose(r @ [0, 0, 1], [0, 0, -1], atol=1e-12)
    # abduction a quarter turn swings the right leg's foot out along the leg's y
    joints.position[0] = math.pi / 2
    frames = tree(decoded(robot.transforms(None, joints, now=0))["transforms"])
    np.testing.assert_allclose(in_frame(frames, "r_foot", "body")[0], [0.2, -0.14, 0.0], atol=1e-12)


@pytest.mark.parametrize("robot", sorted(profiles.stock_profiles()))
def test_link_frames_chain_to_the_feet_of_forward_kinematics(robot: str) -> None:
    kin = scene.RobotScene(profiles.load(profiles.stock_profiles()[robot])).kinematics
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = kin.lower + rng.uniform(size=kin.n_joints) * (kin.upper - kin.lower)
        trans, quats = kin.link_frames(q)
        for leg, foot in enumerate(kin.fk(q)):
            p, r = np.zeros(3), np.eye(3)
            for t, qk in zip(trans[leg], quats[leg], strict=True):
                p, r = p + r @ t, r @ rotation(qk)
            np.testing.assert_allclose(p, foot, atol=1e-12)


def test_transforms_leave_out_what_is_unknown() -> None:
    robot = scene.RobotScene(two_legs())
    only_cameras = decoded(robot.transforms(None, None, now=0))["transforms"]
    assert [(t["parent_frame_id"], t["child_frame_id"]) for t in only_cameras] == [
        ("body", "camera_front")
    ]
    lost = m.JointState(
        names=["l_a", "l_b", "l_c", "r_a", "r_b"], position=[0.0, 0.0, math.nan, 0, 0]
    )
    children = {
        t["child_frame_id"] for t in decoded(robot.transforms(None, lost, now=0))["transforms"]
    }
    assert children == {"camera_front"}, "a leg with a lost or missing joint keeps its last pose"
    bad_body = m.BodyState(orientation=[0.0, 0.0, 0.0, 0.0])
    assert "body" not in {
        t["child_frame_id"] for t in decoded(robot.transforms(bad_body, None, now=0))["transforms"]
    }


def test_robot_geometry_is_locked_to_the_link_frames() -> None:
    robot = scene.RobotScene(two_legs())
    update = decoded(robot.geometry(now=0))
    assert [d["type"] for d in update["deletions"]] == ["ALL"]
    by_id = {e["id"]: e for e in update["entities"]}
    assert set(by_id) == {
        "body", "camera_front", "l_foot", "r_foot",
        *(f"link/{leg}_{part}" for leg in "lr" for part in "abc"),
    }  # fmt: skip
    assert all(e["frame_locked"] for e in update["entities"])
    femur = by_id["link/l_b"]
    assert femur["frame_id"] == "l_b"
    (cylinder,) = femur["cylinders"]
    assert cylinder["size"]["z"] == pytest.approx(0.1)  # the link's length, along its x
    axis = rotation(quat_of(cylinder["pose"])) @ [0, 0, 1]
    np.testing.assert_allclose(axis, [1, 0, 0], atol=1e-12)
    assert xyz(cylinder["pose"]["position"]) == pytest.approx([0.05, 0, 0])


# --- the maps -------------------------------------------------------------------------------


def test_joist_of_known_pose_is_a_box_of_that_pose() -> None:
    joist = m.MappedJoist(
        id=7, confidence=1.0, seen=3, age=0.0, heading=math.pi / 2, offset=1.0, height=0.2,
        endpoints=[[-0.5, 1.0, 0.2], [0.5, 1.0, 0.2]],
    )  # fmt: skip
    update = decoded(scene.joists(m.JoistMap(joists=[joist]), now=0))
    (entity,) = update["entities"]
    assert entity["id"] == "joist/7" and entity["frame_id"] == "odom"
    (box,) = entity["cubes"]
    assert xyz(box["size"]) == pytest.approx([scene.JOIST_WIDTH, 1.0, 0.2])
    centre = [0.0, 1.0 + scene.JOIST_WIDTH / 2, 0.1]
    assert xyz(box["pose"]["position"]) == pytest.approx(centre)
    r = rotation(quat_of(box["pose"]))
    np.testing.assert_allclose(r @ [1, 0, 0], [0, 1, 0], atol=1e-12)  # width along the normal
    assert box["color"] == {"r": 0.0, "g": 1.0, "b": 0.0, "a": pytest.approx(0.9)}


def test_holds_are_spheres_coloured_by_confidence() -> None:
    holds = m.HoldMap(
        holds=[
            m.MappedHold(id=1, confidence=0.0, seen=1, age=0.0, position=[1.0, 2.0, 3.0]),
            m.MappedHold(id=2, confidence=0.5, seen=2, age=0.0, position=[0.0, 0.0, 1.0]),
            m.MappedHold(id=3, confidence=1.0, seen=9, age=0.0, position=[math.nan, 0.0, 1.0]),
        ]
    )
    entities = decoded(scene.holds(holds, now=0))["entities"]
    assert [e["id"] for e in entities] == ["hold/1", "hold/2"]  # a NaN hold is left out
    (red,), (yellow,) = (e["spheres"] for e in entities)
    assert xyz(red["pose"]["position"]) == [1.0, 2.0, 3.0]
    assert xyz(red["size"]) == pytest.approx([scene.HOLD_DIAMETER] * 3)
    assert (red["color"]["r"], red["color"]["g"]) == (1.0, 0.0)
    assert (yellow["color"]["r"], yellow["color"]["g"]) == (1.0, 1.0)
    assert {"key": "seen", "value": "2"} in entities[1]["metadata"]


def test_stair_tread_is_a_block_up_the_flight_from_its_edge() -> None:
    # facing up the flight along +x: the edge's left end is at +y
    step = m.MappedStair(
        id=2, confidence=0.8, seen=4, age=0.1, height=0.3, rise=0.15, depth=0.3,
        edge=[[1.0, 0.5, 0.3], [1.0, -0.5, 0.3]],
    )  # fmt: skip
    (entity,) = decoded(scene.stairs(m.StairMap(steps=[step]), now=0))["entities"]
    (box,) = entity["cubes"]
    assert xyz(box["pose"]["position"]) == pytest.approx([1.15, 0.0, 0.225])
    assert xyz(box["size"]) == pytest.approx([0.3, 1.0, 0.15])
    np.testing.assert_allclose(rotation(quat_of(box["pose"])), np.eye(3), atol=1e-12)


def test_truss_members_are_cylinders_between_their_ends_and_nodes_spheres() -> None:
    truss = m.TrussMembers(
        members=[
            m.TrussMember(
                p0=[0.0, 0.0, 1.0], p1=[2.0, 0.0, 1.0], radius=0.05, axis=[1, 0, 0], id=4
            ),
            m.TrussMember(
                p0=[0.0, 0.0, 1.0], p1=[0.0, 0.0, 0.0], radius=0.02, axis=[0, 0, -1], id=5
            ),
        ],
        nodes=[m.TrussNode(position=[0.0, 0.0, 1.0], members=[4, 5])],
    )
    by_id = {e["id"]: e for e in decoded(scene.truss(truss, now=0))["entities"]}
    (bar,) = by_id["member/4"]["cylinders"]
    assert xyz(bar["pose"]["position"]) == pytest.approx([1.0, 0.0, 1.0])
    assert xyz(bar["size"]) == pytest.approx([0.1, 0.1, 2.0])
    np.testing.assert_allclose(rotation(quat_of(bar["pose"])) @ [0, 0, 1], [1, 0, 0], atol=1e-12)
    (post,) = by_id["member/5"]["cylinders"]  # pointing straight down: the z-flip branch
    np.testing.assert_allclose(rotation(quat_of(post["pose"])) @ [0, 0, 1], [0, 0, -1], atol=1e-12)
    (node,) = by_id["node/0"]["spheres"]
    assert xyz(node["size"]) == pytest.approx([2 * scene.NODE_SCALE * 0.05] * 3)


def test_elevation_grid_cells_land_where_the_body_frame_grid_puts_them() -> None:
    heights = np.arange(6, dtype="<f4").reshape(2, 3)  # rows along x, columns along y
    quarter = [math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]  # yaw 90°
    grid = m.ElevationGrid(
        rows=2, cols=3, resolution=0.1, origin_x=0.5, origin_y=-0.1, heights=heights.tobytes(),
        frame_position=[1.0, 0.0, 0.2], frame_orientation=quarter,
    )  # fmt: skip
    out = decoded(scene.elevation(grid, now=0))
    assert out["column_count"] == 2 and out["cell_stride"] == 4 and out["row_stride"] == 8
    data = np.frombuffer(base64.b64decode(out["data"]), "<f4")
    origin, r = np.array(xyz(out["pose"]["position"])), rotation(quat_of(out["pose"]))
    body = rotation(grid.frame_orientation)
    for row in range(2):
        for col in range(3):
            fg_row, fg_col = col, row  # Foxglove: columns along the grid's x
            value = data[fg_row * 2 + fg_col]
            assert value == heights[row, col]
            corner = origin + r @ [fg_col * 0.1, fg_row * 0.1, 0.0]
            expected = np.array([1.0, 0.0, 0.2]) + body @ [0.5 + row * 0.1, -0.1 + col * 0.1, 0]
            np.testing.assert_allclose(corner, expected, atol=1e-6)
    assert scene.elevation(m.ElevationGrid(rows=2, cols=3, heights=b"\0" * 4), now=0) is None


def test_terrain_map_is_a_grid_with_every_layer_at_its_odometry_cells() -> None:
    """Each TerrainMap layer becomes a float32 field of the cell it describes (height back in
    the odometry frame, NaN kept unknown), so Foxglove colours the grid by any layer."""
    rows, cols, z0 = 2, 3, 0.25
    values = {
        name: np.arange(rows * cols, dtype=np.float32).reshape(rows, cols) + 10 * k
        for k, name in enumerate(m.TERRAIN_LAYERS)
    }
    values["height"] = np.array([[0.01, 0.02, np.nan], [0.04, 0.05, 0.06]], np.float32)
    layers = {n: zlib.compress(v.astype("<f2").tobytes()) for n, v in values.items()}
    terrain = m.TerrainMap(
        rows=rows, cols=cols, resolution=0.05, origin_x=1.0, origin_y=-0.5, origin_z=z0,
        layers=layers,
    )  # fmt: skip
    out = decoded(scene.terrain(terrain, now=0))
    names = [f["name"] for f in out["fields"]]
    assert names == list(m.TERRAIN_LAYERS) and out["column_count"] == rows
    assert xyz(out["pose"]["position"]) == [1.0, -0.5, 0.0]
    data = np.frombuffer(base64.b64decode(out["data"]), "<f4").reshape(cols, rows, len(names))
    for row in range(rows):
        for col in range(cols):
            cell = data[col, row]  # Foxglove: columns along the grid's x (climbd's rows)
            for k, name in enumerate(names):
                want = np.float32(np.float16(values[name][row, col]))
                want = want + np.float32(z0) if name == "height" else want
                if np.isnan(want):
                    assert np.isnan(cell[k])
                else:
                    assert cell[k] == pytest.approx(want, abs=1e-6)
    assert scene.terrain(m.TerrainMap(), now=0) is None


def test_json_channels_carry_nan_as_null_and_still_match_their_schema() -> None:
    health = m.Health(joints=[m.JointHealth(name="rf_coxa")])  # temperature, voltage: NaN
    payload = json.loads(scene.json_payload(health))
    assert payload["joints"][0]["temperature"] is None
    jsonschema.validate(payload, scene.json_schema(m.Health))
    assert scene.json_schema(m.Health)["title"] == "Health"  # fields at the top, for Foxglove


def test_a_map_that_cannot_be_drawn_is_left_out_and_the_view_goes_on(capsys) -> None:
    viewer = Viewer(scene.RobotScene(two_legs()), foxglove.Context())
    short = m.MappedJoist(
        id=1, confidence=1, seen=1, age=0, heading=0, offset=0, height=0.1, endpoints=[[0, 0]] * 2
    )
    assert decoded(scene.joists(m.JoistMap(joists=[short]), now=0))["entities"] == []
    broken = m.JointState(names=["l_a"], position=[0.0])
    viewer.scene.transforms = lambda *_: 1 / 0  # a bug in a translation
    viewer.publish({m.JointState: broken, m.JoistMap: m.JoistMap(joists=[short])}, 0, 0.0)
    viewer.publish({m.JointState: broken}, 1, 1.0)
    err = capsys.readouterr().err
    assert err.count("cannot draw state/body and state/joints: ZeroDivisionError") == 1


# --- the view's own state -------------------------------------------------------------------


def test_latest_keeps_one_message_of_each_kind_and_health_per_role() -> None:
    latest = Latest()
    for k in range(100):
        latest.put(m.JointState(stamp=float(k)))
    latest.put(m.Health(role="control"))
    latest.put(m.Health(role="perception"))
    fresh = latest.take()
    assert fresh[m.JointState].stamp == 99.0 and len(fresh) == 3
    assert latest.take() == {}


def test_presence_says_when_the_robot_is_not_heard_goes_silent_and_comes_back() -> None:
    p = Presence("widowx", "tcp/x:1", silent_after=1.0, started=0.0)
    never = -math.inf
    said = [p.update(never, t) for t in (0.5, 1.5, 2.0)]
    assert said[0] is None and "no robot 'widowx' heard on tcp/x:1" in said[1] and said[2] is None
    assert p.update(2.5, 2.5) == "robot 'widowx' heard"
    assert p.update(2.5, 3.0) is None
    assert "silent" in p.update(2.5, 4.0)
    assert p.update(2.5, 9.0) is None
    assert p.update(9.5, 9.5) == "robot 'widowx' heard again"


# --- end to end -----------------------------------------------------------------------------


def test_view_serves_a_live_robot_to_a_foxglove_client(endpoint: str) -> None:
    maps_ep = f"tcp/127.0.0.1:{free_port()}"
    robot_args = ("run", "--profile", "robots/widowx.toml", "--driver", "fake", "--listen",
                  endpoint, "--quiet")  # fmt: skip
    view = Proc(
        "view", "--robot", "widowx", "--connect", endpoint, "--connect", maps_ep,
        "--port", "0", "--silent-after", "1",
    )  # fmt: skip
    robot = maps = None
    try:
        port = int(view.wait_for("to Foxglove on ws://").split("ws://127.0.0.1:")[1].split()[0])
        view.wait_for("no robot 'widowx' heard on")  # started before the robot: says so
        robot = Proc(*robot_args)
        robot.wait_for("control role")
        view.wait_for("robot 'widowx' heard")
        maps = MapPublisher(maps_ep)
        channels, data = asyncio.run(foxglove_client(port, time.monotonic() + 10))
        topics = check_payloads(channels, data)
        assert set(topics) == {
            "/tf", "/robot", "/joists", "/holds", "/stairs", "/truss", "/elevation", "/mode",
            "/health", "/loop", "/estop",
        }  # fmt: skip

        # the transforms: one tree rooted at odom, with every link, foot and the camera
        frames = tree([t for msg in topics["/tf"] for t in msg["transforms"]])
        profile = profiles.load(ROOT / "robots/widowx.toml")
        expected = {"body", "camera_front"} | {j.name for j in profile.joints}
        expected |= {f"{leg.name}_foot" for leg in profile.legs}
        assert set(frames) == expected
        for frame in frames:
            seen = set()
            while frame != "odom":
                assert frame not in seen and frame in frames, f"{frame} does not reach odom"
                seen.add(frame)
                frame = frames[frame][0]
        assert frames["body"][0] == "odom"
        feet = [in_frame(frames, f"{leg.name}_foot", "body")[0] for leg in profile.legs]
        assert all(f[2] < -0.05 for f in feet), "a standing robot's feet are below its body"

        ids = {e["id"] for msg in topics["/robot"] for e in msg["entities"]}
        assert {"body", "camera_front", "link/rf_femur", "rf_foot"} <= ids
        for topic, kind in (("/joists", "cubes"), ("/holds", "spheres"), ("/stairs", "cubes"),
                            ("/truss", "cylinders")):  # fmt: skip
            assert any(e[kind] for msg in topics[topic] for e in msg["entities"]), topic
        assert topics["/elevation"][-1]["column_count"] == 4
        assert topics["/mode"][-1]["mode"] in {"STAND", "HOLD"}
        assert any(h["role"] == "control" for h in topics["/health"])
        assert topics["/loop"][-1]["rate_hz"] > 0 and topics["/estop"][-1]["engaged"] is False

        # the robot goes away (and the maps with it), then comes back
        maps.close()
        maps = None
        mark = len(view.lines)
        assert robot.stop() == 0
        view.wait_for("robot 'widowx' silent", after=mark)
        mark = len(view.lines)
        robot = Proc(*robot_args)
        view.wait_for("robot 'widowx' heard again", timeout=30, after=mark)
        channels, data = asyncio.run(foxglove_client(port, time.monotonic() + 3))
        tf = next(cid for cid, c in channels.items() if c["topic"] == "/tf")
        assert data.get(tf), "transforms flow again after the robot came back"
    finally:
        if maps is not None:
            maps.close()
        if robot is not None:
            robot.stop()
        code = view.stop()
    assert code == 0, "".join(view.lines)
    assert "Traceback" not in "".join(view.lines)
