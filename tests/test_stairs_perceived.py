"""The stair gait on stairs from perception (issue 35, item 1): Qingzhui in the twin through the
torque-leg driver at 1 kHz plans on the world model's stair map built from the front camera's
ray-cast depth by the stairs perception plugin, placed with the estimated pose at each frame's
time, after the self filter has dropped the pixels that see the robot's legs (without it the
middle-front thigh became a fourth 'step' and the gait's model refused overlapping treads); the
world's geometry only scores the run (tests/support/stair_run.py, ``perceived``).

A bounded variant of ``bench/stairs.py --full --perceived``: the approach and the climb onto the
second tread, 8 s simulated (about 25 s wall on two cores).
"""

from __future__ import annotations

from support.stair_run import StairRun, stair_world

from climbd.daemon.contract.messages import Mode

SECONDS = 8.0
"""Simulated seconds of walking at 0.15 m/s: from 0.8 m before the first riser onto the second
tread, a foothold planned on each of the three steps."""
TOLERANCE = 0.01
"""m: the issue's bound on each step's rise and tread when the gait first plans a foot onto it."""


def test_stairs_seen_by_its_camera_are_climbed_within_1_cm_without_edge_contact() -> None:
    """Every step the gait first plans a foot onto has its rise and tread within 1 cm of the
    world's (the top step's tread is the landing, seen only as far as the camera reaches: its
    rise is scored), and the climb touches no stair with a shin or a foot's side."""
    run = StairRun(stair_world(), feed_forward=True, perceived=True)
    try:
        run.start()
        run.walk(0.15, SECONDS)
    finally:
        run.close()
    flight = run.world.stairs[0]
    assert run.rig.safety.mode == Mode.ACTIVE, run.rig.safety.reason
    assert {1, 2} <= set(run.log.commits), sorted(run.log.commits)
    for step, commit in sorted(run.log.commits.items()):
        assert commit.same_step, commit
        assert abs(commit.rise_error) <= TOLERANCE, commit
        if step < flight.count:
            assert abs(commit.tread_error) <= TOLERANCE, commit
    assert run.log.shin_hits == []
    assert run.log.foot_edge_hits == []
    margins = run.foothold_margins()
    assert (margins >= 0.05).all(), margins.min()
