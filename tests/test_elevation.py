"""Elevation grid: cell heights, count and variance, motion fusion, float Telea hole filling."""

from __future__ import annotations

import math

import cv2
import msgspec
import numpy as np
import pytest
from support.joist_scenes import JoistSpec, body_state, render

from climbd.daemon.algorithms.elevation import ElevationConfig, ElevationMap, fill_holes
from climbd.daemon.contract.messages import ElevationGrid, decode, encode
from climbd.daemon.contract.plugins import PluginError
from climbd.daemon.runtime.loader import instantiate


def _floor_points(n: int, rng: np.random.Generator, sigma: float) -> np.ndarray:
    x = rng.uniform(0.1, 1.1, n)
    y = rng.uniform(-0.6, 0.6, n)
    z = rng.normal(0.0, sigma, n)
    return np.column_stack([x, y, z]).astype(np.float32)


def test_cells_hold_top_and_count_of_their_points():
    rng = np.random.default_rng(1)
    pts = _floor_points(200_000, rng, sigma=0.002)
    box = np.array([[0.505, 0.105, 0.07], [0.505, 0.105, 0.10]], np.float32)
    emap = ElevationMap()
    emap.integrate(np.vstack([pts, box]), body_state())
    grid = emap.crop(body_state())
    row, col = int((0.505 - 0.1) / 0.01), int((0.105 + 0.6) / 0.01)
    assert grid.heights[row, col] == pytest.approx(0.10, abs=1e-6)
    floor = np.delete(grid.heights.ravel(), row * grid.heights.shape[1] + col)
    # Top of ~17 points of σ = 2 mm noise: about +1.7σ above the floor, never a centimetre.
    assert np.nanmedian(floor) == pytest.approx(0.0034, abs=0.0015)
    assert grid.count.sum() == pytest.approx(len(pts) + 2)


def test_variance_is_the_spread_of_a_cells_height_over_frames():
    """One point per cell per frame, σ = 3 mm: after 10 frames the variance is about σ²."""
    rng = np.random.default_rng(4)
    rows, cols = np.mgrid[0:100, 0:120]
    x = (0.1 + (rows.ravel() + 0.5) * 0.01).astype(np.float32)
    y = (-0.6 + (cols.ravel() + 0.5) * 0.01).astype(np.float32)
    emap = ElevationMap()
    for _ in range(10):
        z = rng.normal(0.05, 0.003, x.size).astype(np.float32)
        emap.integrate(np.column_stack([x, y, z]), body_state())
    grid = emap.crop(body_state(), fill=False)
    assert np.median(grid.variance) == pytest.approx(0.9 * 0.003**2, rel=0.15)
    assert np.median(grid.heights) == pytest.approx(0.05, abs=0.001)
    assert (grid.count == 10).all()


def test_the_map_holds_still_while_the_robot_walks_and_turns():
    """A joist seen from one pose is where it belongs in the crop box of another pose."""
    joist = JoistSpec(distance=1.0, yaw=0.0, height=0.10)
    emap = ElevationMap()
    emap.integrate(render([joist]), body_state())
    # Walk 0.3 m forward, 0.05 m left and turn 10°, with no new frame: the map alone answers.
    x, y, yaw = 0.3, 0.05, math.radians(10.0)
    grid = emap.crop(body_state(x, y, yaw), fill=False)
    rows, cols = np.nonzero(grid.heights > 0.05)
    bx = grid.origin_x + (rows + 0.5) * 0.01
    by = grid.origin_y + (cols + 0.5) * 0.01
    wx = x + bx * math.cos(yaw) - by * math.sin(yaw)
    assert rows.size > 100
    near = np.percentile(wx, 2)
    assert near == pytest.approx(joist.distance, abs=0.015)


def test_cells_that_leave_the_view_keep_their_heights():
    joist = JoistSpec(distance=0.6, yaw=0.0, height=0.10)
    emap = ElevationMap()
    emap.integrate(render([joist]), body_state())
    # 0.45 m on, the joist lies in the camera's blind zone (body x < 0.33 m); the new frame,
    # rendered without the joist, sees only floor further ahead and must not erase it.
    emap.integrate(render([], x=0.45), body_state(0.45))
    grid = emap.crop(body_state(0.45), fill=False)
    high = grid.heights > 0.08
    assert high.any(), "the joist seen earlier is still in the map"
    rows = np.nonzero(high)[0]
    assert (grid.origin_x + (rows.min() + 0.5) * 0.01) == pytest.approx(0.15, abs=0.015)
    assert np.nanmedian(grid.heights[high]) == pytest.approx(0.10, abs=0.005)


def test_body_height_changes_shift_heights_to_the_ground_under_the_body():
    pts = _floor_points(50_000, np.random.default_rng(2), sigma=0.0)
    emap = ElevationMap()
    emap.integrate(pts, body_state())
    raised = msgspec.structs.replace(body_state(), position=[0.0, 0.0, 0.1])
    grid = emap.crop(raised, fill=False)
    assert np.nanmedian(grid.heights) == pytest.approx(-0.1, abs=1e-6)


def test_telea_fills_holes_on_float_heights_without_quantising():
    """A 5.31 cm plateau with holes comes back at 5.31 cm, not on an 8-bit height lattice."""
    plateau = np.full((100, 120), 0.0531, np.float32)
    plateau[40:46, 50:60] = np.nan
    plateau[::7, ::5] = np.nan
    filled = fill_holes(plateau, 3)
    assert not np.isnan(filled).any()
    assert np.abs(filled - 0.0531).max() < 1e-4

    rows, cols = np.mgrid[0:100, 0:120]
    ramp = (0.001 * rows + 0.0003 * cols).astype(np.float32)
    holes = ramp.copy()
    holes[40:46, 50:60] = np.nan
    err_float = np.abs(fill_holes(holes, 3) - ramp)[np.isnan(holes)]
    # The paper's way: Telea on the 8-bit image (1.6 mm a level over the 0.4 m crop height).
    image = np.clip((np.nan_to_num(holes) + 0.1) * 625, 0, 255).astype(np.uint8)
    image = cv2.inpaint(image, np.isnan(holes).astype(np.uint8), 3, cv2.INPAINT_TELEA)
    err_8bit = np.abs(image / 625.0 - 0.1 - ramp)[np.isnan(holes)]
    assert err_float.mean() < err_8bit.mean()


def test_grid_message_round_trips_with_nan_for_unknown_cells():
    emap = ElevationMap()
    emap.integrate(render([JoistSpec(1.0, 0.0, 0.1)]), body_state())
    grid = emap.crop(body_state(), fill=False)
    msg = decode(encode(grid.to_message(1.5)), ElevationGrid)
    heights = np.frombuffer(msg.heights, "<f4").reshape(msg.rows, msg.cols)
    assert (msg.rows, msg.cols, msg.resolution) == (100, 120, 0.01)
    np.testing.assert_array_equal(np.isnan(heights), np.isnan(grid.heights))
    assert np.nanmax(heights) == pytest.approx(0.10, abs=0.01)


def test_bad_input_names_the_problem():
    with pytest.raises(ValueError, match="N×3"):
        ElevationMap().integrate(np.zeros((10, 2)), body_state())
    with pytest.raises(ValueError, match="z_max"):
        ElevationConfig(z_min=0.3, z_max=0.1)
    with pytest.raises(PluginError, match=r"plugins.perception\[elevation\].*resolution"):
        instantiate(
            "climbd.perception",
            "elevation",
            {"resolution": -1.0},
            None,
            "widowx.toml: plugins.perception[elevation]",
        )
