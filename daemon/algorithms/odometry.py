"""Leg odometry for robots without foot force sensing: the body pose from the feet the gait
holds in stance (paper 004 eqs. 6-9, with the stance set taken from the gait, not forces).

A foot's global position is registered when it is down, from the pose the other stance feet
give at that instant; while three or more registered feet stay in stance, the pose is their
least-squares rigid fit (``climbd.daemon.algorithms.estimation.stance_pose``). The gait's stance
flag says when a foot should be down, not when it is: a lagging servo lands it tens of milliseconds
later, and registered in the air it drags the pose as it comes down (3 cm per step measured
crossing a joist through the driver). So while three or more other registered feet hold the pose, a
foot entering stance is registered only once it keeps still.

With an IMU (optional), the rotation is the gyro's integral, its tilt pulled toward the
accelerometer's gravity direction while the body is still and its heading pulled slowly toward
the stance feet's: a complementary filter, so feet that slip or land late no longer turn the
estimate (1-2 deg over a joist crossing without it) and the position is fitted on that rotation.
Pure: arrays in, BodyState out.
"""

from __future__ import annotations

import math

import numpy as np

from climbd.daemon.algorithms.estimation import (
    EstimationError,
    Rows,
    exp_so3,
    foot_link_rotations,
    log_so3,
    quaternion,
    roll_feet,
    stance_pose,
)
from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.messages import BodyState
from climbd.daemon.contract.profile import Profile, has_grippers

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
SLIP_FEET = 5
"""Feet down from which a slip is judged: of four, the three left fit exactly, so nothing checks
the choice, and two feet sliding together put the largest residual on a third that held (HubRobo's
crawl under G/6, five 3 m walks of gait variants: worst 2.7 % judged from five, 17.7-21.2 % from
four; bench/odometry.py --ablate, BENCHMARKS.md)."""
STILL_ACCEL = 0.02
"""A specific force within this fraction of gravity's counts as gravity alone (tilt observable).
The magnitude sees an acceleration across gravity only to second order, so the gate is tight
(HubRobo's 5 m crawl under G/6: 1.8 cm at 2 %; the WidowX's tripod 6.5 cm; BENCHMARKS.md)."""
GRAVITY_TIME = 5.0
"""Seconds of rest: time constant of the gravity magnitude learnt from the accelerometer (from its
first sample on): 9.81 m/s² on Earth, 1.62 on the Moon, where HubRobo is built to climb."""
TILT_TIME = 3.0
"""Seconds: time constant pulling the gyro's tilt toward the accelerometer's gravity, long enough
to average over several steps of a walk's sway (5 m walks, bench/odometry.py: the WidowX 8.0 cm
at 1 s, 6.5 cm at 3 s and 5 s). The accelerometer's first sample sets the tilt at once."""
HEADING_TIME = 300.0
"""Seconds: time constant τ pulling the gyro's heading toward the stance feet's. A leg drift of
rate r leaks in as r·(t - τ·(1 - exp(-t/τ))) (0.05°/s over 40 s: 0.13° of 2°); a gyro bias left
after ``BIAS_TIME`` holds an error bias·τ."""
BIAS_TIME = 30.0
"""Seconds of rest: time constant of the gyro bias estimate, learnt while all six feet rest. Slow,
because the body rocks on its feet as a leg lands (0.5 s learnt that as a bias: 0.5° of heading
over a 60° crossing through the driver, 0.16° at 30 s, replayed on the recording)."""
REST_HEADING_TIME = 1.0
"""Seconds: the heading's pull toward the stance feet's at rest, where no foot slips."""
STILL_RATE = 0.005
"""rad/s: the stance feet's rotation rate under which a body on all its feet is at rest."""
POSITION_DRIFT = 0.02
"""m per m walked (one standard deviation): the position error of leg odometry grows with the
path, not with time (bench/odometry.py: 1.2 % for the WidowX over 5 m)."""
HEADING_DRIFT = math.radians(0.4)
"""rad per m walked (one standard deviation) of heading: 2° over 5 m, the bound the odometry
bench holds the robots to (0.04-0.10° measured)."""
TILT_SIGMA = math.radians(1.0)
"""rad: roll and pitch (one standard deviation), pulled toward the accelerometer's gravity."""


class LegOdometry:
    """Dead reckoning of the body in the odometry frame (origin: the start pose)."""

    def __init__(
        self,
        kinematics: Kinematics,
        heading_time: float = HEADING_TIME,
        foot_radius: float = 0.0,
        slip_feet: int = SLIP_FEET,
    ) -> None:
        self.kinematics = kinematics
        self.heading_time = heading_time
        self.slip_feet = slip_feet
        """Feet down from which a slip is judged (``SLIP_FEET``)."""
        self.foot_radius = foot_radius
        """Radius (m) of the rounded feet: a registered stance foot's centre, which FK gives,
        moves as the foot rolls (0: point feet)."""
        self._links: list[Rows] | None = None
        self.attitude: np.ndarray | None = None
        """The IMU's rotation (body to odometry frame), once a gyro sample has come."""
        self.gyro_bias = np.zeros(3)
        self.gravity: float | None = None
        """The specific force's magnitude at rest (m/s²), learnt, once an accelerometer sample
        has come."""
        self._legs_rot: np.ndarray | None = None
        n = len(kinematics.leg_names)
        self.rot = np.eye(3)
        self.origin = np.zeros(3)
        self.walked = 0.0
        """Path length (m) of the body in the odometry frame since the start."""
        self.anchor = np.full((n, 3), np.nan)
        self._seen = np.full((n, 3), np.nan)
        self._still_since = np.full(n, np.nan)
        self._stance_since = np.full(n, np.nan)
        self._stance = np.zeros(n, bool)
        self._last: tuple[float, np.ndarray] | None = None

    def _fit(self, feet: np.ndarray, legs: np.ndarray) -> None:
        """Pose from the registered feet of ``legs`` (three or more), eqs. 7-9 in least squares.

        Of ``slip_feet`` or more, a foot over ``SLIP_DISTANCE`` from where the others put it has
        slipped (or rocked off the ground): the pose is fitted without it and it is registered
        again where it is now.
        """
        legs = legs.copy()
        slipped = np.zeros_like(legs)
        while legs.sum() >= 3:
            try:
                rot, origin = stance_pose(feet[legs], self.anchor[legs])
            except EstimationError:
                break  # collinear stance feet: keep the last pose until they spread again
            self._legs_rot = rot
            if self.attitude is not None:
                rot = self.attitude
                origin = (self.anchor[legs] - feet[legs] @ rot.T).mean(axis=0)
            self.rot, self.origin = rot, origin
            off = np.where(legs, np.linalg.norm(self._global(feet) - self.anchor, axis=1), 0.0)
            worst = int(np.argmax(off))
            if legs.sum() < self.slip_feet or off[worst] <= SLIP_DISTANCE:
                break
            legs[worst] = False
            slipped[worst] = True
        self.anchor[slipped] = self._global(feet[slipped])

    def _lift(self, feet: np.ndarray, lifting: np.ndarray) -> None:
        """Unregister the feet ``lifting`` off the ground. The feet that stay carry the pose on
        unbroken: their anchors move together by what the pose would jump as the fit loses the
        lifting ones (their residuals: the IMU's rotation turned since they were registered,
        the legs' kinematic error), so a map kept in the odometry frame stays under the feet
        (2.8 cm in height as HubRobo lifted its first limb on a 30° wall). A common shift leaves
        the stance feet's rotation, the heading's reference, as it was."""
        if not lifting.any():
            return
        staying = ~np.isnan(self.anchor[:, 0]) & ~lifting
        if staying.sum() < 3:
            self.anchor[lifting] = np.nan
            return
        self._fit(feet, staying | lifting)
        before = self.origin
        self.anchor[lifting] = np.nan
        self._fit(feet, staying)
        self.anchor[staying] += before - self.origin
        self.origin = before

    @classmethod
    def from_profile(cls, profile: Profile, kinematics: Kinematics | None = None) -> LegOdometry:
        """The odometry of ``profile``: its feet roll on ``foot_radius`` unless they are
        grippers. A gripper's spines do not roll, and HubRobo's feet under G/6 turn in place
        rather than roll (too light to turn against the servos): over 3 m with the crawl's
        sway at 0.4, 0.0 % as point feet against 1.8 % rolling, worst of five gait variants
        2.7 % against 3.4 %. The WidowX: 1.2 % rolling, 1.0 % as point feet over 5 m
        (bench/odometry.py --ablate)."""
        radius = 0.0 if has_grippers(profile) else profile.foot_radius or 0.0
        return cls(kinematics or Kinematics(profile), foot_radius=radius)

    def _roll(self, q: np.ndarray, stance: np.ndarray) -> None:
        """Move the anchors of the registered stance feet as their rounded feet roll (no slip:
        the centre moves by r·(dθ × up))."""
        links = foot_link_rotations(self.kinematics, np.asarray(q, float))
        if self._links is not None:
            legs = np.flatnonzero(stance & ~np.isnan(self.anchor[:, 0])).tolist()
            roll_feet(self.anchor, legs, self.rot, links, self._links, self.foot_radius)
        self._links = links

    def _global(self, feet: np.ndarray) -> np.ndarray:
        """Feet (body frame) in the odometry frame at the current pose."""
        return self.origin + feet @ self.rot.T

    def _turn(self, gyro: np.ndarray, accel: np.ndarray | None, dt: float) -> None:
        """Integrate the gyro (rad/s, body frame) over ``dt``; pull the tilt toward gravity when
        the specific force ``accel`` (m/s², body frame) is gravity's alone, the first sample all
        the way."""
        if self.attitude is None:
            self.attitude = self.rot.copy()
        self.attitude = self.attitude @ exp_so3((np.asarray(gyro, float) - self.gyro_bias) * dt)
        if accel is None:
            return
        accel = np.asarray(accel, float)
        norm = float(np.linalg.norm(accel))
        gain = min(1.0, dt / TILT_TIME)
        if self.gravity is None:
            self.gravity, gain = norm, 1.0
        if abs(norm - self.gravity) > STILL_ACCEL * self.gravity:
            return
        up = self.attitude[2]  # the odometry frame's z in the body frame (row 2 of R = R^T z)
        axis = np.cross(accel / norm, up)
        sine = float(np.linalg.norm(axis))
        if sine > 0.0:
            angle = math.atan2(sine, float(accel @ up) / norm)
            self.attitude = self.attitude @ exp_so3(axis * (angle / sine * gain))

    def _steer(
        self,
        gyro: np.ndarray,
        accel: np.ndarray | None,
        legs_rot: np.ndarray | None,
        rest: bool,
        dt: float,
    ) -> None:
        """Pull the IMU's heading toward the stance feet's by ``dt / heading_time``; at ``rest``
        (all feet down, the stance feet's rotation ``legs_rot`` before this update unchanged)
        learn the gyro's bias from ``gyro`` and gravity's magnitude from ``accel``, and pull by
        ``dt / REST_HEADING_TIME``."""
        if self._legs_rot is None:
            return
        tau = self.heading_time
        if rest and legs_rot is not None and dt > 0.0:
            rate = np.linalg.norm(log_so3(legs_rot.T @ self._legs_rot)) / dt
            if rate < STILL_RATE:
                self.gyro_bias += (np.asarray(gyro, float) - self.gyro_bias) * min(
                    1.0, dt / BIAS_TIME
                )
                if accel is not None and self.gravity is not None:
                    norm = float(np.linalg.norm(accel))
                    self.gravity += (norm - self.gravity) * min(1.0, dt / GRAVITY_TIME)
                tau = REST_HEADING_TIME
        turn = self._legs_rot @ self.attitude.T
        yaw = np.arctan2(turn[1, 0], turn[0, 0]) * min(1.0, dt / tau)
        self.attitude = exp_so3(np.array([0.0, 0.0, yaw])) @ self.attitude

    def variance(self) -> list[float]:
        """The pose's variances (x, y, z m²; roll, pitch, yaw rad²) after ``walked`` metres:
        position and heading drift per metre walked, the tilt held by gravity."""
        position = (POSITION_DRIFT * self.walked) ** 2
        heading = (HEADING_DRIFT * self.walked) ** 2
        return [position, position, position, TILT_SIGMA**2, TILT_SIGMA**2, heading]

    def update(
        self,
        q: np.ndarray,
        stance: np.ndarray,
        t: float,
        gyro: np.ndarray | None = None,
        accel: np.ndarray | None = None,
    ) -> BodyState:
        """The body state at ``t`` from joint positions ``q`` and the gait's stance flags, the
        rotation fused with the IMU's ``gyro`` (rad/s) and ``accel`` (m/s²) when given."""
        feet = self.kinematics.fk(q)
        stance = np.asarray(stance, bool)
        if self.foot_radius > 0.0:
            self._roll(q, stance)
        dt = t - self._last[0] if self._last is not None else 0.0
        if gyro is not None:
            self._turn(gyro, accel, dt)
        legs_rot = self._legs_rot
        self._stance_since[stance & ~self._stance] = t
        self._stance = stance.copy()
        registered = ~np.isnan(self.anchor[:, 0])
        new = stance & ~registered
        if new.any() and (registered & stance).sum() < 3:
            # a change of tripod: the feet lifting this tick are still on the ground and give
            # the only pose there is to register the landing ones with
            self._fit(feet, registered)
            self.anchor[new] = self._global(feet[new])
        self._lift(feet, registered & ~stance)
        registered = ~np.isnan(self.anchor[:, 0])
        self._fit(feet, registered)
        seen = self._global(feet)
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
        if gyro is not None:
            rest = bool(stance.all() and not np.isnan(self.anchor[:, 0]).any())
            self._steer(gyro, accel, legs_rot, rest, dt)
        self._seen = seen
        if self._last is not None:
            self.walked += float(np.linalg.norm(self.origin - self._last[1]))
        velocity = (self.origin - self._last[1]) / dt if dt > 0.0 else np.zeros(3)
        self._last = (t, self.origin.copy())
        return BodyState(
            stamp=t,
            position=self.origin.tolist(),
            orientation=[float(x) for x in quaternion(self.rot)],
            linear_velocity=velocity.tolist(),
            stance=stance.tolist(),
            pose_variance=self.variance(),
        )
