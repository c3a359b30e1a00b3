"""Eq. 5 leg by leg (``climbd.daemon.algorithms.statics``, the 1 kHz tick's form): the vectorised
kinematics' feet, Jacobians and foot forces, the legs' own weight by virtual work, and feed-forward
torques that read back as the forces they ask for."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_kinematics import KIN, ROBOTS, sample_q, unit

from climbd.daemon.algorithms.estimation import GRAVITY, exp_so3
from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.algorithms.statics import Statics

MASSES = [0.58, 0.51, 0.37]
"""Qingzhui's link masses in the twin (kg: thigh offset, thigh, shank)."""

joints = st.lists(unit, min_size=18, max_size=18)
forces = st.lists(st.floats(-100.0, 100.0), min_size=18, max_size=18)


@pytest.mark.parametrize("robot", ROBOTS)
@settings(max_examples=100, deadline=None)
@given(u=joints, tau=forces)
def test_statics_equal_the_vectorised_kinematics(robot: str, u: list[float], tau: list[float]):
    kin = KIN[robot]
    q = sample_q(kin, np.array(u[: kin.n_joints]))
    tau = np.array(tau[: kin.n_joints])
    legs = Statics(kin).at(q.tolist())
    np.testing.assert_allclose(legs.feet, kin.fk(q), rtol=0, atol=1e-14)
    jac = np.reshape(legs.jacobians, (-1, 3, 3))
    np.testing.assert_allclose(jac, kin.jacobian(q), rtol=0, atol=1e-14)
    assert legs.weight_jacobians is None
    got = np.array(Statics(kin).foot_forces(legs, tau.tolist(), (0.0, 0.0, -GRAVITY)))
    want = kin.foot_forces(q, tau)
    assert (np.isnan(got) == np.isnan(want)).all()
    ok = np.abs(np.linalg.det(jac)) > 1e-5
    np.testing.assert_allclose(got[ok], want[ok], rtol=1e-9, atol=1e-9)


def _cut(kin: Kinematics, cut: tuple[float, float, float]) -> Kinematics:
    """The same legs with their links scaled by ``cut`` (a profile refuses a zero length, the
    vectorised FK takes it): the feet are then points of the links."""
    cut_kin = copy.copy(kin)
    cut_kin.l1, cut_kin.l2, cut_kin.l3 = kin.l1 * cut[0], kin.l2 * cut[1], kin.l3 * cut[2]
    return cut_kin


CENTRES = ((0.5, 0.0, 0.0), (1.0, 0.5, 0.0), (1.0, 1.0, 0.5))
"""Each link's centre (mid-link) as a cut of the leg."""


@pytest.mark.parametrize("robot", ("qingzhui", "widowx"))
@settings(max_examples=30, deadline=None)
@given(u=joints, tilt=st.lists(st.floats(-0.4, 0.4), min_size=3, max_size=3))
def test_the_legs_weight_is_the_virtual_work_of_their_link_centres(
    robot: str, u: list[float], tilt: list[float]
) -> None:
    """sum_i J_iᵀ m_i g, by finite differences of each link centre's position (mid-link)."""
    kin = KIN[robot]
    q = sample_q(kin, np.array(u[: kin.n_joints]))
    gravity = exp_so3(tilt).T @ np.array([0.0, 0.0, -GRAVITY])
    statics = Statics(kin, MASSES)
    no_push = [(0.0, 0.0, 0.0)] * kin.n_legs
    tau = np.array(statics.torques(statics.at(q.tolist()), no_push, tuple(gravity)))
    cuts = [_cut(kin, cut) for cut in CENTRES]
    h = 1e-6
    for j in range(kin.n_joints):
        dq = np.zeros(kin.n_joints)
        dq[j] = h
        work = sum(
            m * (c.fk(q + dq) - c.fk(q - dq))[j // 3] / (2 * h) @ gravity
            for m, c in zip(MASSES, cuts, strict=True)
        )
        assert tau[j] == pytest.approx(-work, abs=1e-6)


@settings(max_examples=100, deadline=None)
@given(u=joints, push=forces, tilt=st.lists(st.floats(-0.4, 0.4), min_size=3, max_size=3))
def test_feed_forward_torques_read_back_as_the_forces_they_ask_for(
    u: list[float], push: list[float], tilt: list[float]
) -> None:
    """The feed-forward's torques (eq. 5 inverted, the legs' weight added) are what the
    estimator's eq. 5 (the legs' weight removed) reads as each foot's force."""
    kin = KIN["qingzhui"]
    q = sample_q(kin, np.array(u))
    gravity = tuple(exp_so3(tilt).T @ np.array([0.0, 0.0, -GRAVITY]))
    statics = Statics(kin, MASSES)
    legs = statics.at(q.tolist())
    pushes = [tuple(p) for p in np.reshape(push, (6, 3))]
    tau = statics.torques(legs, pushes, gravity)
    got = np.array(statics.foot_forces(legs, tau, gravity))
    ok = np.abs(np.linalg.det(np.reshape(legs.jacobians, (-1, 3, 3)))) > 1e-5
    np.testing.assert_allclose(got[ok], np.array(pushes)[ok], rtol=1e-6, atol=1e-6)


def test_a_straight_leg_reads_no_force() -> None:
    """At a singular pose eq. 5 has no answer: NaN, never a huge finite force."""
    kin = KIN["qingzhui"]
    q = kin.stand_joints()
    theta = kin.to_theta(q)
    theta[0, 2] = theta[0, 1]  # shank along the thigh: the leg is straight
    statics = Statics(kin)
    got = statics.foot_forces(statics.at(kin.to_q(theta).tolist()), [1.0] * 18, (0, 0, -GRAVITY))
    assert np.isnan(got[0]).all()
    assert np.isfinite(got[1:]).all()


def test_link_masses_must_be_three() -> None:
    with pytest.raises(ValueError, match="link_masses: expected 3 values"):
        Statics(KIN["qingzhui"], [1.0, 2.0])
