"""Nothing blocks the tick: a behaviour's plan runs on its worker while the control loop goes on
at its rate on wall time, so an e-stop or a lost heartbeat acts while a plan is being made."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from support.joist_scenes import JoistSpec
from support.joist_world import body_state, oracle_map

from climbd.daemon.algorithms.feature_maps import JoistTracks
from climbd.daemon.algorithms.planning import PlanWorker
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import (
    EStop,
    FootTargets,
    Heartbeat,
    JoistMap,
    Mode,
    ModeRequest,
    SessionClaim,
)
from climbd.daemon.contract.plugins import GaitPlugin
from climbd.daemon.runtime.loop import MonotonicClock
from climbd.daemon.runtime.stack import control_stack
from climbd.drivers.fake import FakeJointBus
from climbd.plugins.gaits import joist_climb
from climbd.plugins.gaits.joist_climb import JoistClimb, JoistClimbConfig, Phase

PLAN_SECONDS = 2.0


class SlowPlanGait(GaitPlugin):
    """Asks for a plan that takes 2 s of wall time when it starts, and holds its feet where
    they stand until the plan arrives (the convention of climbd.daemon.algorithms.planning)."""

    name = "slow_plan"

    def start(self, body, feet) -> None:
        self.feet = np.asarray(feet, float).copy()
        self.worker: PlanWorker[str] = PlanWorker("slow-plan", wait=self.stepped)
        self.started = threading.Event()
        self.worker.request(self._plan)
        self.plan: str | None = None

    def _plan(self) -> str:
        self.started.set()
        time.sleep(PLAN_SECONDS)
        return "ready"

    def stop(self) -> None:
        if hasattr(self, "worker"):
            self.worker.close()

    def step(self, t, dt, body, world, command) -> FootTargets:
        outcome = self.worker.take()
        if outcome is not None:
            self.plan = outcome.plan
        n = len(self.feet)
        return FootTargets(stamp=t, positions=self.feet.tolist(), stance=[True] * n)


class WallRig:
    """A controller on the fake bus, its loop on wall time in a thread of its own."""

    def __init__(self, profile: profiles.Profile) -> None:
        self.profile = profile
        self.clock = MonotonicClock()
        self.bus = FakeJointBus(profile, tau=0.005, clock=self.clock.now)
        self.bus.open()
        self.gait = SlowPlanGait(profile=profile)
        stack = control_stack(profile, self.bus, self.clock, self.gait)
        self.safety, self.controller, self.loop = stack.safety, stack.controller, stack.loop
        self.torque_off_tick: int | None = None
        torque = self.bus.torque

        def record(on: bool) -> None:
            if not on and self.torque_off_tick is None:
                self.torque_off_tick = self.loop.ticks
            torque(on)

        self.bus.torque = record
        self.thread = threading.Thread(target=self.loop.run, daemon=True)

    def __enter__(self) -> WallRig:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.loop.stop()
        self.thread.join(5.0)
        self.gait.stop()

    def wait_for(self, predicate, timeout: float) -> None:
        end = time.monotonic() + timeout
        while not predicate():
            assert time.monotonic() < end, f"timed out; mode {self.safety.mode.value}"
            time.sleep(0.005)

    def activate_during_plan(self) -> int:
        """Stand, go ACTIVE (the gait starts its 2 s plan); the tick count once it plans."""
        assert self.safety.request(Mode.STAND, self.clock.now())
        self.wait_for(lambda: self.safety.reason == "stand complete", 30.0)
        assert self.safety.request(Mode.ACTIVE, self.clock.now(), reason="autonomy")
        self.wait_for(lambda: hasattr(self.gait, "started") and self.gait.started.is_set(), 10.0)
        return self.loop.ticks


@pytest.fixture()
def widowx(robots):
    return profiles.load(robots / "widowx.toml")


def test_an_estop_during_a_two_second_plan_acts_within_one_tick(widowx) -> None:
    """WidowX's e-stop policy is torque off: engaged half a second into the plan, the next
    tick switches torque off, and the loop kept ticking while the plan was being made."""
    with WallRig(widowx) as rig:
        planning_from = rig.activate_during_plan()
        time.sleep(0.5)
        ticked = rig.loop.ticks - planning_from
        at = rig.loop.ticks
        rig.controller.on_estop(EStop(engage=True, source="test", reason="mid-plan"))
        rig.wait_for(lambda: rig.torque_off_tick is not None, 1.0)
        assert rig.gait.plan is None, "the plan was already there: nothing was tested"
    assert ticked >= 0.5 * 0.5 * widowx.rate_hz, f"only {ticked} ticks in 0.5 s of planning"
    assert rig.safety.mode == Mode.ESTOP
    assert rig.torque_off_tick - at <= 1, (at, rig.torque_off_tick)


def test_a_lost_heartbeat_during_a_two_second_plan_holds_within_its_window(widowx) -> None:
    """The operator's session goes silent while the plan is being made: HOLD follows within
    the profile's heartbeat window (plus a tick), not when the plan is done."""
    with WallRig(widowx) as rig:
        c = rig.controller
        c.on_claim(SessionClaim(session="s1", client="alice"))
        seq = iter(range(1, 1_000_000))

        def beat() -> None:
            c.on_heartbeat(Heartbeat(session="s1", seq=next(seq), stamp=rig.clock.now()))

        beat()
        assert rig.safety.request(Mode.STAND, rig.clock.now())
        rig.wait_for(lambda: beat() or rig.safety.reason == "stand complete", 30.0)
        beat()
        c.on_mode(ModeRequest(session="s1", mode=Mode.ACTIVE))
        rig.wait_for(lambda: hasattr(rig.gait, "started") and rig.gait.started.is_set(), 10.0)
        beat()
        last = rig.clock.now()
        rig.wait_for(lambda: rig.safety.mode == Mode.HOLD, PLAN_SECONDS)
        assert rig.gait.plan is None, "the plan was already there: nothing was tested"
    entered = rig.safety.history[-1].at
    window = widowx.safety.heartbeat_window
    assert entered - last <= window + 2.0 / widowx.rate_hz, (entered - last, window)


class GatedPlans:
    """JoistClimb's crossing planner held at a gate until the test opens it; the near face of
    the first joist of each plan asked for, in ``faces``."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.gate = threading.Event()
        self.faces: list[float] = []
        self.real = joist_climb.CrossingPlan
        monkeypatch.setattr(joist_climb, "CrossingPlan", self.plan)

    def plan(self, geometry, *args):
        self.faces.append(geometry.bars[0].face)
        self.gate.wait(10.0)
        return self.real(geometry, *args)

    def open(self, b: JoistClimb) -> None:
        """Let the plans finish, and wait until the one under way is done."""
        self.gate.set()
        end = time.monotonic() + 10.0
        while b.planner.pending and not b.planner.ready and time.monotonic() < end:
            time.sleep(0.01)


def wall_clock_joist_climb(profile: profiles.Profile) -> JoistClimb:
    """JoistClimb on wall time (not stepped: its plans are not waited for), started."""
    b = JoistClimb(JoistClimbConfig(goal_distance=1.1), profile)
    b.start(body_state(b.pose), b.kin.stand_feet())
    return b


def test_joist_climb_holds_still_while_its_crossing_is_planned(widowx, monkeypatch) -> None:
    """On wall time (not stepped) JoistClimb asks for its crossing plan and goes on: the tick
    that asks returns at once in PLAN, its feet stay where they stood until the plan comes,
    and then it crosses on it."""
    plans = GatedPlans(monkeypatch)
    b = wall_clock_joist_climb(widowx)
    joists = [JoistSpec(0.7, 0.0, 0.06)]
    tracks = JoistTracks()
    dt, held, planned_feet = 0.01, 0, None
    try:
        for k in range(int(120 / dt)):
            t = k * dt
            world = {JoistMap.TOPIC: oracle_map(tracks, joists, b.pose, t)}
            feet = np.array(b.step(t, dt, body_state(b.pose, t), world, None).positions)
            if b.mode == Phase.PLAN:
                planned_feet = feet if planned_feet is None else planned_feet
                assert np.allclose(feet, planned_feet, atol=1e-5), "moved while planning"
                held += 1
                if held == 50:
                    plans.open(b)  # the plan may finish now, 50 ticks on
            if b.mode == Phase.CROSS:
                break
    finally:
        plans.gate.set()
        b.stop()
    assert held >= 50, f"held {held} ticks: the plan was not made off the tick"
    assert b.mode == Phase.CROSS and b.plan is not None


def test_a_crossing_plan_made_while_the_joist_moved_is_made_again(widowx, monkeypatch) -> None:
    """A stale plan is re-checked before it is used: the joist seen 3 cm further on while its
    crossing was being planned (a bump of the world) makes the behaviour plan again, and it
    crosses on the plan for where the joist now is."""
    plans = GatedPlans(monkeypatch)
    b = wall_clock_joist_climb(widowx)
    joists = [JoistSpec(0.7, 0.0, 0.06)]
    tracks = JoistTracks()
    dt, t, moved_at = 0.01, 0.0, None
    try:
        while t < 120.0 and b.mode != Phase.CROSS:
            world = {JoistMap.TOPIC: oracle_map(tracks, joists, b.pose, t)}
            b.step(t, dt, body_state(b.pose, t), world, None)
            t += dt
            if b.mode == Phase.PLAN and moved_at is None:
                joists, moved_at = [JoistSpec(0.73, 0.0, 0.06)], t  # the world moves
            elif moved_at is not None and t - moved_at > 0.2 and not plans.gate.is_set():
                plans.open(b)  # the moved joist has been seen: let the first plan finish
    finally:
        plans.gate.set()
        b.stop()
    assert any("the joist moved" in what for _, what in b.events), b.events
    faces = plans.faces
    assert len(faces) == 2 and faces[1] - faces[0] == pytest.approx(0.03, abs=0.01), faces
    assert b.mode == Phase.CROSS
