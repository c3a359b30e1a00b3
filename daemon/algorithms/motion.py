"""What runs every STAND/ACTIVE/HOLD tick after the behaviour: IK -> ruckig -> feed-forward
-> guard, in that order: the guard is the last thing that touches a command.

``feet_step`` takes a gait's FootTargets, solves IK, feeds ruckig the target joint state
(position, and the velocity and acceleration of the target stream by finite differences so
a moving target is tracked rather than chased), adds the controller's feed-forward, and has the
guard clamp position, velocity and effort into the profile's limits.
A leg whose target is unreachable keeps its last reachable target and is reported in
``unreachable``; it is never bent into another pose.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from climbd.daemon.algorithms.guard import Guard, GuardError
from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.algorithms.smoothing import Smoother, SmoothingError
from climbd.daemon.contract.messages import FootTargets, JointCommand
from climbd.daemon.contract.profile import Profile


class MotionError(SmoothingError):
    """A tick the pipeline cannot produce: foot targets that do not fit the profile, or a
    command the guard refuses. A SmoothingError, so a controller holds on any of them."""


FeedForward = Callable[[JointCommand], None]
"""Adds feed-forward to a smoothed command in place (effort, or a compliant servo's sag)."""


class MotionPipeline:
    """IK, ruckig smoothing, feed-forward and the limit guard for one robot at period ``dt``.

    The tick works on plain lists (scalar IK, list-based smoother and guard): for one
    robot's 12-18 joints that is cheaper than numpy's per-call overhead.
    """

    def __init__(
        self, profile: Profile, dt: float, feed_forward: FeedForward | None = None
    ) -> None:
        self.profile = profile
        self.dt = dt
        self.feed_forward = feed_forward
        self.kinematics = Kinematics(profile)
        self.smoother = Smoother(profile, dt)
        self.guard = Guard(profile)
        n_legs, n = self.kinematics.n_legs, self.kinematics.n_joints
        self.unreachable = [False] * n_legs
        self.unreachable_ticks = 0
        self._command = [0.0] * n
        self._target = [0.0] * n
        self._target_qd = [0.0] * n
        self._streaming = False
        self.grip: list[bool] | None = None
        """The grippers' state every command carries: the gait's last ``grip``, kept while no
        gait steps (a HOLD or e-stop never opens a gripper)."""

    @property
    def command(self) -> np.ndarray:
        """The last smoothed joint positions (the trajectory, before feed-forward and the
        guard), profile order."""
        return np.array(self._command)

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
        self._target = self.smoother.position.tolist()
        self._target_qd = [0.0] * len(self._target)
        self._streaming = False
        self._command = list(self._target)
        self.unreachable = [False] * self.kinematics.n_legs

    def feet_step(self, targets: FootTargets) -> JointCommand:
        """One tick towards body-frame foot targets: IK -> ruckig -> feed-forward -> guard."""
        kin = self.kinematics
        feet = targets.positions
        try:
            valid = (
                len(feet) == kin.n_legs
                and all(len(foot) == 3 for foot in feet)
                and math.isfinite(sum(map(sum, feet)))
            )
        except TypeError:
            valid = False
        if not valid:
            raise MotionError(
                f"foot targets: expected {kin.n_legs} finite (x, y, z) positions, got {feet!r:.120}"
            )
        for name in ("stance", "unload", "grip"):
            flags = getattr(targets, name)
            if flags is not None and len(flags) != kin.n_legs:
                raise MotionError(
                    f"foot targets: {name} has {len(flags)} flags, expected {kin.n_legs}"
                )
        q, ok = kin.ik_feet(feet)
        self.unreachable = [not good for good in ok]
        if not all(ok):
            self.unreachable_ticks += 1
            for leg, good in enumerate(ok):
                if not good:
                    q[3 * leg : 3 * leg + 3] = self._target[3 * leg : 3 * leg + 3]
        dt = self.dt
        qd = [(a - b) / dt for a, b in zip(q, self._target, strict=True)]
        qdd = None
        if self._streaming:
            qdd = [(a - b) / dt for a, b in zip(qd, self._target_qd, strict=True)]
        self._target, self._target_qd, self._streaming = q, qd, True
        if targets.grip is not None:
            self.grip = list(targets.grip)
        return self._finish(*self.smoother.advance(q, qd, qdd))

    def joint_step(self, target_q: np.ndarray, duration: float | None = None) -> JointCommand:
        """One tick towards a joint target at rest (STAND to ``stand_joints()``, HOLD); with
        ``duration`` (s) the joints arrive together that long after they set off."""
        target = np.asarray(target_q, float).reshape(-1).tolist()
        self._target = target
        self._target_qd = [0.0] * len(target)
        self._streaming = False
        self.unreachable = [False] * self.kinematics.n_legs
        return self._finish(*self.smoother.advance(target, duration=duration))

    def _finish(self, q: list[float], qd: list[float]) -> JointCommand:
        """Feed-forward, then the guard: position, velocity and effort inside the limits."""
        command = JointCommand(position=q, velocity=qd, grip=self.grip)
        self._command = q
        if self.feed_forward is not None:
            self.feed_forward(command)
        try:
            command = self.guard.command(command)
        except GuardError as e:
            raise MotionError(f"guard: {e}") from None
        return command
