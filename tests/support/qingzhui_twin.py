"""Qingzhui in the twin through the real torque-leg driver: a rig shared by the paper-004 tests.

MIT motors emulated on python-can's virtual bus, coupled to MuJoCo in lock-step by a stepped
clock; the controller, its estimator and a gait run exactly as in the daemon.
"""

from __future__ import annotations

import itertools

import msgspec
import mujoco
import numpy as np
from conftest import ROOT

from climbd.daemon.algorithms.estimation import EstimatorConfig, StateEstimator
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import Heartbeat, Mode, MotionCommand
from climbd.daemon.runtime.loader import Isolated
from climbd.daemon.runtime.loop import SteppedClock
from climbd.daemon.runtime.stack import control_stack
from climbd.drivers.sim.mit_coupling import MitCoupling
from climbd.drivers.sim.mit_motors import MitMotorChain
from climbd.drivers.sim.twin import Twin
from climbd.drivers.torque.bus import MitJointBus
from climbd.drivers.torque.config import TorqueConfig

_channels = itertools.count()
SESSION = "qz-test"
_beats = itertools.count(1)
LOCKSTEP_REPLY_TIMEOUT = 1.0
"""Wall seconds the driver waits for replies: stepped time stands still while it waits, so a
loaded machine delays the run instead of turning late replies into lost motors."""


def heartbeat() -> Heartbeat:
    """The test session's next heartbeat: the robot refuses one whose seq or stamp repeats."""
    n = next(_beats)
    return Heartbeat(session=SESSION, seq=n, stamp=float(n))


class TwinImu:
    """The twin's IMU behind the driver-side ``Imu`` protocol."""

    def __init__(self, twin: Twin) -> None:
        self.twin = twin

    def read(self):
        return self.twin.imu_sample()


def estimator_config(twin: Twin, **overrides) -> EstimatorConfig:
    """Estimator calibration from the twin's build: foot radius and leg link masses."""
    model = twin.model
    leg = twin.profile.legs[0]
    masses = [float(model.body_mass[model.body(j.name).id]) for j in leg.joints]
    return EstimatorConfig(foot_radius=twin.robot.foot_radius, link_masses=masses, **overrides)


def contact_forces(twin: Twin) -> np.ndarray:
    """Force (N, world frame) the world exerts on each foot, summed over its contacts."""
    d, m = twin.data, twin.model
    out = np.zeros((len(twin.robot.foot_geoms), 3))
    wrench = np.zeros(6)
    feet = {int(g): k for k, g in enumerate(twin.robot.foot_geoms)}
    for i in range(d.ncon):
        c = d.contact[i]
        for geom, sign in ((c.geom2, 1.0), (c.geom1, -1.0)):
            if int(geom) in feet:
                mujoco.mj_contactForce(m, d, i, wrench)
                out[feet[int(geom)]] += sign * (c.frame.reshape(3, 3).T @ wrench[:3])
    return out


def flat_world():
    """The stairs world without its flight: level ground for the flat-ground walks."""
    from climbd.drivers.sim.worlds import load as load_world

    world = load_world("stairs")
    world.stairs = []
    return world


class QingzhuiRig:
    """Twin + emulated MIT motors + MitJointBus + Controller on one stepped clock."""

    def __init__(
        self, world="stairs", gait=None, start_x: float = 0.0, feed_forward: bool = False
    ) -> None:
        from climbd.drivers.sim.worlds import load as load_world

        profile = profiles.load(ROOT / "robots" / "qingzhui.toml")
        self.profile = profiles.with_bus_options(profile, reply_timeout=LOCKSTEP_REPLY_TIMEOUT)
        w = load_world(world) if isinstance(world, str) else world
        w.start.x = start_x
        self.twin = Twin(self.profile, w, stepped=True)
        channel = f"qz-twin-{next(_channels)}"
        ids = [j.id for j in self.profile.joints]
        self.chain = MitMotorChain(
            ids, TorqueConfig.from_profile(self.profile).actuator, channel, external_model=True
        )
        self.chain.start()
        self.bus = MitJointBus(self.profile, [channel], interface="virtual")
        self.coupling = MitCoupling(self.twin, self.chain, lambda: self.bus.sent)
        self.bus.open()
        self.clock = SteppedClock(on_advance=self._advance)
        self.gait = gait
        isolated = Isolated(getattr(gait, "name", "gait"), gait) if gait is not None else None
        stack = control_stack(
            self.profile, self.bus, self.clock, isolated, feed_forward=feed_forward
        )
        self.safety, self.controller, self.loop = stack.safety, stack.controller, stack.loop
        self.hooks: list = []
        self.command: MotionCommand | None = None

    def _advance(self, t0: float, t1: float) -> None:
        self.coupling.advance(t0, t1)
        if self.command is not None and round(t1 * 1000) % 100 == 0:
            self.controller.on_heartbeat(heartbeat())
            self.controller.on_motion(self.command)
        for hook in self.hooks:
            hook(t1)

    def run(self, seconds: float) -> None:
        self.loop.run(max_ticks=self.loop.ticks + round(seconds * self.profile.rate_hz))

    def stand(self) -> None:
        assert self.safety.request(Mode.STAND, self.clock.now())
        self.run(2.5)
        assert self.safety.mode == Mode.HOLD, self.safety.reason

    def start_estimator(self, **overrides) -> StateEstimator:
        """Odometry frame = the twin's world; starts at the true pose (where the robot stands)."""
        pos, quat = self.twin.body_pose()
        est = StateEstimator(self.profile, estimator_config(self.twin, **overrides), pos, quat)
        self.controller.estimator = est
        self.controller.imu = TwinImu(self.twin)
        return est

    def activate(self, command: MotionCommand | None = None) -> None:
        now = self.clock.now()
        if command is not None:
            self.safety.claim(SESSION, "test", now)
            self.command = msgspec.structs.replace(command, session=SESSION)
            self.controller.on_heartbeat(heartbeat())
            self.controller.on_motion(self.command)
        assert self.safety.request(Mode.ACTIVE, now, SESSION if command else None)

    def close(self) -> None:
        self.bus.close()
        self.chain.stop()
