"""Pose at a frame's time: the history interpolates (SLERP) and refuses what it cannot pair.

The twin test turns the WidowX in place at 0.5 rad/s in front of a fixed 10 cm joist, with
body states at 100 Hz and each 30 Hz depth frame reaching perception 100 ms after it was taken.
Paired with the pose at its stamp, every detection of the joist lands on the same line in the
odometry frame (within 1 cm and 1°); paired with the latest pose, as perception did before,
it turns by the 100 ms of rotation the robot made meanwhile (2.9°).
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import pytest

from climbd.daemon.algorithms.pose_history import PoseHistory, PoseRefused, Refusal
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.geometry import rotation, slerp, yaw
from climbd.daemon.contract.messages import BodyState
from climbd.daemon.contract.profile import stock_profiles
from climbd.daemon.runtime.perception_role import PerceptionRole

WIDOWX = profiles.load(stock_profiles()["widowx"])
RATE = 0.5
"""rad/s: the turn."""
DELAY = 0.1
"""s: from a frame's exposure to perception."""
FRAME_YAW = 0.5
"""Degrees: the joist detector's yaw error on single frames of this scene, at up to 14° to the
joist (Table 1 allows 2°; 0.28° measured since the near edge is refined on its sub-cell
crossings, 1.05° before)."""
SPREAD_YAW = 1.0
"""Degrees: the issue's bound on the detections' heading spread across the turn (0.43°
measured; 1.15° before the edge refinement)."""


def turning(t: float, rate: float = RATE) -> BodyState:
    """The body at ``t`` turning about z at ``rate`` from heading 0 at t = 0, 1 cm/s forward."""
    h = rate * t
    return BodyState(
        stamp=t,
        position=[0.01 * t, 0.0, 0.1],
        orientation=[math.cos(h / 2), 0.0, 0.0, math.sin(h / 2)],
    )


def test_interpolation_is_the_motion_between_poses():
    history = PoseHistory()
    for k in range(101):
        history.add(turning(k * 0.01))
    for t in (0.123, 0.4567, 0.5, 0.999):
        body = history.at(t)
        assert yaw(body.orientation) == pytest.approx(RATE * t, abs=1e-9)
        assert body.position[0] == pytest.approx(0.01 * t, abs=1e-12)
        assert body.stamp == t


def test_slerp_takes_the_short_way_and_extrapolates():
    q0 = [1.0, 0.0, 0.0, 0.0]
    q1 = [-math.cos(0.1), 0.0, 0.0, -math.sin(0.1)]  # heading 0.2 rad, sign-flipped
    assert yaw(slerp(q0, q1, 0.5)) == pytest.approx(0.1, abs=1e-12)
    assert yaw(slerp(q0, q1, 1.5)) == pytest.approx(0.3, abs=1e-12)


def test_a_frame_a_little_newer_than_the_last_pose_is_extrapolated():
    history = PoseHistory(ahead=0.05)
    for k in range(11):
        history.add(turning(k * 0.01))
    body = history.at(0.14)
    assert yaw(body.orientation) == pytest.approx(RATE * 0.14, abs=1e-9)


@pytest.mark.parametrize(
    ("t", "reason"),
    [
        (0.5, Refusal.TOO_NEW),
        (-4.0, Refusal.TOO_OLD),
        (float("nan"), Refusal.NOT_FINITE),
        (float("inf"), Refusal.NOT_FINITE),
    ],
)
def test_frames_outside_the_history_are_refused(t: float, reason: Refusal):
    history = PoseHistory(span=3.0, ahead=0.05)
    for k in range(11):
        history.add(turning(k * 0.01))
    with pytest.raises(PoseRefused) as e:
        history.at(t)
    assert e.value.reason is reason


def test_no_pose_and_out_of_order_frames_are_refused():
    history = PoseHistory()
    with pytest.raises(PoseRefused) as e:
        history.at(0.0)
    assert e.value.reason is Refusal.NO_POSE
    for k in range(11):
        history.add(turning(k * 0.01))
    history.at(0.08)
    with pytest.raises(PoseRefused) as e:
        history.at(0.05)
    assert e.value.reason is Refusal.OUT_OF_ORDER


def test_the_history_is_bounded_and_begins_anew_when_the_clock_restarts():
    history = PoseHistory(span=1.0)
    for k in range(1000):
        history.add(turning(k * 0.01))
    assert len(history) <= 102
    with pytest.raises(PoseRefused):
        history.at(5.0)
    history.add(turning(0.0))
    history.add(turning(0.01))
    assert history.restarts == 1
    assert history.at(0.005).stamp == 0.005
    history.add(turning(0.005))
    assert history.out_of_order_poses == 1


def _world_line(joist, body: BodyState) -> tuple[float, float]:
    """The joist's near top edge as a line in the odometry frame: its normal's heading (rad)
    and its signed distance from the origin (m), placed with ``body``."""
    rot = rotation(body.orientation)
    ends = [rot @ np.asarray(p) + np.asarray(body.position) for p in joist.endpoints]
    heading = joist.yaw + yaw(body.orientation)
    normal = np.array([math.cos(heading), math.sin(heading)])
    middle = (ends[0][:2] + ends[1][:2]) / 2
    return heading, float(normal @ middle)


def test_a_fixed_joist_stays_put_while_turning_with_the_pose_at_frame_time():
    """Body states are the twin's true pose (a perfect odometry): the test isolates the pairing
    of frames with poses, through the perception role's own pose history."""
    from climbd.daemon.algorithms.kinematics import Kinematics
    from climbd.drivers.sim.twin import Twin
    from climbd.drivers.sim.worlds import JoistRow, World
    from climbd.plugins.perception.joist_perception import JoistPerception

    row = JoistRow(height=0.10, distance=1.0, width=0.04, length=2.4, yaw_deg=0.0)
    twin = Twin(WIDOWX, World(name="turn", joists=[row]), stepped=True, bus=False)
    twin.start()
    try:
        twin.command(Kinematics(WIDOWX).stand_joints())
        twin.advance_to(1.0)
        with twin.lock:
            start_pos = twin.data.qpos[:3].copy()
        role = PerceptionRole(WIDOWX, argparse.Namespace())
        plugin = JoistPerception()

        def pose(t: float) -> BodyState:
            h = RATE * (t - 1.0) - 0.25
            return BodyState(
                stamp=t,
                position=start_pos.tolist(),
                orientation=[math.cos(h / 2), 0.0, 0.0, math.sin(h / 2)],
            )

        frames = []
        lines = []
        for k in range(101, 201):  # 1 s of turning, body states at 100 Hz
            t = k * 0.01
            role.on_body(pose(t))
            if k % 3 == 0:
                body = pose(t)
                with twin.lock:
                    twin.data.qpos[3:7] = body.orientation
                    twin.data.time = t
                frames.append(twin.depth_frame("front"))
            delivered = [f for f in frames if f.timestamp <= t - DELAY + 1e-9]
            for frame in delivered:
                frames.remove(frame)
                paired = role._pose_at(frame.timestamp)
                latest = pose(t)
                joists = plugin.process(frame, paired).joists
                assert joists, f"no joist seen at {frame.timestamp:.2f} s"
                nearest = max(joists, key=lambda j: j.confidence)
                both = (_world_line(nearest, paired), _world_line(nearest, latest))
                lines.append(both)
    finally:
        twin.stop()
    paired = np.array([p for p, _ in lines])
    latest = np.array([q for _, q in lines])
    assert len(lines) >= 25
    face = row.distance - row.width / 2
    assert np.ptp(paired[:, 1]) <= 0.01
    assert np.all(np.abs(paired[:, 1] - face) <= 0.01)
    assert np.all(np.abs(np.degrees(paired[:, 0])) <= FRAME_YAW)
    assert math.degrees(np.ptp(paired[:, 0])) <= SPREAD_YAW
    assert abs(math.degrees(np.median(paired[:, 0]))) <= 0.3
    drift = math.degrees(np.median(latest[:, 0] - paired[:, 0]))
    assert drift == pytest.approx(math.degrees(RATE * DELAY), abs=0.2)
    assert not role.refused
