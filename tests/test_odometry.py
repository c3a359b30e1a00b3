"""Leg odometry: the body path reconstructed from stance feet against a constructed walk."""

from __future__ import annotations

import math

import numpy as np
import pytest

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.algorithms.odometry import HEADING_DRIFT, POSITION_DRIFT, LegOdometry
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.geometry import rotation


def rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_tripod_walk_is_reconstructed(robots) -> None:
    """Feet stay put on the ground while in stance; swing feet move ahead. The true body path
    (forward, turning, bobbing) must come back from the joints and stance flags alone."""
    kin = Kinematics(profiles.load(robots / "widowx.toml"))
    stand = kin.stand_feet()
    odo = LegOdometry(kin)
    tripod = np.array([0, 1, 0, 1, 0, 1], bool)  # rf, rm, rr, lf, lm, lr alternate
    world = stand.copy()
    dt, period = 0.01, 1.0
    path, last = 0.0, np.zeros(3)
    for k in range(601):
        t = k * dt
        pos = np.array([0.03 * t, 0.005 * math.sin(t), 0.002 * math.sin(4 * t)])
        rot = rot_z(0.05 * t)
        phase = (t % period) < period / 2
        stance = tripod if phase else ~tripod
        if k == 0:
            stance = np.ones(6, bool)
        feet_body = (world - pos) @ rot  # a foot lifting off this tick is still on the ground
        q, ok = kin.ik(feet_body)
        assert ok.all()
        body = odo.update(q, stance, t)
        world[~stance] = (pos + stand @ rot.T)[~stance]  # swing feet travel with the body
        if k > 0 and k % 100 == 0:
            assert np.allclose(body.position, pos, atol=1e-6), (t, body.position, pos)
            est = rotation(np.array(body.orientation))
            assert np.allclose(est, rot, atol=1e-6)
        path += float(np.linalg.norm(pos - last))
        last = pos
    # the covariance grows with the path walked: 2 % and 0.4° per metre (one sigma)
    var = np.array(body.pose_variance)
    assert np.sqrt(var[:3]) == pytest.approx([POSITION_DRIFT * path] * 3, rel=1e-3)
    assert math.sqrt(var[5]) == pytest.approx(HEADING_DRIFT * path, rel=1e-3)
    assert var[3] == var[4] > 0.0


def test_too_few_stance_feet_keep_the_last_pose(robots) -> None:
    kin = Kinematics(profiles.load(robots / "widowx.toml"))
    odo = LegOdometry(kin)
    q = kin.stand_joints()
    odo.update(q, np.ones(6, bool), 0.0)
    body = odo.update(q, np.array([1, 1, 0, 0, 0, 0], bool), 0.01)
    assert np.allclose(body.position, 0.0, atol=1e-12)


def test_a_lagging_foot_is_registered_where_it_lands(robots) -> None:
    """Free gait, one leg at a time, the body moving: each swing foot lags its plan by 80 ms, so
    the gait flags it in stance while it is still 2.5 cm up and behind its landing place (as
    the AX-18A emulator's legs do crossing a joist). Registered there, it drags the pose by
    millimetres per step; registered once it rests, the body path comes back within 1 mm."""
    kin = Kinematics(profiles.load(robots / "widowx.toml"))
    stand = kin.stand_feet()
    odo = LegOdometry(kin)
    world = stand.copy()
    dt, swing, lag, stride, height = 0.01, 0.4, 0.08, 0.04, 0.05
    start = world.copy()
    worst = 0.0
    for k in range(int(6 * 2 * swing / dt) + 1):
        t = k * dt
        pos = np.array([stride * t / (12 * swing), 0.0, 0.0])  # as fast as the feet go
        leg, into = divmod(t, 2 * swing)  # each leg swings, then all six stand for as long
        leg = int(leg) % 6
        stance = np.ones(6, bool)
        if into < swing:
            stance[leg] = False
        if into < swing + lag:
            s = min(1.0, max(0.0, (into - lag) / swing))  # the foot follows its plan late
            world[leg] = start[leg] + [stride * s, 0.0, height * math.sin(math.pi * s)]
        else:
            start[leg] = world[leg]
        q, ok = kin.ik(world - pos)
        assert ok.all()
        body = odo.update(q, stance, t)
        worst = max(worst, float(np.linalg.norm(np.array(body.position) - pos)))
    assert worst < 1e-3, f"body estimate off by {worst * 1000:.1f} mm"


def test_a_slipping_foot_is_left_out_and_registered_again(robots) -> None:
    """Six feet down, the body shifting forward; one foot slides 8 mm (a slip), later another.
    Fitted with them, the pose would move by a sixth of each slip; the slipping foot is left
    out of the fit and registered again where it stopped, so the body path stays within 1 mm."""
    kin = Kinematics(profiles.load(robots / "widowx.toml"))
    world = kin.stand_feet()
    odo = LegOdometry(kin)
    stance = np.ones(6, bool)
    worst = 0.0
    for k in range(201):
        t = k * 0.01
        pos = np.array([0.015 * t, 0.002 * t, 0.0])
        if 50 <= k < 60:
            world[0, 0] += 0.0008  # rf slides forward
        if 120 <= k < 130:
            world[4, 1] -= 0.0008  # lm slides sideways
        q, ok = kin.ik(world - pos)
        assert ok.all()
        body = odo.update(q, stance, t)
        worst = max(worst, float(np.linalg.norm(np.array(body.position) - pos)))
    assert worst < 1e-3, f"body estimate off by {worst * 1000:.1f} mm"


REST, BIAS = 90.0, 0.001
"""Seconds the robot stands before walking, and the gyro's bias (rad/s)."""


def _slipping_turn(odo: LegOdometry, kin: Kinematics, imu: bool) -> tuple[float, float]:
    """Stand 90 s, then walk a tripod 40 s turning at 0.02 rad/s and pitching ±1.7°, while the
    stance feet twist on the ground at 0.05°/s (the slow slip measured crossing a joist). The
    IMU reads the true rates plus a 0.06°/s gyro bias. Worst (yaw, tilt) error (rad) walking."""
    stand = kin.stand_feet()
    tripod = np.array([0, 1, 0, 1, 0, 1], bool)
    world = stand.copy()
    dt, rest, slip, turn, bias = 0.02, REST, math.radians(0.05), 0.02, np.array([0, 0, BIAS])
    worst_yaw = worst_tilt = 0.0
    for k in range(int((rest + 40.0) / dt) + 1):
        t = k * dt
        walk = max(0.0, t - rest)
        yaw, pitch, pitch_rate = turn * walk, 0.03 * math.sin(walk), 0.03 * math.cos(walk)
        rot = rot_z(yaw) @ rotation(np.array([math.cos(pitch / 2), 0, math.sin(pitch / 2), 0]))
        pos = np.array([0.03 * walk, 0.0, 0.0])
        stance = np.ones(6, bool) if t < rest else (tripod if walk % 1.0 < 0.5 else ~tripod)
        if t >= rest:
            twist = rot_z(slip * dt)
            world[stance] = pos + (world[stance] - pos) @ twist.T
        q, ok = kin.ik((world - pos) @ rot)
        assert ok.all()
        if imu:
            omega_world = np.array([0, 0, turn if t >= rest else 0.0])
            omega_world = omega_world + rot_z(yaw) @ [0, pitch_rate if t >= rest else 0.0, 0]
            gyro = rot.T @ omega_world + bias
            body = odo.update(q, stance, t, gyro, rot.T @ [0, 0, 9.81])
        else:
            body = odo.update(q, stance, t)
        world[~stance] = (pos + stand @ rot.T)[~stance]
        if t >= rest:
            err = rotation(np.array(body.orientation)).T @ rot
            worst_yaw = max(worst_yaw, abs(math.atan2(err[1, 0], err[0, 0])))
            worst_tilt = max(worst_tilt, math.acos(min(1.0, err[2, 2])))
    return worst_yaw, worst_tilt


def test_the_gyro_bounds_the_heading_of_slipping_legs(robots) -> None:
    """Leg odometry alone turns with the slipping feet (2° in 40 s); fused with the gyro, whose
    bias it learns while the robot stands, the heading error stays within what the complementary
    filter lets in of that slow drift, r·(t - τ·(1 - exp(-t/τ))), and the tilt follows gravity."""
    from climbd.daemon.algorithms.odometry import BIAS_TIME, HEADING_TIME

    kin = Kinematics(profiles.load(robots / "widowx.toml"))
    legs_yaw, _ = _slipping_turn(LegOdometry(kin), kin, imu=False)
    fused_yaw, fused_tilt = _slipping_turn(LegOdometry(kin), kin, imu=True)
    r, t, tau = math.radians(0.05), 40.0, HEADING_TIME
    leak = r * (t - tau * (1.0 - math.exp(-t / tau)))
    left_bias = BIAS * math.exp(-(REST - 0.5) / BIAS_TIME) * t  # half a second to first rest
    bound = leak + left_bias + math.radians(0.1)
    assert legs_yaw > 3 * bound, f"legs alone {math.degrees(legs_yaw):.2f}°: no drift to bound"
    assert fused_yaw < bound, f"fused yaw off {math.degrees(fused_yaw):.2f}° > {bound:.4f} rad"
    assert fused_tilt < math.radians(0.5), f"tilt off {math.degrees(fused_tilt):.2f}°"


@pytest.mark.parametrize("gravity", [9.81, 1.62])
def test_the_tilt_follows_gravity_on_earth_and_on_the_moon(robots, gravity: float) -> None:
    """A robot standing still for 60 s; its gyro has a 0.1°/s pitch bias. The accelerometer
    reads gravity's specific force, whatever its magnitude (HubRobo climbs under G/6): the tilt
    is pulled toward it, so the pitch error stays within a few tenths of a degree, where the
    bias alone (learnt at rest over 30 s) leaves 2.6° under G/6 without it."""
    kin = Kinematics(profiles.load(robots / "hubrobo.toml"))
    odo = LegOdometry(kin)
    q = kin.stand_joints()
    stance = np.ones(len(kin.leg_names), bool)
    bias = np.array([0.0, math.radians(0.1), 0.0])
    dt, worst = 0.01, 0.0
    for k in range(6001):
        body = odo.update(q, stance, k * dt, bias, np.array([0.0, 0.0, gravity]))
        tilt = rotation(np.array(body.orientation))[2, 2]
        worst = max(worst, math.degrees(math.acos(min(1.0, tilt))))
    assert odo.gravity == pytest.approx(gravity)
    assert worst < 0.3, f"tilt off {worst:.2f}° under {gravity} m/s²"


def test_two_of_four_feet_sliding_together_are_not_taken_for_one_slip(robots) -> None:
    """HubRobo on four feet, the body shifting forward; both rear feet slide 8 mm back
    together (the crawl's slide under G/6). All four residuals are equal and nothing tells
    which feet held, so the fit of the four keeps the estimate within half the slide. Judging
    one foot as slipped (here a front foot, which held) and fitting the other three put the
    estimate 7.0 mm off and kept it there."""
    kin = Kinematics(profiles.load(robots / "hubrobo.toml"))
    world = kin.stand_feet()
    rear = [k for k, leg in enumerate(kin.leg_names) if leg.endswith("r")]
    assert len(rear) == 2
    odo = LegOdometry(kin)
    worst = 0.0
    for k in range(201):
        t = k * 0.01
        pos = np.array([0.01 * t, 0.0, 0.0])
        if 50 <= k < 60:
            world[rear, 0] -= 0.0008
        q, ok = kin.ik(world - pos)
        assert ok.all()
        body = odo.update(q, np.ones(4, bool), t)
        worst = max(worst, float(np.linalg.norm(np.array(body.position) - pos)))
    assert worst <= 0.004 + 1e-4, f"body estimate off by {worst * 1000:.1f} mm"


def test_rolling_feet_keep_the_body_path(robots) -> None:
    """Four rounded feet (HubRobo's 11.5 mm) roll without slip as the body moves 6 cm forward
    over them: each centre moves by r·(dθ × up) as its foot link pitches. Told the radius,
    the odometry follows the rolling centres and the body path stays within 0.5 mm; taking the
    centres as fixed it falls behind by the roll."""
    from climbd.daemon.algorithms.estimation import foot_link_rotations, log_so3

    profile = profiles.load(robots / "hubrobo.toml")
    kin = Kinematics(profile)
    r = profile.foot_radius
    errors = {}
    for radius in (r, 0.0):
        world = kin.stand_feet()
        odo = LegOdometry(kin, foot_radius=radius)
        q, _ = kin.ik(world)
        links = foot_link_rotations(kin, q)
        worst = 0.0
        for k in range(301):
            pos = np.array([0.0002 * k, 0.0, 0.0])
            for _ in range(4):  # the centres where the feet have rolled to: a fixed point
                q, ok = kin.ik(world - pos)
                now = foot_link_rotations(kin, q)
                pairs = zip(now, links, strict=True)
                turn = np.array([log_so3(np.array(a) @ np.array(b).T) for a, b in pairs])
                rolled = world + r * np.column_stack([turn[:, 1], -turn[:, 0], np.zeros(4)])
                q, ok = kin.ik(rolled - pos)
            assert ok.all()
            world, links = rolled, foot_link_rotations(kin, q)
            body = odo.update(q, np.ones(4, bool), k * 0.01)
            worst = max(worst, float(np.linalg.norm(np.array(body.position) - pos)))
        errors[radius] = worst
    assert errors[r] < 5e-4, f"rolling feet: off by {errors[r] * 1000:.2f} mm"
    assert errors[0.0] > 4 * errors[r], errors


def test_the_accelerometers_first_sample_sets_the_tilt_at_once(robots) -> None:
    """HubRobo switched on standing on a 30° wall under G/6: its first update with the IMU puts
    the tilt within 0.1° of the wall's, where a pull at TILT_TIME alone would still be 30° off;
    the heading stays the start's."""
    kin = Kinematics(profiles.load(robots / "hubrobo.toml"))
    odo = LegOdometry(kin)
    incline = math.radians(30.0)
    gravity = 9.80665 / 6 * np.array([-math.sin(incline), 0.0, math.cos(incline)])
    body = odo.update(kin.stand_joints(), np.ones(4, bool), 0.0, np.zeros(3), gravity)
    turned = rotation(np.array(body.orientation))
    assert math.degrees(math.acos(turned[2, 2])) == pytest.approx(30.0, abs=0.1)
    assert abs(math.degrees(math.atan2(turned[1, 0], turned[0, 0]))) < 0.1


def test_a_foot_lifting_off_leaves_the_pose_where_it_was(robots) -> None:
    """HubRobo stands on a 30° wall; its odometry starts level on the gyro alone, and the
    accelerometer's first sample, after the feet were registered, turns the tilt 30°, which a
    few TILT_TIMEs steady. Lifting one limb then leaves the body's estimate within 0.1 mm of
    where it was: a map kept in the odometry frame stays under the feet. The fit of the three
    that stay, on their anchors as registered, put it 2.9 cm off (2.8 cm through the driver in
    the twin)."""
    from climbd.daemon.algorithms.odometry import TILT_TIME

    kin = Kinematics(profiles.load(robots / "hubrobo.toml"))
    odo = LegOdometry(kin)
    q = kin.stand_joints()
    incline = math.radians(30.0)
    gravity = 9.80665 / 6 * np.array([-math.sin(incline), 0.0, math.cos(incline)])
    dt, stance = 0.01, np.ones(4, bool)
    steps = round(5 * TILT_TIME / dt)
    for k in range(steps):
        body = odo.update(q, stance, k * dt, np.zeros(3), gravity if k >= 10 else None)
    pitch = math.degrees(math.acos(rotation(np.array(body.orientation))[2, 2]))
    assert pitch == pytest.approx(30.0, abs=0.5)
    before = np.array(body.position)
    stance[0] = False
    after = np.array(odo.update(q, stance, steps * dt, np.zeros(3), gravity).position)
    assert np.linalg.norm(after - before) < 1e-4, f"jumped {np.round(after - before, 4)} m"
