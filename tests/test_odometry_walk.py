"""Short version of bench/odometry.py: a straight walk in the twin through the robot's own
Dynamixel driver, the odometry scored by the twin's true pose at the end (issue #32's goal:
within 2 % of the distance and 2° of heading; the bench walks 5 m)."""

from __future__ import annotations

import pytest
from support.walk_run import dynamixel_walk


@pytest.mark.parametrize(
    "robot,gait,vx,seconds",
    [("hubrobo", "crawl", 0.02, 50.0), ("widowx", "tripod", 0.05, 30.0)],
)
def test_leg_odometry_keeps_within_two_percent_of_a_walk(robot, gait, vx, seconds) -> None:
    """HubRobo crawls 1 m under G/6, where its feet slide; the WidowX walks 1.5 m at 1 g.
    The estimate ends within 2 % of the distance and 2° of the heading, inside the standard
    deviation the odometry published, and well inside dead reckoning of the command."""
    w = dynamixel_walk(robot, gait, vx, seconds)
    assert w.distance > 0.9 * vx * seconds, w.distance
    assert w.position_error <= 0.02 * w.distance, (w.position_error, w.distance)
    assert w.yaw_error_deg <= 2.0
    assert w.position_error <= w.sigma_xy and w.yaw_error_deg <= w.sigma_yaw_deg
    assert w.position_error < 0.5 * w.baseline_error
