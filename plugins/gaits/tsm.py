"""Tumble Stability Margin (Yoneda & Hirose 1996, paper 001 ref. [15]) with grip forces.

For every edge of the support polygon (a tumble axis), the moment about the axis of the
resultant external force at the CoM plus the largest moment the grippers off that axis can
resist with (holding force × their distance from the axis), divided by the force's magnitude:
a length (m). The margin is the smallest over the axes; negative means the robot tumbles.
"""

from __future__ import annotations

import numpy as np


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b over the last axis (length 3): np.cross without its axis handling, which costs
    more than the product on the few vectors here (the TSM runs for every planned step)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return np.stack(
        (
            a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
            a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
        ),
        axis=-1,
    )


def ordered(contacts: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Contacts (…, k, 3) sorted counter-clockwise about ``normal`` (seen from the robot's
    side), each stance of the leading axes on its own."""
    centre = contacts.mean(axis=-2, keepdims=True)
    e1 = cross(normal, [1.0, 0.0, 0.0])
    if np.linalg.norm(e1) < 1e-6:
        e1 = cross(normal, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = cross(normal, e1)
    rel = contacts - centre
    order = np.argsort(np.arctan2(rel @ e2, rel @ e1), axis=-1)
    return np.take_along_axis(contacts, order[..., None], axis=-2)


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
    com = np.asarray(com, float)[None]
    return float(tumble_stability_margins(com, contacts, force, grip_force, normal)[0])


def tumble_stability_margins(
    coms: np.ndarray,
    contacts: np.ndarray,
    force: np.ndarray,
    grip_force: float,
    normal: np.ndarray,
) -> np.ndarray:
    """TSM (m) for each CoM of ``coms`` (n×3) over the same contacts, force and grips (see
    ``tumble_stability_margin``): the support polygon's axes are worked out once."""
    coms, contacts = np.asarray(coms, float), np.asarray(contacts, float)
    return stance_margins(coms[None], contacts[None], force, grip_force, normal)[0]


def stance_margins(
    coms: np.ndarray,
    contacts: np.ndarray,
    force: np.ndarray,
    grip_force: float,
    normal: np.ndarray,
) -> np.ndarray:
    """TSM (m, shaped m×n) of CoMs (m×n×3) over m stances of k gripping contacts each
    (m×k×3), in one vectorised pass (a planner checks many candidate swings at once)."""
    coms, contacts = np.asarray(coms, float), np.asarray(contacts, float)
    if contacts.shape[1] < 2:
        return np.full(coms.shape[:2], -np.inf)
    p = ordered(contacts, np.asarray(normal, float))  # (m, k, 3)
    q = np.roll(p, -1, axis=1)
    axis = q - p
    axis /= np.linalg.norm(axis, axis=2, keepdims=True)
    arm = coms[:, :, None, :] - p[:, None, :, :]  # (m, n, k, 3)
    gravity = np.einsum("mnkj,mkj->mnk", cross(force, arm), axis)
    rel = p[:, None, :, :] - p[:, :, None, :]  # (m, k axis, k contact, 3)
    along = np.einsum("mikj,mij->mik", rel, axis)
    distance = np.linalg.norm(rel - along[..., None] * axis[:, :, None, :], axis=3)
    grip = grip_force * distance.sum(axis=2)  # (m, k)
    return np.min((gravity + grip[:, None, :]) / np.linalg.norm(force), axis=2)
