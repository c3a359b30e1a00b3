"""HubRobo free-climbs through its own control path in the twin (issue 36, item 3): the
Dynamixel Protocol 2.0 driver on the twin's emulated servos and gripper servos (a pty), the
controller and guard on a stepped clock, the ``free_climb`` plugin planning on its worker.

The hold map is the world's true holds placed by the body's estimate (tests/support/
climb_driver.py), so these tests isolate the gait from perception.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from support.climb_driver import DriverClimb

SECONDS = 12.0
"""Three 4 s swings: the climb is told so (``duration``), as the paper's 45 s runs are."""


@pytest.fixture(scope="module")
def climbed():
    climb = DriverClimb(seed=0, duration=SECONDS)
    try:
        climb.begin()
        yield climb, climb.run(SECONDS)
    finally:
        climb.close()


def test_hubrobo_climbs_through_its_dynamixel_driver_isolating_the_gait(climbed) -> None:
    """Every swing's gripper opens and closes through the driver and holds where it lands:
    three swings, no missed grip, no slip, the TSM of the holding grippers ≥ 0 throughout, and
    the base goes up the slope (0.139 m: ``bench/free_climb_driver.py --seeds 1 --seconds
    12``)."""
    climb, log = climbed
    assert climb.left == "", climb.left
    assert log.steps == 3 and log.waits == 0
    assert climb.releases == 3, "each swing's gripper opened through the driver, once"
    assert log.missed == 0 and log.slips == 0
    assert min(log.tsm) >= 0.0
    assert log.distance > 0.05


def test_the_gait_plans_on_the_grips_the_driver_reports(climbed) -> None:
    """Tick by tick through a swing, the body the control role gives the gait carries the
    grippers' holds as the driver decodes them from the gripper servos (fingers stopped on a
    hold), equal to the twin's when the tick read them (a tick follows its physics step): the
    swing's gripper holds nothing while it is open, and holds again once it closes on its
    hold."""
    climb, _ = climbed
    controller, twin = climb.stack.controller, climb.twin
    seen = []
    for _ in range(round(1.2 * climb.config.swing_period * climb.profile.rate_hz)):
        climb.stack.run(1.0 / climb.profile.rate_hz)
        truth = twin.holding().tolist()
        assert controller.body.holding == truth
        seen.append(truth)
    assert [True] * 4 in seen and any(not all(held) for held in seen)


def test_a_grip_the_driver_reports_empty_is_backed_off_isolating_the_gait() -> None:
    """Halfway through the first swing its hold stops being graspable: the foot lands, the
    gripper servo closes all the way (nothing between its fingers), the driver reports no hold,
    and the gait keeps three grips, swings back to the hold it left and grips it again; no slip,
    TSM ≥ 0."""
    climb = DriverClimb(seed=0, duration=SECONDS)
    try:
        climb.begin()
        cfg = climb.config
        first = climb.run(cfg.swing_period / 2)
        runner, gait, twin = climb.gait.runner, climb.gait, climb.twin
        step = runner.step
        assert step is not None and not step.wait
        k = int(np.argmin(np.linalg.norm(gait.holds - step.target, axis=1)))
        geom = twin.model.geom(f"hold_{gait.hold_ids[k]}").id
        twin.robot.graspable_geoms = twin.robot.graspable_geoms[twin.robot.graspable_geoms != geom]
        log = climb.run(cfg.swing_period / 2 + cfg.grip_wait + cfg.swing_period + 0.5)
        assert climb.left == "", climb.left
        assert runner.missed == 1
        back = runner.steps[1]
        np.testing.assert_allclose(back.target, step.start, atol=1e-9)
        assert climb.bus.read().holding[step.limb] and twin.holding()[step.limb]
        assert first.slips == log.slips == 0
        assert min(first.tsm + log.tsm) >= 0.0
    finally:
        climb.close()


def test_a_hold_taken_off_the_wall_mid_swing_is_backed_off_isolating_the_gait(caplog) -> None:
    """Halfway through the first swing its hold is taken off the wall and out of the hold map:
    the limb swings back to the hold it left and the driver reports it gripped again; no slip,
    no missed grip, TSM ≥ 0."""
    climb = DriverClimb(seed=0, duration=SECONDS)
    try:
        climb.begin()
        cfg = climb.config
        first = climb.run(cfg.swing_period / 2)
        runner, gait = climb.gait.runner, climb.gait
        step = runner.step
        assert step is not None and not step.wait
        k = int(np.argmin(np.linalg.norm(gait.holds - step.target, axis=1)))
        climb.take_off(int(gait.hold_ids[k]))
        caplog.set_level(logging.INFO, logger="climbd.gait.free_climb")
        log = climb.run(cfg.swing_period / 2 + cfg.swing_period + 0.5)
        assert climb.left == "", climb.left
        assert f"limb {step.limb}'s hold" in caplog.text
        assert "left the hold map mid-swing: back to the hold it left" in caplog.text
        back = runner.steps[1]
        np.testing.assert_allclose(back.target, step.start, atol=1e-9)
        assert climb.bus.read().holding[step.limb] and climb.twin.holding()[step.limb]
        assert runner.missed == 0 and first.slips == log.slips == 0
        assert min(first.tsm + log.tsm) >= 0.0
    finally:
        climb.close()
