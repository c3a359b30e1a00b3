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

import math
from collections.abc import Sequence

import msgspec
import numpy as np

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.algorithms.statics import LegStatics, Statics, Vector, dot, rotate
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.messages import BodyState
from climbd.daemon.contract.profile import Profile
from climbd.daemon.contract.units import NonNegative, Positive

GRAVITY = 9.80665
ICP_GATE = 3.0
"""Standard deviations: an ICP correction beyond the drift filter 2 expects is rejected."""


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


def exp_so3(w: Sequence[float]) -> np.ndarray:
    """Rotation matrix of rotation vector ``w`` (Rodrigues: I + sin|w|/|w| W + (1 - cos|w|)/|w|²
    W², W the cross-product matrix of w), written out: a tick has several and numpy's per-call
    cost is most of one."""
    x, y, z = map(float, w)
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < 1e-12:
        return np.array([[1.0, -z, y], [z, 1.0, -x], [-y, x, 1.0]])
    a = math.sin(angle) / angle
    b = (1.0 - math.cos(angle)) / (angle * angle)
    return np.array(
        [
            [1.0 - b * (y * y + z * z), b * x * y - a * z, b * x * z + a * y],
            [b * x * y + a * z, 1.0 - b * (x * x + z * z), b * y * z - a * x],
            [b * x * z - a * y, b * y * z + a * x, 1.0 - b * (x * x + y * y)],
        ]
    )


def log_so3(r: np.ndarray) -> np.ndarray:
    """Rotation vector of rotation matrix ``r``."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = np.asarray(r, float).tolist()
    c = min(max((r00 + r11 + r22 - 1.0) / 2.0, -1.0), 1.0)
    angle = math.acos(c)
    if math.pi - angle < 1e-6:
        w, vec = np.linalg.eigh((r + np.transpose(r)) / 2.0)
        return angle * vec[:, np.argmax(w)]
    scale = 0.5 if angle < 1e-9 else angle / (2.0 * math.sin(angle))
    return np.array([scale * (r21 - r12), scale * (r02 - r20), scale * (r10 - r01)])


def orthonormalised(m: np.ndarray) -> np.ndarray:
    """``m``, a rotation up to rounding, back onto SO(3): one Newton step of the polar
    decomposition, m (3I - mᵀm) / 2, which squares the error (an SVD costs several times more
    and gives the same rotation to rounding at the 1e-16 errors of a product of rotations)."""
    return m @ (1.5 * np.eye(3) - 0.5 * (m.T @ m))


def quaternion(r: np.ndarray) -> list[float]:
    """Unit quaternion (w, x, y, z) of rotation matrix ``r``."""
    x, y, z = log_so3(r).tolist()
    angle = math.sqrt(x * x + y * y + z * z)
    scale = math.sin(angle / 2) / angle if angle > 1e-12 else 0.0
    return [math.cos(angle / 2), scale * x, scale * y, scale * z]


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
    (a, b, c), (d, e, f), (g, h, i) = rot.tolist()
    if a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) < 0:
        # a reflection: the proper rotation flips the weakest direction
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


Rows = tuple[Vector, Vector, Vector]


def foot_link_rotations(kin: Kinematics, q: np.ndarray) -> list[Rows]:
    """Orientation in the body frame of each leg's last link (the foot's), as rows: the first
    joint turns about z (coxa-femur-tibia: yaw) or x (abduction-thigh-shank: roll), then the
    link pitches about y by -(femur + tibia) or by the shank angle."""
    frames = zip(kin.to_theta(q).tolist(), kin.cft.tolist(), kin.cos_yaw, kin.sin_yaw, strict=True)
    links = []
    for (a, b, c), cft, cy, sy in frames:
        ca, sa = math.cos(a), math.sin(a)
        pitch = -(b + c) if cft else c
        cp, sp = math.cos(pitch), math.sin(pitch)
        if cft:
            r0, r1, r2 = (ca * cp, -sa, ca * sp), (sa * cp, ca, sa * sp), (-sp, 0.0, cp)
        else:
            r0, r1, r2 = (cp, 0.0, sp), (sa * sp, ca, -sa * cp), (-ca * sp, sa, ca * cp)
        cy, sy = float(cy), float(sy)
        links.append(
            (
                tuple(cy * x - sy * y for x, y in zip(r0, r1, strict=True)),
                tuple(sy * x + cy * y for x, y in zip(r0, r1, strict=True)),
                r2,
            )
        )
    return links


def roll_feet(
    anchors: np.ndarray,
    legs: Sequence[int],
    rot: np.ndarray,
    links: list[Rows],
    previous: list[Rows],
    radius: float,
) -> None:
    """Move the anchors (odometry frame) of stance feet ``legs`` rolling on a rounded foot of
    ``radius``: rolling without slip moves the centre, which FK gives, by r·(dθ × up), dθ the
    foot link's turn from ``previous`` to ``links`` (body frame), turned by ``rot`` into the
    world. Over a stride the foot pitches back by its angle of travel, and the centre with it."""
    r = rot.tolist()
    for leg in legs:
        turn = log_so3([[dot(a, b) for b in previous[leg]] for a in links[leg]]).tolist()
        anchors[leg, 0] += radius * dot(r[1], turn)
        anchors[leg, 1] -= radius * dot(r[0], turn)


class SupportTorques:
    """Gravity feed-forward: eq. 5 inverted, tau = J^T F - sum_i J_i^T m_i g, with each stance
    foot pushing down (world frame) with its share of the robot's weight (share by ``load``).

    Torque-controlled legs get it as the command's feed-forward torque, so stance legs hold the
    body's height at low position gains; swing legs get their own links' weight only.
    """

    def __init__(self, kin: Kinematics, mass: float, link_masses: list[float]) -> None:
        self.statics = Statics(kin, link_masses)
        self.link_masses = list(link_masses)
        self.weight = mass * GRAVITY
        self.carriers = max(kin.n_legs // 2, 1)

    def shares(self, load: np.ndarray) -> np.ndarray:
        """Support (N, up) each foot's feed-forward provides: the weight split by ``load``, the
        whole of it once the loads add up to ``carriers`` (half the legs, a tripod), so feet
        taking their share from others keep the sum and feet landing on their own ramp it."""
        load = np.asarray(load, float)
        return load * (self.weight / max(load.sum(), self.carriers))

    def __call__(
        self, q: np.ndarray, load: np.ndarray, rot: np.ndarray, legs: LegStatics | None = None
    ) -> np.ndarray:
        """Joint torques (n_joints,) for joints ``q``, body ``rot`` and each leg's ``load``
        (n_legs,): 1 a stance foot's full share, 0 swing, between while a foot takes its share.
        ``legs``: the statics at ``q`` where the tick has them already (the estimator's)."""
        if legs is None:
            legs = self.statics.at(np.asarray(q, float).tolist())
        ux, uy, uz = rot[2].tolist()  # world up in the body frame
        pushes = [(-f * ux, -f * uy, -f * uz) for f in self.shares(load).tolist()]
        gravity = (-GRAVITY * ux, -GRAVITY * uy, -GRAVITY * uz)
        return np.array(self.statics.torques(legs, pushes, gravity))


# --- the estimator -------------------------------------------------------------------------


class StateEstimator:
    """Leg odometry from the stance tripod, fused with the IMU (filter 1) and ICP (filter 2).

    ``update(q, tau, gyro, accel, dt)`` returns the BodyState; without ``gyro``/``accel`` the
    pose is the kinematic one. ``icp_correction(translation, directions)`` feeds filter 2 with
    the shift that aligns the latest stair cloud (placed with this estimate) onto the map.
    A step runs every 1 ms tick on a few 3-vectors, so its filter arithmetic is written out on
    floats: numpy's per-call overhead would cost several times the arithmetic.
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
        self.statics = Statics(self.kin, self.config.link_masses)
        self.legs: LegStatics | None = None
        """The statics of the latest step's joints (the gravity feed-forward reuses them)."""
        self.group = tripod_groups(profile, self.config.groups)
        self._members = [np.flatnonzero(self.group == g) for g in (0, 1)]
        self.weight = profile.mass * GRAVITY
        n = self.kin.n_legs
        self.anchors = np.zeros((n, 3))
        self.forces = np.zeros((n, 3))
        self.support = np.zeros(n)
        self.stance_group = -1
        self.touched = [False] * n
        self.holding = [False] * n
        self.switches = 0
        self._links: list[Rows] = []
        # filter 1: heading variance and per axis the position/velocity covariance (pp, pv, vv)
        self.rot = np.eye(3) if orientation is None else rotation(orientation)
        self.pos = np.zeros(3) if position is None else np.asarray(position, float).copy()
        self.vel = np.zeros(3)
        self.omega = np.zeros(3)
        self.p_heading = 1e-4
        self.p_pv = [[1e-4, 0.0, 1e-2] for _ in range(3)]
        # filter 2: translation drift correction applied on top of filter 1, its covariance
        self.drift_pos = np.zeros(3)
        self.p_drift = np.zeros((3, 3))
        self.icp_rejected = 0
        self._lowpass: list[list[float]] | None = None

    # --- filter 1 -------------------------------------------------------------------------

    def _predict(self, gyro: Vector, accel: Vector, dt: float) -> list[float]:
        """The gyro turns the body, the accelerometer (less gravity) moves it; each axis's
        position/velocity covariance grows by F P Fᵀ + Q (constant acceleration noise).
        Returns the specific force in the world frame, which ``_tilt`` low-passes."""
        c = self.config
        self.omega = self.rot @ gyro
        self.rot = self.rot @ exp_so3((gyro[0] * dt, gyro[1] * dt, gyro[2] * dt))
        self.p_heading += c.gyro_noise**2 * dt
        force = rotate(self.rot.tolist(), accel)
        acc = [force[0], force[1], force[2] - GRAVITY]
        pos, vel = self.pos.tolist(), self.vel.tolist()
        for k in range(3):
            pos[k] += vel[k] * dt + 0.5 * acc[k] * dt * dt
            vel[k] += acc[k] * dt
        self.pos, self.vel = np.array(pos), np.array(vel)
        q_pp = 0.25 * dt**4 * c.accel_noise**2
        q_vv = dt * dt * c.accel_noise**2 + dt * c.velocity_walk**2
        for p in self.p_pv:
            pp, pv, vv = p
            p[0] = pp + 2.0 * dt * pv + dt * dt * vv + q_pp
            p[1] = pv + dt * vv
            p[2] = vv + q_vv
        return force

    def _rotate(self, delta: Sequence[float]) -> None:
        self.rot = orthonormalised(exp_so3(delta) @ self.rot)

    def _tilt(self, force: list[float], pos_kin: list[float], dt: float) -> list[float]:
        """The turn pulling the tilt toward gravity: specific force (world) = acceleration + g·z,
        with the force low-passed twice (f1, f2) and the acceleration the same filter's second
        derivative of the stance feet's position, (p - 2·p1 + p2) / T² (T = ``gravity_time``)."""
        c = self.config
        if self._lowpass is None:
            self._lowpass = [list(force), list(force), list(pos_kin), list(pos_kin)]
        a = min(1.0, dt / c.gravity_time)
        f1, f2, p1, p2 = self._lowpass
        up = [0.0, 0.0, 0.0]
        for k in range(3):
            f1[k] += a * (force[k] - f1[k])
            f2[k] += a * (f1[k] - f2[k])
            p1[k] += a * (pos_kin[k] - p1[k])
            p2[k] += a * (p1[k] - p2[k])
            up[k] = f2[k] - (pos_kin[k] - 2.0 * p1[k] + p2[k]) / c.gravity_time**2
        scale = min(1.0, dt / c.tilt_time) / math.sqrt(up[0] ** 2 + up[1] ** 2 + up[2] ** 2)
        return [up[1] * scale, -up[0] * scale, 0.0]

    def _correct(
        self,
        rot_kin: np.ndarray,
        feet: list[Vector],
        touching: list[int],
        holding: list[int],
        force: list[float],
        dt: float,
    ) -> None:
        """Heading from the stance feet's rotation, tilt from gravity, then position from the
        feet fitted on that rotation (eq. 8 with R known): the height from the touching feet, as
        a slide keeps a foot on its tread, the rest from the holding ones; where none are, the
        IMU's prediction stands."""
        c = self.config
        heading = float(log_so3(rot_kin @ self.rot.T)[2])
        gain = self.p_heading / (self.p_heading + c.kinematic_rotation_noise**2)
        self.p_heading *= 1.0 - gain
        r = self.rot.tolist()
        anchors = self.anchors.tolist()

        def origin(leg: int, axis: int) -> float:
            """Where the body is if foot ``leg`` is at its anchor: anchor - R · foot."""
            return anchors[leg][axis] - dot(r[axis], feet[leg])

        pos = self.pos.tolist()
        pos_kin = list(pos)
        if holding:
            pos_kin[0] = sum(origin(leg, 0) for leg in holding) / len(holding)
            pos_kin[1] = sum(origin(leg, 1) for leg in holding) / len(holding)
        if touching:
            pos_kin[2] = sum(origin(leg, 2) for leg in touching) / len(touching)
        turn = self._tilt(force, pos_kin, dt)
        turn[2] = gain * heading
        self._rotate(turn)
        vel = self.vel.tolist()
        noise = c.kinematic_position_noise**2
        for axis, measured in enumerate((bool(holding), bool(holding), bool(touching))):
            if not measured:
                continue
            p = self.p_pv[axis]
            pp, pv, vv = p
            k_pos, k_vel = pp / (pp + noise), pv / (pp + noise)
            innovation = pos_kin[axis] - pos[axis]
            pos[axis] += k_pos * innovation
            vel[axis] += k_vel * innovation
            p[0], p[1], p[2] = pp - k_pos * pp, pv - k_pos * pv, vv - k_vel * pv
        self.pos, self.vel = np.array(pos), np.array(vel)

    # --- leg odometry (eqs. 5-9) ------------------------------------------------------------

    def _register(self, legs: Sequence[int], feet: np.ndarray) -> None:
        """Global positions of feet that just took the load, from the current estimate."""
        self.anchors[legs] = self.pos + feet[legs] @ self.rot.T

    def _footing(
        self, stance: np.ndarray, feet: np.ndarray, forces: list[Vector]
    ) -> tuple[list[int], list[int]]:
        """Stance feet that touch (support above ``slip_load``) and those that also hold
        (traction inside ``slip_ratio``). A foot's first touch since its touchdown registers it
        where it is; one holding again after a slide is moved there along the ground only."""
        c = self.config
        r = self.rot.tolist()
        load = c.slip_load * self.weight / len(stance)
        touching, holding, first, slid = [], [], [], []
        for leg in stance.tolist():
            x, y, z = rotate(r, forces[leg])
            if not -z > load:
                self.holding[leg] = False
                continue
            touching.append(leg)
            if not self.touched[leg]:
                first.append(leg)
            holds = math.hypot(x, y) < -c.slip_ratio * z
            if holds:
                holding.append(leg)
                if not self.holding[leg] and self.touched[leg]:
                    slid.append(leg)
            self.touched[leg] = True
            self.holding[leg] = holds
        if first or slid:
            height = self.anchors[slid, 2]
            self._register(first + slid, feet)
            self.anchors[slid, 2] = height
        return touching, holding

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
        self.legs = legs = self.statics.at(q.tolist())
        feet = np.array(legs.feet)
        imu = gyro is not None and accel is not None and dt > 0
        if imu:
            gyro, accel = tuple(map(float, gyro)), tuple(map(float, accel))
            force = self._predict(gyro, accel, dt)
        up = self.rot[2].tolist()  # world up in the body frame
        gravity = (-GRAVITY * up[0], -GRAVITY * up[1], -GRAVITY * up[2])
        forces = self.statics.foot_forces(legs, np.asarray(tau, float).tolist(), gravity)
        self.forces = np.array(forces)
        if self.config.foot_radius > 0.0:
            links = foot_link_rotations(self.kin, q)
            if self.stance_group >= 0:
                legs_down = self._members[self.stance_group].tolist()
                r = self.config.foot_radius
                roll_feet(self.anchors, legs_down, self.rot, links, self._links, r)
            self._links = links
        support = [-dot(f, up) for f in forces]
        support = [0.0 if math.isnan(s) else s for s in support]
        self.support = np.array(support)
        sums = [sum(support[leg] for leg in members) for members in self._members]
        if planned is not None:
            down = np.asarray(planned, bool).tolist()
            for g, members in enumerate(self._members):
                if not any(down[leg] for leg in members):
                    sums[g] = -math.inf
        leading = 0 if sums[0] >= sums[1] else 1
        margin = self.config.switch_margin * self.weight
        if self.stance_group < 0 or (
            leading != self.stance_group and sums[leading] > sums[1 - leading] + margin
        ):
            self.stance_group = leading
            self.switches += 1
            self._register(self._members[leading], feet)
            for leg in self._members[leading]:
                self.touched[leg] = False
        stance = self._members[self.stance_group]
        try:
            rot_kin, pos_kin = stance_pose(feet[stance], self.anchors[stance])
        except EstimationError:
            rot_kin, pos_kin = self.rot, self.pos
        if imu:
            touching, holding = self._footing(stance, feet, forces)
            self._correct(rot_kin, legs.feet, touching, holding, force, dt)
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
            pose_variance=self.variance(),
        )

    def variance(self) -> list[float]:
        """The pose's variances (x, y, z m²; roll, pitch, yaw rad²): filter 1's position and
        heading with filter 2's drift correction; the tilt, a gyro random walk pulled toward
        gravity with time constant τ, holds gyro_noise² · τ / 2."""
        position = [self.p_pv[k][0] + float(self.p_drift[k, k]) for k in range(3)]
        tilt = self.config.gyro_noise**2 * self.config.tilt_time / 2.0
        return [*position, tilt, tilt, self.p_heading]
