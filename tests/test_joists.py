"""Joist detection: thresholds, merging, confidence, the Edge Drawing guard, plugin and CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from support.joist_scenes import JoistSpec, body_state, render

from climbd.daemon import cli
from climbd.daemon.algorithms.elevation import ElevationMap, Grid
from climbd.daemon.contract.messages import Joists, decode, encode
from climbd.daemon.runtime.loader import instantiate
from climbd.plugins.perception.joists import (
    JoistConfig,
    JoistDetector,
    detect_lines,
    edge_drawing,
    height_image,
    segment_limit,
)


def _grid(heights: np.ndarray, observed: np.ndarray | None = None) -> Grid:
    """A crop-box grid (origin 0.1 m ahead, 1.2 m wide) over synthetic heights."""
    seen = np.ones(heights.shape, bool) if observed is None else observed
    zeros = np.zeros(heights.shape, np.float32)
    raw = np.where(seen, heights, np.nan).astype(np.float32)
    return Grid(raw, heights.astype(np.float32), zeros, zeros, 0.1, -0.6, 0.01)


def _board(height: float, row0: int, rows: int = 4, cols: slice = slice(None)) -> np.ndarray:
    grid = np.zeros((100, 120), np.float32)
    grid[row0 : row0 + rows, cols] = height
    return grid


def test_boards_under_5_cm_are_not_joists_and_over_are():
    detector = JoistDetector()
    assert detector.detect(_grid(_board(0.035, 50))) == []
    found = detector.detect(_grid(_board(0.07, 50)))
    assert len(found) == 1
    assert found[0].height == pytest.approx(0.07, abs=0.003)
    # Near face at row 50: body x = 0.1 + 0.50 m, the cell's half width of bias allowed.
    assert found[0].distance == pytest.approx(0.60, abs=0.01)
    assert found[0].yaw == pytest.approx(0.0, abs=math.radians(0.5))


def test_segments_of_one_joist_are_merged_across_a_gap():
    """A notch in the joist splits its edge in two collinear segments: one joist, full extent."""
    heights = _board(0.10, 60)
    heights[:, 55:63] = 0.0
    detector = JoistDetector()
    found = detector.detect(_grid(heights))
    assert len(detector.last_lines) >= 3
    assert len(found) == 1
    ys = sorted(p[1] for p in found[0].endpoints)
    assert ys[0] < -0.5 and ys[1] > 0.5
    assert found[0].height == pytest.approx(0.10, abs=0.003)


def test_height_is_joist_top_minus_the_local_floor():
    """On a floor 4 cm below the body's ground, a 10 cm joist still reads 10 cm."""
    heights = _board(0.10, 60) - 0.04
    found = JoistDetector().detect(_grid(heights))
    assert found[0].height == pytest.approx(0.10, abs=0.003)
    assert found[0].endpoints[0][2] == pytest.approx(0.06, abs=0.003)


def test_two_joists_are_reported_nearest_first_with_signed_yaw():
    a = render([JoistSpec(0.6, math.radians(-20.0), 0.10), JoistSpec(1.2, math.radians(25), 0.1)])
    emap = ElevationMap()
    grid = emap.update(a, body_state())
    found = JoistDetector().detect(grid)
    assert len(found) == 2
    assert math.degrees(found[0].yaw) == pytest.approx(-20.0, abs=2.0)
    assert math.degrees(found[1].yaw) == pytest.approx(25.0, abs=2.0)
    assert found[0].distance == pytest.approx(0.6, abs=0.02)
    # The far joist crosses the robot's path beyond the 1.1 m box: its visible part is nearer.
    assert 1.0 < found[1].distance <= 1.1


def test_confidence_falls_when_the_edge_was_barely_measured():
    """A third of the joist's edge lies in an inpainted area: confidence about two thirds."""
    heights = _board(0.10, 60)
    full = JoistDetector().detect(_grid(heights))[0]
    seen = np.ones(heights.shape, bool)
    seen[40:80, 80:] = False
    part = JoistDetector().detect(_grid(heights, seen))
    assert full.confidence == pytest.approx(1.0, abs=0.02)
    assert part and part[0].confidence == pytest.approx(80 / 120, abs=0.05)


def test_an_edge_between_two_inpainted_areas_is_not_a_joist():
    heights = _board(0.10, 60)
    seen = np.ones(heights.shape, bool)
    seen[50:75, :] = False
    assert JoistDetector().detect(_grid(heights, seen)) == []


def _serpentine() -> np.ndarray:
    """A wall winding over the whole image: one edge chain far longer than 8·(w + h)."""
    img = np.full((300, 120), 60, np.uint8)
    for k, r in enumerate(range(4, 296, 8)):
        img[r : r + 4, 4:116] = 160
        if r + 8 < 296:
            cols = slice(112, 116) if k % 2 == 0 else slice(4, 8)
            img[r : r + 12, cols] = 160
    return img


def test_edge_drawing_guard_switches_to_lsd_on_a_long_winding_segment():
    ed = edge_drawing(JoistConfig())
    img = _serpentine()
    ed.detectEdges(img)
    assert max(len(s) for s in ed.getSegments()) > segment_limit(img.shape)
    lines, source = detect_lines(ed, img)
    assert source == "lsd"
    assert len(lines) > 20
    plain = np.full((300, 120), 60, np.uint8)
    plain[150:154] = 160
    lines, source = detect_lines(ed, plain)
    assert source == "edge_drawing"
    rows = sorted(round(float(v)) for v in lines[:, [1, 3]].ravel())
    assert rows[0] >= 148 and rows[-1] <= 155


def test_detector_survives_a_winding_obstacle_and_still_finds_the_joist():
    heights = (_serpentine().astype(np.float32) - 60) / 625.0 * 0.5
    heights[220:, :] = 0.0
    heights[250:254, :] = 0.12
    grid = Grid(heights, heights, heights * 0, heights * 0, 0.1, -0.6, 0.01)
    detector = JoistDetector()
    found = detector.detect(grid)
    assert detector.last_source == "lsd"
    joist = [j for j in found if abs(j.height - 0.12) < 0.01]
    assert joist and joist[0].distance == pytest.approx(0.1 + 2.5, abs=0.02)


def test_height_image_keeps_thresholds_apart_and_bad_scales_are_refused():
    img = height_image(np.array([[0.0, 0.05, 0.14]], np.float32), -0.1, 625.0)
    assert img[0, 1] - img[0, 0] >= 30 and img[0, 2] - img[0, 1] >= 55
    with pytest.raises(ValueError, match="image_scale"):
        JoistConfig(image_scale=100.0)


def test_plugin_from_entry_point_publishes_joists():
    plugin = instantiate(
        "climbd.perception", "joists", {"grid": {"length": 1.0}}, None, "test: joists"
    )
    msg = plugin.process_cloud(render([JoistSpec(0.9, 0.0, 0.10)]), body_state(), 2.0)
    back = decode(encode(msg), Joists)
    assert back.frame_stamp == 2.0
    assert back.joists[0].distance == pytest.approx(0.9, abs=0.02)
    assert plugin.grid is not None and plugin.grid.filled.shape == (100, 120)


def test_perceive_command_prints_joists_as_json(tmp_path, capsys):
    path = tmp_path / "cloud.npy"
    np.save(path, render([JoistSpec(0.8, math.radians(45.0), 0.18)]))
    assert cli.main(["perceive", "joists", str(path)]) == 0
    out = json.loads(capsys.readouterr().out)
    joist = out["joists"][0]
    assert set(joist) == {"distance", "yaw", "height", "endpoints", "confidence"}
    assert joist["distance"] == pytest.approx(0.8, abs=0.03)
    assert joist["yaw"] == pytest.approx(math.radians(45.0), abs=math.radians(2.0))
    assert joist["height"] == pytest.approx(0.18, abs=0.01)
