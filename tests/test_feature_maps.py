"""Holds and joists tracked across frames: identities, fusion, confidence, misses, bounds."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.joist_world import JoistSpec, body_state, mapped, perceive

from climbd.daemon.algorithms.feature_maps import (
    HOLD_FOOTPRINT,
    HoldTracks,
    JoistTracks,
    StairTracks,
    ViewCone,
    flight,
    joists_seen_from,
)
from climbd.daemon.algorithms.tracks import TrackConfig, Tracker
from climbd.daemon.contract.hardware import DepthFrame, Intrinsics
from climbd.daemon.contract.messages import GraspablePoints, Joist, Joists, Stair, Stairs

HOLDS = np.array([[0.30, 0.10, 0.05], [0.35, -0.12, 0.08], [0.50, 0.00, 0.12]])


def _pose(x: float, heading: float) -> tuple[list[float], list[float]]:
    return [x, 0.0, 0.1], [math.cos(heading / 2), 0.0, 0.0, math.sin(heading / 2)]


def _seen_from(x: float, heading: float, holds: np.ndarray, noise: float, rng, stamp: float):
    """GraspablePoints of ``holds`` (odometry frame) as a robot at x, heading sees them."""
    position, orientation = _pose(x, heading)
    c, s = math.cos(heading), math.sin(heading)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    body = (holds - position) @ rot + rng.normal(0.0, noise, holds.shape)
    return GraspablePoints(
        stamp=stamp,
        frame_stamp=stamp,
        frame_position=position,
        frame_orientation=orientation,
        points=body.tolist(),
    )


def test_holds_keep_their_identity_height_and_grow_sure():
    rng = np.random.default_rng(1)
    tracks = HoldTracks()
    for k in range(20):
        tracks.update(_seen_from(0.005 * k, 0.02 * k, HOLDS, 0.003, rng, 0.1 * k), None)
    held = sorted(tracks.tracker.tracks, key=lambda t: t.id)
    assert [t.id for t in held] == [1, 2, 3]
    for track, truth in zip(held, HOLDS, strict=True):
        assert np.linalg.norm(track.estimate - truth) <= 0.003
        assert track.seen == 20 and track.confidence == pytest.approx(1 - 0.5**20)
    message = tracks.message(2.5, 2.0)
    assert [h.position[2] for h in message.holds] == pytest.approx(HOLDS[:, 2], abs=0.003)
    assert message.holds[0].age == pytest.approx(2.0 - 1.9)


def test_a_hold_in_view_that_is_no_longer_seen_is_dropped_and_one_out_of_view_kept():
    tracker = Tracker(TrackConfig(gate=0.02, max_misses=3))
    stamp = 0.0
    tracker.update(list(HOLDS), [0.5] * 3, stamp)
    only_first = np.array([True, False, False])
    for k in range(1, 4):
        tracker.update([HOLDS[0]], [0.5], float(k), lambda ts: np.ones(len(ts), bool))
    assert [t.id for t in tracker.tracks] == [1]
    tracker = Tracker(TrackConfig(gate=0.02, max_misses=3))
    tracker.update(list(HOLDS), [0.5] * 3, stamp)
    for k in range(1, 10):
        tracker.update([HOLDS[0]], [0.5], float(k), lambda ts: only_first[: len(ts)])
    assert [t.id for t in tracker.tracks] == [1, 2, 3]


def test_tracks_expire_and_stay_bounded():
    tracker = Tracker(TrackConfig(gate=0.01, expiry=5.0, max_tracks=50))
    rng = np.random.default_rng(2)
    for k in range(100):
        tracker.update(list(rng.uniform(-5, 5, (10, 3))), [0.5] * 10, float(k))
    assert len(tracker.tracks) <= 50
    assert min(t.last_seen for t in tracker.tracks) >= 99 - 5.0


def test_the_view_cone_holds_what_the_camera_sees():
    k = Intrinsics(640, 480, 400.0, 400.0, 320.0, 240.0)
    forward = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1]], float)
    frame = DepthFrame(np.zeros((480, 640), np.uint16), 0.001, k, forward, 0.0)
    position, orientation = _pose(1.0, math.pi / 2)
    cone = ViewCone(frame, position, orientation, max_range=2.0)
    inside = cone.contains(np.array([[1.0, 1.0, 0.1], [1.0, -1.0, 0.1], [1.0, 3.5, 0.1]]))
    assert inside.tolist() == [True, False, False]


def test_a_hold_hidden_behind_a_leg_or_in_a_hole_is_not_expected_in_view():
    """A camera 1 m above a board, looking down: three holds on the board. The first's pixel
    sees the board (visible: were it gone, a miss); the second's sees a gripper 10 cm above it
    (hidden, as under a swinging limb); the third's has no return (a hole, or a leg's pixel the
    self filter cut): neither may count a miss. All three are inside the image."""
    k = Intrinsics(64, 48, 40.0, 40.0, 32.0, 24.0)
    down = np.array([[0, -1, 0, 0], [-1, 0, 0, 0], [0, 0, -1, 1], [0, 0, 0, 1]], float)
    depth = np.full((48, 64), 1000, np.uint16)
    holds = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.2, 0.0]])
    depth[16, 32] = 900  # the pixel of (0.2, 0, 0): row 24 - 40 * 0.2, column 32
    depth[24, 24] = 0  # the pixel of (0, 0.2, 0)
    cone = ViewCone(DepthFrame(depth, 0.001, k, down, 0.0), [0.0, 0.0, 0.0], [1, 0, 0, 0], 2.0)
    assert cone.contains(holds).tolist() == [True, True, True]
    assert cone.visible(holds).tolist() == [True, False, False]


def test_a_hold_whose_footprint_the_frame_did_not_see_whole_is_hidden_not_missed():
    """A camera 1 m above a board (400 px focal length: 2 cm is 8 px). Hold A's footprint is
    board all round: visible. Hold B's own pixel sees the board but a gripper's cut pixels lie
    2 cm beside it (the detector cannot judge B): hidden with the hold footprint, visible to
    the point test. Hold C's footprint runs off the image's edge: hidden."""
    k = Intrinsics(640, 480, 400.0, 400.0, 320.0, 240.0)
    down = np.array([[0, -1, 0, 0], [-1, 0, 0, 0], [0, 0, -1, 1], [0, 0, 0, 1]], float)
    depth = np.full((480, 640), 1000, np.uint16)
    holds = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, -0.795, 0.0]])
    depth[160 - 3 : 160 + 4, 320 + 5 : 320 + 12] = 0  # beside B (row 160, column 320)
    cone = ViewCone(DepthFrame(depth, 0.001, k, down, 0.0), [0.0, 0.0, 0.0], [1, 0, 0, 0], 2.0)
    assert cone.visible(holds).tolist() == [True, True, True]
    assert cone.visible(holds, HOLD_FOOTPRINT).tolist() == [True, False, False]


def test_a_joist_seen_while_walking_and_turning_is_one_track_on_its_line():
    spec = JoistSpec(height=0.10, distance=1.2, yaw=math.radians(20.0), length=1.8)
    rng = np.random.default_rng(3)
    tracks = JoistTracks()
    for k in range(30):
        x, heading = 0.02 * k, math.radians(8.0) * math.sin(k / 4)
        seen = perceive([spec], np.array([x, 0.0, heading]), 0.1 * k)
        for joist in seen.joists:
            joist.endpoints = (np.asarray(joist.endpoints) + rng.normal(0, 0.004, (2, 3))).tolist()
            joist.yaw += rng.normal(0.0, math.radians(0.5))
        _, orientation = _pose(x, heading)
        seen.frame_position, seen.frame_orientation = [x, 0.0, 0.0], orientation
        tracks.update(seen, None)
    (track,) = tracks.tracker.tracks
    offset, heading, height, _ = track.estimate
    assert math.degrees(heading) == pytest.approx(20.0, abs=0.5)
    n = np.array([math.cos(spec.yaw), math.sin(spec.yaw)])
    assert offset == pytest.approx(float(n @ [spec.distance, 0.0]), abs=0.005)
    assert height == pytest.approx(0.10, abs=1e-9)
    mapped = tracks.message(3.0, 3.0).joists[0]
    assert mapped.seen == 30 and mapped.confidence > 0.99
    ends = np.asarray(mapped.endpoints)
    assert np.linalg.norm(ends[1, :2] - ends[0, :2]) > 0.8


def test_a_joist_seen_from_its_far_side_is_the_same_joist():
    tracks = JoistTracks()
    edge = [[1.0, -0.3, 0.1], [1.0, 0.3, 0.1]]
    near = Joists(
        frame_stamp=0.0,
        joists=[Joist(distance=1.0, yaw=0.0, height=0.1, endpoints=edge)],
    )
    tracks.update(near, None)
    back = [[0.98, 0.3, 0.1], [0.98, -0.3, 0.1]]
    far = Joists(
        frame_stamp=1.0,
        frame_position=[2.0, 0.0, 0.0],
        frame_orientation=[0.0, 0.0, 0.0, 1.0],
        joists=[Joist(distance=0.98, yaw=0.0, height=0.1, endpoints=back)],
    )
    tracks.update(far, None)
    (track,) = tracks.tracker.tracks
    assert track.seen == 2 and track.estimate[0] == pytest.approx(1.01, abs=1e-9)
    assert track.estimate[1] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("yaw_deg", [0.0, 30.0, -60.0])
def test_a_mapped_joist_seen_from_another_pose_is_what_that_pose_would_detect(yaw_deg):
    """The behaviours' query: a joist mapped from one pose, asked for from another (walked on
    0.2 m and turned 5°), reads as the detector would report it from there: the same
    distance along the path, yaw and height as the oracle's detection from that pose."""
    spec = JoistSpec(0.9, math.radians(yaw_deg), 0.10)
    tracks = JoistTracks()
    first = np.array([0.0, 0.0, 0.0])
    mapped(tracks, perceive([spec], first, 0.0), body_state(first))
    later = np.array([0.2, 0.02, math.radians(5.0)])
    (seen,) = joists_seen_from(tracks.message(0.0, 0.0), body_state(later))
    (truth,) = perceive([spec], later, 0.0).joists
    assert seen.distance == pytest.approx(truth.distance, abs=1e-9)
    assert seen.yaw == pytest.approx(truth.yaw, abs=1e-9)
    assert seen.height == pytest.approx(truth.height)


def _flight(x0: float, yaw_deg: float, stamp: float) -> Stairs:
    """Three 13 × 30 cm steps whose first edge is ``x0`` m ahead along ``yaw_deg``, 1 m wide,
    edges left then right facing up the flight (as stairs perception reports them)."""
    up = np.array([math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))])
    left = np.array([-up[1], up[0]])
    steps = []
    for k in range(3):
        middle = (x0 + 0.3 * k) * up
        ends = [middle + 0.5 * left, middle - 0.5 * left]
        top = 0.13 * (k + 1)
        steps.append(
            Stair(height=top, rise=0.13, depth=0.3, edge=[[*e.tolist(), top] for e in ends])
        )
    return Stairs(stamp=stamp, frame_stamp=stamp, steps=steps[::-1])


@pytest.mark.parametrize("yaw_deg", [0.0, 100.0, -170.0])
def test_stair_steps_keep_their_identity_and_fuse_as_the_flight_is_seen_again(yaw_deg):
    """Each step is one track across frames whatever the flight's heading; a frame 1 cm off
    moves the step by a fraction of it; the map lists the flight bottom first, edges left then
    right, as the stair gait's model reads them."""
    tracks = StairTracks()
    tracks.update(_flight(0.8, yaw_deg, 0.0), None)
    first = tracks.message(0.0, 0.0)
    tracks.update(_flight(0.81, yaw_deg, 0.1), None)
    second = tracks.message(0.1, 0.1)
    assert [s.id for s in first.steps] == [s.id for s in second.steps]
    assert [s.height for s in second.steps] == pytest.approx([0.13, 0.26, 0.39])
    assert all(s.seen == 2 and s.rise == pytest.approx(0.13) for s in second.steps)
    (truth,) = [s for s in _flight(0.8, yaw_deg, 0.0).steps if s.height == pytest.approx(0.13)]
    np.testing.assert_allclose(first.steps[0].edge, truth.edge, atol=1e-9)
    up = np.array([math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))])
    moved = np.mean(second.steps[0].edge, axis=0)[:2] @ up - 0.8
    assert 0.0 < moved < 0.01
    model_input = flight(second)
    assert [s.height for s in model_input.steps] == [s.height for s in second.steps]
