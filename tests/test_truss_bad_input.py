"""Truss modelling on bad input (issue 37): no cylinders, a single plane, one member seen
end-on, NaN and duplicated points, 10^7 points. Each gives a clear result (no members, or
the true ones) and no traceback; a cloud past ``max_points`` is decimated with a logged note."""

from __future__ import annotations

import logging
import tracemalloc

import numpy as np
import pytest

from climbd.drivers.sim import truss_scene as ts
from climbd.plugins.perception.truss import TrussConfig, TrussModeller
from climbd.plugins.perception.truss import model as truss_model
from climbd.plugins.perception.truss.cloud import voxel_downsample
from climbd.plugins.perception.truss.evaluate import evaluate

CAMERA = ts.DepthCamera().scaled(0.5)
MEMORY_BOUND = 2 * 2**30
"""A generous bound on the modeller's peak allocation (bytes): unbounded growth, not speed."""


def _ends(model: truss_model.TrussModel) -> list[tuple[np.ndarray, np.ndarray]]:
    """The model's members as end pairs, as ``evaluate`` takes them."""
    return [(m.p0, m.p1) for m in model.members]


def _five_member() -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray, float]]]:
    """The five-member scene's merged cloud (half resolution) and its true tubes."""
    scene = ts.render(ts.five_member(), camera=CAMERA, seed=7)
    return scene.cloud, [(t.p0, t.p1, t.radius) for t in scene.members]


def _plane(tilt_deg: float, rng: np.random.Generator) -> np.ndarray:
    """A 2 m x 2 m plane tilted ``tilt_deg`` from vertical (90: a floor), 2 mm noise."""
    tilt = np.radians(tilt_deg)
    across, up = np.array([0.0, 1.0, 0.0]), np.array([np.sin(tilt), 0.0, np.cos(tilt)])
    normal = np.cross(across, up)
    u, v = rng.uniform(-1.0, 1.0, (2, 160_000))
    offset = rng.normal(0.0, 0.002, u.size)
    return np.outer(u, across) + np.outer(v + 1.2, up) + np.outer(offset, normal)


@pytest.mark.parametrize("seed", [0, 1, 6])
def test_uniform_noise_gives_no_members(seed):
    """200 000 points in a 1 m cube: dense enough that they pass the outlier removal and
    reach RANSAC, with no cylinder among them. Seeds 1 and 6 each gave a member before a
    segment had to keep its bore clear (more points inside it than on it: a volume)."""
    rng = np.random.default_rng(seed)
    noise = rng.uniform([-0.5, -0.5, 0.5], [0.5, 0.5, 1.5], (200_000, 3))
    model = TrussModeller(TrussConfig(seed=seed)).model(noise)
    assert len(model.points) > 100_000
    assert model.members == []


@pytest.mark.parametrize("tilt_deg", [90.0, 30.0], ids=["floor", "tilted-wall"])
def test_a_single_plane_gives_no_members(tilt_deg):
    assert TrussModeller().model(_plane(tilt_deg, np.random.default_rng(1))).members == []


@pytest.mark.parametrize("offsets", [[0.0], [0.0, 0.03, -0.03]], ids=["cap", "cap-and-rim"])
def test_one_member_seen_end_on_gives_it_or_nothing(offsets):
    """A 50 mm tube seen along its axis from 0.6 to 1.2 m (its end cap) and from 3 cm off it
    (a rim of its side too): no member, or the tube, never one elsewhere."""
    tube = ts.Tube(np.array([0.0, 0.0, 1.0]), np.array([1.5, 0.0, 1.0]), 0.025)
    geometry = ts.TrussGeometry((tube,), (), floor_half_size=0.0)
    poses = [
        ts.look_at_pose([1.5 + d, o, 1.0 + o / 2], [0.5, 0.0, 1.0])
        for d in (0.6, 0.9, 1.2)
        for o in offsets
    ]
    with np.errstate(invalid="ignore"):  # the generator's floor test on rays parallel to it
        cloud = ts.render(geometry, poses=poses, seed=1).cloud
    model = TrussModeller().model(cloud)
    accuracy = evaluate(_ends(model), [(tube.p0, tube.p1, tube.radius)])
    assert len(model.members) <= 1
    assert accuracy.false_members == 0


def test_nan_rows_and_duplicated_points_give_the_same_members():
    """NaN rows, 5 % of the cloud, change nothing; every point three times gives the same
    members, the ends within 20 mm (11.6 mm measured): the plane search samples every k-th
    point, k from the cloud's length, so RANSAC draws differently (as another seed would)."""
    clean, _ = _five_member()
    rng = np.random.default_rng(2)
    at = rng.integers(0, len(clean) + 1, len(clean) // 19)
    with_nan = np.insert(clean, at, np.nan, axis=0)
    expected = TrussModeller().model(clean)
    truth = [(m.p0, m.p1, m.cylinder.radius) for m in expected.members]
    assert len(truth) == 5
    got = TrussModeller().model(with_nan)
    np.testing.assert_allclose(np.array(_ends(got)), np.array(_ends(expected)), atol=1e-9)
    tripled = TrussModeller().model(np.repeat(with_nan, 3, axis=0))
    accuracy = evaluate(_ends(tripled), truth)
    assert accuracy.all_found and accuracy.false_members == 0
    assert accuracy.max("end_error") < 0.02


def test_ten_million_points_are_decimated_to_their_voxels_with_a_note(caplog):
    """The five-member cloud repeated to 10^7 points, each copy jittered by 1 mm: modelled on
    its voxel centroids (a logged note names both counts) and every member still found."""
    clean, truth = _five_member()
    rng = np.random.default_rng(0)
    cloud = np.repeat(clean, -(-(10**7) // len(clean)), axis=0)[: 10**7]
    cloud += rng.normal(0.0, 0.001, cloud.shape)
    config = TrussConfig()
    voxels = len(voxel_downsample(cloud, config.voxel))
    assert voxels <= config.max_points
    tracemalloc.start()
    with caplog.at_level(logging.INFO, logger=truss_model.__name__):
        model = TrussModeller(config).model(cloud)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    notes = [r.getMessage() for r in caplog.records if r.name == truss_model.__name__]
    assert len(notes) == 1
    assert f"{10**7} finite points in" in notes[0] and f"{voxels} kept" in notes[0]
    assert peak < MEMORY_BOUND
    accuracy = evaluate(_ends(model), truth)
    assert accuracy.all_found and accuracy.false_members == 0


def test_more_voxels_than_max_points_are_thinned_with_a_warning(caplog):
    """A cloud whose voxel centroids alone exceed ``max_points`` keeps 1 in k of them, at
    most ``max_points``, with a warning that members may be missed."""
    rng = np.random.default_rng(3)
    noise = rng.uniform(0.0, 1.0, (200_000, 3))
    config = TrussConfig(max_points=50_000)
    voxels = len(voxel_downsample(noise, config.voxel))
    kept = len(range(0, voxels, -(-voxels // config.max_points)))
    assert kept <= config.max_points < voxels
    with caplog.at_level(logging.INFO, logger=truss_model.__name__):
        model = TrussModeller(config).model(noise)
    assert model.members == []
    [note] = [r for r in caplog.records if r.name == truss_model.__name__]
    assert note.levelno == logging.WARNING
    assert "200000 finite points in" in note.getMessage()
    assert f"{kept} kept" in note.getMessage()
    assert "members may be missed" in note.getMessage()
    with pytest.raises(ValueError, match="max_points"):
        TrussConfig(max_points=0)
