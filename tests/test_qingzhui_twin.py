"""The lock-step CAN twin is repeatable: HIL runs of Qingzhui through the torque-leg driver give
the same joint log every time, however loaded the machine (the driver and the emulator thread
settle every frame before physics steps)."""

from __future__ import annotations

import numpy as np
from qingzhui_twin import QingzhuiRig

from daemon.messages import MotionCommand
from daemon.plugins import Isolated
from plugins.gaits.periodic import Tripod


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
