"""A run's summary scores what the robot did at each joist against paper 000, from the path."""

from __future__ import annotations

import numpy as np
import pytest

from climbd.drivers.sim.joist_outcomes import describe, joist_outcomes
from climbd.drivers.sim.worlds import JoistRow, World


def attic() -> World:
    """A 10 cm joist turned 15° at 1 m and an 18 cm one at 2.7 m, both 1.8 m long."""
    return World(
        name="t",
        joists=[
            JoistRow(height=0.10, distance=1.0, yaw_deg=15.0, length=1.8),
            JoistRow(height=0.18, distance=2.7, length=1.8),
        ],
    )


def polyline(points: list[tuple[float, float]], step: float = 0.01) -> np.ndarray:
    """Points every ``step`` m along straight segments through ``points``."""
    out = [np.array(points[0], float)]
    for a, b in zip(points[:-1], points[1:], strict=True):
        a, b = np.array(a, float), np.array(b, float)
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
        out += [a + (b - a) * k / n for k in range(1, n + 1)]
    return np.array(out)


def test_climbed_the_low_joist_and_went_round_the_high_ones_end():
    # straight over the first joist's middle, then up to the second, left past its end at
    # y 0.9 m, and on; 0.1 s per cm
    path = polyline([(0.0, 0.0), (2.3, 0.0), (2.3, 1.2), (3.5, 1.2)])
    times = np.arange(len(path)) * 0.1
    low, high = joist_outcomes(attic(), times, path)
    assert (low.paper, low.did, low.as_paper) == ("climb", "climbed over", True)
    # the near edge of the turned joist crosses y = 0 at x = 1 - 0.019 / cos 15°
    edge = 1.0 - 0.5 * 1.5 * 0.0254 / np.cos(np.radians(15.0))
    assert low.at == pytest.approx(edge * 100 * 0.1, abs=0.11)
    assert (high.paper, high.did, high.as_paper) == ("go round", "went round its end", True)
    near = 2.7 - 0.5 * 1.5 * 0.0254
    assert high.at == pytest.approx((230 + 120 + (near - 2.3) * 100) * 0.1, abs=0.11)


def test_a_high_joist_climbed_or_a_joist_not_reached_is_told_apart():
    path = polyline([(0.0, 0.3), (0.5, 0.3), (0.5, 1.5), (3.5, 1.5)])  # round the first's end
    times = np.arange(len(path)) * 0.1
    low, high = joist_outcomes(attic(), times, path)
    assert (low.did, low.as_paper) == ("went round its end", False)
    assert (high.did, high.as_paper) == ("went round its end", True)
    over = polyline([(0.0, 0.0), (3.0, 0.0)])
    _, high = joist_outcomes(attic(), np.arange(len(over)) * 0.1, over)
    assert (high.did, high.as_paper) == ("climbed over", False)
    short = polyline([(0.0, 0.0), (0.5, 0.0)])
    outcomes = joist_outcomes(attic(), np.arange(len(short)) * 0.1, short)
    assert [(o.did, o.at) for o in outcomes] == [("not reached", None)] * 2
    text = describe(outcomes).splitlines()
    assert text[0] == (
        "joist 1: 10 cm, the paper's robot would climb; this run not reached (NOT as the paper)"
    )
