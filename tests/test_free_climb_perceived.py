"""HubRobo free-climbs on the holds its own camera finds (issue 36 item 1), through its own
control path: the hold map's rock relief in the twin, the D435 ray-cast there into the
pyrealsense2 software device, the perception role (the legs cut from each frame, graspable
detection, the world model's hold map in the odometry frame with the body's estimate at each
frame's time), its hold map over Zenoh, and the ``free_climb`` plugin planning on it through
the Dynamixel driver (tests/support/climb_driver.py, ``perceive``), after the frames of the way
up to the start. The world's holds only score."""

from __future__ import annotations

import numpy as np
import pytest
from support.climb_driver import DriverClimb

from climbd.drivers.sim.twin import GRASP_OFFSET
from climbd.plugins.perception.gripper_mask import GripperGeometry

SECONDS = 12.0
"""Three 4 s swings, the climb told so (``duration``)."""
NEAR = 0.5
"""m up the wall in the odometry frame (from the body's start): the holds this climb and its
next swings reach (the body ends about 0.15 m up, the front feet 0.25 m beyond it). Holds seen
0.65-0.7 m up, at a grazing angle, were mapped up to 2.2 cm off their height."""


@pytest.fixture(scope="module")
def climbed():
    climb = DriverClimb(seed=0, relief="rock", perceive=True, duration=SECONDS)
    try:
        climb.begin()
        yield climb, climb.run(SECONDS)
    finally:
        climb.close()


def test_hubrobo_climbs_on_the_holds_its_own_camera_finds(climbed) -> None:
    """Three swings or more, each landing where its gripper closes on a hold of the rock (the
    twin grips only within the palm's radius of one), no slip, the TSM of the holding grippers ≥ 0
    throughout, and the base goes up the slope."""
    climb, log = climbed
    assert climb.left == "", climb.left
    assert log.steps >= 3 and log.waits == 0
    assert log.missed == 0 and log.slips == 0
    assert min(log.tsm) >= 0.0
    assert log.distance > 0.05


def test_the_hold_map_is_built_from_the_camera_and_lies_on_the_rocks_holds(climbed) -> None:
    """The perception role's hold map, in the odometry frame: of its holds within ``NEAR``
    (those this climb and its next swings reach), 80 % or more lie where a gripper closing on
    them holds, within the palm's radius (``GRASP_OFFSET``) of a true hold in the wall's plane
    (the rest is rock the detector takes for a hold and the twin does not let a gripper hold),
    at least 20 of them within 1 cm, at the hold's height within the spines' closing height (a
    hold that far off its mapped height is still between the closing spines); holds seen
    again are surer; and it holds holds within the rear limbs' reach at the start, behind
    where the standing camera's view begins (0.13 m ahead of the body), which the approach's
    frames saw."""
    climb, _ = climbed
    check = climb.map_check()
    mapped, position, gap = check.map.holds, check.mapped, check.to_true
    normal = climb.rotation[:, 2]
    within = position[:, 0] < NEAR
    held = gap[within] <= GRASP_OFFSET
    assert held.mean() >= 0.8, f"{held.sum()} of {within.sum()} mapped holds on a true hold"
    near = within & (gap <= 0.01)
    assert near.sum() >= 20
    reach = GripperGeometry().closing_height
    assert np.abs((position[near] - check.true[check.nearest[near]]) @ normal).max() < reach
    confidence = np.array([h.confidence for h in mapped])
    seen = np.array([h.seen for h in mapped])
    assert (confidence[seen > 1] > confidence[seen == 1].max(initial=0.0)).all()
    assert np.count_nonzero(position[:, 0] < 0.1) >= 5  # odometry x: the start's body x
