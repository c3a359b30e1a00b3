"""Leg odometry for robots without foot force sensing: the body pose from the feet the gait
holds in stance (paper 004 eqs. 6-9, with the stance set taken from the gait, not forces).

A foot's global position is registered when it enters stance, from the pose the other stance
feet give at that instant; while three or more registered feet stay in stance, the pose is
their least-squares rigid fit (``daemon.estimation.stance_pose``). Pure: arrays in, BodyState out.
"""

from __future__ import annotations

import contextlib

import numpy as np

from daemon.estimation import EstimationError, quaternion, stance_pose
from daemon.kinematics import Kinematics
from daemon.messages import BodyState


class LegOdometry:
    """Dead reckoning of the body in the odometry frame (origin: the start pose)."""

    def __init__(self, kinematics: Kinematics) -> None:
        self.kinematics = kinematics
        n = len(kinematics.leg_names)
        self.rot = np.eye(3)
        self.origin = np.zeros(3)
        self.anchor = np.full((n, 3), np.nan)
        self._last: tuple[float, np.ndarray] | None = None

    def _fit(self, feet: np.ndarray, legs: np.ndarray) -> None:
        """Pose from the registered feet of ``legs`` (three or more), eqs. 7-9 in least squares."""
        if legs.sum() >= 3:
            # collinear stance feet: keep the last pose until they spread again
            with contextlib.suppress(EstimationError):
                self.rot, self.origin = stance_pose(feet[legs], self.anchor[legs])

    def update(self, q: np.ndarray, stance: np.ndarray, t: float) -> BodyState:
        """The body state at ``t`` from joint positions ``q`` and the gait's stance flags."""
        feet = self.kinematics.fk(q)
        stance = np.asarray(stance, bool)
        new = stance & np.isnan(self.anchor[:, 0])
        if new.any():
            # feet in stance until now are still on the ground this tick (a lifting foot has
            # not left it yet): they give the pose that registers the feet touching down
            self._fit(feet, ~np.isnan(self.anchor[:, 0]))
            self.anchor[new] = self.origin + feet[new] @ self.rot.T
        self.anchor[~stance] = np.nan
        self._fit(feet, stance)
        velocity = np.zeros(3)
        if self._last is not None and t > self._last[0]:
            velocity = (self.origin - self._last[1]) / (t - self._last[0])
        self._last = (t, self.origin.copy())
        return BodyState(
            stamp=t,
            position=self.origin.tolist(),
            orientation=[float(x) for x in quaternion(self.rot)],
            linear_velocity=velocity.tolist(),
            stance=stance.tolist(),
        )
