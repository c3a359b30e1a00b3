"""Standing up in the twin through the Dynamixel driver: the stand takes the profile's
``stand_time`` and the robot never leaves the ground (a foot or its body touches it), standing
up or in the second after. At its joints' limits the WidowX stood in 0.38 s and HubRobo, under
G/6, in 0.3 s, and both hopped off the floor as their legs stopped: 5 and 34 ticks of 10 ms."""

from __future__ import annotations

import pytest
from support.walk_run import dynamixel_stack

from climbd.daemon.contract.messages import Mode

GAIT = {"widowx": "tripod", "hubrobo": "crawl"}


@pytest.mark.parametrize("robot", ["widowx", "hubrobo"])
def test_the_stand_takes_its_time_and_keeps_a_foot_on_the_ground(robot: str) -> None:
    with dynamixel_stack(robot, GAIT[robot]) as (twin, stack, clock, profile):
        safety, loop = stack.safety, stack.loop
        loop.run(max_ticks=round(0.5 * profile.rate_hz))  # OFF: the twin settles on the floor
        airborne, rise, held = 0, [], []
        advance = clock.on_advance

        def watched(t0: float, t1: float) -> None:  # each period the twin steps, to 1 s in HOLD
            nonlocal airborne
            advance(t0, t1)
            airborne += not (twin.foot_contacts().any() or twin.base_contacts())
            rise.append(twin.body_pose()[0][2])
            if safety.mode != Mode.STAND:
                held.append(t1)
                if t1 - held[0] >= 1.0:
                    loop.stop()

        clock.on_advance = watched
        start = clock.now()
        assert safety.request(Mode.STAND, start, reason="start-up")
        horizon = 3 * profile.safety.stand_time + 1.0
        loop.run(max_ticks=loop.ticks + round(horizon * profile.rate_hz))
        assert safety.mode == Mode.HOLD and safety.reason == "stand complete", safety.reason
        took = safety.history[-1].at - start
    assert 0.9 * profile.safety.stand_time <= took <= profile.safety.stand_time + 1.0, took
    assert airborne == 0, f"off the ground for {airborne} ticks"
    assert max(rise) - rise[0] > 0.5 * profile.stand.body_height, "the body did not rise"
