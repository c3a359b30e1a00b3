"""Leg kinematics: FK∘IK identity, Jacobian vs finite differences, paper 004 eqs. 1-5, stand."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from climbd.daemon.algorithms.kinematics import Kinematics, KinematicsError
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.profile import stock_profiles

ROBOTS = ("widowx", "hubrobo", "qingzhui", "mixed")
KIN = {name: Kinematics(profiles.load(path)) for name, path in stock_profiles().items()}


def mixed_profile() -> profiles.Profile:
    """Qingzhui with every other leg a coxa-femur-tibia leg: both chains in one robot."""
    data = profiles.msgspec.to_builtins(KIN["qingzhui"].profile)
    for leg in data["legs"][::2]:
        leg["kind"] = "coxa_femur_tibia"
    return profiles.from_dict(data, "mixed")


KIN["mixed"] = Kinematics(mixed_profile())

unit = st.floats(0.0, 1.0)


def sample_q(kin: Kinematics, u: np.ndarray) -> np.ndarray:
    """A joint vector inside the limits from uniform samples ``u`` in [0, 1]."""
    return kin.lower + u * (kin.upper - kin.lower)


def on_branch(kin: Kinematics, q: np.ndarray) -> np.ndarray:
    """Legs whose pose lies on the IK's knee branch, away from singular and wrapped poses."""
    theta = kin.to_theta(q)
    b, c = theta[:, 1], theta[:, 2]
    l1, l2, l3 = kin.l1, kin.l2, kin.l3
    bend = np.where(kin.cft, c, c - b) * kin.knee_sign
    reach = np.where(
        kin.cft,
        l1 + l2 * np.cos(b) + l3 * np.cos(b + c),
        l2 * np.sin(b) + l3 * np.sin(c),
    )
    return (bend > 0.05) & (bend < np.pi - 0.05) & (reach > 0.01)


@pytest.mark.parametrize("robot", ROBOTS)
@settings(max_examples=150, deadline=None)
@given(u=st.lists(unit, min_size=18, max_size=18))
def test_fk_of_ik_is_identity_over_the_reachable_workspace(robot: str, u: list[float]) -> None:
    kin = KIN[robot]
    q = sample_q(kin, np.array(u[: kin.n_joints]))
    feet = kin.fk(q)
    q_ik, reachable = kin.ik(feet)
    branch = on_branch(kin, q)
    assert reachable[branch].all(), "a pose inside the limits on the knee branch is reachable"
    err = np.linalg.norm(kin.fk(q_ik)[reachable] - feet[reachable], axis=1)
    assert np.all(err < 1e-9)
    np.testing.assert_allclose(q_ik.reshape(-1, 3)[branch], q.reshape(-1, 3)[branch], atol=1e-6)
    q_tick, reachable_tick = kin.ik_feet(feet.tolist())
    assert reachable_tick == reachable.tolist()
    err = np.linalg.norm(kin.fk(np.array(q_tick))[reachable] - feet[reachable], axis=1)
    assert np.all(err < 1e-9)


def test_a_foot_at_full_extension_is_reachable_by_both_iks() -> None:
    """HubRobo's leg with its knee straight (at its limit): the law of cosines gives
    1 + 2e-16 on numpy's path and 1.0 on math's; both IKs reach it with its own joints
    (found by the property test above: the masks differed)."""
    kin = KIN["hubrobo"]
    u = np.zeros(kin.n_joints)
    u[6:9] = [0.8588757264743412, 0.05464322956027458, 1.0]
    q = sample_q(kin, u)
    feet = kin.fk(q)
    q_ik, reachable = kin.ik(feet)
    q_tick, reachable_tick = kin.ik_feet(feet.tolist())
    assert reachable[2] and reachable_tick[2]
    assert reachable_tick == reachable.tolist()
    np.testing.assert_allclose(q_ik[6:9], q[6:9], atol=1e-6)
    np.testing.assert_allclose(q_tick[6:9], q[6:9], atol=1e-6)


@pytest.mark.parametrize("robot", ROBOTS)
@settings(max_examples=100, deadline=None)
@given(offsets=st.lists(st.floats(-0.3, 0.3), min_size=18, max_size=18))
def test_scalar_tick_ik_equals_the_vectorised_ik(robot: str, offsets: list[float]) -> None:
    """``ik_feet`` (the control tick's scalar IK) gives ``ik``'s joints and reachable mask,
    inside and outside the workspace and the joint limits."""
    kin = KIN[robot]
    feet = kin.stand_feet() + np.reshape(offsets[: kin.n_joints], (-1, 3))
    q, reachable = kin.ik(feet)
    q_tick, reachable_tick = kin.ik_feet(feet.tolist())
    assert reachable_tick == reachable.tolist()
    np.testing.assert_allclose(q_tick, q, rtol=0, atol=1e-12)


@pytest.mark.parametrize("robot", ROBOTS)
def test_legs_repeated_solve_many_points_per_leg_as_each_leg_alone(robot: str) -> None:
    """``Kinematics(profile, repeat=k)`` (a planner's many candidates per leg) gives each of
    its k points per leg the joints and reachable mask the robot's own IK gives that point,
    inside and outside the workspace and its legs' own joint limits (made to differ from leg
    to leg here); its scalar tick IK agrees too."""
    data = profiles.msgspec.to_builtins(KIN[robot].profile)
    for i, leg in enumerate(data["legs"]):
        for joint in leg["joints"]:
            joint["limits"]["upper"] -= 0.05 * i
    kin, k = Kinematics(profiles.from_dict(data, robot)), 5
    many = Kinematics(kin.profile, repeat=k)
    rng = np.random.default_rng(3)
    offsets = rng.uniform(-0.3, 0.3, (k, kin.n_legs, 3)) * np.linspace(0.0, 1.0, k)[:, None, None]
    feet = kin.stand_feet()[None] + offsets  # (k, legs, 3): some far outside the workspace
    q, reachable = many.ik(feet.transpose(1, 0, 2).reshape(-1, 3))
    q = q.reshape(kin.n_legs, k, 3)
    reachable = reachable.reshape(kin.n_legs, k)
    assert reachable.any() and not reachable.all()
    for i in range(k):
        q_one, reachable_one = kin.ik(feet[i])
        assert reachable[:, i].tolist() == reachable_one.tolist()
        np.testing.assert_allclose(q[:, i], q_one.reshape(-1, 3), rtol=0, atol=1e-12)
    q_tick, reachable_tick = many.ik_feet(feet.transpose(1, 0, 2).reshape(-1, 3).tolist())
    assert reachable_tick == reachable.reshape(-1).tolist()
    np.testing.assert_allclose(np.reshape(q_tick, q.shape), q, rtol=0, atol=1e-12)


@pytest.mark.parametrize("robot", ROBOTS)
@settings(max_examples=100, deadline=None)
@given(u=st.lists(unit, min_size=18, max_size=18))
def test_jacobian_matches_finite_differences(robot: str, u: list[float]) -> None:
    kin = KIN[robot]
    q = sample_q(kin, np.array(u[: kin.n_joints]))
    jac = kin.jacobian(q)
    h = 1e-6
    for k in range(3):
        dq = np.zeros(kin.n_joints)
        dq[k::3] = h
        column = (kin.fk(q + dq) - kin.fk(q - dq)) / (2 * h)
        np.testing.assert_allclose(jac[:, :, k], column, atol=1e-8)


@settings(max_examples=100, deadline=None)
@given(
    u=st.lists(unit, min_size=18, max_size=18),
    force=st.lists(st.floats(-100.0, 100.0), min_size=18, max_size=18),
)
def test_foot_forces_invert_the_jacobian_transpose(u: list[float], force: list[float]) -> None:
    """Paper 004 eq. 5: F = (J^T)^-1 tau, so torques made by tau = J^T F give F back."""
    kin = KIN["qingzhui"]
    q = sample_q(kin, np.array(u))
    f = np.array(force).reshape(6, 3)
    tau = np.einsum("lji,lj->li", kin.jacobian(q), f).reshape(-1)
    got = kin.foot_forces(q, tau)
    det = np.abs(np.linalg.det(kin.jacobian(q)))
    ok = det > 1e-5
    np.testing.assert_allclose(got[ok], f[ok], rtol=1e-6, atol=1e-6)
    assert np.isnan(got[det < 1e-12]).all() and not np.isnan(got[det >= 1e-12]).any()


def paper_004_toe(theta_a, theta_t, theta_s, l_ab, l_be):
    """Paper 004 eqs. 1-3 as printed, in the paper's leg frame."""
    rho = l_ab * np.sin(theta_t) + l_be * np.sin(theta_s)
    return np.array(
        [
            l_ab * np.cos(theta_t) + l_be * np.cos(theta_s),
            rho * np.cos(theta_a),
            rho * np.sin(theta_a),
        ]
    )


def paper_004_jacobian(theta_a, theta_t, theta_s, l_ab, l_be):
    """Paper 004 eq. 4: columns d/d(theta_t, theta_s, theta_a) in the paper's leg frame."""
    st_, ss, sa = np.sin(theta_t), np.sin(theta_s), np.sin(theta_a)
    ct, cs, ca = np.cos(theta_t), np.cos(theta_s), np.cos(theta_a)
    rho = l_ab * st_ + l_be * ss
    return np.array(
        [
            [-l_ab * st_, -l_be * ss, 0.0],
            [l_ab * ct * ca, l_be * cs * ca, -rho * sa],
            [l_ab * ct * sa, l_be * cs * sa, rho * ca],
        ]
    )


@settings(max_examples=100, deadline=None)
@given(u=st.lists(unit, min_size=18, max_size=18))
def test_qingzhui_leg_follows_paper_004_equations(u: list[float]) -> None:
    """Our leg frame is the paper's with its y pointing down: (x, y, z) = (l1 + xp, zp, -yp)."""
    kin = KIN["qingzhui"]
    q = sample_q(kin, np.array(u))
    theta = kin.to_theta(q)
    feet_leg = kin.fk_leg(theta)
    jac_leg = kin.jacobian_leg(theta)
    to_ours = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
    for i in range(kin.n_legs):
        a, t, s = theta[i]
        toe = paper_004_toe(a, t, s, kin.l2[i], kin.l3[i])
        np.testing.assert_allclose(feet_leg[i], to_ours @ toe + [kin.l1[i], 0, 0], atol=1e-12)
        jac = to_ours @ paper_004_jacobian(a, t, s, kin.l2[i], kin.l3[i])
        np.testing.assert_allclose(jac_leg[i], jac[:, [2, 0, 1]], atol=1e-12)


@pytest.mark.parametrize("robot", ROBOTS)
def test_stand_pose_puts_feet_at_reach_and_height(robot: str) -> None:
    kin = KIN[robot]
    stand = kin.profile.stand
    feet = kin.fk(kin.stand_joints())
    np.testing.assert_allclose(feet, kin.stand_feet(), atol=1e-12)
    np.testing.assert_allclose(feet[:, 2], -stand.body_height)
    radial = np.linalg.norm(feet[:, :2] - kin.mount[:, :2], axis=1)
    np.testing.assert_allclose(radial, stand.foot_reach)
    leg_dir = np.stack([np.cos(kin.yaw), np.sin(kin.yaw)], 1)
    np.testing.assert_allclose(np.sum((feet[:, :2] - kin.mount[:, :2]) * leg_dir, 1), radial)


def test_zero_offset_and_direction_map_kinematic_to_joint_angles(robots) -> None:
    """q = direction * theta + zero_offset: flipping a joint flips its command, same foot."""
    base = profiles.load(robots / "hubrobo.toml")
    data = profiles.msgspec.to_builtins(base)
    joint = data["legs"][0]["joints"][1]
    joint.update(direction=-1, zero_offset=0.2)
    joint["limits"].update(lower=-1.5708 + 0.2, upper=1.0472 + 0.2)
    flipped = Kinematics(profiles.from_dict(data, "flipped"))
    plain = KIN["hubrobo"]
    q = plain.stand_joints()
    q_flipped = flipped.stand_joints()
    assert q_flipped[1] == pytest.approx(0.2 - q[1])
    np.testing.assert_allclose(flipped.fk(q_flipped), plain.fk(q), atol=1e-12)


def test_unreachable_targets_are_reported_not_clamped() -> None:
    kin = KIN["widowx"]
    feet = kin.stand_feet()
    feet[0] += [1.0, 0.0, 0.0]  # far outside the workspace
    feet[1, 2] = 0.05  # above the coxa, reachable only by folding past the tibia limit
    q, reachable = kin.ik(feet)
    assert reachable.tolist() == [False, False, True, True, True, True]
    assert np.isnan(q[0:3]).all(), "no pose is invented for a point outside the workspace"
    assert not np.isnan(q[3:6]).any()
    lower, upper = kin.lower[3:6], kin.upper[3:6]
    assert np.any((q[3:6] < lower) | (q[3:6] > upper)), "the solution is reported as it is"
    np.testing.assert_allclose(kin.fk(q)[2:], feet[2:], atol=1e-12)


def test_body_and_leg_frames_round_trip() -> None:
    kin = KIN["qingzhui"]
    pts = np.random.default_rng(4).normal(size=(6, 3))
    np.testing.assert_allclose(kin.to_body(kin.to_leg(pts)), pts, atol=1e-12)
    outward = kin.to_leg(kin.mount + np.stack([np.cos(kin.yaw), np.sin(kin.yaw), 0 * kin.yaw], 1))
    np.testing.assert_allclose(outward, np.tile([1.0, 0, 0], (6, 1)), atol=1e-12)


def test_unreachable_stand_pose_is_a_clear_profile_error(robots) -> None:
    data = profiles.msgspec.to_builtins(profiles.load(robots / "widowx.toml"))
    data["stand"]["foot_reach"] = 0.5
    kin = Kinematics(profiles.from_dict(data, "tall.toml"))
    with pytest.raises(KinematicsError, match=r"tall.toml: \$.stand: legs .*foot_reach=0.5"):
        kin.stand_joints()
