"""The world model from the twin's ray-cast L515 frames: its terrain map against the world.

The WidowX walks (kinematically, 2 cm a frame) toward a row of two joists, 10 cm and 18 cm tall;
each frame is fused with the body's true pose, so the test isolates the map from odometry (the
pose pairing is tests/test_pose_history.py's). The world's joists score the map: the floor within
5 mm, the joist tops within 1 cm (paper 000's 1 cm cells), their near faces as steps (of what
the camera sees of them), the floor traversable and the faces not.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.algorithms.world import TerrainView, WorldModel
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import BodyState
from climbd.daemon.contract.profile import stock_profiles

WIDOWX = profiles.load(stock_profiles()["widowx"])
INCH = 0.0254


@pytest.fixture(scope="module")
def mapped():
    from climbd.drivers.sim.twin import Twin
    from climbd.drivers.sim.worlds import JoistRow, World

    row = JoistRow(height=0.10, distance=0.9, count=1, width=1.5 * INCH)
    tall = JoistRow(height=0.18, distance=0.9 + 16 * INCH, count=1, width=1.5 * INCH)
    twin = Twin(WIDOWX, World(name="rows", joists=[row, tall]), stepped=True, bus=False)
    twin.start()
    world = WorldModel()
    try:
        twin.command(Kinematics(WIDOWX).stand_joints())
        twin.advance_to(1.0)
        with twin.lock:
            start = twin.data.qpos[:7].copy()
        for k in range(15):
            with twin.lock:
                twin.data.qpos[:7] = start
                twin.data.qpos[0] += 0.02 * k
                twin.data.time = 1.0 + k / 30
                pos, quat = twin.data.qpos[:3].copy(), twin.data.qpos[3:7].copy()
            frame = twin.depth_frame("front")
            body = BodyState(
                stamp=frame.timestamp, position=pos.tolist(), orientation=quat.tolist()
            )
            world.frame(frame, body)
    finally:
        twin.stop()
    terrain = world.messages(2.0)[0]
    return TerrainView(terrain), row, tall


def test_the_floor_and_the_joist_tops_are_where_the_world_has_them(mapped):
    view, row, tall = mapped
    floor = [view.height_at(x, y) for x in (0.6, 0.7) for y in (-0.2, 0.0, 0.2)]
    assert np.nanmax(np.abs(floor)) <= 0.005, floor
    assert all(np.isfinite(floor))
    for joist in (row, tall):
        top = [view.height_at(joist.distance, y) for y in (-0.2, 0.0, 0.2)]
        assert np.allclose(top, joist.height, atol=0.01), (joist.height, top)


def test_the_near_faces_are_steps_of_what_is_seen_and_not_traversable(mapped):
    """The 10 cm joist's face is a step of its height; the 18 cm one's foot is hidden behind the
    first joist from here, so its face reads the part seen (more than 12 cm)."""
    view, row, tall = mapped
    for joist, least in ((row, row.height - 0.01), (tall, 0.12)):
        face = joist.distance - joist.width / 2
        steps = [view.value("step", face + d, 0.0) for d in (-0.02, -0.01, 0.0, 0.01)]
        assert least <= np.nanmax(steps) <= joist.height + 0.01, steps
        assert view.traversability_at(face, 0.0) == 0.0
    assert view.traversability_at(0.65, 0.0) > 0.9
    assert math.isinf(view.age_at(-3.0, 0.0, 2.0))
