"""Paper 000 Table 2, test 3, in the MuJoCo twin: an 18 cm joist 1 m ahead is gone round.

The whole chain runs on the twin's physics: ray-cast depth frames → joist perception's
``process(frame, body)`` → joist_climb → IK → ruckig → guard → joint goals (set in-process,
not through the Dynamixel emulator, to keep the test short); the body pose comes from the twin.
"""

from __future__ import annotations

import numpy as np
import pytest

from daemon import profile as profiles
from daemon.messages import BodyState, Joists
from daemon.motion import MotionPipeline
from daemon.profile import stock_profiles
from drivers.sim.twin import Twin
from drivers.sim.worlds import JoistRow, World
from plugins.gaits.joist_climb import JoistClimb, JoistClimbConfig
from plugins.perception.joist_perception import JoistPerception

DT = 0.01
PERCEPTION_PERIOD = 50


@pytest.mark.slow
def test_table_2_test_3_high_joist_is_sidestepped_in_the_twin():
    profile = profiles.load(stock_profiles()["widowx"])
    joist = JoistRow(height=0.18, distance=1.0, width=0.04, length=1.0)
    twin = Twin(profile, World(name="table2_test3", joists=[joist]), stepped=True, bus=False)
    twin.start()
    try:
        pipeline = MotionPipeline(profile, DT)
        kin = pipeline.kinematics
        twin.command(kin.stand_joints())
        twin.advance_to(1.0)
        pipeline.start(twin.joint_positions())
        behaviour = JoistClimb(JoistClimbConfig(goal_distance=1.4), profile)
        behaviour.start(BodyState(), kin.fk(twin.joint_positions()))
        perception = JoistPerception()
        world: dict = {}
        touched = 0
        t = 1.0
        for k in range(int(45.0 / DT)):
            pos, quat = twin.body_pose()
            body = BodyState(position=[float(v) for v in pos], orientation=[float(v) for v in quat])
            if k % PERCEPTION_PERIOD == 0:
                frame = twin.depth_frame("front")
                world = {Joists.TOPIC: perception.process(frame, body)}
            targets = behaviour.step(t, DT, body, world, None)
            twin.command(np.array(pipeline.feet_step(targets).position))
            t += DT
            twin.advance_to(t)
            touched += int(twin.base_contacts())
            if behaviour.done:
                break
        pos, _ = twin.body_pose()
    finally:
        twin.stop()
    events = [e for _, e in behaviour.events]
    assert events[0].startswith("sidestep") and "too high" in events[0]
    assert any(e.startswith("walk: no high joist") for e in events)
    assert behaviour.done
    assert pos[0] > joist.distance + 0.3, "walked on past the joist"
    assert abs(pos[1]) > joist.length / 2, "went round its end"
    assert touched == 0 and pipeline.unreachable_ticks == 0
