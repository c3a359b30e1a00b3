"""``climbd view``: depth as a point cloud in the camera's frame, decimated in rate and size.

The cloud is checked against perception's own deprojection (``frame_to_points``: the points
perception works on, in the body frame) through the camera's mount, and served to a client
that speaks the Foxglove WebSocket protocol (no climbd code on its side), which decodes it
against the schema the channel advertises when the first depth image is drawn.
"""

from __future__ import annotations

import asyncio
import base64
import threading
import time
from pathlib import Path

import foxglove
import numpy as np
from support.foxglove_ws import first_on
from support.scene_decode import decoded

from climbd.daemon.algorithms.cloud import frame_to_points
from climbd.daemon.cli.view import Latest, Viewer, camera_intrinsics
from climbd.daemon.contract import messages as m
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.hardware import DepthFrame, mount_extrinsics
from climbd.daemon.runtime import scene

ROOT = Path(__file__).resolve().parent.parent
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def widowx() -> profiles.Profile:
    return profiles.load(ROOT / "robots/widowx.toml")


def image(seed: int = 0, camera: str = "front", stamp: float = 0.0) -> m.DepthImage:
    """A 640×480 depth image (the WidowX's L515) of 0.5–2.5 m with a tenth of no returns."""
    rng = np.random.default_rng(seed)
    depth = rng.integers(2000, 10000, size=(480, 640), dtype=np.uint16)  # × 0.25 mm
    depth[rng.uniform(size=depth.shape) < 0.1] = 0
    return m.DepthImage(
        stamp=stamp, camera=camera, width=640, height=480, depth_scale=0.00025,
        depth=depth.astype("<u2").tobytes(),
    )  # fmt: skip


def cloud_points(msg: dict) -> np.ndarray:
    fields = [(f["name"], f["offset"], f["type"]) for f in msg["fields"]]
    assert fields == [("x", 0, "FLOAT32"), ("y", 4, "FLOAT32"), ("z", 8, "FLOAT32")]
    assert msg["point_stride"] == 12
    return np.frombuffer(base64.b64decode(msg["data"]), "<f4").reshape(-1, 3)


def test_cloud_is_where_perception_puts_the_points_and_at_most_the_points_asked() -> None:
    profile = widowx()
    (camera,) = profile.cameras
    intrinsics = camera_intrinsics(profile)("front", 640, 480)
    assert camera_intrinsics(profile)("back", 640, 480) is None
    img = image()
    msg = decoded(scene.depth_cloud(img, intrinsics, 20_000, now=5))
    assert msg["frame_id"] == "camera_front"
    points = cloud_points(msg)
    assert 0.8 * 19_200 < len(points) <= 20_000  # every 4th pixel of 640×480, returns only
    extrinsics = mount_extrinsics(camera)
    in_body = points @ extrinsics[:3, :3].T + extrinsics[:3, 3]
    depth = np.frombuffer(img.depth, "<u2").reshape(480, 640)
    frame = DepthFrame(depth, img.depth_scale, intrinsics, extrinsics, img.stamp)
    np.testing.assert_allclose(in_body, frame_to_points(frame, decimation=4), atol=1e-5)
    for most in (1, 100, 5_000, 640 * 480):
        n = len(cloud_points(decoded(scene.depth_cloud(img, intrinsics, most, now=0))))
        assert 0.5 * min(most, 0.9 * 640 * 480) < n <= most, most
    short = m.DepthImage(camera="front", width=640, height=480, depth=b"\0" * 10)
    assert scene.depth_cloud(short, intrinsics, 100, now=0) is None


def test_clouds_go_out_at_the_cloud_rate_for_each_camera(capsys) -> None:
    profile = widowx()
    stream = scene.SceneStream(
        scene.RobotScene(profile),
        refused=lambda text: print(text),
        intrinsics=camera_intrinsics(profile),
        cloud_period=0.5,
        cloud_points=1000,
    )
    clouds = 0
    for k in range(90):  # 3 s of a 30 fps camera, and an unknown camera beside it
        t = k / 30
        fresh = [image(k % 3, stamp=t), image(0, camera="back", stamp=t)]
        out = stream.update(fresh, int(t * 1e9), t)
        clouds += sum(topic == scene.CLOUD for topic, _ in out)
    assert clouds == 6
    assert capsys.readouterr().out.count("cannot draw sim/depth: ValueError: no camera 'back'") == 1
    plain = scene.SceneStream(scene.RobotScene(profile))  # no intrinsics: depth is not drawn
    assert all(topic != scene.CLOUD for topic, _ in plain.update([image()], 0, 0.0))


def test_latest_keeps_the_newest_image_of_each_camera() -> None:
    latest = Latest()
    for k in range(5):
        latest.put(m.DepthImage(camera="front", stamp=float(k)))
    latest.put(m.DepthImage(camera="back"))
    fresh = latest.take()
    assert fresh[(m.DepthImage, "front")].stamp == 4.0 and len(fresh) == 2


def test_view_advertises_depth_when_heard_and_serves_it_as_a_point_cloud() -> None:
    context = foxglove.Context()
    profile = widowx()
    viewer = Viewer(
        scene.RobotScene(profile),
        context,
        intrinsics=camera_intrinsics(profile),
        cloud_period=0.2,
        cloud_points=2000,
    )
    assert "/depth" not in viewer.channels, "no depth heard: no depth channel"
    server = foxglove.start_server(host="127.0.0.1", port=0, context=context)
    stop = threading.Event()

    def robot() -> None:  # what the view's main loop does with what Zenoh hands it
        k = 0
        while not stop.is_set():
            fresh = {(m.DepthImage, "front"): image(k % 2, stamp=k * 0.05)}
            viewer.publish(fresh, time.time_ns(), time.monotonic())
            k += 1
            stop.wait(0.05)

    thread = threading.Thread(target=robot, daemon=True)
    thread.start()
    try:
        channel, msg = asyncio.run(first_on(server.port, "/depth", time.monotonic() + 10))
    finally:
        stop.set()
        thread.join(5)
        server.stop()
    assert channel["schemaName"] == "foxglove.PointCloud" and channel["encoding"] == "protobuf"
    assert msg["frame_id"] == "camera_front"
    assert 1000 < len(cloud_points(msg)) <= 2000
