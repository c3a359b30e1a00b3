"""Recording and playback, unplug/replug recovery, and newest-wins capture on software devices."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from climbd.daemon.contract.hardware import DriverError
from climbd.daemon.contract.messages import Health
from climbd.daemon.contract.profile import CameraConfig
from climbd.daemon.runtime.capture import Capture
from climbd.drivers.realsense.camera import PlaybackSource, RealSenseCamera
from climbd.drivers.realsense.models import L515
from climbd.drivers.realsense.software import SoftwareDepthCamera

INTRINSICS = L515.intrinsics(640, 480)


def _images(n, seed=0):
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 65535, (480, 640), dtype=np.uint16) for _ in range(n)]


def _wait(predicate, timeout=5.0):
    end = time.monotonic() + timeout
    while not predicate() and time.monotonic() < end:
        time.sleep(0.01)
    return predicate()


def test_recording_plays_back_every_frame_bit_for_bit_with_timestamps(tmp_path):
    bag = tmp_path / "run.bag"
    images = _images(12)
    stamps = [1234.5 + k * 0.0333 for k in range(12)]
    camera = SoftwareDepthCamera(
        INTRINSICS, L515.depth_unit, np.eye(4), model="L515", record_to=bag, queue_size=16
    )
    camera.open()
    for image, stamp in zip(images, stamps, strict=True):
        camera.push(image, stamp)
    camera.close()

    config = CameraConfig(model="L515", width=640, height=480)
    player = RealSenseCamera(config, PlaybackSource(bag, real_time=False), timeout=None)
    player.open()
    played = []
    for frame in player.frames():
        time.sleep(0.02)  # a consumer slower than 30 fps: nothing may be lost
        played.append(frame)
    player.close()
    assert len(played) == len(images)
    for k, frame in enumerate(played):
        np.testing.assert_array_equal(frame.depth, images[k])
        assert abs(frame.timestamp - stamps[k]) < 1e-9
        assert frame.number == k
        assert frame.depth_scale == L515.depth_unit
        assert frame.intrinsics == INTRINSICS


def test_real_time_playback_keeps_the_recorded_pace(tmp_path):
    bag = tmp_path / "paced.bag"
    camera = SoftwareDepthCamera(INTRINSICS, 0.001, np.eye(4), record_to=bag, queue_size=16)
    camera.open()
    for k, image in enumerate(_images(10, seed=1)):
        camera.push(image, 10.0 + k * 0.05)
        time.sleep(0.05)
    camera.close()
    player = RealSenseCamera(CameraConfig(), PlaybackSource(bag, real_time=True), timeout=None)
    player.open()
    start = time.monotonic()
    stamps = [f.timestamp for f in player.frames()]
    elapsed = time.monotonic() - start
    player.close()
    assert stamps == sorted(stamps) and len(stamps) >= 2
    # Frames were recorded at least 50 ms apart; played in real time they come no faster (a slow
    # machine can only stretch both the recording and the playback, never shorten them).
    assert elapsed >= 0.9 * (stamps[-1] - stamps[0])


def test_missing_recording_is_a_clear_error(tmp_path):
    player = RealSenseCamera(CameraConfig(), PlaybackSource(tmp_path / "nope.bag"))
    with pytest.raises(DriverError, match="nope.bag: recording not found"):
        player.open()
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"not a rosbag" * 10)
    with pytest.raises(DriverError, match="junk.bag: not a readable RealSense recording"):
        RealSenseCamera(CameraConfig(), PlaybackSource(junk)).open()


def test_unplug_and_replug_recover_without_restarting_the_reader():
    camera = SoftwareDepthCamera(INTRINSICS, 0.001, np.eye(4), timeout=0.5, queue_size=8)
    camera.open()
    got = []
    reader = threading.Thread(target=lambda: got.extend(camera.frames()), daemon=True)
    reader.start()
    image = np.full((480, 640), 1500, np.uint16)
    for k in range(5):
        camera.push(image, k / 30)
    assert _wait(lambda: len(got) == 5)

    camera.unplug()
    assert _wait(lambda: not camera.health().connected)
    with pytest.raises(DriverError, match="unplugged"):
        camera.push(image, 1.0)
    assert _wait(lambda: "no RealSense with serial SW-DEPTH-0" in camera.health().last_error)

    camera.replug()
    assert _wait(lambda: camera.health().connected)
    for k in range(5):
        camera.push(image, 2.0 + k / 30)
    assert _wait(lambda: len(got) == 10)
    health = camera.health()
    assert health.reconnects == 1 and health.frames == 10
    assert [f.timestamp for f in got[5:]] == pytest.approx([2.0 + k / 30 for k in range(5)])

    # A producer that stops (device alive, no frames) is caught by the frame timeout.
    assert _wait(lambda: camera.health().reconnects == 2, timeout=3.0)
    camera.push(image, 3.0)
    assert _wait(lambda: len(got) == 11)
    camera.close()
    reader.join(timeout=3.0)
    assert not reader.is_alive()


def test_slow_consumer_gets_the_newest_frame_and_drops_are_in_health():
    camera = SoftwareDepthCamera(INTRINSICS, 0.001, np.eye(4))
    capture = Capture(camera, "front")
    capture.start()
    try:
        images = _images(10, seed=2)
        for k, image in enumerate(images):
            camera.push(image, k / 30)
            time.sleep(0.005)
        assert _wait(lambda: capture.received + camera.health().dropped == 10)
        frame = capture.latest(timeout=1.0)
        assert frame.number == 9
        np.testing.assert_array_equal(frame.depth, images[9])
        health = capture.report(Health(role="perception"))
        assert health.dropped_frames == 9
        assert capture.latest(timeout=0.05) is None  # each frame handed out once

        camera.push(images[0], 1.0)
        frame = capture.latest(timeout=1.0)
        assert frame.number == 10 and capture.report(Health()).dropped_frames == 9
    finally:
        capture.stop()
    assert not capture.running
