"""Ruckig smoothing: limits hold on the commanded samples, replanning keeps continuity."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from climbd.daemon.algorithms.smoothing import Smoother, SmoothingError
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.profile import stock_profiles

PROFILES = {name: profiles.load(path) for name, path in stock_profiles().items()}


def limits(profile):
    joints = profile.joints
    return (
        np.array([j.limits.velocity for j in joints]),
        np.array([j.limits.acceleration for j in joints]),
        np.array([j.limits.jerk for j in joints]),
    )


def assert_within_limits(samples: np.ndarray, dt: float, profile, scale: float = 1.0) -> None:
    """Finite differences of the commanded samples against velocity, acceleration, jerk.

    Samples of a trajectory continuous up to acceleration with bounded jerk have n-th
    differences / dt^n bounded by the n-th derivative's bound (B-spline averaging).
    """
    v, a, j = limits(profile)
    rel = 1e-6
    vel = np.diff(samples, 1, axis=0) / dt
    acc = np.diff(samples, 2, axis=0) / dt**2
    jerk = np.diff(samples, 3, axis=0) / dt**3
    assert np.all(np.abs(vel) <= v * scale * (1 + rel)), np.abs(vel).max(0) / (v * scale)
    assert np.all(np.abs(acc) <= a * (1 + rel) + 1e-6), np.abs(acc).max(0) / a
    assert np.all(np.abs(jerk) <= j * (1 + rel) + 1e-3), np.abs(jerk).max(0) / j


@pytest.mark.parametrize("robot", ["widowx", "qingzhui"])
@settings(max_examples=25, deadline=None)
@given(
    data=st.lists(
        st.tuples(st.integers(1, 40), st.lists(st.floats(-3.0, 3.0), min_size=18, max_size=18)),
        min_size=1,
        max_size=8,
    )
)
def test_random_retargeting_respects_velocity_acceleration_jerk(robot, data) -> None:
    """Targets that jump anywhere, any time: every commanded sample stays within the limits."""
    retarget(robot, data)


def retarget(robot: str, data: list[tuple[int, list[float]]]) -> Smoother:
    """Each target of ``data`` for its number of ticks from rest at zero, asserting the limits."""
    profile = PROFILES[robot]
    dt = 1.0 / profile.rate_hz
    smoother = Smoother(profile, dt)
    start = np.zeros(18)
    smoother.reset(start)
    samples = [start]
    for ticks, target in data:
        for _ in range(ticks):
            samples.append(smoother.step(np.array(target)).copy())
    assert_within_limits(np.array(samples), dt, profile)
    return smoother


def offsets(**joints: float) -> list[float]:
    """18 joint targets, zero but for ``q<index>=value``."""
    target = [0.0] * 18
    for name, value in joints.items():
        target[int(name.removeprefix("q"))] = value
    return target


def test_a_failed_plan_does_not_leave_a_stale_trajectory_for_the_retry() -> None:
    """Hypothesis found it: at tick 91 ruckig fails for lb_abduction (q6) braking into 0 when
    its target moves to 0.04, and again at tick 92; the nudged retry plans. Ruckig's failed
    plan at tick 92 had already rewritten the lower joints' trajectories from the new state,
    and the retry, equal to tick 91's cached input, sampled them one tick late: lf_thigh (q4,
    near its velocity limit) jumped a tick ahead, 11691 rad/s^2 against 200."""
    data = [
        (1, offsets(q6=1.0)),
        (2, offsets()),
        (12, offsets(q6=1.0)),
        (33, offsets(q4=1.0, q6=-1.0)),
        (12, offsets()),
        (30, offsets(q4=1.0)),
        (2, offsets(q6=0.04)),
    ]
    assert retarget("qingzhui", data).fallbacks >= 2


def test_reaches_a_static_target_and_stays() -> None:
    profile = PROFILES["widowx"]
    smoother = Smoother(profile, 0.01)
    smoother.reset(np.zeros(18))
    target = np.linspace(-1.0, 1.0, 18)
    for _ in range(200):
        q = smoother.step(target)
    np.testing.assert_allclose(q, target, atol=1e-12)
    np.testing.assert_allclose(smoother.velocity, 0.0, atol=1e-12)


def track_sinusoid(feed_forward: bool) -> float:
    """Largest error following a 1 Hz, 0.3 rad sinusoid at 1 kHz (well inside the limits)."""
    profile = PROFILES["qingzhui"]
    dt = 0.001
    smoother = Smoother(profile, dt)
    w, amp = 2 * np.pi, 0.3
    smoother.reset(np.zeros(18), np.full(18, amp * w))
    err = 0.0
    for k in range(1, 2000):
        t = k * dt
        target = np.full(18, amp * np.sin(w * t))
        if feed_forward:
            qd = np.full(18, amp * w * np.cos(w * t))
            q = smoother.step(target, qd, np.full(18, -amp * w * w * np.sin(w * t)))
        else:
            q = smoother.step(target)
        err = max(err, float(np.abs(q - target).max()))
    return err


def test_moving_target_is_tracked_with_its_velocity() -> None:
    """Given the target's velocity and acceleration, ruckig tracks instead of chasing."""
    tracked, chased = track_sinusoid(True), track_sinusoid(False)
    assert tracked < 2e-3 and tracked < 0.1 * chased, (tracked, chased)


def test_reset_starts_from_the_given_state_without_a_jump() -> None:
    profile = PROFILES["widowx"]
    dt = 0.01
    smoother = Smoother(profile, dt)
    here = np.linspace(-0.5, 0.5, 18)
    smoother.reset(here)
    q = smoother.step(here + 1.0)
    _, _, jerk = limits(profile)
    assert np.all(np.abs(q - here) <= jerk * dt**3 / 6 * (1 + 1e-9)), "first tick: jerk only"


def test_new_target_mid_motion_replans_from_the_current_state() -> None:
    """Reversing the target mid-motion: velocity changes by at most a_max * dt per tick."""
    profile = PROFILES["widowx"]
    dt = 0.01
    smoother = Smoother(profile, dt)
    smoother.reset(np.zeros(18))
    samples = [np.zeros(18)]
    for _ in range(20):
        samples.append(smoother.step(np.full(18, 1.0)).copy())
    moving = smoother.velocity.copy()
    assert np.all(moving > 0.5)
    for _ in range(60):
        samples.append(smoother.step(np.full(18, -1.0)).copy())
    assert np.all(smoother.velocity < 0)
    assert_within_limits(np.array(samples), dt, profile)


def test_scale_derates_the_velocity_limit() -> None:
    profile = PROFILES["widowx"]
    dt = 0.01
    smoother = Smoother(profile, dt)
    smoother.scale = 0.5
    smoother.reset(np.zeros(18))
    samples = [np.zeros(18)] + [smoother.step(np.full(18, 2.0)).copy() for _ in range(150)]
    assert_within_limits(np.array(samples), dt, profile, scale=0.5)
    v, _, _ = limits(profile)
    assert np.abs(np.diff(samples, axis=0) / dt).max() == pytest.approx(0.5 * v.max(), rel=1e-3)
    with pytest.raises(ValueError, match="scale must be in"):
        smoother.scale = 0.0


def test_errors_are_smoothing_errors_naming_the_joint() -> None:
    profile = PROFILES["widowx"]
    smoother = Smoother(profile, 0.01)
    with pytest.raises(SmoothingError, match="before reset"):
        smoother.step(np.zeros(18))
    smoother.reset(np.zeros(18))
    target = np.zeros(18)
    target[4] = np.nan
    with pytest.raises(SmoothingError, match="rm_femur"):
        smoother.step(target)
    with pytest.raises(SmoothingError, match="expected 18 joints, got 3"):
        smoother.step(np.zeros(3))


def test_solver_failure_on_a_degenerate_state_is_retried_from_rest() -> None:
    """Ruckig 0.19 fails on this state (a 9e-9 rad move with 3.5e-5 rad/s left, 20000 rad/s^3).

    The smoother zeroes that rounding-level motion and plans again; the command stays finite
    and continuous.
    """
    profile = PROFILES["qingzhui"]
    smoother = Smoother(profile, 0.001)
    q0 = np.full(18, 1.604135641520858)
    smoother.reset(q0, np.full(18, -3.470661304644776e-05), np.full(18, -0.06027520438323086))
    target = np.full(18, 1.604135650669141)
    q = smoother.step(target, np.zeros(18), np.zeros(18))
    assert smoother.fallbacks == 1
    assert np.all(np.abs(q - q0) < 1e-7)
    for _ in range(5):
        q = smoother.step(target)
    np.testing.assert_allclose(q, target, atol=1e-12)


def test_rounding_level_state_towards_a_slowly_moving_target_is_planned() -> None:
    """Ruckig 0.19 fails from this state (Qingzhui's stance abduction at a tripod change in the
    twin) to a target 9e-9 rad away moving at 4e-5 rad/s, and from rest to it as well: the
    retry also brings that rounding-level target to rest, the command stays continuous."""
    smoother = Smoother(PROFILES["qingzhui"], 0.001)
    q0 = np.full(18, -0.0010132821721019506)
    smoother.reset(q0, np.full(18, 3.546546689152542e-05), np.full(18, -0.0317917099154543))
    target = np.full(18, -0.0010132909854105217)
    q = smoother.step(target, np.full(18, 4.0562992707554243e-05), np.full(18, -0.0257492492673))
    assert smoother.fallbacks == 1
    assert np.all(np.abs(q - q0) < 1e-7)
    for _ in range(5):
        q = smoother.step(target)
    np.testing.assert_allclose(q, target, atol=1e-12)


@pytest.mark.parametrize(
    "q0,qd0,qdd0,target,target_qd,target_qdd",
    [
        # Qingzhui's mb abduction in stance on the stairs: 6e-9 rad to go, 1.3 rad/s^2 left
        (-5.686724495847607e-4, -2.148123382101844e-5, -1.3227196956633076,
         -5.686662268590628e-4, 6.317262481463255e-6, -0.0203573459975),
        # its mb thigh braking into its target: 4.5e-5 rad to go at 0.057 rad/s, 48 rad/s^2
        (0.28531507221895813, -0.05683456846951164, 47.67555250656845,
         0.28526989339900144, -1.637554758460169e-6, 0.008974919696314032),
    ],
)  # fmt: skip
def test_a_state_the_solver_fails_on_is_planned_toward_a_nudged_target(
    q0, qd0, qdd0, target, target_qd, target_qdd
) -> None:
    """Ruckig 0.19 fails on these states of the twin's stair runs, from rest as well (the robot
    went to HOLD on the stairs); a target NUDGE along the motion plans, and the joints go on to
    settle on the target."""
    smoother = Smoother(PROFILES["qingzhui"], 0.001)
    smoother.reset(np.full(18, q0), np.full(18, qd0), np.full(18, qdd0))
    goal = np.full(18, target)
    q = smoother.step(goal, np.full(18, target_qd), np.full(18, target_qdd))
    assert smoother.fallbacks == 1
    assert np.all(np.abs(q - q0) < 1e-4)
    for _ in range(20):
        q = smoother.step(goal)
    np.testing.assert_allclose(q, goal, atol=1e-12)


def test_rounding_level_steps_of_a_streamed_target_are_planned() -> None:
    """Ruckig 0.19 fails on 1e-7..4e-7 rad steps of a target streamed at 1 kHz with its finite-
    difference velocity and acceleration (the pipeline's stream; hypothesis found it). The
    retry from rest plans them and the joints settle on the target."""
    dt = 0.001
    smoother = Smoother(PROFILES["qingzhui"], dt)
    smoother.reset(np.zeros(18))
    steps = np.concatenate([np.geomspace(1e-7, 4e-7, 9), -np.geomspace(1e-7, 4e-7, 9)])
    target, target_qd = np.zeros(18), np.zeros(18)
    for k in range(40):
        q = steps if k >= 3 else np.zeros(18)
        qd = (q - target) / dt
        qdd = (qd - target_qd) / dt if k else None
        out = smoother.step(q, qd, qdd)
        target, target_qd = q, qd
    assert smoother.fallbacks >= 1
    np.testing.assert_allclose(out, steps, atol=1e-12)
