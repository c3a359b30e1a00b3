"""The lock-step CAN twin is repeatable: HIL runs of Qingzhui through the torque-leg driver give
the same joint log every time, however loaded the machine (the driver and the emulator thread
settle every frame before physics steps)."""

from __future__ import annotations

import numpy as np
from support.qingzhui_twin import QingzhuiRig, flat_world

from climbd.daemon.contract.messages import MotionCommand
from climbd.daemon.runtime.loader import Isolated
from climbd.drivers.torque.config import TorqueConfig
from climbd.plugins.gaits.periodic import Tripod


def _joint_log(seconds: float) -> np.ndarray:
    rig = QingzhuiRig()
    rig.controller.gait = Isolated("tripod", Tripod(None, rig.profile))
    log: list[list[float]] = []
    rig.hooks.append(lambda t: log.append(rig.controller.measured.position))
    try:
        rig.stand()
        rig.activate(MotionCommand(vx=0.1))
        rig.run(seconds)
    finally:
        rig.close()
    return np.array(log)


def test_two_stepped_runs_give_identical_joint_logs() -> None:
    first, second = _joint_log(0.4), _joint_log(0.4)
    assert first.shape == second.shape
    assert len(first) > 2800, "one sample per 1 kHz tick of 2.5 s standing and 0.4 s walking"
    assert np.ptp(first[-400:], axis=0).max() > 0.01, "the legs moved while walking"
    np.testing.assert_array_equal(first, second)


def test_gravity_feed_forward_holds_the_body_height_at_the_profile_gains() -> None:
    """Standing within 5 mm of the stand height, and walking on three legs at it in the median
    (without it, at kp 60, it stood 3.6 cm low). At a tripod change the landing tripod
    takes its share only once it touches, so the body still dips up to ~3 cm there."""
    rig = QingzhuiRig(flat_world(), feed_forward=True)
    rig.controller.gait = Isolated("tripod", Tripod(None, rig.profile))
    heights: list[float] = []
    try:
        rig.start_estimator()
        rig.stand()
        stand = rig.profile.stand.body_height + rig.twin.robot.foot_radius
        standing = rig.twin.body_pose()[0][2]
        assert rig.bus.kp == TorqueConfig.from_profile(rig.profile).kp
        rig.hooks.append(lambda t: heights.append(rig.twin.body_pose()[0][2]))
        rig.activate(MotionCommand(vx=0.1))
        rig.run(2.0)
        effort = np.asarray(rig.controller.command.effort)
    finally:
        rig.close()
    assert abs(standing - stand) < 0.005, (standing, stand)
    assert abs(np.median(heights) - stand) < 0.01, (np.median(heights), stand)
    assert np.abs(effort).max() > 1.0, "stance joints carry a feed-forward torque"
