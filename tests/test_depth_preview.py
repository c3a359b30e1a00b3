"""Depth on a real robot (issue #39): the perception role sends its frames decimated for viewers
(``DepthPreview`` on ``state/depth``, with the decimated image's own intrinsics), and ``climbd
view`` draws them on ``/depth`` as it draws the twin's ``sim/depth``.

A synthetic frame of a flat floor at a known camera pose goes through the role's decimation,
the wire and the scene's deprojection, and comes out on the floor; end to end, a perception
role on the synthetic floor camera (``--source floor``) publishes previews at their period to
a plain Zenoh subscriber, and a view connected to it serves them as a point cloud.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import math
import time
from pathlib import Path

import msgspec
import numpy as np
import pytest
from conftest import free_port
from support.foxglove_ws import Proc as ViewProc
from support.foxglove_ws import first_on
from support.scene_decode import decoded
from support.zenoh_roles import Observer, Proc

from climbd.daemon.algorithms.world import WorldConfig, world_config
from climbd.daemon.contract import messages as m
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.hardware import DepthFrame, Intrinsics, mount_extrinsics
from climbd.daemon.runtime import scene
from climbd.daemon.runtime.perception_role import PerceptionRole, depth_preview, preview_stride

ROOT = Path(__file__).resolve().parent.parent
FLOOR = -0.25
"""m: the floor's height in the body frame."""


def widowx() -> profiles.Profile:
    return profiles.load(ROOT / "robots/widowx.toml")


def camera_looking_down(tilt_deg: float = 50.0) -> profiles.CameraConfig:
    return msgspec.convert(
        {"name": "front", "mount": {"position": [0.1, 0.02, 0.12], "tilt_deg": tilt_deg}},
        profiles.CameraConfig,
    )


def floor_frame(
    camera: profiles.CameraConfig,
    intrinsics: Intrinsics,
    stamp: float = 1.0,
    scale: float = 0.00025,
    max_range: float = 4.0,
) -> DepthFrame:
    """A frame of the plane z = FLOOR (body frame), rendered by ray-plane intersection."""
    k = intrinsics
    extrinsics = mount_extrinsics(camera)
    u, v = np.meshgrid(np.arange(k.width), np.arange(k.height))
    rays = np.stack([(u - k.ppx) / k.fx, (v - k.ppy) / k.fy, np.ones(u.shape)], axis=-1)
    down = rays @ extrinsics[2, :3]
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (FLOOR - extrinsics[2, 3]) / down
    valid = (down < 0) & (z > 0.1) & (z < max_range)
    depth = np.where(valid, np.round(z / scale), 0).astype(np.uint16)
    return DepthFrame(depth, scale, intrinsics, extrinsics, stamp)


def cloud_points(msg: dict) -> np.ndarray:
    fields = [(f["name"], f["offset"], f["type"]) for f in msg["fields"]]
    assert fields == [("x", 0, "FLOAT32"), ("y", 4, "FLOAT32"), ("z", 8, "FLOAT32")]
    assert msg["point_stride"] == 12
    return np.frombuffer(base64.b64decode(msg["data"]), "<f4").reshape(-1, 3)


def preview_stream(refused: list[str], **options) -> scene.SceneStream:
    """A scene drawing clouds as the view does, with no camera model of its own."""
    return scene.SceneStream(
        scene.RobotScene(widowx()), refused=refused.append, clouds=True, **options
    )


def drawn_clouds(stream: scene.SceneStream, messages, now: float = 0.0) -> list[dict]:
    out = stream.update(messages, int(now * 1e9), now)
    return [decoded(cloud) for topic, cloud in out if topic == scene.CLOUD]


# --- the preview and its cloud ---------------------------------------------------------------


@pytest.mark.parametrize(
    "size,points", [((640, 480), 4800), ((848, 480), 4800), ((1280, 720), 1000), ((640, 480), 1)]
)
def test_the_stride_is_the_smallest_that_fits_and_keeps_the_aspect(size, points) -> None:
    w, h = size
    step = preview_stride(w, h, points)
    assert math.ceil(w / step) * math.ceil(h / step) <= points
    assert step == 1 or math.ceil(w / (step - 1)) * math.ceil(h / (step - 1)) > points
    assert preview_stride(640, 480, 4800) == 8


@pytest.mark.parametrize("tilt", [30.0, 50.0, 90.0])
def test_a_preview_of_a_floor_is_drawn_on_the_floor(tilt: float) -> None:
    camera = camera_looking_down(tilt)
    intrinsics = Intrinsics(640, 480, fx=612.3, fy=611.7, ppx=318.4, ppy=242.9)
    frame = floor_frame(camera, intrinsics, stamp=12.5)
    preview = depth_preview(frame, "front", 4800)
    assert preview is not None
    assert (preview.width, preview.height, preview.stride) == (80, 60, 8)
    assert preview.frame_stamp == 12.5 and preview.camera == "front"
    assert preview.fx == pytest.approx(612.3 / 8) and preview.cy == pytest.approx(242.9 / 8)
    wire = m.decode(m.encode(preview), m.DepthPreview)
    assert len(m.encode(preview)) < 11_000

    refused: list[str] = []
    (cloud,) = drawn_clouds(preview_stream(refused), [wire])
    assert not refused
    assert cloud["frame_id"] == "camera_front"
    points = cloud_points(cloud)
    assert 1000 < len(points) <= 4800
    extrinsics = mount_extrinsics(camera)
    in_body = points @ extrinsics[:3, :3].T + extrinsics[:3, 3]
    assert np.abs(in_body[:, 2] - FLOOR).max() < 0.005
    # the same pixels of the full frame, deprojected with the full frame's intrinsics
    full = m.DepthImage(
        camera="front", width=640, height=480, depth_scale=frame.depth_scale,
        depth=frame.depth.astype("<u2").tobytes(),
    )  # fmt: skip
    same = cloud_points(decoded(scene.depth_cloud(full, intrinsics, 4800, now=0)))
    np.testing.assert_allclose(points, same, atol=1e-5)


def test_the_view_decimates_a_preview_further_to_its_cloud_points() -> None:
    camera = camera_looking_down(90.0)
    intrinsics = Intrinsics(640, 480, fx=600.0, fy=600.0, ppx=320.0, ppy=240.0)
    preview = depth_preview(floor_frame(camera, intrinsics), "front", 4800)
    refused: list[str] = []
    (cloud,) = drawn_clouds(preview_stream(refused, cloud_points=1000), [preview])
    points = cloud_points(cloud)
    assert 500 < len(points) <= 1000 and not refused
    extrinsics = mount_extrinsics(camera)
    in_body = points @ extrinsics[:3, :3].T + extrinsics[:3, 3]
    assert np.abs(in_body[:, 2] - FLOOR).max() < 0.005


def test_a_blank_frame_gives_an_empty_cloud_and_an_odd_preview_none() -> None:
    intrinsics = Intrinsics(640, 480, fx=600.0, fy=600.0, ppx=320.0, ppy=240.0)
    blank = DepthFrame(np.zeros((480, 640), np.uint16), 0.001, intrinsics, np.eye(4), 1.0)
    preview = depth_preview(blank, "front", 4800)
    assert preview is not None and preview.depth == b"\0" * (2 * 80 * 60)
    refused: list[str] = []
    stream = preview_stream(refused)
    (cloud,) = drawn_clouds(stream, [preview])
    assert len(cloud_points(cloud)) == 0 and not refused

    # frames the world model counts as malformed, or without a usable scale: no preview
    for depth, scale in [
        (np.zeros((480, 640), np.float32), 0.001),
        (np.zeros((240, 320), np.uint16), 0.001),
        (np.zeros((480, 640), np.uint16), math.nan),
    ]:
        assert depth_preview(DepthFrame(depth, scale, intrinsics, np.eye(4), 1.0), "f", 100) is None

    # a preview no cloud can be drawn of (empty, or from a peer with no intrinsics) is left
    # out and said once; the stream goes on
    odd = [
        m.DepthPreview(camera="a"),
        m.DepthPreview(camera="b", width=2, height=1, depth=b"\1" * 4),
    ]
    for k, msg in enumerate(odd):
        assert drawn_clouds(stream, [msg], now=10.0 + k) == []
    assert len(refused) == 1 and "cannot draw state/depth" in refused[0]


def test_previews_are_drawn_at_the_cloud_rate_and_only_when_clouds_are_on() -> None:
    camera = camera_looking_down()
    intrinsics = Intrinsics(640, 480, fx=600.0, fy=600.0, ppx=320.0, ppy=240.0)
    preview = depth_preview(floor_frame(camera, intrinsics), "front", 4800)
    stream = preview_stream([], cloud_period=0.5)
    clouds = sum(len(drawn_clouds(stream, [preview], now=k / 10)) for k in range(30))
    assert clouds == 6
    off = scene.SceneStream(scene.RobotScene(widowx()))  # record --scene: no clouds
    assert drawn_clouds(off, [preview]) == []


def test_a_twin_camera_is_drawn_from_its_full_frame_not_its_preview() -> None:
    camera = camera_looking_down()
    intrinsics = Intrinsics(640, 480, fx=600.0, fy=600.0, ppx=320.0, ppy=240.0)
    frame = floor_frame(camera, intrinsics)
    preview = depth_preview(frame, "front", 4800)
    full = m.DepthImage(
        camera="front", width=640, height=480, depth_scale=frame.depth_scale,
        depth=frame.depth.astype("<u2").tobytes(),
    )  # fmt: skip
    stream = preview_stream([], intrinsics=lambda c, w, h: intrinsics, cloud_period=0.0)
    assert len(drawn_clouds(stream, [preview], now=0.0)) == 1  # no twin heard yet
    assert len(drawn_clouds(stream, [full], now=1.0)) == 1
    assert drawn_clouds(stream, [preview], now=2.0) == []


def test_an_oversized_preview_is_refused_at_decode() -> None:
    payload = msgspec.msgpack.encode(
        {"schema": m.SCHEMA_VERSION, "depth": b"\0" * (m.MAX_PREVIEW_BYTES + 1)}
    )
    with pytest.raises(msgspec.ValidationError, match=r"\$\.depth"):
        m.decode(payload, m.DepthPreview)


# --- the perception role ---------------------------------------------------------------------


def test_the_role_sends_a_preview_every_period_of_frame_time_posed_or_not() -> None:
    profile = widowx()
    role = PerceptionRole(profile, argparse.Namespace())
    assert role.preview == (0.5, 4800)
    intrinsics = Intrinsics(640, 480, fx=600.0, fy=600.0, ppx=320.0, ppy=240.0)
    camera = camera_looking_down()
    sent: list[m.Message] = []
    for k in range(90):  # 3 s at 30 fps, no body state ever: every frame refused a pose
        frame = floor_frame(camera, intrinsics, stamp=100.0 + k / 30)
        role._publish_preview(frame, sent.append)
    assert [type(s) for s in sent] == [m.DepthPreview] * 6
    assert all(s.camera == "front" and s.width * s.height <= 4800 for s in sent)
    stamps = np.diff([s.frame_stamp for s in sent])
    assert np.all((stamps >= 0.5 - 1e-9) & (stamps < 0.54))

    off = PerceptionRole(with_world(profile, preview_period=0.0), argparse.Namespace())
    sent.clear()
    for k in range(30):
        off._publish_preview(floor_frame(camera, intrinsics, stamp=k / 30), sent.append)
    assert sent == []


def with_world(profile: profiles.Profile, **world) -> profiles.Profile:
    data = msgspec.to_builtins(profile)
    data["world"] = world
    return profiles.from_dict(data, "widowx")


def test_preview_fields_are_checked_in_the_world_table() -> None:
    config = world_config(with_world(widowx(), preview_period=0.25, preview_points=1200))
    assert (config.preview_period, config.preview_points) == (0.25, 1200)
    assert WorldConfig().preview_period == 0.5
    for field, value in [("preview_period", -1.0), ("preview_points", 0),
                         ("preview_points", m.MAX_PREVIEW_PIXELS + 1)]:  # fmt: skip
        with pytest.raises(profiles.ProfileError, match=rf"\$\.world\.{field}"):
            world_config(with_world(widowx(), **{field: value}))


# --- end to end ------------------------------------------------------------------------------


def test_a_perception_role_on_a_floor_camera_serves_depth_to_a_subscriber_and_the_view() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    profile = widowx()
    (camera,) = profile.cameras
    role = Proc(
        "run", "--profile", "robots/widowx.toml", "--role", "perception", "--source", "floor",
        "--listen", endpoint, "--duration", "60",
    )  # fmt: skip
    observer = view = None
    try:
        role.wait_for("perception role", timeout=60)
        observer = Observer("widowx", [endpoint])
        observer.watch(m.DepthPreview)
        observer.wait(m.DepthPreview, lambda p: True, timeout=30)
        time.sleep(3.0)
        got = observer.seen[m.DepthPreview]
        arrivals = [t for t, _ in got]
        assert len(got) >= 5
        rate = (len(got) - 1) / (arrivals[-1] - arrivals[0])
        assert 1.4 < rate < 2.6, rate  # preview_period 0.5 s
        frames = np.diff([p.frame_stamp for _, p in got])
        assert np.all(frames > 0.45) and np.all(frames < 0.7), frames
        last = got[-1][1]
        assert (last.camera, last.width, last.height, last.stride) == ("front", 80, 60, 8)
        assert abs(last.frame_stamp - time.monotonic()) < 1.0  # the robot's (monotonic) clock

        # its points lie on the floor the synthetic camera sees, body_height below the body
        (cloud,) = drawn_clouds(preview_stream([]), [last])
        points = cloud_points(cloud)
        assert 1000 < len(points) <= 4800
        extrinsics = mount_extrinsics(camera)
        in_body = points @ extrinsics[:3, :3].T + extrinsics[:3, 3]
        assert np.abs(in_body[:, 2] + profile.stand.body_height).max() < 0.005

        view = ViewProc(
            "view", "--robot", "widowx", "--connect", endpoint, "--port", "0",
            "--cloud-rate", "4", "--cloud-points", "2000",
        )  # fmt: skip
        port = int(view.wait_for("to Foxglove on ws://").split("ws://127.0.0.1:")[1].split()[0])
        channel, msg = asyncio.run(first_on(port, "/depth", time.monotonic() + 20))
        assert channel["schemaName"] == "foxglove.PointCloud"
        assert msg["frame_id"] == "camera_front"
        served = cloud_points(msg)
        assert 500 < len(served) <= 2000
        in_body = served @ extrinsics[:3, :3].T + extrinsics[:3, 3]
        assert np.abs(in_body[:, 2] + profile.stand.body_height).max() < 0.005
    finally:
        if view is not None:
            code = view.stop()
            assert code == 0 and "Traceback" not in "".join(view.lines), "".join(view.lines)
        if observer is not None:
            observer.close()
        assert role.stop() == 0, role.text
    assert "Traceback" not in role.text
