"""The limit guard and the motion pipeline: whatever is asked, commands stay inside the limits."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from climbd.daemon.algorithms.guard import Guard, GuardError
from climbd.daemon.algorithms.motion import MotionError, MotionPipeline
from climbd.daemon.algorithms.smoothing import SmoothingError
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import FootTargets
from climbd.daemon.contract.profile import stock_profiles

PROFILES = {name: profiles.load(path) for name, path in stock_profiles().items()}


def bounds(profile) -> tuple[np.ndarray, np.ndarray]:
    return (
        np.array([j.limits.lower for j in profile.joints]),
        np.array([j.limits.upper for j in profile.joints]),
    )


@settings(max_examples=200, deadline=None)
@given(q=st.lists(st.floats(-1e6, 1e6), min_size=18, max_size=18))
def test_clamp_puts_any_finite_command_inside_the_limits(q: list[float]) -> None:
    profile = PROFILES["widowx"]
    lower, upper = bounds(profile)
    q = np.array(q)
    out, clamped = Guard(profile).clamp(q)
    assert np.all((out >= lower) & (out <= upper))
    inside = (q >= lower) & (q <= upper)
    np.testing.assert_array_equal(clamped, ~inside)
    np.testing.assert_array_equal(out[inside], q[inside])


def test_non_finite_or_misshapen_commands_are_rejected_by_name() -> None:
    guard = Guard(PROFILES["hubrobo"])
    q = np.zeros(12)
    q[5] = np.inf
    with pytest.raises(GuardError, match="rr_tibia"):
        guard.clamp(q)
    with pytest.raises(GuardError, match=r"shape \(18,\), expected \(12,\)"):
        guard.clamp(np.zeros(18))


feet_strategy = st.lists(
    st.lists(st.floats(-0.6, 0.6), min_size=3, max_size=3), min_size=6, max_size=6
)


@pytest.mark.parametrize("robot", ["widowx", "qingzhui"])
@settings(max_examples=30, deadline=None)
@given(targets=st.lists(feet_strategy, min_size=1, max_size=6), hold=st.integers(1, 30))
def test_pipeline_commands_stay_inside_the_limits_whatever_is_asked(
    robot: str, targets: list, hold: int
) -> None:
    """Random foot targets (mostly unreachable, some wildly so) never leave the limits."""
    profile = PROFILES[robot]
    pipeline = MotionPipeline(profile, 1.0 / profile.rate_hz)
    lower, upper = bounds(profile)
    pipeline.start(pipeline.kinematics.stand_joints())
    for feet in targets:
        for _ in range(hold):
            cmd = pipeline.feet_step(FootTargets(positions=feet, stance=[True] * 6))
            q = np.array(cmd.position)
            assert np.all((q >= lower) & (q <= upper))
        _, reachable = pipeline.kinematics.ik(np.array(feet))
        np.testing.assert_array_equal(pipeline.unreachable, ~reachable)


def test_unreachable_leg_keeps_its_last_target_and_is_reported() -> None:
    profile = PROFILES["widowx"]
    pipeline = MotionPipeline(profile, 0.01)
    kin = pipeline.kinematics
    stand = kin.stand_joints()
    pipeline.start(stand)
    feet = kin.stand_feet()
    feet[2] += [0.0, 0.0, 1.0]
    for _ in range(100):
        cmd = pipeline.feet_step(FootTargets(positions=feet.tolist(), stance=[True] * 6))
    assert pipeline.unreachable_legs == ["rr"]
    np.testing.assert_allclose(np.array(cmd.position), stand, atol=1e-9)


def test_pipeline_starts_at_the_measured_state_and_names_bad_input() -> None:
    profile = PROFILES["hubrobo"]
    pipeline = MotionPipeline(profile, 0.01)
    measured = pipeline.kinematics.stand_joints() + 0.05
    pipeline.start(measured)
    np.testing.assert_array_equal(pipeline.command, measured)
    cmd = pipeline.joint_step(measured)
    np.testing.assert_allclose(cmd.position, measured, atol=1e-12)
    with pytest.raises(MotionError, match="expected 4 finite"):
        pipeline.feet_step(FootTargets(positions=[[0.0, 0.0, 0.0]] * 3, stance=[True] * 3))
    feet = pipeline.kinematics.stand_feet(0.1).tolist()
    with pytest.raises(MotionError, match="stance has 3 flags, expected 4"):
        pipeline.feet_step(FootTargets(positions=feet, stance=[True] * 3))
    with pytest.raises(MotionError, match="unload has 6 flags, expected 4"):
        pipeline.feet_step(FootTargets(positions=feet, stance=[True] * 4, unload=[False] * 6))
    with pytest.raises(SmoothingError, match="rf_coxa"):
        pipeline.joint_step(np.full(12, np.nan))
