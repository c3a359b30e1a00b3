"""Couples emulated MIT-mode motors on a CAN bus to the physics twin, in lock-step.

The driver (drivers/torque/bus.py) talks CAN to ``MitMotorChain`` exactly as to real
actuators; this coupling hands each motor's last command (position, velocity, kp, kd,
feed-forward torque; zero gains out of motor mode) to the twin's MIT law, steps physics, and
writes the joint state (position, velocity, torque as the joint's torque sensor reads it)
back into the motors, which the next replies carry. Each step first waits until the emulator
has taken every frame the driver sent, so a stepped run does not depend on thread timing:

    coupling = MitCoupling(twin, chain, frames_sent=lambda: driver.sent)
    clock = SteppedClock(on_advance=coupling.advance)
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from climbd.drivers.sim.mit_motors import MitMotorChain
from climbd.drivers.sim.twin import Twin

SETTLE_TIMEOUT = 5.0
"""Wall seconds the emulator thread has to take the driver's frames before a step fails."""


class MitCoupling:
    """Motor commands → twin joint torques; twin joint state → motor replies."""

    def __init__(self, twin: Twin, chain: MitMotorChain, frames_sent: Callable[[], int]) -> None:
        if not twin.robot.torque_legs:
            raise ValueError(f"twin of {twin.profile.name}: not a torque-controlled robot")
        self.twin = twin
        self.chain = chain
        self.ids = [j.id for j in twin.profile.joints]
        missing = [i for i in self.ids if i not in chain.motors]
        if missing:
            raise ValueError(f"MIT chain on {chain.channel!r} lacks motors {missing}")
        self.motors = [chain.motors[i] for i in self.ids]
        self.frames_sent = frames_sent
        self.publish()

    def _settle(self) -> None:
        """Wait until the emulator took every frame the driver sent, so commands are current."""
        want = self.frames_sent()
        deadline = time.monotonic() + SETTLE_TIMEOUT
        while sum(m.frames for m in self.motors) < want:
            if time.monotonic() > deadline:
                raise RuntimeError(
                    f"MIT emulator on {self.chain.channel!r} took "
                    f"{sum(m.frames for m in self.motors)} of {want} frames in {SETTLE_TIMEOUT} s"
                )
            time.sleep(0)

    def apply(self) -> None:
        """Copy every motor's last command into the twin's MIT law (zero gains when idle)."""
        n = len(self.motors)
        goal, rate, kp, kd, ff = (np.zeros(n) for _ in range(5))
        on = np.zeros(n, bool)
        for k, m in enumerate(self.motors):
            c = m.command
            if m.motor_mode and c is not None:
                goal[k], rate[k], kp[k], kd[k], ff[k] = (
                    c.position,
                    c.velocity,
                    c.kp,
                    c.kd,
                    c.torque,
                )
                on[k] = True
            else:
                goal[k] = m.position
        twin = self.twin
        with twin.lock:
            twin.goal[:], twin.mit_rate[:], twin.mit_kp[:] = goal, rate, kp
            twin.mit_kd[:], twin.mit_ff[:], twin.torque_on[:] = kd, ff, on

    def publish(self) -> None:
        """Write the twin's joint positions, velocities and torques into the motors."""
        q = self.twin.joint_positions()
        qd = self.twin.joint_velocities()
        tau = self.twin.joint_efforts()
        for k, motor in enumerate(self.ids):
            self.chain.set_state(motor, float(q[k]), float(qd[k]), float(tau[k]))

    def advance(self, t0: float, t1: float) -> None:
        """SteppedClock hook: apply the last commands, step physics from ``t0`` to ``t1``."""
        self._settle()
        self.apply()
        self.twin.advance_to(t0, t1)
        self.publish()
