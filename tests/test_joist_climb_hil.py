"""Paper 000 Table 2 through the daemon's driver path (joist_twin_run, ``driver=True``).

joist_climb runs as a gait plugin under the Controller and the safety supervisor, on the body
its leg odometry estimates, writing through dynamixel_sdk to the twin's AX-18A emulator on its
pty, lock-step by count. The full Table 2 test 3 takes about 75 s of wall time here, so the
test runs a shortened scene; the in-process runs of tests/test_joist_climb_twin.py are the fast
variant.
bench/joist_climb.py runs every Table 2 case both ways and compares their decisions and end
poses (the check that the fast variant stands for the driver path).
"""

from __future__ import annotations

from support.joist_twin_run import run_scenario
from test_joist_climb_twin import assert_went_round

from climbd.drivers.sim.worlds import JoistRow


def test_a_high_joist_is_gone_round_through_the_driver_isolating_the_gait():
    """Table 2 test 3 shortened for the suite (an 18 cm joist 0.6 m long at 0.7 m instead of
    1.8 m at 1 m: a third of the sidestep); bench/joist_climb.py runs the full scene."""
    row = JoistRow(height=0.18, distance=0.7, width=0.04, length=0.6)
    hil = run_scenario([row], goal=1.05, seconds=120.0, driver=True)
    assert hil.held == "", f"the safety supervisor left ACTIVE: {hil.held}"
    assert hil.unreachable_ticks == 0
    assert_went_round(hil, row)
