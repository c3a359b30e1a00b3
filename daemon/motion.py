"""What runs every STAND/ACTIVE/HOLD tick after the behaviour: IK -> ruckig -> guard.

``feet_step`` takes a gait's FootTargets, solves IK, feeds ruckig the target joint state
(position, and the velocity and acceleration of the target stream by finite differences so
a moving target is tracked rather than chased), and clamps the result to the position limits.
A leg whose target is unreachable keeps its last reachable target and is reported in
``unreachable``; it is never bent into another pose.
"""

from __future__ import annotations

import numpy as np

from daemon.guard import Guard, GuardError
from daemon.kinematics import Kinematics
from daemon.messages import FootTargets, JointCommand
from daemon.profile import Profile
from daemon.smoothing import Smoother, SmoothingError


class MotionError(SmoothingError):
    """A tick the pipeline cannot produce: foot targets that do not fit the profile, or a
    command the guard refuses. A SmoothingError, so a controller holds on any of them."""


class MotionPipeline:
    """IK, ruckig smoothing and the limit guard for one robot at control period ``dt``."""

    def __init__(self, profile: Profile, dt: float) -> None:
        self.profile = profile
        self.dt = dt
        self.kinematics = Kinematics(profile)
        self.smoother = Smoother(profile, dt)
        self.guard = Guard(profile)
        n_legs, n = self.kinematics.n_legs, self.kinematics.n_joints
        self.unreachable = np.zeros(n_legs, bool)
        self.unreachable_ticks = 0
        self.clamped = np.zeros(n, bool)
        self.command = np.zeros(n)
        self._target = np.zeros(n)
        self._target_qd = np.zeros(n)
        self._streaming = False

    @property
    def unreachable_legs(self) -> list[str]:
        """Names of the legs whose last foot target was unreachable (for health)."""
        names = self.kinematics.leg_names
        return [n for n, bad in zip(names, self.unreachable, strict=True) if bad]

    def set_speed_scale(self, scale: float) -> None:
        """Derate the velocity limits to ``scale`` (0, 1] of the profile's (servo overheat)."""
        if scale != self.smoother.scale:
            self.smoother.scale = scale

    def start(self, measured_q: np.ndarray, measured_qd: np.ndarray | None = None) -> None:
        """Begin from the measured joint state: the first command equals it (no jump)."""
        self.smoother.reset(measured_q, measured_qd)
        self._target = self.smoother.position.copy()
        self._target_qd = np.zeros_like(self._target)
        self._streaming = False
        self.command = self._target.copy()
        self.unreachable[:] = False
        self.clamped[:] = False

    def feet_step(self, targets: FootTargets) -> JointCommand:
        """One tick towards body-frame foot targets: IK -> ruckig -> guard."""
        kin = self.kinematics
        feet = np.asarray(targets.positions, float)
        if feet.shape != (kin.n_legs, 3) or not np.isfinite(feet).all():
            raise MotionError(
                f"foot targets: expected {kin.n_legs} finite (x, y, z) positions, got "
                f"{feet.shape if feet.ndim else 'none'}"
            )
        q, ok = kin.ik(feet)
        self.unreachable = ~ok
        if not ok.all():
            self.unreachable_ticks += 1
            keep = np.repeat(~ok, 3)
            q[keep] = self._target[keep]
        qd = (q - self._target) / self.dt
        qdd = (qd - self._target_qd) / self.dt if self._streaming else None
        self._target, self._target_qd, self._streaming = q, qd, True
        return self._finish(self.smoother.step(q, qd, qdd))

    def joint_step(self, target_q: np.ndarray) -> JointCommand:
        """One tick towards a joint target at rest (STAND to ``stand_joints()``, HOLD)."""
        target = np.asarray(target_q, float)
        self._target = target.copy()
        self._target_qd = np.zeros_like(target)
        self._streaming = False
        self.unreachable[:] = False
        return self._finish(self.smoother.step(target))

    def _finish(self, q: np.ndarray) -> JointCommand:
        try:
            self.command, self.clamped = self.guard.clamp(q)
        except GuardError as e:
            raise MotionError(f"guard: {e}") from None
        return JointCommand(
            position=self.command.tolist(), velocity=self.smoother.velocity.tolist()
        )
