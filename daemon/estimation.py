"""Stance-based body state estimation (paper 004, section 3.1, eqs. 5-9) with two filters.

Each tick: foot forces from joint torques (eq. 5); the stance tripod is the group whose feet
carry the larger support force (group A: MF, RB, LB; group B: MB, RF, LF), among those the gait
has not lifted; the body pose in the global (odometry) frame follows from the three stance feet
(eqs. 6-9), whose global positions are registered when their group takes the load. Filter 1
fuses that with the IMU: the gyro carries the rotation, gravity corrects its tilt and the stance
feet its heading; the accelerometer predicts the position and the stance feet, fitted on that
rotation, correct it (Kalman), each foot as far as its eq. 5 force says it holds its ground.
Filter 2 holds the position drift that ICP of each stair cloud onto the stitched map measures,
along the directions the stairs in view constrain (treads the height, risers the ascent).
Pure: arrays in, BodyState out, no clock, no I/O.
"""

from __future__ import annotations

import copy
import math
from typing import Annotated

import msgspec
import numpy as np

from daemon.kinematics import Kinematics
from daemon.messages import BodyState
from daemon.profile import Profile

GRAVITY = 9.80665
ICP_GATE = 3.0
"""Standard deviations: an ICP correction beyond the drift filter 2 expects is rejected."""
Positive = Annotated[float, msgspec.Meta(gt=0)]
NonNegative = Annotated[float, msgspec.Meta(ge=0)]


class EstimatorConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Noise figures (SI, 1-sigma) of the two filters and the stance detector.

    The kinematic pose corrects the IMU's heading only (``kinematic_rotation_noise``): its tilt
    drifts with every misregistered foot, and a tilt error turns the distance walked into height.
    The tilt is pulled toward gravity instead, with time constant ``tilt_time`` (s): gravity is
    the world-frame specific force less the body's acceleration, both low-passed twice with
    ``gravity_time`` (s), the acceleration from the stance feet's positions.
    ``foot_radius``: radius of the rubber foot (m); a stance foot rolls on it, which moves its
    centre (what FK gives) over the ground. ``link_masses``: mass (kg) of each leg's three
    links, centres at mid-link, whose weight the joint torques carry besides the foot force.
    ``groups``: the two tripods by leg name; empty
    means paper 004's layout rule (alternate legs along each side).
    With the IMU, eq. 5's force tells what each stance foot does: under ``slip_load`` of an
    equal share of the weight it is off the ground and leaves the position fit; with traction
    over support above ``slip_ratio`` (below the ground's friction coefficient) it slides and
    gives the height only, the other feet and the IMU carrying the rest; holding again, it is
    registered again along the ground. (In the twin the body's bounce after each touchdown
    unloads front feet to 16 N under 47 N of traction: they slid 15 mm.)
    """

    gyro_noise: Positive = 0.02
    accel_noise: Positive = 0.5
    velocity_walk: Positive = 0.5
    kinematic_position_noise: Positive = 0.005
    kinematic_rotation_noise: Positive = 0.01
    gravity_time: Positive = 0.5
    tilt_time: Positive = 2.0
    drift_position_rate: Positive = 0.005
    icp_position_noise: Positive = 0.005
    switch_margin: NonNegative = 0.1
    slip_ratio: Positive = 0.6
    slip_load: NonNegative = 0.2
    foot_radius: NonNegative = 0.0
    link_masses: list[float] = []
    groups: list[list[str]] = []


# --- rotations ----------------------------------------------------------------------------


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix of a 3-vector."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def exp_so3(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of rotation vector ``w`` (Rodrigues)."""
    angle = float(np.linalg.norm(w))
    if angle < 1e-12:
        return np.eye(3) + skew(w)
    k = skew(w / angle)
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def log_so3(r: np.ndarray) -> np.ndarray:
    """Rotation vector of rotation matrix ``r``."""
    c = min(max((r[0, 0] + r[1, 1] + r[2, 2] - 1.0) / 2.0, -1.0), 1.0)
    angle = math.acos(c)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if angle < 1e-9:
        return 0.5 * v
    if math.pi - angle < 1e-6:
        w, vec = np.linalg.eigh((r + r.T) / 2.0)
        return angle * vec[:, np.argmax(w)]
    return angle / (2.0 * math.sin(angle)) * v


def cross_up(v: np.ndarray) -> np.ndarray:
    """v × z (z up), written out: numpy's cross costs tens of µs on one 3-vector."""
    return np.array([v[1], -v[0], 0.0])


def orthonormalised(m: np.ndarray) -> np.ndarray:
    """``m``, a rotation up to rounding, back onto SO(3): one Newton step of the polar
    decomposition, m (3I - mᵀm) / 2, which squares the error (an SVD costs several times more
    and gives the same rotation to rounding at the 1e-16 errors of a product of rotations)."""
    return m @ (1.5 * np.eye(3) - 0.5 * (m.T @ m))


def quaternion(r: np.ndarray) -> list[float]:
    """Unit quaternion (w, x, y, z) of rotation matrix ``r``."""
    w = log_so3(r)
    angle = float(np.linalg.norm(w))
    axis = w / angle if angle > 1e-12 else np.zeros(3)
    return [math.cos(angle / 2), *(math.sin(angle / 2) * axis).tolist()]


def rotation(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of quaternion (w, x, y, z)."""
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


# --- eqs. 6-9 -------------------------------------------------------------------------------


class EstimationError(ValueError):
    """Stance feet that do not determine a pose (collinear, or inconsistent distances)."""


def stance_pose(feet_body: np.ndarray, feet_global: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Body rotation and origin in the global frame from three stance feet (eqs. 7-9).

    Solves eq. 8 (global foot = origin + R · body foot, all three feet) in least squares
    (Kabsch); with consistent feet this meets eq. 7's distances exactly. Eq. 7's trilateration
    followed by eq. 9 amplifies millimetre foot errors about twice into height at Qingzhui's
    stance (measured in the twin), so the least-squares form replaces it.
    """
    pb = np.asarray(feet_body, float)
    pg = np.asarray(feet_global, float)
    cb, cg = pb.sum(0) / len(pb), pg.sum(0) / len(pg)
    u, s, vt = np.linalg.svd((pg - cg).T @ (pb - cb))
    if s[1] < 1e-12:  # rank < 2: the feet are collinear (or coincide)
        raise EstimationError("stance feet are collinear: no pose")
    rot = u @ vt
    if np.linalg.det(rot) < 0:  # a reflection: the proper rotation flips the weakest direction
        u[:, 2] = -u[:, 2]
        rot = u @ vt
    origin = cg - rot @ cb
    return rot, origin


def tripod_groups(profile: Profile, names: list[list[str]] | None = None) -> np.ndarray:
    """Group index (0 = A, 1 = B) of every leg: from ``names`` or the alternating layout rule.

    The rule puts legs alternately along each side, the sides shifted by one: for Qingzhui it
    gives paper 004's group A (MF, RB, LB) and group B (MB, RF, LF); group A holds the most
    forward leg.
    """
    legs = [leg.name for leg in profile.legs]
    if names:
        group = np.full(len(legs), -1)
        for g, members in enumerate(names[:2]):
            for name in members:
                if name not in legs:
                    raise ValueError(f"estimator groups: no leg {name!r} (legs: {legs})")
                group[legs.index(name)] = g
        if (group < 0).any():
            missing = [n for n, g in zip(legs, group, strict=True) if g < 0]
            raise ValueError(f"estimator groups: legs {missing} are in neither group")
        return group
    mounts = np.array([leg.mount for leg in profile.legs], float)
    angle = np.arctan2(mounts[:, 1], mounts[:, 0])
    left = (angle > 0) | np.isclose(angle, np.pi)
    group = np.zeros(len(legs), int)
    for side, members in enumerate((np.flatnonzero(left), np.flatnonzero(~left))):
        order = members[np.argsort(mounts[members, 0], kind="stable")]
        for rank, leg in enumerate(order):
            group[leg] = (rank + side) % 2
    front = int(np.argmax(mounts[:, 0]))
    return group if group[front] == 0 else 1 - group


def support_forces(forces_body: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """Vertical support (N, + up on the body) of each foot from its eq. 5 force, body frame."""
    return -(np.asarray(forces_body) @ rot.T)[:, 2]


def foot_link_rotations(kin: Kinematics, q: np.ndarray) -> np.ndarray:
    """Orientation (n_legs, 3, 3) in the body frame of each leg's last link (the foot's)."""
    th = kin.to_theta(q)
    a, b, c = th[:, 0], th[:, 1], th[:, 2]
    ca, sa = np.cos(a), np.sin(a)
    pitch = np.where(kin.cft, -(b + c), c)
    cp, sp = np.cos(pitch), np.sin(pitch)
    ry = np.zeros((kin.n_legs, 3, 3))
    ry[:, 0, 0], ry[:, 0, 2], ry[:, 1, 1], ry[:, 2, 0], ry[:, 2, 2] = cp, sp, 1.0, -sp, cp
    first = np.zeros((kin.n_legs, 3, 3))
    # coxa-femur-tibia: yaw about z; abduction-thigh-shank: roll about x
    first[:, 0, 0] = np.where(kin.cft, ca, 1.0)
    first[:, 0, 1] = np.where(kin.cft, -sa, 0.0)
    first[:, 1, 0] = np.where(kin.cft, sa, 0.0)
    first[:, 1, 1] = ca
    first[:, 1, 2] = np.where(kin.cft, 0.0, -sa)
    first[:, 2, 1] = np.where(kin.cft, 0.0, sa)
    first[:, 2, 2] = np.where(kin.cft, 1.0, ca)
    return kin.rot @ first @ ry


class FootForces:
    """Eq. 5 with the legs' own weight removed: F = (J^T)^-1 (tau + sum_i J_i^T m_i g).

    ``J_i`` is the Jacobian of link i's centre, i.e. the foot Jacobian of the same leg with
    its links cut at that centre. F is the force each foot exerts on its contact (body frame).
    """

    def __init__(self, kin: Kinematics, link_masses: list[float]) -> None:
        if link_masses and len(link_masses) != 3:
            raise ValueError(f"estimator link_masses: expected 3 values, found {link_masses}")
        self.kin = kin
        self.weighted: Kinematics | None = None
        if link_masses:
            # the foot Jacobian is linear in the link lengths, so sum_i m_i J_i is the Jacobian
            # of one leg whose link j is l_j x (half its own mass + the masses beyond it)
            m1, m2, m3 = link_masses
            self.weighted = copy.copy(kin)
            w = self.weighted
            w.l1, w.l2, w.l3 = kin.l1 * (m1 / 2 + m2 + m3), kin.l2 * (m2 / 2 + m3), kin.l3 * m3 / 2

    def link_gravity(self, q: np.ndarray, rot: np.ndarray) -> np.ndarray:
        """sum_i J_i^T m_i g (n_legs, 3): the joint torques the legs' own weight asks for."""
        if self.weighted is None:
            return np.zeros((self.kin.n_legs, 3))
        g = rot.T @ np.array([0.0, 0.0, -GRAVITY])
        return np.einsum("lij,i->lj", self.weighted.jacobian(q), g)

    def __call__(self, q: np.ndarray, tau: np.ndarray, rot: np.ndarray) -> np.ndarray:
        tau = np.asarray(tau, float).reshape(self.kin.n_legs, 3)
        return self.kin.foot_forces(q, tau + self.link_gravity(q, rot))


class SupportTorques:
    """Gravity feed-forward: eq. 5 inverted, tau = J^T F - sum_i J_i^T m_i g, with each stance
    foot pushing down (world frame) with its share of the robot's weight (share by ``load``).

    Torque-controlled legs get it as the command's feed-forward torque, so stance legs hold the
    body's height at low position gains; swing legs get their own links' weight only.
    """

    def __init__(self, kin: Kinematics, mass: float, link_masses: list[float]) -> None:
        self.forces = FootForces(kin, link_masses)
        self.link_masses = list(link_masses)
        self.weight = mass * GRAVITY
        self.carriers = max(kin.n_legs // 2, 1)

    def shares(self, load: np.ndarray) -> np.ndarray:
        """Support (N, up) each foot's feed-forward provides: the weight split by ``load``, the
        whole of it once the loads add up to ``carriers`` (half the legs, a tripod), so feet
        taking their share from others keep the sum and feet landing on their own ramp it."""
        load = np.asarray(load, float)
        return load * (self.weight / max(load.sum(), self.carriers))

    def __call__(self, q: np.ndarray, load: np.ndarray, rot: np.ndarray) -> np.ndarray:
        """Joint torques (n_joints,) for joints ``q``, body ``rot`` and each leg's ``load``
        (n_legs,): 1 a stance foot's full share, 0 swing, between while a foot takes its share."""
        kin = self.forces.kin
        push = np.outer(self.shares(load), rot.T @ np.array([0.0, 0.0, -1.0]))
        tau = np.einsum("lij,li->lj", kin.jacobian(q), push)
        return (tau - self.forces.link_gravity(q, rot)).reshape(-1)


# --- the estimator -------------------------------------------------------------------------


class StateEstimator:
    """Leg odometry from the stance tripod, fused with the IMU (filter 1) and ICP (filter 2).

    ``update(q, tau, gyro, accel, dt)`` returns the BodyState; without ``gyro``/``accel`` the
    pose is the kinematic one. ``icp_correction(translation, directions)`` feeds filter 2 with
    the shift that aligns the latest stair cloud (placed with this estimate) onto the map.
    """

    def __init__(
        self,
        profile: Profile,
        config: EstimatorConfig | None = None,
        position: np.ndarray | None = None,
        orientation: np.ndarray | None = None,
    ) -> None:
        self.config = config or EstimatorConfig()
        self.kin = Kinematics(profile)
        self.foot_forces = FootForces(self.kin, self.config.link_masses)
        self.group = tripod_groups(profile, self.config.groups)
        self.weight = profile.mass * GRAVITY
        n = self.kin.n_legs
        self.anchors = np.zeros((n, 3))
        self.forces = np.zeros((n, 3))
        self.support = np.zeros(n)
        self.stance_group = -1
        self.touched = np.zeros(n, bool)
        self.holding = np.zeros(n, bool)
        self.switches = 0
        self._link_rot = np.zeros((n, 3, 3))
        # filter 1: heading variance and per-axis position/velocity
        self.rot = np.eye(3) if orientation is None else rotation(orientation)
        self.pos = np.zeros(3) if position is None else np.asarray(position, float).copy()
        self.vel = np.zeros(3)
        self.omega = np.zeros(3)
        self.p_heading = 1e-4
        self.p_pv = np.tile(np.diag([1e-4, 1e-2]), (3, 1, 1))
        # filter 2: translation drift correction applied on top of filter 1, its covariance
        self.drift_pos = np.zeros(3)
        self.p_drift = np.zeros((3, 3))
        self.icp_rejected = 0
        self._lowpass: np.ndarray | None = None
        self.kinematic: tuple[np.ndarray, np.ndarray] | None = None

    # --- filter 1 -------------------------------------------------------------------------

    def _predict(self, gyro: np.ndarray, accel: np.ndarray, dt: float) -> None:
        c = self.config
        self.omega = self.rot @ gyro
        self.rot = self.rot @ exp_so3(gyro * dt)
        self.p_heading += c.gyro_noise**2 * dt
        acc = self.rot @ accel - np.array([0.0, 0.0, GRAVITY])
        f = np.array([[1.0, dt], [0.0, 1.0]])
        self.pos += self.vel * dt + 0.5 * acc * dt * dt
        self.vel += acc * dt
        q = np.diag([0.25 * dt**4, dt * dt]) * c.accel_noise**2 + np.diag([0.0, dt]) * (
            c.velocity_walk**2
        )
        self.p_pv = f @ self.p_pv @ f.T + q

    def _rotate(self, delta: np.ndarray) -> None:
        self.rot = orthonormalised(exp_so3(delta) @ self.rot)

    def _tilt(self, accel: np.ndarray, pos_kin: np.ndarray, dt: float) -> np.ndarray:
        """The turn pulling the tilt toward gravity: specific force (world) = acceleration + g·z,
        with the force low-passed twice (f1, f2) and the acceleration the same filter's second
        derivative of the stance feet's position, (p - 2·p1 + p2) / T² (T = ``gravity_time``)."""
        c = self.config
        force = self.rot @ accel
        if self._lowpass is None:
            self._lowpass = np.array([force, force, pos_kin, pos_kin])
        a = min(1.0, dt / c.gravity_time)
        f1, f2, p1, p2 = self._lowpass
        f1 += a * (force - f1)
        f2 += a * (f1 - f2)
        p1 += a * (pos_kin - p1)
        p2 += a * (p1 - p2)
        up = f2 - (pos_kin - 2.0 * p1 + p2) / c.gravity_time**2
        return cross_up(up / np.linalg.norm(up)) * min(1.0, dt / c.tilt_time)

    def _correct(
        self,
        rot_kin: np.ndarray,
        feet: np.ndarray,
        touching: np.ndarray,
        holding: np.ndarray,
        accel: np.ndarray,
        dt: float,
    ) -> None:
        """Heading from the stance feet's rotation, tilt from gravity, then position from the
        feet fitted on that rotation (eq. 8 with R known): the height from the touching feet, as
        a slide keeps a foot on its tread, the rest from the holding ones; where none are, the
        IMU's prediction stands."""
        c = self.config
        heading = log_so3(rot_kin @ self.rot.T)[2]
        gain = self.p_heading / (self.p_heading + c.kinematic_rotation_noise**2)
        self.p_heading *= 1.0 - gain
        origins = self.anchors - feet @ self.rot.T
        measured = np.array([len(holding), len(holding), len(touching)]) > 0
        pos_kin = self.pos.copy()
        if len(holding):
            pos_kin[:2] = origins[holding, :2].mean(0)
        if len(touching):
            pos_kin[2] = origins[touching, 2].mean()
        turn = self._tilt(accel, pos_kin, dt)
        turn[2] = gain * heading
        self._rotate(turn)
        h = np.array([1.0, 0.0])
        s = self.p_pv[:, 0, 0] + c.kinematic_position_noise**2
        k = self.p_pv[:, :, 0] / s[:, None] * measured[:, None]
        innov = pos_kin - self.pos
        self.pos += k[:, 0] * innov
        self.vel += k[:, 1] * innov
        self.p_pv -= k[:, :, None] * (h @ self.p_pv)[:, None, :]

    # --- leg odometry (eqs. 5-9) ------------------------------------------------------------

    def _register(self, legs: np.ndarray, feet: np.ndarray) -> None:
        """Global positions of feet that just took the load, from the current estimate."""
        self.anchors[legs] = self.pos + feet[legs] @ self.rot.T

    def _roll(self, legs: np.ndarray, link_rot: np.ndarray) -> None:
        """Move the anchors of rolling stance feet: the centre moves by dθ × (r·up)."""
        r = self.config.foot_radius
        if r <= 0.0:
            return
        turns = self.rot @ link_rot[legs] @ np.swapaxes(self._link_rot[legs], 1, 2) @ self.rot.T
        for leg, turn in zip(legs, turns, strict=True):
            self.anchors[leg] += r * cross_up(log_so3(turn))

    def _footing(self, stance: np.ndarray, feet: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stance feet that touch (support above ``slip_load``) and those that also hold
        (traction inside ``slip_ratio``). A foot's first touch since its touchdown registers it
        where it is; one holding again after a slide is moved there along the ground only."""
        c = self.config
        force = self.forces[stance] @ self.rot.T
        support = -force[:, 2]
        touches = support > c.slip_load * self.weight / len(stance)
        holds = touches & (np.hypot(force[:, 0], force[:, 1]) < c.slip_ratio * support)
        first = stance[touches & ~self.touched[stance]]
        slid = stance[holds & ~self.holding[stance] & self.touched[stance]]
        height = self.anchors[slid, 2]
        self._register(np.concatenate([first, slid]), feet)
        self.anchors[slid, 2] = height
        self.touched[stance] |= touches
        self.holding[:] = False
        self.holding[stance] = holds
        return stance[touches], stance[holds]

    def update(
        self,
        q: np.ndarray,
        tau: np.ndarray,
        gyro: np.ndarray | None = None,
        accel: np.ndarray | None = None,
        dt: float = 0.0,
        stamp: float = 0.0,
        planned: np.ndarray | None = None,
    ) -> BodyState:
        """One estimation step from joint positions and torques (and the IMU, if given).
        ``planned``: the gait's stance per foot; a group none of whose feet it has down cannot
        take the stance, however much eq. 5 reads on it: a near-straight swinging leg turns
        torque error into thousands of newtons (twin, 180 mm stairs: MB read 4490 N in swing,
        the swinging tripod took the stance and the height jumped 18 mm)."""
        q = np.asarray(q, float)
        feet = self.kin.fk(q)
        link_rot = foot_link_rotations(self.kin, q)
        imu = gyro is not None and accel is not None and dt > 0
        if imu:
            self._predict(np.asarray(gyro, float), np.asarray(accel, float), dt)
        self.forces = self.foot_forces(q, tau, self.rot)
        if self.stance_group >= 0:
            self._roll(np.flatnonzero(self.group == self.stance_group), link_rot)
        self._link_rot = link_rot
        support = support_forces(self.forces, self.rot)
        self.support = np.where(np.isnan(support), 0.0, support)
        sums = np.array([self.support[self.group == g].sum() for g in (0, 1)])
        if planned is not None:
            down = np.asarray(planned, bool)
            sums = np.where([down[self.group == g].any() for g in (0, 1)], sums, -np.inf)
        leading = int(np.argmax(sums))
        margin = self.config.switch_margin * self.weight
        if self.stance_group < 0 or (
            leading != self.stance_group and sums[leading] > sums[1 - leading] + margin
        ):
            self.stance_group = leading
            self.switches += 1
            self._register(np.flatnonzero(self.group == leading), feet)
            self.touched[self.group == leading] = False
        stance = np.flatnonzero(self.group == self.stance_group)
        try:
            rot_kin, pos_kin = stance_pose(feet[stance], self.anchors[stance])
        except EstimationError:
            rot_kin, pos_kin = self.rot, self.pos
        self.kinematic = (rot_kin, pos_kin)
        if imu:
            touching, holding = self._footing(stance, feet)
            self._correct(rot_kin, feet, touching, holding, np.asarray(accel, float), dt)
        else:
            if dt > 0:
                self.vel = (pos_kin - self.pos) / dt
            self.rot, self.pos = rot_kin, pos_kin
        self._drift_predict(dt)
        return self.body(stamp)

    # --- filter 2 (ICP) ---------------------------------------------------------------------

    def _drift_predict(self, dt: float) -> None:
        self.p_drift.flat[::4] += self.config.drift_position_rate**2 * dt  # the diagonal

    def icp_correction(self, translation: np.ndarray, directions: np.ndarray) -> None:
        """Fuse an ICP shift (global frame: moves the newest cloud onto the stitched map) along
        each of its orthonormal ``directions`` (k, 3), the ones the stairs in view constrain.

        The cloud was placed with this estimate, so the shift along a direction measures the
        position error there, negated. One scalar Kalman update a direction, less what the
        updates before it moved the drift along it, gated at ``ICP_GATE`` sigma (a rejected
        direction counts in ``icp_rejected``); the rotation is the IMU's.
        """
        noise = self.config.icp_position_noise**2
        shift = np.asarray(translation, float)
        before = self.drift_pos.copy()
        for d in np.asarray(directions, float).reshape(-1, 3):
            innovation = float(d @ (shift - (self.drift_pos - before)))
            pd = self.p_drift @ d
            var = float(d @ pd) + noise
            if innovation * innovation > ICP_GATE**2 * var:
                self.icp_rejected += 1
                continue
            gain = pd / var
            self.drift_pos += gain * innovation
            self.p_drift -= np.outer(gain, pd)

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Final body rotation and position: filter 2's correction applied to filter 1."""
        return self.rot, self.pos + self.drift_pos

    def body(self, stamp: float = 0.0) -> BodyState:
        rot, pos = self.pose()
        stance = (self.group == self.stance_group).tolist()
        return BodyState(
            stamp=stamp,
            position=pos.tolist(),
            orientation=quaternion(rot),
            linear_velocity=self.vel.tolist(),
            angular_velocity=self.omega.tolist(),
            stance=stance,
        )
