"""Paper 004's state estimation against the twin's ground truth: Qingzhui walks its tripod gait
through the torque-leg driver at 1 kHz; foot forces (eq. 5), stance tripod, pose (eqs. 6-9),
IMU fusion (filter 1) and ICP drift correction (filter 2)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import ROOT
from support.qingzhui_twin import QingzhuiRig, contact_forces, estimator_config, flat_world

from climbd.daemon.algorithms.estimation import (
    GRAVITY,
    EstimatorConfig,
    StateEstimator,
    SupportTorques,
    exp_so3,
    log_so3,
    roll_feet,
    stance_pose,
    tripod_groups,
)
from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.messages import BodyState, MotionCommand, decode, encode
from climbd.daemon.runtime.loader import Isolated
from climbd.plugins.gaits.periodic import Tripod

WALK = 3.5
"""Seconds of tripod walking recorded (four stance changes at the default 1.5 s cycle)."""


def _errors(truth_pos, truth_quat, est_rot, est_pos):
    pos = np.linalg.norm(est_pos - truth_pos, axis=1)
    rot = np.array(
        [
            np.degrees(np.linalg.norm(log_so3(r @ rotation(q).T)))
            for r, q in zip(est_rot, truth_quat, strict=True)
        ]
    )
    return pos, rot


@pytest.fixture(scope="module")
def walk():
    """One recorded walk on level ground: joint state as the driver read it, IMU, truth,
    contact forces."""
    rig = QingzhuiRig(flat_world())
    gait = Tripod(None, rig.profile)
    rig.controller.gait = Isolated("tripod", gait)
    rig.stand()
    est = rig.start_estimator()
    log = {
        k: []
        for k in (
            "q",
            "tau",
            "gyro",
            "accel",
            "pos",
            "quat",
            "est_rot",
            "est_pos",
            "contact",
            "touching",
            "forces",
            "stance",
            "support",
        )
    }

    def record(t):
        m = rig.controller.measured
        imu = rig.twin.imu_sample()
        pos, quat = rig.twin.body_pose()
        rot, p = est.pose()
        for k, v in (
            ("q", m.position),
            ("tau", m.effort),
            ("gyro", imu.gyro),
            ("accel", imu.accel),
            ("pos", pos),
            ("quat", quat),
            ("est_rot", rot),
            ("est_pos", p),
            ("contact", contact_forces(rig.twin)),
            ("touching", rig.twin.foot_contacts()),
            ("forces", est.forces.copy()),
            ("stance", est.group == est.stance_group),
            ("support", est.support.copy()),
        ):
            log[k].append(np.array(v, float))

    rig.hooks.append(record)
    rig.activate(MotionCommand(vx=0.1))
    rig.run(WALK)
    rig.close()
    out = {k: np.array(v) for k, v in log.items()}
    out["switches"] = est.switches
    out["profile"] = rig.profile
    out["config"] = estimator_config(rig.twin)
    out["travel"] = out["pos"][-1, 0] - out["pos"][0, 0]
    return out


def test_paper_groups_for_qingzhui(walk) -> None:
    names = [leg.name for leg in walk["profile"].legs]
    group = tripod_groups(walk["profile"])
    assert {n for n, g in zip(names, group, strict=True) if g == 0} == {"mf", "rb", "lb"}  # group A
    assert {n for n, g in zip(names, group, strict=True) if g == 1} == {"mb", "rf", "lf"}  # group B


def test_support_torques_push_each_stance_foot_down_with_its_share(walk) -> None:
    """Feed-forward torques against virtual work by finite differences of FK: tau_j = dfoot/dq_j . F
    with F the stance foot's share of the weight pointing down in the world (tilted body)."""
    profile = walk["profile"]
    kin = Kinematics(profile)
    q = walk["q"][len(walk["q"]) // 2]
    rot = exp_so3(np.array([0.1, -0.15, 0.4]))
    stance = np.array([True, False, True, False, True, False])
    tau = SupportTorques(kin, profile.mass, [])(q, stance, rot).reshape(6, 3)
    share = rot.T @ np.array([0.0, 0.0, -profile.mass * GRAVITY / 3])
    eps = 1e-6
    for j in range(len(q)):
        dq = np.zeros_like(q)
        dq[j] = eps
        dfoot = (kin.fk(q + dq) - kin.fk(q - dq)) / (2 * eps)
        leg = j // 3
        expected = dfoot[leg] @ share if stance[leg] else 0.0
        assert tau[leg, j % 3] == pytest.approx(expected, abs=1e-5)
    forces = kin.foot_forces(q, tau.reshape(-1)) @ rot.T
    np.testing.assert_allclose(
        forces[stance].sum(axis=0), [0, 0, -profile.mass * GRAVITY], atol=1e-9
    )


def test_body_state_goes_on_the_wire(walk) -> None:
    """``climbd run`` publishes the estimator's BodyState: every field encodes."""
    est = StateEstimator(walk["profile"], walk["config"])
    est.update(walk["q"][0], walk["tau"][0])
    body = decode(encode(est.body(1.0)), BodyState)
    np.testing.assert_allclose(body.orientation, est.body().orientation)


def test_stance_pose_recovers_a_random_pose_exactly() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        rot = exp_so3(rng.normal(0, 0.4, 3))
        origin = rng.normal(0, 1.0, 3)
        body = rng.uniform(-0.6, 0.6, (3, 3)) + [0, 0, -0.3]
        rot_e, origin_e = stance_pose(body, origin + body @ rot.T)
        np.testing.assert_allclose(rot_e, rot, atol=1e-9)
        np.testing.assert_allclose(origin_e, origin, atol=1e-9)


def test_estimate_tracks_truth_within_2cm_2deg_while_walking(walk) -> None:
    assert walk["travel"] > 0.1, "the robot walked"
    assert walk["switches"] >= 4, "stance changed between the tripods"
    pos, rot = _errors(walk["pos"], walk["quat"], walk["est_rot"], walk["est_pos"])
    assert pos.max() < 0.02 and rot.max() < 2.0, (pos.max(), rot.max())


def test_stance_group_follows_the_contacts(walk) -> None:
    touching, stance, support = walk["touching"], walk["stance"].astype(bool), walk["support"]
    # wherever one tripod is in the air, the estimator names the other one as stance
    single = touching.sum(1) == 3
    assert single.sum() > 500
    np.testing.assert_array_equal(stance[single], touching[single].astype(bool))
    assert (support[single][~touching[single].astype(bool)] < 10.0).all()


def test_foot_forces_within_10_percent_of_contact_forces_in_stance(walk) -> None:
    """Eq. 5 (with the legs' weight removed) against MuJoCo's contact forces, world frame."""
    touching = walk["touching"].astype(bool)
    single = touching.sum(1) == 3
    est_reaction = -np.einsum("tij,tlj->tli", walk["est_rot"], walk["forces"])
    contact = walk["contact"]
    err = np.linalg.norm(est_reaction - contact, axis=2) / np.linalg.norm(contact, axis=2).clip(1)
    in_stance = err[single][touching[single]]
    assert len(in_stance) > 1500
    assert np.percentile(in_stance, 99) < 0.10, np.percentile(in_stance, [50, 99, 100])


def _replay(walk, q_noise: float, imu: bool, seed: int = 0):
    """Position error (m) and tilt error (deg, angle between true and estimated up axes)."""
    rng = np.random.default_rng(seed)
    est = StateEstimator(walk["profile"], walk["config"], walk["pos"][0], walk["quat"][0])
    pos_err, tilt_err = [], []
    for k in range(len(walk["q"])):
        q = walk["q"][k] + rng.normal(0, q_noise, walk["q"].shape[1])
        if imu:
            est.update(q, walk["tau"][k], walk["gyro"][k], walk["accel"][k], 1e-3)
        else:
            est.update(q, walk["tau"][k])
        rot, pos = est.pose()
        up = rotation(walk["quat"][k])[:, 2]
        tilt_err.append(np.degrees(np.arccos(np.clip(rot[:, 2] @ up, -1.0, 1.0))))
        pos_err.append(np.linalg.norm(pos - walk["pos"][k]))
    return np.array(pos_err), np.array(tilt_err)


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2)))


def test_imu_fusion_gains_over_kinematics_alone(walk) -> None:
    """With 3 mrad encoder noise: filter 1 (gyro, accelerometer) smooths the pose tick to tick;
    both estimates stay within 2 cm / 2 degrees. (The slow drift of the stance hand-overs is
    not observable by the IMU: the tilt error is not reliably lower, so it is only printed.)"""
    pos_k, tilt_k = _replay(walk, 0.003, imu=False)
    pos_f, tilt_f = _replay(walk, 0.003, imu=True)
    jitter_k, jitter_f = _rms(np.diff(pos_k)), _rms(np.diff(pos_f))
    print(
        f"tilt rms {_rms(tilt_k):.3f} -> {_rms(tilt_f):.3f} deg, position rms "
        f"{_rms(pos_k) * 1e3:.1f} -> {_rms(pos_f) * 1e3:.1f} mm, jitter "
        f"{jitter_k * 1e3:.2f} -> {jitter_f * 1e3:.2f} mm/tick"
    )
    assert jitter_f < 0.2 * jitter_k
    assert pos_k.max() < 0.02 and tilt_k.max() < 2.0
    assert pos_f.max() < 0.02 and tilt_f.max() < 2.0


def test_icp_correction_removes_drift_along_what_is_constrained_and_gates_each(walk) -> None:
    """Filter 2: a 3 cm height and 2 cm ascent drift that ICP measures along z and x (treads and
    risers in view) is mostly removed, y (unconstrained) is left to the legs; an alignment one
    tread (30 x 13 cm) off is rejected in both directions, and a direction gated alone does not
    stop the other."""
    est = StateEstimator(walk["profile"], walk["config"], walk["pos"][0], walk["quat"][0])
    for k in range(len(walk["q"])):
        est.update(walk["q"][k], walk["tau"][k], dt=1e-3)
    drift = np.array([0.02, -0.01, 0.03])
    est.pos = est.pos + drift
    before = est.pose()[1] - walk["pos"][-1]
    # ICP shifts the newest cloud (placed with the drifted pose) back onto the map along x, z
    x_z = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    est.icp_correction(-drift * [1.0, 0.0, 1.0], x_z)
    after = est.pose()[1] - walk["pos"][-1]
    assert abs(before[0]) > 0.015 and abs(after[0]) < 0.5 * abs(before[0]), (before, after)
    assert abs(before[2]) > 0.025 and abs(after[2]) < 0.5 * abs(before[2]), (before, after)
    assert after[1] == pytest.approx(before[1], abs=1e-9)
    est.icp_correction(np.array([0.3, 0.0, -0.13]), x_z)  # one tread of 300 x 130 mm
    assert est.icp_rejected == 2
    np.testing.assert_allclose(est.pose()[1], after + walk["pos"][-1], atol=1e-9)
    est.icp_correction(np.array([0.3, 0.0, -after[2]]), x_z)
    assert est.icp_rejected == 3
    final = est.pose()[1] - walk["pos"][-1]
    assert final[0] == pytest.approx(after[0], abs=1e-9) and abs(final[2]) < abs(after[2])


SLIDE = 0.02
"""Metres the sliding foot of ``_slide`` moves along x."""


def _stand(
    config: EstimatorConfig, ticks: int, load, planned: np.ndarray | None = None
) -> tuple[StateEstimator, np.ndarray]:
    """A standing Qingzhui (body still at the origin, 0.3 m up, IMU at rest, tripod A carrying
    the weight in thirds) run for ``ticks`` at 1 kHz; ``load(k, feet, force)`` may move feet
    (body frame) and change the forces of tick ``k``; ``planned``: the gait's stance, passed on.
    The estimator and its body positions."""
    kin = Kinematics(QINGZHUI)
    est = StateEstimator(QINGZHUI, config, BODY)
    feet = kin.stand_feet()
    track = []
    for k in range(ticks):
        force = np.zeros((kin.n_legs, 3))
        force[TRIPOD_A, 2] = -WEIGHT / 3
        load(k, feet, force)
        q, _ = kin.ik(feet)
        tau = np.einsum("lij,li->lj", kin.jacobian(q), force).reshape(-1)
        est.update(q, tau, np.zeros(3), np.array([0.0, 0.0, GRAVITY]), 1e-3, planned=planned)
        track.append(est.pose()[1].copy())
    return est, np.array(track) - BODY


QINGZHUI = profiles.load(ROOT / "robots" / "qingzhui.toml")
WEIGHT = QINGZHUI.mass * GRAVITY
BODY = np.array([0.0, 0.0, 0.3])
TRIPOD_A = np.flatnonzero(tripod_groups(QINGZHUI) == 0)
LEG = {leg.name: i for i, leg in enumerate(QINGZHUI.legs)}


def _slide(config: EstimatorConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tripod-A foot MF of a standing Qingzhui slides ``SLIDE`` along x over 50 ms, unloaded to
    30 N under 25 N of traction, then holds again: the estimated body positions, and MF's anchor
    at the end and its true place."""
    mf = LEG["mf"]
    others = np.setdiff1d(TRIPOD_A, [mf])
    stand = Kinematics(QINGZHUI).stand_feet()

    def load(k: int, feet: np.ndarray, force: np.ndarray) -> None:
        feet[mf, 0] = stand[mf, 0] + SLIDE * min(max(k - 100, 0), 50) / 50
        if 100 <= k < 150:
            force[mf] = [25.0, 0.0, -30.0]
            force[others, 2] = -(WEIGHT - 30.0) / 2

    est, track = _stand(config, 400, load)
    return track, est.anchors[mf], BODY + stand[mf] + [SLIDE, 0.0, 0.0]


def test_a_sliding_stance_foot_does_not_drag_the_estimate() -> None:
    """The slide shows in eq. 5's force (traction over support above ``slip_ratio``): the foot
    leaves the fit, the IMU and the other feet hold the body, and the foot is moved to where it
    holds again along the ground; taken as holding, it drags the body back by a third of its
    slide."""
    held, anchor, foot = _slide(EstimatorConfig())
    dragged, _, _ = _slide(EstimatorConfig(slip_ratio=1e6, slip_load=0.0))
    assert np.linalg.norm(held, axis=1).max() < 0.001, held
    assert dragged[-1, 0] < -0.2 * SLIDE, dragged[-1]
    np.testing.assert_allclose(anchor, foot, atol=0.001)


def test_a_tripod_the_gait_lifted_does_not_take_the_stance() -> None:
    """A near-straight swinging leg reads thousands of newtons from eq. 5 (twin, 180 mm stairs:
    MB, 4490 N): with the gait's schedule (tripod B lifted) tripod A keeps the stance and the
    body does not move; on the force sums alone, B takes it."""
    mb = LEG["mb"]

    def load(k: int, feet: np.ndarray, force: np.ndarray) -> None:
        if 100 <= k < 150:
            force[mb, 2] = -4490.0

    planned = np.zeros(len(LEG), bool)
    planned[TRIPOD_A] = True
    est, track = _stand(EstimatorConfig(), 300, load, planned)
    assert est.switches == 1 and est.stance_group == 0, (est.switches, est.stance_group)
    assert np.linalg.norm(track, axis=1).max() < 0.001
    unscheduled, _ = _stand(EstimatorConfig(), 300, load)
    assert unscheduled.switches == 3


@pytest.mark.parametrize("body_yaw", [0.0, math.pi / 2])
def test_a_ball_foot_rolls_its_radius_times_its_turn(body_yaw: float) -> None:
    """A wheel of radius r turned by dθ about a horizontal axis advances r·dθ at right angles to
    it (its top leads); turned about the vertical it spins in place. Foot 0 pitches 0.1 rad about
    the body's y axis, foot 1 yaws 0.3 rad; the body is yawed by ``body_yaw``."""
    r, pitch = 0.012, 0.1
    anchors = np.zeros((2, 3))
    previous = [tuple(map(tuple, np.eye(3)))] * 2
    links = [tuple(map(tuple, exp_so3([0.0, pitch, 0.0]))), tuple(map(tuple, exp_so3([0, 0, 0.3])))]
    body = exp_so3([0.0, 0.0, body_yaw])
    roll_feet(anchors, [0, 1], body, links, previous, r)
    assert np.allclose(anchors[0], r * pitch * body[:, 0], atol=1e-12)
    assert np.allclose(anchors[1], 0.0, atol=1e-12)
