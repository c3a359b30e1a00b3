"""Terrain layers against surfaces whose normals, slopes, steps and roughness are known."""

from __future__ import annotations

import math

import numpy as np
import pytest

from climbd.daemon.algorithms.terrain import TerrainConfig, terrain_layers

RES = 0.01


def _grid(rows: int = 80, cols: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """x (along rows) and y (along cols) of each cell, m."""
    x, y = np.meshgrid(np.arange(rows) * RES, np.arange(cols) * RES, indexing="ij")
    return x, y


@pytest.mark.parametrize("degrees", [0.0, 10.0, 30.0])
def test_a_tilted_plane_has_its_slope_and_normal(degrees: float):
    x, y = _grid()
    tilt = math.radians(degrees)
    direction = np.array([math.cos(0.6), math.sin(0.6)])
    heights = math.tan(tilt) * (direction[0] * x + direction[1] * y)
    layers = terrain_layers(heights, RES)
    inner = (slice(5, -5), slice(5, -5))
    assert np.allclose(layers.slope[inner], tilt, atol=1e-6)
    expected = np.array([-direction[0] * math.sin(tilt), -direction[1] * math.sin(tilt)])
    assert np.allclose(layers.normals[inner][..., :2], expected, atol=1e-6)
    assert np.allclose(layers.roughness[inner], 0.0, atol=1e-6)


def test_a_joist_edge_is_a_step_of_its_height_and_not_traversable_above_the_limit():
    """Slope and roughness made lenient so that the step alone decides at the edge."""
    x, _ = _grid()
    only_step = TerrainConfig(critical_step=0.14, critical_slope=1.57, critical_roughness=1.0)
    for height, passable in ((0.10, True), (0.18, False)):
        heights = np.where(x >= 0.40, height, 0.0)
        layers = terrain_layers(heights, RES, only_step)
        edge = layers.step[38:43, 30]
        assert np.nanmax(edge) == pytest.approx(height, abs=1e-9)
        assert layers.step[10, 30] == 0.0 and layers.step[70, 30] == 0.0
        assert layers.traversability[10, 30] == pytest.approx(1.0)
        assert bool(layers.traversability[40, 30] > 0.0) is passable
        assert terrain_layers(heights, RES).traversability[40, 30] == 0.0  # 35° slope too


def test_roughness_is_the_spread_about_the_plane():
    rng = np.random.default_rng(3)
    x, y = _grid(200, 200)
    sigma = 0.005
    heights = 0.2 * x + rng.normal(0.0, sigma, x.shape)
    layers = terrain_layers(heights, RES, TerrainConfig(plane_radius=0.05))
    inner = layers.roughness[10:-10, 10:-10]
    assert np.median(inner) == pytest.approx(sigma, rel=0.1)
    assert np.median(layers.slope[10:-10, 10:-10]) == pytest.approx(math.atan(0.2), abs=0.01)


def test_unknown_cells_stay_unknown_and_sparse_windows_give_nothing():
    x, _ = _grid()
    heights = np.full(x.shape, np.nan)
    heights[10, 10] = heights[10, 11] = 0.0
    layers = terrain_layers(heights, RES)
    assert np.isnan(layers.slope).all() and np.isnan(layers.traversability).all()
    assert np.isnan(layers.step[0, 0])


def test_bad_weights_are_refused_by_name():
    with pytest.raises(ValueError, match="weights must sum to 1"):
        TerrainConfig(slope_weight=0.5, step_weight=0.5, roughness_weight=0.5)
