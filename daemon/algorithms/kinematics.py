"""Vectorised 3-DOF leg kinematics for all legs of a profile: FK, IK, Jacobian, foot forces.

Frames. Body frame: x forward, y left, z up. Leg frame of leg i: origin at its ``mount``,
x along the mount ``yaw`` (outward), z up; ``foot_body = mount + Rz(yaw) @ foot_leg``.

Joint convention. Joint vectors are in profile order (leg by leg, three joints each) and in
each joint's own convention: ``q = direction * theta + zero_offset``, where ``theta`` is the
kinematic angle below. Position limits apply to ``q``.

Kinematic angles, ``links = [l1, l2, l3]``:

- ``coxa_femur_tibia`` (WidowX, HubRobo): coxa yaw ``gamma`` about z (+ counter-clockwise),
  femur elevation ``alpha`` above the horizontal (+ up), tibia ``beta`` relative to the femur
  (+ up). ``r = l1 + l2 cos(alpha) + l3 cos(alpha + beta)``,
  foot = ``(r cos(gamma), r sin(gamma), l2 sin(alpha) + l3 sin(alpha + beta))``.
  Knee "a" is the knee-up branch (``beta <= 0``), knee "b" the knee-down branch.
- ``abduction_thigh_shank`` (Qingzhui, paper 004 eqs. 1-3): abduction ``theta_a`` about the
  leg x axis, thigh ``theta_t`` and shank ``theta_s`` both measured (as in the paper) from the
  outward axis, + downward; ``l1`` is the offset from the abduction joint to the thigh joint.
  With ``rho = l2 sin(theta_t) + l3 sin(theta_s)``:
  foot = ``(l1 + l2 cos(theta_t) + l3 cos(theta_s), rho sin(theta_a), -rho cos(theta_a))``,
  i.e. the paper's (x, y, z) with its y pointing down and its z along our leg y. Knee "a" has
  the knee above the foot line (``theta_s >= theta_t``), knee "b" below it.

IK reports unreachable legs (outside the workspace or outside the joint limits) in a mask
and never clamps them into another pose. ``ik_feet`` is the same IK leg by leg with ``math``:
for one tick's few legs, numpy's per-call overhead costs more than the arithmetic.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np

from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.profile import Profile

LIMIT_TOLERANCE = 1e-9
"""Rounding (rad) allowed past a joint limit before IK calls a target unreachable."""

EXTENSION_TOLERANCE = 1e-12
"""Rounding allowed past a straight knee (the law of cosines' |cos| <= 1): a foot at full
extension is reachable, whichever float path (numpy or math) computes it."""

CFT = "coxa_femur_tibia"
ATS = "abduction_thigh_shank"


class KinematicsError(ValueError):
    """A profile whose geometry cannot be used (e.g. an unreachable stand pose)."""


def rot_z(angle: np.ndarray) -> np.ndarray:
    """Rotation matrices about z, shape (..., 3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros((*np.shape(angle), 3, 3))
    out[..., 0, 0], out[..., 0, 1] = c, -s
    out[..., 1, 0], out[..., 1, 1] = s, c
    out[..., 2, 2] = 1.0
    return out


def rot_rpy(roll: float, pitch: float, yaw: float = 0.0) -> np.ndarray:
    """Rotation matrix Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    return rot_z(yaw) @ ry @ rx


def _two_link(u, w, l2, l3, knee_sign):
    """Planar two-link IK: (first angle, relative second angle, reachable) for point (u, w)."""
    c = (u * u + w * w - (l2 * l2 + l3 * l3)) / (2.0 * l2 * l3)
    ok = np.abs(c) <= 1.0 + EXTENSION_TOLERANCE
    rel = knee_sign * np.arccos(np.clip(c, -1.0, 1.0))
    first = np.arctan2(w, u) - np.arctan2(l3 * np.sin(rel), l2 + l3 * np.cos(rel))
    return first, rel, ok


class Kinematics:
    """FK, IK, Jacobian and foot forces of every leg of ``profile``, vectorised over legs."""

    def __init__(self, profile: Profile, repeat: int = 1) -> None:
        """``repeat`` > 1 repeats each leg that many times in a row (leg-major), so one call
        solves ``repeat`` points per leg (a planner checking many candidate footholds)."""
        self.profile = profile
        legs = profile.legs
        self.n_legs = len(legs)
        self.n_joints = 3 * self.n_legs
        self.leg_names = [leg.name for leg in legs]
        self.mount = np.array([leg.mount for leg in legs], float)
        self.yaw = np.array([leg.yaw for leg in legs], float)
        self.rot = rot_z(self.yaw)
        self.cos_yaw, self.sin_yaw = np.cos(self.yaw), np.sin(self.yaw)
        links = np.array([leg.links for leg in legs], float)
        self.l1, self.l2, self.l3 = links[:, 0], links[:, 1], links[:, 2]
        joints = profile.joints
        self.direction = np.array([j.direction for j in joints], float)
        self.zero_offset = np.array([j.zero_offset for j in joints], float)
        self.lower = np.array([j.limits.lower for j in joints], float)
        self.upper = np.array([j.limits.upper for j in joints], float)
        self._mid = 0.5 * (self.lower + self.upper)
        self._half_range = 0.5 * (self.upper - self.lower) + LIMIT_TOLERANCE
        self.cft = np.array([leg.kind == CFT for leg in legs])
        self.all_cft = bool(self.cft.all())
        self.knee_sign = np.array(
            [
                (-1.0 if leg.kind == CFT else 1.0) * (1.0 if leg.knee == "a" else -1.0)
                for leg in legs
            ]
        )
        if repeat > 1:
            self._repeat(repeat)

    def _repeat(self, times: int) -> None:
        """Each leg's arrays repeated ``times`` times in a row (see ``__init__``)."""
        for name in ("mount", "yaw", "rot", "cos_yaw", "sin_yaw", "l1", "l2", "l3", "cft"):
            setattr(self, name, np.repeat(getattr(self, name), times, axis=0))
        self.knee_sign = np.repeat(self.knee_sign, times)
        for name in ("direction", "zero_offset", "lower", "upper", "_mid", "_half_range"):
            per_leg = getattr(self, name).reshape(self.n_legs, 3)
            setattr(self, name, np.repeat(per_leg, times, axis=0).reshape(-1))
        self.leg_names = [name for name in self.leg_names for _ in range(times)]
        self.n_legs *= times
        self.n_joints *= times

    @functools.cached_property
    def _leg_frames(self) -> list[tuple]:
        """Per leg, for ``ik_feet``: its form, mount, yaw's cosine and sine, links and knee
        sign as floats (built on first use: a planner's many-leg Kinematics never needs them)."""
        return [
            (cft, *mount.tolist(), cy, sy, *links.tolist(), ks)
            for cft, mount, cy, sy, links, ks in zip(
                self.cft.tolist(),
                self.mount,
                self.cos_yaw.tolist(),
                self.sin_yaw.tolist(),
                np.column_stack((self.l1, self.l2, self.l3)),
                self.knee_sign.tolist(),
                strict=True,
            )
        ]

    @functools.cached_property
    def _leg_joints(self) -> list[list[float]]:
        """Per leg, for ``ik_feet``: each joint's direction and zero offset."""
        return np.stack([self.direction, self.zero_offset], 1).reshape(-1, 6).tolist()

    @functools.cached_property
    def _leg_limits(self) -> list[list[float]]:
        """Per leg, for ``ik_feet``: each joint's mid-range and half range (with tolerance)."""
        return np.stack([self._mid, self._half_range], 1).reshape(-1, 6).tolist()

    # --- joint <-> kinematic angles ---------------------------------------------------

    def to_theta(self, q: np.ndarray) -> np.ndarray:
        """Kinematic angles (n_legs, 3) from a joint vector in the profile's convention."""
        q = np.asarray(q, float)
        return ((q - self.zero_offset) * self.direction).reshape(self.n_legs, 3)

    def to_q(self, theta: np.ndarray) -> np.ndarray:
        """Joint vector (n_joints,) from kinematic angles (n_legs, 3)."""
        return np.reshape(theta, -1) * self.direction + self.zero_offset

    # --- frames -----------------------------------------------------------------------

    def to_leg(self, feet: np.ndarray) -> np.ndarray:
        """Body-frame points (n_legs, 3) into each leg's frame."""
        d = np.asarray(feet, float) - self.mount
        c, s = self.cos_yaw, self.sin_yaw
        out = np.empty_like(d)
        out[:, 0] = c * d[:, 0] + s * d[:, 1]
        out[:, 1] = c * d[:, 1] - s * d[:, 0]
        out[:, 2] = d[:, 2]
        return out

    def to_body(self, feet_leg: np.ndarray) -> np.ndarray:
        """Leg-frame points (n_legs, 3) into the body frame."""
        c, s = self.cos_yaw, self.sin_yaw
        out = np.array(self.mount)
        out[:, 0] += c * feet_leg[:, 0] - s * feet_leg[:, 1]
        out[:, 1] += s * feet_leg[:, 0] + c * feet_leg[:, 1]
        out[:, 2] += feet_leg[:, 2]
        return out

    def _by_kind(self, cft, ats, *args):
        """Evaluate the coxa-femur-tibia and/or abduction-thigh-shank form, as the legs need."""
        if self.all_cft:
            return cft(*args)
        if not self.cft.any():
            return ats(*args)
        a, b = cft(*args), ats(*args)
        return tuple(
            np.where(self.cft.reshape(-1, *[1] * (x.ndim - 1)), x, y)
            for x, y in zip(a, b, strict=True)
        )

    # --- forward kinematics -----------------------------------------------------------

    def fk_leg(self, theta: np.ndarray) -> np.ndarray:
        """Feet in their leg frames (n_legs, 3) from kinematic angles (n_legs, 3)."""
        return self._by_kind(self._fk_cft, self._fk_ats, theta)[0]

    def _fk_cft(self, theta: np.ndarray) -> tuple[np.ndarray]:
        gamma, alpha, beta = theta[:, 0], theta[:, 1], theta[:, 2]
        l2, l3 = self.l2, self.l3
        r = self.l1 + l2 * np.cos(alpha) + l3 * np.cos(alpha + beta)
        z = l2 * np.sin(alpha) + l3 * np.sin(alpha + beta)
        return (np.stack([r * np.cos(gamma), r * np.sin(gamma), z], 1),)

    def _fk_ats(self, theta: np.ndarray) -> tuple[np.ndarray]:
        """Paper 004 eqs. 1-3 in our leg frame."""
        ta, tt, ts = theta[:, 0], theta[:, 1], theta[:, 2]
        l2, l3 = self.l2, self.l3
        rho = l2 * np.sin(tt) + l3 * np.sin(ts)
        x = self.l1 + l2 * np.cos(tt) + l3 * np.cos(ts)
        return (np.stack([x, rho * np.sin(ta), -rho * np.cos(ta)], 1),)

    def fk(self, q: np.ndarray) -> np.ndarray:
        """Feet in the body frame (n_legs, 3) from a joint vector (n_joints,)."""
        return self.to_body(self.fk_leg(self.to_theta(q)))

    def link_frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each leg's chain of link frames from a joint vector (n_joints,): translations
        (n_legs, 4, 3) and unit quaternions (w, x, y, z), shape (n_legs, 4, 4), each frame
        relative to the one before it (the first relative to the body).

        Frame k (k = 0, 1, 2) sits on joint k's axis with x along the link it moves (length
        ``links[k]``); frame 3 is the foot, ``links[2]`` along x of frame 2, with frame 2's
        orientation. ``coxa_femur_tibia``: Rz(yaw + gamma), then Ry(-alpha), Ry(-beta).
        ``abduction_thigh_shank``: Rz(yaw) Rx(theta_a), then Ry(theta_t), Ry(theta_s -
        theta_t). Chaining them puts frame 3 at ``fk(q)``; a NaN joint gives NaN frames.
        """
        theta = self.to_theta(q)
        cft = self.cft
        yaw_angle = self.yaw + np.where(cft, theta[:, 0], 0.0)
        roll_angle = np.where(cft, 0.0, theta[:, 0])
        pitch_1 = np.where(cft, -theta[:, 1], theta[:, 1])
        pitch_2 = np.where(cft, -theta[:, 2], theta[:, 2] - theta[:, 1])
        cz, sz = np.cos(yaw_angle / 2), np.sin(yaw_angle / 2)
        cx, sx = np.cos(roll_angle / 2), np.sin(roll_angle / 2)
        quat = np.zeros((self.n_legs, 4, 4))
        quat[:, 0] = np.stack([cz * cx, cz * sx, sz * sx, sz * cx], 1)
        quat[:, 1, 0], quat[:, 1, 2] = np.cos(pitch_1 / 2), np.sin(pitch_1 / 2)
        quat[:, 2, 0], quat[:, 2, 2] = np.cos(pitch_2 / 2), np.sin(pitch_2 / 2)
        quat[:, 3, 0] = 1.0
        trans = np.zeros((self.n_legs, 4, 3))
        trans[:, 0] = self.mount
        trans[:, 1, 0], trans[:, 2, 0], trans[:, 3, 0] = self.l1, self.l2, self.l3
        return trans, quat

    def link_points(self, q: np.ndarray) -> np.ndarray:
        """Each leg's joint axes' origins and foot in the body frame, (n_legs, 4, 3): the
        mount, the second and third joints and the foot, chained from ``link_frames``; the
        segments between them are the coxa (or abduction link), femur (thigh) and tibia
        (shank)."""
        trans, quats = self.link_frames(q)
        points = np.empty((self.n_legs, 4, 3))
        for leg in range(self.n_legs):
            p, r = np.zeros(3), np.eye(3)
            for k in range(4):
                p = p + r @ trans[leg, k]
                r = r @ rotation(quats[leg, k])
                points[leg, k] = p
        return points

    # --- inverse kinematics -----------------------------------------------------------

    def ik_leg(self, feet_leg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Kinematic angles (n_legs, 3) and a geometric-reachability mask from leg-frame feet."""
        return self._by_kind(self._ik_cft, self._ik_ats, feet_leg)

    def _ik_cft(self, feet_leg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x, y, z = feet_leg[:, 0], feet_leg[:, 1], feet_leg[:, 2]
        alpha, beta, ok = _two_link(np.hypot(x, y) - self.l1, z, self.l2, self.l3, self.knee_sign)
        return np.stack([np.arctan2(y, x), alpha, beta], 1), ok

    def _ik_ats(self, feet_leg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The thigh plane holds (x - l1, rho), rho = hypot(y, z) pointing down the leg."""
        x, y, z = feet_leg[:, 0], feet_leg[:, 1], feet_leg[:, 2]
        rho = np.hypot(y, z)
        theta_t, rel, ok = _two_link(x - self.l1, rho, self.l2, self.l3, self.knee_sign)
        return np.stack([np.arctan2(y, -z), theta_t, theta_t + rel], 1), ok

    def ik(self, feet: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Joint vector (n_joints,) and per-leg reachable mask from body-frame feet (n_legs, 3).

        A leg is unreachable when its foot is outside the workspace (its joints are NaN) or
        when the solution breaks a joint's position limits (its joints hold that solution).
        """
        theta, ok = self.ik_leg(self.to_leg(feet))
        q = theta.reshape(-1) * self.direction + self.zero_offset
        inside = (np.abs(q - self._mid) <= self._half_range).reshape(self.n_legs, 3).all(1)
        if ok.all():
            return q, inside
        q.reshape(self.n_legs, 3)[~ok] = np.nan
        return q, ok & inside

    def ik_feet(self, feet: Sequence[Sequence[float]]) -> tuple[list[float], list[bool]]:
        """``ik`` leg by leg with ``math`` for one set of body-frame feet (the control tick).

        Same joints (to rounding) and reachable mask as ``ik``; feet must be finite.
        """
        q: list[float] = []
        ok: list[bool] = []
        for (fx, fy, fz), frame, joints, limits in zip(
            feet, self._leg_frames, self._leg_joints, self._leg_limits, strict=True
        ):
            cft, mx, my, mz, c, s, l1, l2, l3, k = frame
            d0, o0, d1, o1, d2, o2 = joints
            m0, h0, m1, h1, m2, h2 = limits
            dx, dy = fx - mx, fy - my
            x, y, z = c * dx + s * dy, c * dy - s * dx, fz - mz
            if cft:
                u, w, first = math.hypot(x, y) - l1, z, math.atan2(y, x)
            else:
                u, w, first = x - l1, math.hypot(y, z), math.atan2(y, -z)
            cos_rel = (u * u + w * w - (l2 * l2 + l3 * l3)) / (2.0 * l2 * l3)
            if abs(cos_rel) > 1.0 + EXTENSION_TOLERANCE:
                q += (math.nan, math.nan, math.nan)
                ok.append(False)
                continue
            rel = k * math.acos(max(-1.0, min(1.0, cos_rel)))
            second = math.atan2(w, u) - math.atan2(l3 * math.sin(rel), l2 + l3 * math.cos(rel))
            q0 = first * d0 + o0
            q1 = second * d1 + o1
            q2 = (rel if cft else second + rel) * d2 + o2
            q += (q0, q1, q2)
            ok.append(abs(q0 - m0) <= h0 and abs(q1 - m1) <= h1 and abs(q2 - m2) <= h2)
        return q, ok

    # --- differential kinematics ------------------------------------------------------

    def jacobian_leg(self, theta: np.ndarray) -> np.ndarray:
        """d(foot_leg)/d(theta), shape (n_legs, 3, 3), columns in joint order."""
        return self._by_kind(self._jacobian_cft, self._jacobian_ats, theta)[0]

    def _jacobian_cft(self, theta: np.ndarray) -> tuple[np.ndarray]:
        gamma, alpha, beta = theta[:, 0], theta[:, 1], theta[:, 2]
        l2, l3 = self.l2, self.l3
        cg, sg = np.cos(gamma), np.sin(gamma)
        ab = alpha + beta
        r = self.l1 + l2 * np.cos(alpha) + l3 * np.cos(ab)
        z = l2 * np.sin(alpha) + l3 * np.sin(ab)
        dr_beta = -l3 * np.sin(ab)
        dz_beta = l3 * np.cos(ab)
        jac = np.zeros((self.n_legs, 3, 3))  # element by element: np.stack costs more here
        jac[:, 0, 0], jac[:, 0, 1], jac[:, 0, 2] = -r * sg, -z * cg, dr_beta * cg
        jac[:, 1, 0], jac[:, 1, 1], jac[:, 1, 2] = r * cg, -z * sg, dr_beta * sg
        jac[:, 2, 1], jac[:, 2, 2] = l2 * np.cos(alpha) + dz_beta, dz_beta
        return (jac,)

    def _jacobian_ats(self, theta: np.ndarray) -> tuple[np.ndarray]:
        """Paper 004 eq. 4 in our leg frame and joint order (abduction, thigh, shank)."""
        ta, tt, ts = theta[:, 0], theta[:, 1], theta[:, 2]
        l2, l3 = self.l2, self.l3
        ca, sa = np.cos(ta), np.sin(ta)
        st, ss = l2 * np.sin(tt), l3 * np.sin(ts)
        rho = st + ss
        tc, sc = l2 * np.cos(tt), l3 * np.cos(ts)
        jac = np.zeros((self.n_legs, 3, 3))  # element by element: np.stack costs more here
        jac[:, 0, 1], jac[:, 0, 2] = -st, -ss
        jac[:, 1, 0], jac[:, 1, 1], jac[:, 1, 2] = rho * ca, tc * sa, sc * sa
        jac[:, 2, 0], jac[:, 2, 1], jac[:, 2, 2] = rho * sa, -tc * ca, -sc * ca
        return (jac,)

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """d(foot_body)/dq per leg, shape (n_legs, 3, 3), in the joints' own convention."""
        jac = self.rot @ self.jacobian_leg(self.to_theta(q))
        return jac * self.direction.reshape(self.n_legs, 1, 3)

    def foot_forces(self, q: np.ndarray, tau: np.ndarray, min_det: float = 1e-12) -> np.ndarray:
        """Foot forces (n_legs, 3) in the body frame from joint torques: F = (J^T)^-1 tau.

        Paper 004 eq. 5: F is the force the foot exerts on its contact (the contact pushes
        back with -F). Legs at a singular pose (|det J| < ``min_det``) get NaN.
        """
        jt = np.swapaxes(self.jacobian(q), 1, 2)
        tau = np.asarray(tau, float).reshape(self.n_legs, 3)
        singular = np.abs(np.linalg.det(jt)) < min_det
        jt[singular] = np.eye(3)
        forces = np.linalg.solve(jt, tau[..., None])[..., 0]
        forces[singular] = np.nan
        return forces

    # --- standing pose ----------------------------------------------------------------

    def stand_feet(self, body_height: float | None = None) -> np.ndarray:
        """Standing feet (n_legs, 3): ``foot_reach`` along each mount yaw, ``body_height`` down."""
        stand = self.profile.stand
        height = stand.body_height if body_height is None else body_height
        feet_leg = np.zeros((self.n_legs, 3))
        feet_leg[:, 0] = stand.foot_reach
        feet = self.to_body(feet_leg)
        feet[:, 2] = -height
        return feet

    def stand_joints(self) -> np.ndarray:
        """Joint vector of the standing pose; KinematicsError if a leg cannot reach it."""
        q, ok = self.ik(self.stand_feet())
        if not ok.all():
            bad = [n for n, good in zip(self.leg_names, ok, strict=True) if not good]
            raise KinematicsError(
                f"{self.profile.source or self.profile.name}: $.stand: legs {bad} cannot reach "
                f"the stand pose (body_height={self.profile.stand.body_height}, "
                f"foot_reach={self.profile.stand.foot_reach}) within their joint limits"
            )
        return q
