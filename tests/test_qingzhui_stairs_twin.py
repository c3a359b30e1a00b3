"""Qingzhui's stair gait in the twin through the torque-leg driver at 1 kHz (paper 004): a bounded
variant of the stair run (bench/stairs.py --full runs the whole one): the approach over level
ground and the climb onto the second tread, planned from the stair model, with no shin or foot
contact on a stair edge (the twin's contacts), every touch-down in its tread's middle area (true
geometry), swing feet tracking their planned paths, and the estimate within 2 cm / 2° of the
twin's pose on the approach.

The configuration ``climbd run`` uses for the Qingzhui profile: the gravity feed-forward on and the
profile's gains on the motors (kp 300 N·m/rad, kd 4 N·m·s/rad; at kp 60 the swing legs lag).
"""

from __future__ import annotations

import numpy as np
import pytest
from support.stair_run import StairRun, stair_world

from climbd.daemon.algorithms.estimation import GRAVITY
from climbd.daemon.contract.messages import Mode

APPROACH, CLIMB = 3.0, 5.0
"""Seconds of walking: to the first riser (the estimate's check), then onto the second tread."""


@pytest.fixture(scope="module")
def climb():
    run = StairRun(stair_world(), feed_forward=True)
    run.start()
    run.walk(0.15, APPROACH)
    run.approach = [e.copy() for e in run.log.pose_errors()]
    run.approach_plain = [e.max() for e in run.log.pose_errors(plain=True)]
    run.walk(0.15, CLIMB)
    yield run
    run.close()


def test_climbs_onto_the_stairs(climb) -> None:
    pos, _ = climb.rig.twin.body_pose()
    flight = climb.world.stairs[0]
    assert climb.rig.safety.mode == Mode.ACTIVE, climb.rig.safety.reason
    assert pos[0] > flight.distance + 0.1 and pos[2] > climb.rig.profile.stand.body_height + 0.1
    assert not climb.rig.twin.fallen(climb.rig.profile.stand.body_height)


def test_no_shin_or_foot_contact_with_an_edge(climb) -> None:
    assert climb.log.shin_hits == []
    assert climb.log.foot_edge_hits == []


def test_touchdowns_in_middle_areas(climb) -> None:
    """The plan puts footholds >= 5 cm from the tread ends (paper 004's middle area); the feet
    land there in the twin's true geometry."""
    margins = climb.foothold_margins()
    assert len(margins) >= 18
    assert (margins >= 0.05).all(), margins


def test_the_weight_passes_between_tripods_without_dropping_the_body(climb, record_property):
    """Each half cycle opens with both tripods down while the feed-forward passes to the one
    that landed: the feet's total support (the twin's contact forces) never falls under half
    the weight. Swapping it at once let it fall to 0-50 N of 245 N, and the rebound slid the
    feet."""
    support = np.array(climb.log.support)
    weight = climb.rig.profile.mass * GRAVITY
    record_property("support_min_max_N", [float(support.min()), float(support.max())])
    assert support.min() > 0.5 * weight, (support.min(), weight)


APEX, TOUCHDOWN = 0.02, 0.01
"""Swing feet's joint-level tracking (m: commanded against measured joints' foot, body frame).
At the apex the foot is >= 5 cm (the plan's least step height) above the highest tread under
it, 2.5 cm clear with the foot's radius, so a 2 cm lag keeps it clear; at touch-down 1 cm, the
margin the footholds' 5 cm middle areas were checked with before."""


def test_swing_feet_track_their_paths(climb, record_property) -> None:
    """The commanded joints' foot against the measured one at the swing apex and at touch-down;
    the twin's foot against its planned place (odometry frame, so the estimate's drift adds in)
    is recorded beside it."""
    apex, touchdown = climb.log.swing_tracking(0.45, 0.55), climb.log.swing_tracking(0.97, 1.0)
    record_property("apex_foot_planned_joint_m", np.asarray(apex).tolist())
    record_property("touchdown_foot_planned_joint_m", np.asarray(touchdown).tolist())
    assert apex[1] < APEX and touchdown[1] < TOUCHDOWN, (apex, touchdown)


def test_estimate_within_2cm_2deg_on_the_approach(climb) -> None:
    pos, rot = climb.approach
    assert pos.max() < 0.02 and rot.max() < 2.0, (pos.max(), rot.max())


def test_estimate_without_imu_on_the_approach(climb, record_property) -> None:
    """Kinematics alone (no IMU, no ICP) over the approach, beside the fused estimate."""
    record_property("fused_max_m_deg", [float(e.max()) for e in climb.approach])
    record_property("kinematic_only_max_m_deg", [float(e) for e in climb.approach_plain])
    assert climb.approach_plain[0] < 0.02 and climb.approach_plain[1] < 2.0, climb.approach_plain
