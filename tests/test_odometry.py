"""Leg odometry: the body path reconstructed from stance feet against a constructed walk."""

from __future__ import annotations

import math

import numpy as np

from daemon import profile as profiles
from daemon.estimation import rotation
from daemon.kinematics import Kinematics
from daemon.odometry import LegOdometry


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


def test_too_few_stance_feet_keep_the_last_pose(robots) -> None:
    kin = Kinematics(profiles.load(robots / "widowx.toml"))
    odo = LegOdometry(kin)
    q = kin.stand_joints()
    odo.update(q, np.ones(6, bool), 0.0)
    body = odo.update(q, np.array([1, 1, 0, 0, 0, 0], bool), 0.01)
    assert np.allclose(body.position, 0.0, atol=1e-12)
