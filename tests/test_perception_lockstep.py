"""Stepped sim runs wait for perception's answer to each depth frame (PerceptionGate).

The faults this guards (``make demo`` past ~262 s): every frame stamp goes s -> ms -> s through
pyrealsense2's software device, and some come back an ulp short, so an exact comparison took
perception's answer for an older frame and waited out PERCEPTION_WAIT (5 s) for it: one frame
in 32 of the demo's, one in 8 past 2^18 ms = 262.144 s. And a frame with nothing in range
(the robot facing the attic's end) failed the joist plugin, so the role answered no frame
again and every frame was waited out.
"""

from __future__ import annotations

import argparse
import logging
import threading
import time

import numpy as np
from support.still_body import StillBody

from climbd.daemon.cli.sim_host import PerceptionGate, feed, sim_camera
from climbd.daemon.contract.messages import BodyState, DepthImage, Joists, decode, encode
from climbd.daemon.contract.profile import load
from climbd.daemon.runtime.capture import Capture
from climbd.daemon.runtime.loader import Restarting, RestartPolicy
from climbd.daemon.runtime.perception_role import PerceptionRole, make_plugins

SIM_SECONDS = 300.0
PHYSICS_STEP = 0.001
"""The twin's MuJoCo timestep: simulated time is the sum of its steps, as ``data.time``."""


def _twin_frame_stamps(fps: float) -> list[float]:
    """The stamps the twin gives its frames: MuJoCo's time after each step (summed, with its
    rounding), a frame when a camera period is due (Twin._cameras_due)."""
    stamps, t, due, period = [], 0.0, 0.0, 1.0 / fps
    while t < SIM_SECONDS:
        t += PHYSICS_STEP
        if t + 1e-9 >= due:
            due = max(due + period, t)
            stamps.append(t)
    return stamps


def test_every_twin_frame_is_answered_through_the_software_camera(caplog):
    """300 s of the demo's frames through the perception role's sim path: the wire message, the
    role's software RealSense and capture thread, a feature naming the frame and back over the
    wire; the gate must find every frame answered (before the fix 93 of 3001 waited 5 s)."""
    profile = load("robots/widowx-attic-sim.toml")
    config = profile.cameras[0]
    camera = sim_camera(profile, config)
    push = feed(camera, config)
    capture = Capture(camera, config.name)
    gate = PerceptionGate(wait=0.01)
    depth = bytes(2 * config.width * config.height)
    stamps = _twin_frame_stamps(config.fps)
    inexact = 0
    capture.start()
    try:
        gate.answered(-1.0)  # perception is up: lock-step from here
        for stamp in stamps:
            gate.rendered(stamp)
            image = DepthImage(
                stamp=stamp,
                camera=config.name,
                width=config.width,
                height=config.height,
                depth_scale=camera.software.depth_scale,
                depth=depth,
            )
            push(decode(encode(image), DepthImage))
            frame = capture.latest(timeout=5.0)
            assert frame is not None, f"no frame from the software camera for {stamp!r}"
            inexact += frame.timestamp != stamp
            feature = Joists(stamp=frame.timestamp, frame_stamp=frame.timestamp)
            gate.answered(decode(encode(feature), Joists).frame_stamp)
            gate.pass_frame()
    finally:
        capture.stop()
    assert len(stamps) == 3001 and stamps[-1] > 262.144
    assert inexact > 0, "every stamp came back exact: the software device no longer rounds"
    assert gate.given_up == 0, f"{gate.given_up} of {len(stamps)} frames were waited out"
    assert capture.dropped == 0 and "did not answer" not in caplog.text


def test_a_stalled_perception_role_costs_one_wait_and_is_said(caplog):
    """A role that stops answering is waited for once, said so, and no longer waited for
    until it answers again; then lock-step resumes and a new stall is said again."""
    gate = PerceptionGate(wait=0.05)
    gate.rendered(0.0)
    assert gate.pass_frame()  # start-up: perception has not answered yet, nothing to wait for
    gate.answered(0.0)
    with caplog.at_level(logging.WARNING, logger="climbd.sim"):
        gate.rendered(0.1)
        assert not gate.pass_frame()
        for stamp in (0.2, 0.3, 0.4):
            gate.rendered(stamp)
            assert gate.pass_frame()
        assert gate.given_up == 1
        assert caplog.text.count("did not answer the frame at 0.10 s") == 1
        gate.answered(0.4)
        assert "perception answers again (frame at 0.40 s)" in caplog.text
        gate.rendered(0.5)
        assert not gate.pass_frame()
    assert gate.given_up == 2 and "did not answer the frame at 0.50 s" in caplog.text


def test_a_frame_with_nothing_in_range_is_answered():
    """A frame with no pixel in range (all zero: nothing within max_range, or all closer than
    min_range) through the software camera to the profile's isolated joist plugin, after one
    that saw something: an answer naming each frame, the plugin still healthy, and the joist
    it saw before still there (before the fix OpenCV raised on the empty cloud and the plugin
    was failed for the rest of the run)."""
    profile = load("robots/widowx-attic-sim.toml")
    config = profile.cameras[0]
    camera = sim_camera(profile, config)
    capture = Capture(camera, config.name)
    (plugin,) = make_plugins(profile, None, lambda name, error: None)
    scale = camera.software.depth_scale
    wall = np.full((config.height, config.width), round(0.5 / scale), np.uint16)
    nothing = np.zeros((config.height, config.width), np.uint16)
    body = BodyState(position=[0.0, 0.0, profile.stand.body_height])
    answers = []
    capture.start()
    try:
        for k, depth in enumerate((wall, nothing, nothing)):
            camera.push(depth, 0.1 * (k + 1))
            frame = capture.latest(timeout=5.0)
            assert frame is not None
            answers.append(plugin.call(plugin.plugin.process, frame, body))
    finally:
        capture.stop()
    assert plugin.status == "ok", plugin.status
    assert [round(a.frame_stamp, 6) for a in answers] == [0.1, 0.2, 0.3]
    assert answers[0].joists, "the wall's foot 0.5 m ahead reads as a step: a joist"
    assert answers[2].joists == answers[1].joists == answers[0].joists  # nothing new to fuse


class _Cracked:
    """A perception plugin whose every frame fails (a lens cracked, a bug); ``built`` counts
    the instances made (at start and at each restart)."""

    built = 0

    def __init__(self) -> None:
        _Cracked.built += 1

    def process(self, frame, body):
        raise RuntimeError("lens cracked")


def test_a_role_whose_plugin_keeps_failing_gives_it_up_and_says_so(caplog):
    """The role's worker on the software camera with a plugin that fails every frame: it is
    restarted after each streak, given up when it fails right after its last restart, and the
    worker ends with the role's failure naming the plugin and its error (``run`` then exits
    non-zero, the control role gives up waiting and holds on stale features)."""
    profile = load("robots/widowx-attic-sim.toml")
    config = profile.cameras[0]
    camera = sim_camera(profile, config)
    capture = Capture(camera, config.name)
    role = PerceptionRole(profile, argparse.Namespace())
    policy = RestartPolicy(failures_to_restart=2, restarts=2, first_backoff=0.02)
    _Cracked.built = 0
    cracked = Restarting("cracked", _Cracked, role.plugin_failed, policy)
    published = []
    blank = np.zeros((config.height, config.width), np.uint16)
    capture.start()
    worker = threading.Thread(
        target=role._work,
        args=(capture, [cracked], lambda m: published.append(m) if isinstance(m, Joists) else None),
    )
    try:
        with StillBody(role):
            worker.start()
            end = time.monotonic() + 10.0
            while worker.is_alive() and time.monotonic() < end:
                camera.push(blank, time.monotonic() - 0.03)
                time.sleep(0.01)
    finally:
        role._stop.set()
        worker.join(5.0)
        capture.stop()
    assert not published and not worker.is_alive()
    assert _Cracked.built == 3, "started, then restarted twice"
    assert cracked.failed and cracked.status == "failed: RuntimeError: lens cracked"
    assert role.failure.startswith(
        "perception plugin cracked cannot be kept going (RuntimeError: lens cracked)"
    )
    assert "failed again right after restart 2: RuntimeError: lens cracked; given up" in caplog.text
