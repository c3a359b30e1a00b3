"""The control stack, assembled in one place: safety, controller and loop over one joint bus.

``climbd run``, the tests and the benches all build it here, so what runs on the robot is what
they exercise: the gait isolated (a failure holds), its ``stepped`` flag from the clock (a
stepped clock is simulated time: plans are waited for; on wall time nothing blocks a tick), the
driver's between-ticks hook on wall time, the loop's statistics in health.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from climbd.daemon.algorithms.estimation import StateEstimator
from climbd.daemon.contract.hardware import Imu, JointBus, ServedBetweenTicks
from climbd.daemon.contract.messages import Message, Mode
from climbd.daemon.contract.plugins import GaitPlugin
from climbd.daemon.contract.profile import Profile
from climbd.daemon.runtime.control import Controller
from climbd.daemon.runtime.loader import Isolated
from climbd.daemon.runtime.loop import Clock, ControlLoop, MonotonicClock, SteppedClock
from climbd.daemon.runtime.safety import Safety


@dataclass
class ControlStack:
    """One robot's control stack on one clock."""

    profile: Profile
    bus: JointBus
    clock: Clock
    safety: Safety
    controller: Controller
    loop: ControlLoop

    def run(self, seconds: float) -> None:
        """Run the loop for ``seconds`` of its clock's time (in the calling thread)."""
        self.loop.run(max_ticks=self.loop.ticks + round(seconds * self.profile.rate_hz))

    def stand(self) -> bool:
        """Request STAND and run until the rise completes (HOLD), at most three stand times;
        whether it did."""
        if not self.safety.request(Mode.STAND, self.clock.now(), reason="start-up"):
            return False
        end = self.clock.now() + 3 * self.profile.safety.stand_time
        while self.safety.mode == Mode.STAND and self.clock.now() < end:
            self.run(0.1)
        return self.safety.mode == Mode.HOLD and self.safety.reason == "stand complete"


def control_stack(
    profile: Profile,
    bus: JointBus,
    clock: Clock,
    gait: GaitPlugin | Isolated[GaitPlugin] | None = None,
    *,
    publish: Callable[[Message], None] | None = None,
    estimator: StateEstimator | None = None,
    imu: Imu | None = None,
    feed_forward: bool = False,
    tick: Callable[[float, float], None] | None = None,
) -> ControlStack:
    """The stack for ``profile`` over an open ``bus``: a bare ``gait`` is isolated (its failure
    holds the robot); ``tick`` wraps the controller's tick where a harness needs to."""
    safety = Safety(profile)
    if isinstance(gait, GaitPlugin):
        name = gait.name or type(gait).__name__

        def failed(plugin: str, error: BaseException) -> None:
            safety.hold(clock.now(), f"gait {plugin} failed")

        gait = Isolated(name, gait, failed)
    if gait is not None:
        gait.plugin.stepped = isinstance(clock, SteppedClock)
    controller = Controller(
        profile,
        bus,
        safety,
        clock.now,
        gait,
        publish,
        estimator=estimator,
        imu=imu,
        feed_forward=feed_forward,
    )
    # Between ticks on wall time the joint bus takes its replies (a stepped clock has none).
    serves = isinstance(bus, ServedBetweenTicks) and isinstance(clock, MonotonicClock)
    idle = bus.serve_until if serves else None
    loop = ControlLoop(profile.rate_hz, clock, tick or controller.tick, idle)
    controller.loop_stats = loop.stats
    return ControlStack(profile, bus, clock, safety, controller, loop)
