"""Paper 000 Table 1 in the MuJoCo twin: its ray-cast L515 sees a joist 1 m ahead.

One frame per case from the twin's depth camera (WidowX profile mount) through the plugin's
``process(frame, body)`` (the frame path the daemon uses): yaw ≤ 2°, height ≤ 1 cm, distance
≤ 5 cm; also at Table 2's steepest yaws (70°; 75° is a known gap, see FAR_EDGE).
"""

from __future__ import annotations

import math

import pytest

from daemon import profile as profiles
from daemon.kinematics import Kinematics
from daemon.messages import BodyState
from daemon.profile import stock_profiles
from drivers.sim.twin import Twin
from drivers.sim.worlds import JoistRow, World
from plugins.perception.joist_perception import JoistPerception

WIDOWX = profiles.load(stock_profiles()["widowx"])


FAR_EDGE = (
    "at 75 deg the near face is seen edge-on and the distance is read ~12 cm long, off a line "
    "between the near and far top edges (width / cos 75 deg = 15 cm apart); yaw and height hold"
)


@pytest.mark.parametrize(
    ("height", "yaw_deg"),
    [
        pytest.param(
            h, y, marks=[pytest.mark.xfail(strict=True, reason=FAR_EDGE)] if y == 75 else []
        )
        for h in (0.10, 0.18)
        for y in (75, 70, 60, 45, 30)
    ],
)
def test_table_1_in_the_twin(height: float, yaw_deg: float):
    row = JoistRow(height=height, distance=1.0, width=0.04, length=1.8, yaw_deg=yaw_deg)
    twin = Twin(WIDOWX, World(name="table1", joists=[row]), stepped=True, bus=False)
    twin.start()
    try:
        twin.command(Kinematics(WIDOWX).stand_joints())
        twin.advance_to(1.0)
        pos, quat = twin.body_pose()
        frame = twin.depth_frame("front")
    finally:
        twin.stop()
    body = BodyState(position=[float(v) for v in pos], orientation=[float(v) for v in quat])
    joists = JoistPerception().process(frame, body).joists
    assert joists
    nearest = joists[0]
    psi = math.radians(yaw_deg)
    face = row.distance - pos[0] - (row.width / 2) / math.cos(psi)
    assert abs(math.degrees(nearest.yaw) - yaw_deg) <= 2.0
    assert abs(nearest.height - height) <= 0.01
    assert abs(nearest.distance - face) <= 0.05
