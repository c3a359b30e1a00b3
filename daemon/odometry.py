"""Leg odometry for robots without foot force sensing: the body pose from the feet the gait
holds in stance (paper 004 eqs. 6-9, with the stance set taken from the gait, not forces).

A foot's global position is registered when it is down, from the pose the other stance feet
give at that instant; while three or more registered feet stay in stance, the pose is their
least-squares rigid fit (``daemon.estimation.stance_pose``). The gait's stance flag says when a
foot should be down, not when it is: a lagging servo lands it tens of milliseconds later, and
registered in the air it drags the pose as it comes down (3 cm per step measured crossing a
joist through the driver). So while three or more other registered feet hold the pose, a foot
entering stance is registered only once it keeps still. Pure: arrays in, BodyState out.
"""

from __future__ import annotations

import numpy as np

from daemon.estimation import EstimationError, quaternion, stance_pose
from daemon.kinematics import Kinematics
from daemon.messages import BodyState

TOUCHDOWN_SPEED = 0.03
"""Speed (m/s, odometry frame) under which a foot in stance counts as resting on the ground."""
TOUCHDOWN_TIME = 0.02
"""Seconds a foot in stance must rest before it is registered (a lagging swing's turning point
is still for an instant only)."""
SETTLE_TIME = 0.3
"""Seconds after its stance began by which a foot is registered even if it never rested."""
SLIP_DISTANCE = 0.003
"""Disagreement (m) with the other stance feet over which a foot counts as slipped: above the
encoders' ~1 mm at the foot, below the 4 mm a step's slip puts in the twin."""


class LegOdometry:
    """Dead reckoning of the body in the odometry frame (origin: the start pose)."""

    def __init__(self, kinematics: Kinematics) -> None:
        self.kinematics = kinematics
        n = len(kinematics.leg_names)
        self.rot = np.eye(3)
        self.origin = np.zeros(3)
        self.anchor = np.full((n, 3), np.nan)
        self._seen = np.full((n, 3), np.nan)
        self._still_since = np.full(n, np.nan)
        self._stance_since = np.full(n, np.nan)
        self._stance = np.zeros(n, bool)
        self._last: tuple[float, np.ndarray] | None = None

    def _fit(self, feet: np.ndarray, legs: np.ndarray) -> None:
        """Pose from the registered feet of ``legs`` (three or more), eqs. 7-9 in least squares.

        Of four or more, a foot over ``SLIP_DISTANCE`` from where the others put it has slipped
        (or rocked off the ground): the pose is fitted without it and it is registered again
        where it is now.
        """
        legs = legs.copy()
        slipped = np.zeros_like(legs)
        while legs.sum() >= 3:
            try:
                self.rot, self.origin = stance_pose(feet[legs], self.anchor[legs])
            except EstimationError:
                break  # collinear stance feet: keep the last pose until they spread again
            off = np.where(legs, np.linalg.norm(self._global(feet) - self.anchor, axis=1), 0.0)
            worst = int(np.argmax(off))
            if legs.sum() == 3 or off[worst] <= SLIP_DISTANCE:
                break
            legs[worst] = False
            slipped[worst] = True
        self.anchor[slipped] = self._global(feet[slipped])

    def _global(self, feet: np.ndarray) -> np.ndarray:
        """Feet (body frame) in the odometry frame at the current pose."""
        return self.origin + feet @ self.rot.T

    def update(self, q: np.ndarray, stance: np.ndarray, t: float) -> BodyState:
        """The body state at ``t`` from joint positions ``q`` and the gait's stance flags."""
        feet = self.kinematics.fk(q)
        stance = np.asarray(stance, bool)
        self._stance_since[stance & ~self._stance] = t
        self._stance = stance.copy()
        registered = ~np.isnan(self.anchor[:, 0])
        new = stance & ~registered
        if new.any() and (registered & stance).sum() < 3:
            # a change of tripod: the feet lifting this tick are still on the ground and give
            # the only pose there is to register the landing ones with
            self._fit(feet, registered)
            self.anchor[new] = self._global(feet[new])
        self.anchor[~stance] = np.nan
        registered = ~np.isnan(self.anchor[:, 0])
        self._fit(feet, registered)
        seen = self._global(feet)
        dt = t - self._last[0] if self._last is not None else 0.0
        still = np.zeros_like(stance)
        if dt > 0.0:
            still = stance & (np.linalg.norm(seen - self._seen, axis=1) / dt < TOUCHDOWN_SPEED)
        self._still_since[~still] = np.nan
        self._still_since[still & np.isnan(self._still_since)] = t
        landed = (stance & ~registered) & (
            (t - self._still_since >= TOUCHDOWN_TIME) | (t - self._stance_since >= SETTLE_TIME)
        )
        if landed.any():
            self.anchor[landed] = seen[landed]
            self._fit(feet, registered | landed)
            seen = self._global(feet)
        self._seen = seen
        velocity = (self.origin - self._last[1]) / dt if dt > 0.0 else np.zeros(3)
        self._last = (t, self.origin.copy())
        return BodyState(
            stamp=t,
            position=self.origin.tolist(),
            orientation=[float(x) for x in quaternion(self.rot)],
            linear_velocity=velocity.tolist(),
            stance=stance.tolist(),
        )
