"""The fixed-rate loop: exact tick sequence under a stepped clock, no drift, overrun skipping."""

from __future__ import annotations

import pytest

from climbd.daemon.runtime.loop import ControlLoop, MonotonicClock, SteppedClock


def test_stepped_clock_gives_the_exact_tick_sequence() -> None:
    clock = SteppedClock(start=10.0)
    ticks: list[tuple[float, float, float]] = []
    loop = ControlLoop(1000.0, clock, lambda t, dt: ticks.append((t, dt, clock.now())))
    loop.run(max_ticks=2500)
    assert len(ticks) == 2500
    assert [t for t, _, _ in ticks] == [10.0 + k * 0.001 for k in range(2500)]
    assert all(dt == 0.001 and now == t for t, dt, now in ticks)
    s = loop.stats()
    assert s.ticks == 2500 and s.overruns == 0 and s.lateness_max == 0.0


def test_idle_work_runs_before_each_deadline_and_the_tick_after() -> None:
    """``idle`` gets each tick's deadline before the tick runs (the joint bus takes its replies
    there), and the tick still runs at that deadline."""
    clock = SteppedClock()
    events: list[tuple[str, float]] = []
    loop = ControlLoop(
        100.0,
        clock,
        lambda t, dt: events.append(("tick", t)),
        idle=lambda deadline: events.append(("idle", deadline)),
    )
    loop.run(max_ticks=3)
    assert events == [(kind, k * 0.01) for k in range(3) for kind in ("idle", "tick")]


def test_late_ticks_do_not_shift_the_schedule() -> None:
    """A tick that costs 60 % of the period is followed by a tick on the original grid."""
    clock = SteppedClock()
    seen: list[float] = []

    def tick(t: float, dt: float) -> None:
        seen.append(t)
        clock.advance(0.6 * dt if len(seen) % 2 else 0.1 * dt)

    ControlLoop(100.0, clock, tick).run(max_ticks=100)
    assert seen == pytest.approx([k * 0.01 for k in range(100)], abs=1e-12)


def test_overrun_is_counted_and_the_schedule_skips_ahead() -> None:
    clock = SteppedClock()
    seen: list[float] = []

    def tick(t: float, dt: float) -> None:
        seen.append(t)
        if len(seen) == 5:
            clock.advance(3.5 * dt)  # a stall: three and a half periods

    loop = ControlLoop(100.0, clock, tick)
    loop.run(max_ticks=10)
    assert loop.stats().overruns == 1
    # ticks 0..4 on the grid, then the next due deadline after the stall (no burst of 3)
    assert seen[:5] == pytest.approx([0.0, 0.01, 0.02, 0.03, 0.04])
    assert seen[5] == pytest.approx(0.07)
    assert seen[6:] == pytest.approx([0.08, 0.09, 0.10, 0.11])


def test_a_loop_run_in_chunks_keeps_one_schedule() -> None:
    """A rig that runs the loop ten ticks at a time (the twin rigs between perception frames)
    gets the same deadlines as one call: each call carries on the schedule, not restarting it
    at the clock's present time (which ticked 10 times in 9 periods)."""
    clock = SteppedClock()
    seen: list[float] = []
    loop = ControlLoop(100.0, clock, lambda t, dt: seen.append(t))
    while loop.ticks < 50:
        loop.run(max_ticks=loop.ticks + 10)
    assert seen == pytest.approx([k * 0.01 for k in range(50)], abs=1e-12)
    assert clock.now() == pytest.approx(0.49)


def test_on_advance_steps_a_twin_in_lock_step() -> None:
    spans: list[tuple[float, float]] = []
    clock = SteppedClock(on_advance=lambda t0, t1: spans.append((t0, t1)))
    ControlLoop(50.0, clock, lambda t, dt: None).run(max_ticks=4)
    assert [x for span in spans for x in span] == pytest.approx([0.0, 0.02, 0.02, 0.04, 0.04, 0.06])


def test_monotonic_clock_sleeps_to_an_absolute_deadline() -> None:
    clock = MonotonicClock()
    deadline = clock.now() + 0.02
    clock.sleep_until(deadline)
    assert clock.now() >= deadline


def test_rate_must_be_positive() -> None:
    with pytest.raises(ValueError, match="control rate"):
        ControlLoop(0.0, SteppedClock(), lambda t, dt: None)
