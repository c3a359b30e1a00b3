"""Tumble Stability Margin (Yoneda & Hirose 1996, paper 001 ref. [15]) with grip forces.

For every edge of the support polygon (a tumble axis), the moment about the axis of the
resultant external force at the CoM plus the largest moment the grippers off that axis can
resist with (holding force × their distance from the axis), divided by the force's magnitude:
a length (m). The margin is the smallest over the axes; negative means the robot tumbles.
"""

from __future__ import annotations

import numpy as np


def ordered(contacts: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Contacts sorted counter-clockwise about ``normal`` (seen from the robot's side)."""
    centre = contacts.mean(axis=0)
    e1 = np.cross(normal, [1.0, 0.0, 0.0])
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.cross(normal, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    rel = contacts - centre
    return contacts[np.argsort(np.arctan2(rel @ e2, rel @ e1))]


def tumble_stability_margin(
    com: np.ndarray,
    contacts: np.ndarray,
    force: np.ndarray,
    grip_force: float,
    normal: np.ndarray,
) -> float:
    """TSM (m) of gripping ``contacts`` (k×3) under ``force`` (N, e.g. m·g) acting at ``com``.

    ``normal`` points from the wall towards the robot; ``grip_force`` (N) is each gripper's
    holding force, resisting about every axis it is not on.
    """
    if len(contacts) < 2:
        return -np.inf
    p = ordered(np.asarray(contacts, float), np.asarray(normal, float))
    q = np.roll(p, -1, axis=0)
    axis = q - p
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    gravity = np.einsum("ij,ij->i", np.cross(force, com - p), axis)
    rel = p[None, :, :] - p[:, None, :]
    along = np.einsum("ikj,ij->ik", rel, axis)
    distance = np.linalg.norm(rel - along[..., None] * axis[:, None, :], axis=2)
    grip = grip_force * distance.sum(axis=1)
    return float(np.min((gravity + grip) / np.linalg.norm(force)))
