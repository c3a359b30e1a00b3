"""Control and perception as separate processes over real Zenoh on loopback; stale features hold.

The supervisor (``climbd run --role all``) runs the roles as children; the observer is a third
Zenoh session in the test. Assertions use the daemon's own Health/ModeState stamps.
"""

from __future__ import annotations

import math
import os
import signal
import time

import numpy as np
from conftest import free_port
from support.zenoh_roles import Observer, Proc

from climbd.daemon.cli.status import fleet
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import EStop, FootTargets, Health, Joists, Mode, ModeState
from climbd.daemon.contract.plugins import GaitPlugin
from climbd.daemon.runtime.loader import Isolated
from climbd.daemon.runtime.loop import SteppedClock
from climbd.daemon.runtime.stack import control_stack
from climbd.drivers.fake import FakeJointBus

GRID = "features/grid"


def control_health(obs: Observer, pred, timeout: float = 30.0) -> Health:
    """The first control-role Health satisfying ``pred``."""
    return obs.wait(Health, lambda h: h.role == "control" and pred(h), timeout)


def test_perception_crash_leaves_control_safe_and_is_restarted(endpoint: str, robots) -> None:
    max_age = profiles.load(robots / "widowx.toml").safety.feature_max_age
    sup = Proc(
        "run", "--profile", "robots/widowx.toml", "--driver", "fake", "--role", "all",
        "--listen", endpoint, "--source", "floor", "--plugin", "elevation", "--quiet",
    )  # fmt: skip
    obs = Observer("widowx", [endpoint])
    try:
        first = int(sup.wait_for(r"started perception role \(pid (\d+)\)")[0].group(1))
        obs.wait(ModeState, lambda m: m.mode == Mode.HOLD, 60)
        fresh = control_health(obs, lambda h: h.features.get(GRID, math.inf) <= max_age, 60)

        os.kill(first, signal.SIGSTOP)  # perception hangs: its features stop coming
        stale = control_health(
            obs, lambda h: h.stamp > fresh.stamp and h.features.get(GRID, 0.0) > max_age
        )
        assert stale.mode == Mode.HOLD, "the robot keeps holding while perception is away"
        assert stale.loop.ticks > fresh.loop.ticks, "the control loop kept running"
        os.kill(first, signal.SIGKILL)  # ... then crashes

        restarted = sup.wait_for(r"started perception role \(pid (\d+)\)", count=2)
        assert int(restarted[1].group(1)) != first
        control_health(
            obs, lambda h: h.stamp > stale.stamp and h.features.get(GRID, math.inf) <= max_age
        )
        assert len(sup.wait_for(r"started control role")) == 1, "control was never restarted"
        assert "perception role exited with signal 9" in sup.text
        assert sup.stop() == 0
    finally:
        obs.close()
        sup.kill()


class NeedsJoists(GaitPlugin):
    """Keeps its feet still, but only with joists in view (``needs``)."""

    needs = ("features/joists",)

    def start(self, body, feet):
        self.feet = np.array(feet)

    def step(self, t, dt, body, world, command):
        assert "features/joists" in world
        return FootTargets(stamp=t, positions=self.feet.tolist(), stance=[True] * len(self.feet))


def test_behaviour_needing_stale_features_holds(robots) -> None:
    profile = profiles.load(robots / "widowx.toml")
    clock = SteppedClock()
    bus = FakeJointBus(profile, tau=0.01, clock=clock.now)
    bus.open()
    gait = Isolated("needs-joists", NeedsJoists(profile=profile), lambda n, e: None)
    stack = control_stack(profile, bus, clock, gait)
    safety, controller, loop = stack.safety, stack.controller, stack.loop

    def run(seconds: float) -> None:
        loop.run(max_ticks=loop.ticks + round(seconds * profile.rate_hz))

    safety.request(Mode.STAND, clock.now())
    run(profile.safety.stand_time * 3)
    controller.on_feature(Joists(stamp=clock.now()))
    assert safety.request(Mode.ACTIVE, clock.now())
    run(0.5 * profile.safety.feature_max_age)
    assert safety.mode == Mode.ACTIVE and gait.status == "ok"
    arrived = controller.features["features/joists"].at
    run(profile.safety.feature_max_age)
    assert safety.mode == Mode.HOLD and "features/joists: stale" in safety.reason
    held_at = safety.history[-1].at
    limit = profile.safety.feature_max_age
    assert limit < held_at - arrived <= limit + 1.0 / profile.rate_hz + 1e-9


def test_two_robots_on_one_network_do_not_hear_each_other(tmp_path, robots) -> None:
    other = tmp_path / "widowx2.toml"
    other.write_text(f'include = "{robots / "widowx.toml"}"\nname = "widowx2"\n')
    a_ep, b_ep = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    a = Proc("run", "--profile", "robots/widowx.toml", "--driver", "fake", "--quiet",
             "--listen", a_ep)  # fmt: skip
    b = Proc("run", "--profile", str(other), "--driver", "fake", "--quiet",
             "--listen", b_ep, "--connect", a_ep)  # fmt: skip
    obs_a, obs_b = Observer("widowx", [a_ep]), Observer("widowx2", [a_ep, b_ep])
    try:
        for obs in (obs_a, obs_b):
            obs.wait(ModeState, lambda m: m.mode == Mode.HOLD, 60)
        estop = obs_b.bus.publisher(EStop)  # reaches both robots' processes
        for _ in range(10):
            estop.put(EStop(engage=True, source="test"))
            time.sleep(0.1)
        obs_b.wait(ModeState, lambda m: m.mode == Mode.ESTOP)
        after = obs_b.wait(ModeState, lambda m: m.mode == Mode.ESTOP).stamp
        a_now = control_health(obs_a, lambda h: h.stamp > after + 0.5)
        assert a_now.mode == Mode.HOLD, "widowx must not act on widowx2's e-stop"
        assert [m.mode for m in obs_a.messages(ModeState)].count(Mode.ESTOP) == 0

        robots_seen = fleet(obs_a.bus, timeout=2.0)
        assert {"widowx", "widowx2"} <= set(robots_seen)
        assert robots_seen["widowx"]["roles"] == ["control"]
        assert robots_seen["widowx2"]["mode"].mode == Mode.ESTOP
        listing = Proc("status", "--all", "--connect", a_ep)
        assert listing.proc.wait(30) == 0
        listing.wait_for(r"^widowx2\s+roles control\s+ESTOP")
        listing.wait_for(r"^widowx\s+roles control\s+HOLD")
        assert a.stop() == 0 and b.stop() == 0
    finally:
        obs_a.close()
        obs_b.close()
        a.kill()
        b.kill()
