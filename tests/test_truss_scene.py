"""The truss scene generator: geometry rules, ray casting checked against MuJoCo, noise, poses."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from climbd.drivers.sim import truss_scene as ts

CAMERA = ts.DepthCamera().scaled(0.25)


def _distance_to_axis(point: np.ndarray, tube: ts.Tube) -> float:
    t = np.clip((point - tube.p0) @ tube.axis, 0.0, tube.length)
    return float(np.linalg.norm(point - tube.p0 - t * tube.axis))


def test_trusses_have_the_papers_member_counts_and_a_coupler_at_every_crossing():
    five, seven, big = ts.five_member(), ts.seven_member(), ts.scaffold(1, 2, 2)
    assert (len(five.tubes), len(seven.tubes)) == (5, 7)
    assert len(big.tubes) > 7
    # five: 2 posts x 2 ledgers + 2 diagonal ends; seven adds the transom on two posts
    assert (len(five.couplers), len(seven.couplers)) == (6, 8)
    for geometry in (five, seven, big):
        for block in geometry.couplers:
            hidden = [
                t
                for t in geometry.tubes
                if _distance_to_axis(block.centre, t) < t.radius + block.half.max()
            ]
            assert len(hidden) >= 2, "a coupler clamps two tubes"


def test_intersecting_tubes_are_refused_with_their_indices():
    a = ts.Tube(np.array([0.0, -1, 1]), np.array([0.0, 1, 1]), 0.024)
    b = ts.Tube(np.array([0.01, 0, 0]), np.array([0.01, 0, 2]), 0.024)
    with pytest.raises(ValueError, match="tubes 0 and 1 intersect"):
        ts.assemble([a, b])


def test_ray_cast_depth_matches_mujoco_mj_multiray():
    geometry = ts.seven_member()
    model = mujoco.MjModel.from_xml_string(ts.to_mjcf(geometry))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    for pose in ts.orbit_poses(geometry, count=3):
        ours = ts.depth_image(geometry, pose, CAMERA)
        v, u = np.mgrid[0 : CAMERA.height, 0 : CAMERA.width]
        rays = np.stack(
            [(u - CAMERA.ppx) / CAMERA.fx, (v - CAMERA.ppy) / CAMERA.fy, np.ones(u.shape)], -1
        ).reshape(-1, 3)
        vec = rays @ (pose[:3, :3] @ ts.OPTICAL_TO_BODY).T
        n = len(vec)
        geom, dist = np.zeros(n, np.int32), np.zeros(n)
        mujoco.mj_multiRay(
            model, data, pose[:3, 3], vec.ravel(), None, 1, -1, geom, dist, np.zeros(3 * n), n, 9
        )
        theirs = np.where(geom >= 0, dist, 0.0).reshape(ours.shape)
        theirs[(theirs < CAMERA.min_range) | (theirs > CAMERA.max_range)] = 0.0
        assert np.array_equal(ours > 0, theirs > 0)
        hit = ours > 0
        assert hit.sum() > 0.3 * hit.size
        np.testing.assert_allclose(ours[hit], theirs[hit], atol=1e-5)


def test_points_of_a_noise_free_view_lie_on_the_geometry():
    geometry = ts.five_member()
    scene = ts.render(geometry, camera=CAMERA, noise=ts.NO_NOISE, poses=ts.orbit_poses(geometry, 2))
    cloud = scene.cloud
    above = cloud[cloud[:, 2] > 1e-4]
    gaps = np.full(len(above), np.inf)
    for tube in geometry.tubes:
        w = above - tube.p0
        t = w @ tube.axis
        radial = np.linalg.norm(w - np.outer(t, tube.axis), axis=1)
        side = np.where((t >= 0) & (t <= tube.length), np.abs(radial - tube.radius), np.inf)
        caps = np.minimum(np.abs(t), np.abs(t - tube.length))
        gaps = np.minimum(gaps, np.minimum(side, np.where(radial <= tube.radius, caps, np.inf)))
    on_tubes = gaps < 1e-5
    # what is not on a tube is on a coupler: inside or on its box
    rest = above[~on_tubes]
    inside = np.zeros(len(rest), bool)
    for block in geometry.couplers:
        local = (rest - block.centre) @ block.rotation
        inside |= (np.abs(local) <= block.half + 1e-5).all(axis=1)
    assert on_tubes.mean() > 0.8
    assert inside.all()


def test_noise_grows_with_range_and_reported_poses_carry_odometry_noise():
    rng = np.random.default_rng(1)
    flat = np.full((200, 200), 1.0)
    far = np.full((200, 200), 4.0)
    noise = ts.DepthNoise(flying=0, dropout=0)
    near_sigma = np.std(ts.add_noise(flat, CAMERA, noise, rng) - flat)
    far_sigma = np.std(ts.add_noise(far, CAMERA, noise, rng) - far)
    assert near_sigma == pytest.approx(noise.a + noise.b, rel=0.05)
    assert far_sigma == pytest.approx(noise.a + 16 * noise.b, rel=0.05)
    geometry = ts.five_member()
    scene = ts.render(geometry, camera=CAMERA, seed=3)
    offsets = [
        np.linalg.norm(np.asarray(v.body.position) - v.true_pose[:3, 3]) for v in scene.views
    ]
    assert 0 < max(offsets) < 5 * np.sqrt(3) * ts.DepthNoise().pose_translation


def test_flying_pixels_appear_only_on_depth_edges():
    depth = np.full((50, 50), 3.0)
    depth[:, :25] = 1.0
    noise = ts.DepthNoise(a=0, b=0, c=0, flying=1.0, dropout=0)
    noisy = ts.add_noise(depth, CAMERA, noise, np.random.default_rng(0))
    moved = np.argwhere(np.abs(noisy - depth) > 1e-9)
    assert len(moved) > 0
    assert set(moved[:, 1]) == {24}
    assert ((noisy[:, 24] >= 1.0) & (noisy[:, 24] <= 3.0)).all()


def test_grazing_surfaces_lose_their_returns():
    """A floor seen by a level camera 0.3 m above it: rows whose true incidence (the ray
    against the floor's normal, tan = range along the axis / height) is under the grazing
    onset keep every return, rows past its end lose every one, and in between the share
    lost follows the linear ramp."""
    camera = ts.DepthCamera()
    height = 0.3
    v = np.arange(camera.height, dtype=float)
    below = v - camera.ppy
    z = np.where(below > 0, height * camera.fy / np.maximum(below, 1e-9), 0.0)
    z[(z < camera.min_range) | (z > camera.max_range)] = 0.0
    depth = np.repeat(z[:, None], camera.width, axis=1)
    noise = ts.DepthNoise(a=0, b=0, c=0, flying=0, dropout=0)
    noisy = ts.add_noise(depth, camera, noise, np.random.default_rng(0))
    incidence = np.degrees(np.arctan2(z, height))
    kept = (noisy > 0).sum(axis=1) / camera.width
    rows = (z > 0) & (np.roll(z, 1) > 0) & (np.roll(z, -1) > 0)
    assert rows.sum() > 20
    lost = 1.0 - kept
    ramp = np.clip((incidence - 70.0) / 15.0, 0.0, 1.0)
    assert (lost[rows & (incidence < 70.0)] == 0.0).all()
    assert (lost[rows & (incidence > 85.0)] == 1.0).all()
    middle = rows & (incidence > 72.0) & (incidence < 83.0)
    assert middle.sum() >= 3
    np.testing.assert_allclose(lost[middle], ramp[middle], atol=0.1)
