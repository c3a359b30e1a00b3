"""The world model's terrain map on a constructed floor with a 10 cm joist, walked over 3 m.

Clouds are the scene's surface sampled inside the crop box from each pose (body frame): the map
must read the floor and the joist's top to float16's millimetre, find the joist's edge as a
step of its height, keep the floor traversable and the edge not, age what it no longer sees,
stay the same size however far the robot walks, and refresh per frame exactly what a whole-map
filter chain would give.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from climbd.daemon.algorithms.elevation import ElevationConfig
from climbd.daemon.algorithms.terrain import terrain_layers
from climbd.daemon.algorithms.world import TerrainModel, TerrainView, WorldConfig
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.messages import TerrainMap, decode, encode

JOIST_X, JOIST_WIDTH, JOIST_HEIGHT = 1.5, 0.04, 0.10
BODY_HEIGHT = 0.12
CONFIG = WorldConfig(elevation=ElevationConfig(z_min=-0.4, z_max=0.3))


def ground(x: np.ndarray) -> np.ndarray:
    """The scene's height at world x: floor at 0, the joist's top across it."""
    return np.where(np.abs(x - JOIST_X) <= JOIST_WIDTH / 2, JOIST_HEIGHT, 0.0)


def body_at(x: float, heading: float, stamp: float):
    from climbd.daemon.contract.messages import BodyState

    return BodyState(
        stamp=stamp,
        position=[x, 0.0, BODY_HEIGHT],
        orientation=[math.cos(heading / 2), 0.0, 0.0, math.sin(heading / 2)],
    )


def cloud(body) -> np.ndarray:
    """The scene's surface in the crop box ahead of ``body``, 4 mm apart, in the body frame."""
    u, v = np.meshgrid(np.arange(0.1, 1.1, 0.004), np.arange(-0.6, 0.6, 0.004), indexing="ij")
    rot = rotation(body.orientation)
    ahead = np.stack([u.ravel(), v.ravel(), np.zeros(u.size)], axis=1) @ rot.T
    world = ahead + np.asarray(body.position) * [1, 1, 0]
    world[:, 2] = ground(world[:, 0])
    return (world - np.asarray(body.position)) @ rot


@pytest.fixture(scope="module")
def walked() -> tuple[TerrainModel, list]:
    model = TerrainModel(CONFIG)
    bodies = []
    for k in range(61):
        body = body_at(0.05 * k - 1.5, 0.15 * math.sin(k / 6), 0.1 * k)
        model.update(cloud(body), body)
        bodies.append(body)
    return model, bodies


def test_heights_steps_and_traversability_of_the_scene(walked):
    model, bodies = walked
    view = TerrainView(decode(encode(model.message(6.1, bodies[-1])), TerrainMap))
    assert view.height_at(2.0, 0.1) == pytest.approx(0.0, abs=0.001)
    assert view.height_at(JOIST_X, 0.2) == pytest.approx(JOIST_HEIGHT, abs=0.001)
    edge = [view.value("step", JOIST_X - JOIST_WIDTH / 2 - d, 0.0) for d in (0.0, 0.01, 0.02)]
    assert max(edge) == pytest.approx(JOIST_HEIGHT, abs=0.001)
    assert view.traversability_at(2.0, 0.1) == pytest.approx(1.0, abs=0.01)
    assert view.value("slope", 2.0, 0.1) == pytest.approx(0.0, abs=0.01)
    assert view.traversability_at(JOIST_X - JOIST_WIDTH / 2, 0.0) == 0.0
    assert math.isnan(view.height_at(50.0, 0.0))


def test_what_is_no_longer_seen_ages(walked):
    model, bodies = walked
    now = bodies[-1].stamp
    view = TerrainView(model.message(now, bodies[-1]))
    assert view.age_at(bodies[-1].position[0] + 0.5, 0.0, now) == pytest.approx(0.0, abs=0.01)
    behind = view.age_at(bodies[-1].position[0] - 0.2, 0.0, now + 1.0)
    assert 1.0 < behind < 6.0
    assert math.isinf(view.age_at(bodies[-1].position[0], 0.95, now))


def test_the_window_rolls_with_the_robot_and_keeps_its_size(walked):
    model, bodies = walked
    assert model.map.recentred >= 5
    assert model.map.heights.shape == (model.map.side, model.map.side)
    x0 = model.map.origin[0]
    assert x0 <= bodies[-1].position[0] <= x0 + model.map.side * CONFIG.elevation.resolution
    assert math.isnan(TerrainView(model.message(6.1, bodies[-1])).height_at(-1.4, 0.0))


def test_the_per_frame_refresh_equals_the_whole_map_chain(walked):
    model, _ = walked
    full = terrain_layers(model.map.heights, CONFIG.elevation.resolution, CONFIG.terrain)
    for name, expected in (
        ("slope", full.slope),
        ("roughness", full.roughness),
        ("step", full.step),
        ("traversability", full.traversability),
        ("normal_x", full.normals[..., 0]),
    ):
        got = model.layer(name)
        assert np.array_equal(np.isnan(got), np.isnan(expected)), name
        assert np.allclose(got, expected, equal_nan=True, atol=1e-5), name


def test_a_layer_of_the_wrong_size_is_refused_by_name(walked):
    model, bodies = walked
    message = model.message(6.1, bodies[-1])
    message.rows += 1
    with pytest.raises(ValueError, match="layer 'height' holds"):
        TerrainView(message)
