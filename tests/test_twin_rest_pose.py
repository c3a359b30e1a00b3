"""The twin's belly-down rest pose (closed form in drivers/sim) against the daemon's IK."""

from __future__ import annotations

import sys

import msgspec
import mujoco
import numpy as np
import pytest

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.profile import Profile, load, stock_profiles
from climbd.drivers.sim import rest_pose
from climbd.drivers.sim.twin import Twin
from climbd.drivers.sim.worlds import World

PROFILES = sorted(stock_profiles())


def _daemon_rest(profile: Profile, foot_z: float) -> tuple[np.ndarray, float] | None:
    """The rest pose as the twin computed it before: daemon IK over the same reaches."""
    kin = Kinematics(profile)
    stand = profile.stand
    span = min(sum(leg.links) for leg in profile.legs)
    for reach in np.linspace(stand.foot_reach, 0.95 * span, 12):
        feet_leg = np.zeros((kin.n_legs, 3))
        feet_leg[:, 0] = reach
        feet = kin.to_body(feet_leg)
        feet[:, 2] = foot_z
        q, ok = kin.ik(feet)
        if ok.all():
            return q, float(reach)
    return None


def _rot(quat: np.ndarray) -> np.ndarray:
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, quat)
    return m.reshape(3, 3)


@pytest.fixture(scope="module", params=PROFILES)
def twin(request):
    return Twin(load(stock_profiles()[request.param]), World(name="flat"), stepped=True, bus=False)


def test_rest_pose_equals_daemon_ik(twin):
    """Same reach, same knee branch, same joints as the daemon's Kinematics.ik (1e-6 rad)."""
    foot_z = twin.robot.foot_radius - twin.robot.body_half_height
    expected = _daemon_rest(twin.profile, foot_z)
    assert expected is not None
    q_daemon, reach = expected
    q = twin.rest_joints()
    assert q.shape == q_daemon.shape
    np.testing.assert_allclose(q, q_daemon, rtol=0, atol=1e-6)
    _, feet = rest_pose.rest_joints(twin.profile, foot_z)
    np.testing.assert_allclose(feet, Kinematics(twin.profile).fk(q_daemon), atol=1e-9)
    assert np.hypot(
        *(feet[:, :2] - np.array([leg.mount for leg in twin.profile.legs])[:, :2]).T
    ) == (pytest.approx(reach))


def test_rest_pose_puts_feet_on_the_ground(twin):
    """After reset the robot lies belly down: in the MuJoCo model every foot sphere's bottom is
    level with the base box's bottom, and nothing sinks into the ground or floats above it."""
    d, r = twin.data, twin.robot
    np.testing.assert_allclose(twin.joint_positions(), twin.rest_joints(), atol=1e-12)
    mujoco.mj_kinematics(twin.model, d)
    pos, quat = d.qpos[:3], d.qpos[3:7]
    feet_body = (d.site_xpos[r.foot_sites] - pos) @ _rot(quat)
    np.testing.assert_allclose(feet_body[:, 2], r.foot_radius - r.body_half_height, atol=1e-9)
    np.testing.assert_allclose(_rot(quat), np.eye(3), atol=1e-12)
    belly = pos[2] - r.body_half_height
    foot_bottom = d.site_xpos[r.foot_sites, 2] - r.foot_radius
    np.testing.assert_allclose(foot_bottom, belly, atol=1e-9)
    # _drop_onto_ground lifts until no geom touches, then 1 mm; leg capsules may be thicker
    # than the feet, so the feet can sit a few mm up, never below the ground.
    assert (foot_bottom > 0).all() and (foot_bottom < 0.01).all()
    assert not twin.base_contacts()


def test_no_rest_pose_raises_the_same_error():
    """Femur limits no belly-down pose satisfies: the twin refuses, as the daemon IK does."""
    profile = load(stock_profiles()["widowx"])
    legs = []
    for leg in profile.legs:
        joints = list(leg.joints)
        femur = joints[1]
        limits = msgspec.structs.replace(femur.limits, lower=2.9, upper=3.0)
        joints[1] = msgspec.structs.replace(femur, limits=limits)
        legs.append(msgspec.structs.replace(leg, joints=joints))
    bad = msgspec.structs.replace(profile, legs=legs)
    foot_z = 0.01 - 0.018
    assert _daemon_rest(bad, foot_z) is None
    assert rest_pose.rest_joints(bad, foot_z) is None
    with pytest.raises(
        ValueError,
        match=r"twin of widowx: no rest pose \(belly down, feet on the ground\) within the "
        r"joint limits; pass initial_joints",
    ):
        Twin(bad, World(name="flat"), stepped=True, bus=False)


def _with(profile: Profile, knee: str, wide: bool) -> Profile:
    """``profile`` with every knee on branch ``knee``, joint limits ±2π if ``wide``."""
    legs = []
    for leg in profile.legs:
        joints = leg.joints
        if wide:
            joints = [
                msgspec.structs.replace(
                    j, limits=msgspec.structs.replace(j.limits, lower=-6.28, upper=6.28)
                )
                for j in joints
            ]
        legs.append(msgspec.structs.replace(leg, knee=knee, joints=joints))
    return msgspec.structs.replace(profile, legs=legs)


@pytest.mark.parametrize("wide", [False, True], ids=["limits", "wide"])
@pytest.mark.parametrize("knee", ["a", "b"])
@pytest.mark.parametrize("name", PROFILES)
def test_leg_ik_matches_daemon_ik_on_both_knee_branches(name, knee, wide):
    """Random feet in and out of reach: same joints and same reachable verdict, per leg."""
    profile = _with(load(stock_profiles()[name]), knee, wide)
    kin = Kinematics(profile)
    rng = np.random.default_rng(7)
    span = max(sum(leg.links) for leg in profile.legs)
    mounts = np.array([leg.mount for leg in profile.legs])
    checked = 0
    for _ in range(200):
        feet = mounts + rng.uniform(-1.1 * span, 1.1 * span, mounts.shape)
        q_daemon, ok = kin.ik(feet)
        for i, (leg, foot) in enumerate(zip(profile.legs, feet, strict=True)):
            q = rest_pose.leg_joints(leg, foot)
            assert (q is not None) == bool(ok[i])
            if q is not None:
                np.testing.assert_allclose(q, q_daemon[3 * i : 3 * i + 3], rtol=0, atol=1e-9)
                checked += 1
    assert checked > 100 or not wide  # stock limits may exclude knee "b" altogether


def test_twin_does_not_import_the_algorithms_layer(tmp_path):
    """The import-linter contract: drivers (the twin included) stay off daemon/algorithms."""
    import subprocess

    code = (
        "import sys, climbd.drivers.sim.twin, climbd.drivers.sim.rest_pose\n"
        "print(any(m.startswith('climbd.daemon.algorithms') for m in sys.modules))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    assert out.strip() == "False"
