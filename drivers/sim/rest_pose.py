"""The twin's belly-down rest pose, from the profile's leg geometry in closed form.

Drivers may not import daemon/algorithms, so this restates, for the one pose the twin needs,
the leg conventions of daemon/algorithms/kinematics.py (tests/test_twin_rest_pose.py checks
the result against that IK). Leg frame: origin at the leg's ``mount``, x along its ``yaw``
(outward), z up. Kinematic angles θ map to joint space as ``q = direction · θ + zero_offset``,
and the joint limits apply to ``q``:

- ``coxa_femur_tibia``: coxa yaw about z, femur elevation above the horizontal (+ up), tibia
  relative to the femur (+ up); knee "a" is knee-up (tibia angle ≤ 0).
- ``abduction_thigh_shank``: abduction about the leg x, thigh and (absolute) shank angles from
  the outward axis (+ down), ``l1`` the abduction-to-thigh offset; knee "a" has the knee above
  the foot line (shank angle ≥ thigh angle).
"""

from __future__ import annotations

import math

import numpy as np

from climbd.daemon.contract.profile import Leg, Profile

LIMIT_TOLERANCE = 1e-9
"""Rounding (rad) allowed past a joint limit, as the daemon's IK allows."""

REACH_STEPS = 12
"""Reaches tried, from the stand's ``foot_reach`` to 95 % of the shortest leg's span."""


def leg_joints(leg: Leg, foot: np.ndarray) -> np.ndarray | None:
    """Joint positions q (3,) putting the foot of ``leg`` at body-frame ``foot``, on the
    profile's knee branch; None when the point is out of reach or breaks a joint limit."""
    cy, sy = math.cos(leg.yaw), math.sin(leg.yaw)
    dx, dy, dz = (float(f) - float(m) for f, m in zip(foot, leg.mount, strict=True))
    x, y, z = cy * dx + sy * dy, cy * dy - sy * dx, dz
    l1, l2, l3 = (float(v) for v in leg.links)
    cft = leg.kind == "coxa_femur_tibia"
    knee = (-1.0 if cft else 1.0) * (1.0 if leg.knee == "a" else -1.0)
    if cft:
        u, w, first = math.hypot(x, y) - l1, z, math.atan2(y, x)
    else:
        u, w, first = x - l1, math.hypot(y, z), math.atan2(y, -z)
    cos_rel = (u * u + w * w - (l2 * l2 + l3 * l3)) / (2.0 * l2 * l3)
    if not abs(cos_rel) <= 1.0:
        return None
    rel = knee * math.acos(cos_rel)
    second = math.atan2(w, u) - math.atan2(l3 * math.sin(rel), l2 + l3 * math.cos(rel))
    theta = (first, second, rel if cft else second + rel)
    q = np.array([t * j.direction + j.zero_offset for t, j in zip(theta, leg.joints, strict=True)])
    for qi, j in zip(q, leg.joints, strict=True):
        lo, hi = j.limits.lower, j.limits.upper
        if abs(qi - 0.5 * (lo + hi)) > 0.5 * (hi - lo) + LIMIT_TOLERANCE:
            return None
    return q


def rest_feet(profile: Profile, reach: float, foot_z: float) -> np.ndarray:
    """Body-frame feet (n_legs, 3): ``reach`` out along each mount yaw, at height ``foot_z``."""
    feet = np.array([leg.mount for leg in profile.legs], float)
    for foot, leg in zip(feet, profile.legs, strict=True):
        foot[0] += math.cos(leg.yaw) * reach
        foot[1] += math.sin(leg.yaw) * reach
    feet[:, 2] = foot_z
    return feet


def rest_reaches(profile: Profile) -> np.ndarray:
    """The reaches tried for the rest pose, nearest first."""
    span = min(sum(leg.links) for leg in profile.legs)
    return np.linspace(profile.stand.foot_reach, 0.95 * span, REACH_STEPS)


def rest_joints(profile: Profile, foot_z: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Joint vector (profile order) and body-frame feet of the nearest reach from the stand's
    ``foot_reach`` outward at which every foot reaches height ``foot_z`` within the joint
    limits; None if no reach does."""
    for reach in rest_reaches(profile):
        feet = rest_feet(profile, float(reach), foot_z)
        legs = [leg_joints(leg, foot) for leg, foot in zip(profile.legs, feet, strict=True)]
        if all(q is not None for q in legs):
            return np.concatenate(legs), feet
    return None
