"""Paper 004 eq. 5 both ways, leg by leg with ``math``: foot forces from joint torques (the
estimator) and joint torques from foot forces (the gravity feed-forward), each with the legs'
own weight, at 1 kHz.

For six 3 x 3 systems a tick numpy's per-call overhead costs several times the arithmetic (as
for ``Kinematics.ik_feet``); ``Kinematics.fk``, ``jacobian`` and ``foot_forces`` are the
vectorised forms these agree with.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

from climbd.daemon.algorithms.kinematics import CFT, Kinematics

Vector = tuple[float, float, float]
Matrix = tuple[float, float, float, float, float, float, float, float, float]
"""A 3 x 3 matrix, row-major."""


class LegStatics(NamedTuple):
    """Every leg at one joint vector: foot (body frame), foot Jacobian d(foot)/dq (body frame,
    joints' own convention) and the weight Jacobian sum_i m_i J_i of the leg's link centres."""

    feet: list[Vector]
    jacobians: list[Matrix]
    weight_jacobians: list[Matrix] | None


def _jacobian(cft: bool, trig: Vector, lengths: Vector, frame: Vector) -> Matrix:
    """Foot Jacobian of one leg in the body frame (eq. 4 for abduction-thigh-shank legs) from
    the leg's sines and cosines ``trig`` = (c0, s0, c1, s1, c2, s2), its link ``lengths`` and
    ``frame`` = (cos yaw, sin yaw, d0, d1, d2) with the joints' directions."""
    c0, s0, c1, s1, c2, s2 = trig
    l1, l2, l3 = lengths
    c, s, d0, d1, d2 = frame
    if cft:  # c2, s2: of alpha + beta
        r = l1 + l2 * c1 + l3 * c2
        z = l2 * s1 + l3 * s2
        dr, dz = -l3 * s2, l3 * c2
        a = (-r * s0, -z * c0, dr * c0)
        b = (r * c0, -z * s0, dr * s0)
        e = (0.0, l2 * c1 + dz, dz)
    else:
        st, ss, tc, sc = l2 * s1, l3 * s2, l2 * c1, l3 * c2
        rho = st + ss
        a = (0.0, -st, -ss)
        b = (rho * c0, tc * s0, sc * s0)
        e = (rho * s0, -tc * c0, -sc * c0)
    return (
        (c * a[0] - s * b[0]) * d0,
        (c * a[1] - s * b[1]) * d1,
        (c * a[2] - s * b[2]) * d2,
        (s * a[0] + c * b[0]) * d0,
        (s * a[1] + c * b[1]) * d1,
        (s * a[2] + c * b[2]) * d2,
        e[0] * d0,
        e[1] * d1,
        e[2] * d2,
    )


def dot(a: Sequence[float], b: Sequence[float]) -> float:
    """a · b of two 3-vectors."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def rotate(rows: Sequence[Sequence[float]], v: Sequence[float]) -> list[float]:
    """R v for R given by its rows."""
    return [dot(row, v) for row in rows]


def transpose_times(m: Matrix, v: Vector) -> Vector:
    """mᵀ v."""
    return (
        m[0] * v[0] + m[3] * v[1] + m[6] * v[2],
        m[1] * v[0] + m[4] * v[1] + m[7] * v[2],
        m[2] * v[0] + m[5] * v[1] + m[8] * v[2],
    )


def solve_transposed(m: Matrix, b: Vector, min_det: float) -> Vector:
    """x with mᵀ x = b: x = C b / det m, C the cofactor matrix (rows r1 × r2, r2 × r0, r0 × r1);
    NaN where |det m| < ``min_det`` (a singular leg)."""
    a0, a1, a2, b0, b1, b2, e0, e1, e2 = m
    c0 = (b1 * e2 - b2 * e1, b2 * e0 - b0 * e2, b0 * e1 - b1 * e0)
    c1 = (e1 * a2 - e2 * a1, e2 * a0 - e0 * a2, e0 * a1 - e1 * a0)
    c2 = (a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0)
    det = a0 * c0[0] + a1 * c0[1] + a2 * c0[2]
    if not abs(det) >= min_det:
        return (math.nan, math.nan, math.nan)
    x, y, z = b
    return (
        (c0[0] * x + c0[1] * y + c0[2] * z) / det,
        (c1[0] * x + c1[1] * y + c1[2] * z) / det,
        (c2[0] * x + c2[1] * y + c2[2] * z) / det,
    )


def link_weights(link_masses: Sequence[float]) -> Vector:
    """Per link, half its own mass plus the masses beyond it: the Jacobian is linear in the
    link lengths, so sum_i m_i J_i is the Jacobian of the leg with link j scaled by weight j."""
    m1, m2, m3 = link_masses
    return (m1 / 2 + m2 + m3, m2 / 2 + m3, m3 / 2)


class Statics:
    """Eq. 5 for every leg of ``kin``'s profile, with links of ``link_masses`` (kg, centres at
    mid-link; empty: massless legs)."""

    def __init__(self, kin: Kinematics, link_masses: Sequence[float] = ()) -> None:
        if link_masses and len(link_masses) != 3:
            raise ValueError(f"estimator link_masses: expected 3 values, found {link_masses}")
        self.link_masses = list(link_masses)
        self._legs = []
        for i, leg in enumerate(kin.profile.legs):
            d = kin.direction[3 * i : 3 * i + 3].tolist()
            lengths = (float(kin.l1[i]), float(kin.l2[i]), float(kin.l3[i]))
            weighted = None
            if link_masses:
                weights = link_weights(link_masses)
                weighted = tuple(w * x for w, x in zip(weights, lengths, strict=True))
            frame = (float(kin.cos_yaw[i]), float(kin.sin_yaw[i]), *d)
            mount = tuple(kin.mount[i].tolist())
            offsets = tuple(kin.zero_offset[3 * i : 3 * i + 3].tolist())
            self._legs.append((leg.kind == CFT, mount, lengths, weighted, frame, offsets))

    def at(self, q: Sequence[float]) -> LegStatics:
        """Feet and Jacobians of every leg at joints ``q`` (profile order)."""
        feet: list[Vector] = []
        jacobians: list[Matrix] = []
        weight_jacobians: list[Matrix] | None = [] if self.link_masses else None
        for i, (cft, mount, lengths, weighted, frame, offsets) in enumerate(self._legs):
            c, s, d0, d1, d2 = frame
            t0 = (q[3 * i] - offsets[0]) * d0
            t1 = (q[3 * i + 1] - offsets[1]) * d1
            t2 = (q[3 * i + 2] - offsets[2]) * d2
            last = t1 + t2 if cft else t2
            trig = (math.cos(t0), math.sin(t0), math.cos(t1), math.sin(t1))
            trig += (math.cos(last), math.sin(last))
            c0, s0, c1, s1, c2, s2 = trig
            l1, l2, l3 = lengths
            if cft:
                r = l1 + l2 * c1 + l3 * c2
                x, y, z = r * c0, r * s0, l2 * s1 + l3 * s2
            else:
                rho = l2 * s1 + l3 * s2
                x, y, z = l1 + l2 * c1 + l3 * c2, rho * s0, -rho * c0
            feet.append((mount[0] + c * x - s * y, mount[1] + s * x + c * y, mount[2] + z))
            jacobians.append(_jacobian(cft, trig, lengths, frame))
            if weight_jacobians is not None:
                weight_jacobians.append(_jacobian(cft, trig, weighted, frame))
        return LegStatics(feet, jacobians, weight_jacobians)

    def foot_forces(
        self, legs: LegStatics, tau: Sequence[float], gravity: Vector, min_det: float = 1e-12
    ) -> list[Vector]:
        """Eq. 5 with the legs' own weight removed: F = (Jᵀ)⁻¹ (tau + sum_i J_iᵀ m_i g), the
        force each foot exerts on its contact (body frame; ``gravity`` in the body frame)."""
        forces = []
        weights = legs.weight_jacobians
        for i, jac in enumerate(legs.jacobians):
            b = (tau[3 * i], tau[3 * i + 1], tau[3 * i + 2])
            if weights is not None:
                w = transpose_times(weights[i], gravity)
                b = (b[0] + w[0], b[1] + w[1], b[2] + w[2])
            forces.append(solve_transposed(jac, b, min_det))
        return forces

    def torques(self, legs: LegStatics, pushes: Sequence[Vector], gravity: Vector) -> list[float]:
        """Eq. 5 inverted: tau = Jᵀ F - sum_i J_iᵀ m_i g per leg, F the force ``pushes`` asks
        each foot to exert (body frame), flattened in joint order."""
        tau: list[float] = []
        weights = legs.weight_jacobians
        for i, jac in enumerate(legs.jacobians):
            t = transpose_times(jac, pushes[i])
            if weights is not None:
                w = transpose_times(weights[i], gravity)
                t = (t[0] - w[0], t[1] - w[1], t[2] - w[2])
            tau += t
        return tau
