"""Tumble Stability Margin (Yoneda & Hirose) with grip forces, against hand-derived moments."""

from __future__ import annotations

import math

import numpy as np
import pytest

from climbd.plugins.gaits.tsm import (
    stance_margins,
    tumble_stability_margin,
    tumble_stability_margins,
)

SQUARE = np.array([[0.1, 0.1, 0.0], [-0.1, 0.1, 0.0], [-0.1, -0.1, 0.0], [0.1, -0.1, 0.0]])
UP = np.array([0.0, 0.0, 1.0])


def test_level_ground_margin_is_distance_to_nearest_edge():
    force = np.array([0.0, 0.0, -10.0])
    com = np.array([0.03, 0.0, 0.06])
    assert tumble_stability_margin(com, SQUARE[[2, 0, 3, 1]], force, 0.0, UP) == pytest.approx(0.07)


def test_grip_forces_add_their_moments():
    force = np.array([0.0, 0.0, -10.0])
    com = np.array([0.0, 0.0, 0.06])
    # each edge has the two other grippers 0.2 m off its axis: + 9 N × 0.4 m
    expected = (10.0 * 0.1 + 9.0 * 0.4) / 10.0
    assert tumble_stability_margin(com, SQUARE, force, 9.0, UP) == pytest.approx(expected)


def test_com_outside_support_is_negative_without_grip():
    force = np.array([0.0, 0.0, -10.0])
    triangle = SQUARE[:3]
    com = np.array([0.08, -0.08, 0.06])  # beyond the diagonal from (0.1, 0.1) to (-0.1, -0.1)
    margin = tumble_stability_margin(com, triangle, force, 0.0, UP)
    assert margin == pytest.approx(-0.16 / math.sqrt(2))


def test_slope_shifts_the_downhill_margin_by_height_times_tangent():
    slope = math.radians(30)
    force = 2.3 * 9.80665 / 6 * np.array([-math.sin(slope), 0.0, -math.cos(slope)])
    h = 0.06
    margin = tumble_stability_margin(np.array([0.0, 0.0, h]), SQUARE, force, 0.0, UP)
    assert margin == pytest.approx(0.1 * math.cos(slope) - h * math.sin(slope))


def test_margins_of_many_coms_are_the_level_ground_distances():
    """One CoM per row: each margin is its distance to the nearest edge of the square."""
    force = np.array([0.0, 0.0, -10.0])
    coms = np.array([[0.03, 0.0, 0.06], [0.0, -0.05, 0.06], [0.12, 0.0, 0.06]])
    margins = tumble_stability_margins(coms, SQUARE, force, 0.0, UP)
    np.testing.assert_allclose(margins, [0.07, 0.05, -0.02], atol=1e-12)
    assert tumble_stability_margins(coms, SQUARE[:1], force, 9.0, UP).tolist() == [-np.inf] * 3


def test_stances_at_once_are_each_stance_on_its_own():
    """Three triangles of the square (contacts given in any order), two CoMs each: the
    batched margins are the level-ground distances of each CoM to its own triangle's edges."""
    force = np.array([0.0, 0.0, -10.0])
    stances = np.stack([SQUARE[[0, 1, 2]], SQUARE[[3, 1, 0]], SQUARE[[1, 3, 2]]])
    coms = np.array(
        [
            [[-0.05, 0.05, 0.06], [0.0, 0.05, 0.06]],  # the second nearest the diagonal y = x
            [[0.05, 0.05, 0.06], [0.05, 0.09, 0.06]],  # the second 0.01 below the edge y = 0.1
            [[-0.05, -0.05, 0.06], [-0.09, -0.05, 0.06]],  # the second 0.01 off x = -0.1
        ]
    )
    margins = stance_margins(coms, stances, force, 0.0, UP)
    d = 0.05 / math.sqrt(2)
    np.testing.assert_allclose(margins, [[0.05, d], [0.05, 0.01], [0.05, 0.01]], atol=1e-12)
