"""A kinematic world for the joist behaviour: joists on the ground and a perception oracle.

The robot's true pose is the behaviour's own dead reckoning (feet never slip here), and the
oracle reports each joist as joist perception would: its near top edge clipped to the 1 m ×
1.2 m crop box ahead of the body, distance along the heading, signed yaw, height. ``mapped``
folds what it reports into the world model's joist map, which the behaviour reads.
"""

from __future__ import annotations

import math

import msgspec
import numpy as np

from climbd.daemon.algorithms.feature_maps import JoistTracks
from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.messages import BodyState, Joist, JoistMap, Joists
from support.joist_scenes import JoistSpec

CROP = (0.1, 1.1, 0.6)


def _rot(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s], [s, c]])


def perceive(joists: list[JoistSpec], pose: np.ndarray, stamp: float) -> Joists:
    """Joists message of what a robot at ``pose`` (x, y, yaw) sees inside the crop box."""
    out = []
    x0, x1, half = CROP
    for spec in joists:
        n = np.array([math.cos(spec.yaw), math.sin(spec.yaw)])
        u = np.array([-n[1], n[0]])
        centre = np.array([spec.distance, 0.0])
        ends = [centre + s * u * spec.length / 2 for s in (-1.0, 1.0)]
        body = [_rot(-pose[2]) @ (e - pose[:2]) for e in ends]
        a, b = body
        ts = np.linspace(0.0, 1.0, 801)
        pts = a[None, :] + ts[:, None] * (b - a)[None, :]
        inside = (pts[:, 0] >= x0) & (pts[:, 0] <= x1) & (np.abs(pts[:, 1]) <= half)
        if inside.sum() < 10:
            continue
        seg = pts[inside]
        nb = _rot(-pose[2]) @ n
        y_path = float(np.clip(0.0, seg[:, 1].min(), seg[:, 1].max()))
        c = float(nb @ seg[0])
        distance = (c - nb[1] * y_path) / nb[0] if abs(nb[0]) > 1e-6 else math.inf
        out.append(
            Joist(
                distance=distance,
                yaw=math.atan2(nb[1], nb[0]),
                height=spec.height,
                endpoints=[[*seg[0], spec.height], [*seg[-1], spec.height]],
                confidence=1.0,
            )
        )
    out.sort(key=lambda j: j.distance)
    return Joists(stamp=stamp, frame_stamp=stamp, joists=out)


def mapped(tracks: JoistTracks, seen: Joists, body: BodyState) -> JoistMap:
    """The world model's joist map once ``seen``, a frame's joists seen from ``body``, is
    folded into ``tracks``: what the behaviour decides from."""
    placed = msgspec.structs.replace(
        seen, frame_position=body.position, frame_orientation=body.orientation
    )
    tracks.update(placed, None)
    return tracks.message(seen.stamp, seen.frame_stamp)


def oracle_map(
    tracks: JoistTracks, joists: list[JoistSpec], pose: np.ndarray, stamp: float
) -> JoistMap:
    """The joist map once what a robot at ``pose`` (x, y, yaw) sees is folded into ``tracks``."""
    return mapped(tracks, perceive(joists, pose, stamp), body_state(pose, stamp))


def world_feet(pose: np.ndarray, body_height: float, feet_body: np.ndarray) -> np.ndarray:
    """Body-frame feet (level body at ``body_height``) on the ground frame (z up from floor)."""
    xy = pose[:2] + (_rot(pose[2]) @ feet_body[:, :2].T).T
    return np.column_stack([xy, feet_body[:, 2] + body_height])


def joist_distance(spec: JoistSpec, points: np.ndarray) -> np.ndarray:
    """Signed distance (m) of ground points from the joist box (negative inside), x-y-z."""
    n = np.array([math.cos(spec.yaw), math.sin(spec.yaw)])
    u = np.array([-n[1], n[0]])
    rel = points[:, :2] - np.array([spec.distance, 0.0])
    s = rel @ n
    along = rel @ u
    z = points[:, 2]
    half = np.array([spec.width / 2, spec.length / 2, spec.height / 2])
    local = np.column_stack([s - spec.width / 2, along, z - spec.height / 2])
    q = np.abs(local) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return outside + inside


def knees(kin: Kinematics, feet_body: np.ndarray) -> np.ndarray:
    """Knee (femur–tibia joint) positions in the body frame for body-frame feet (IK branch)."""
    theta, _ = kin.ik_leg(kin.to_leg(feet_body))
    gamma, alpha = theta[:, 0], theta[:, 1]
    r = kin.l1 + kin.l2 * np.cos(alpha)
    knee_leg = np.column_stack([r * np.cos(gamma), r * np.sin(gamma), kin.l2 * np.sin(alpha)])
    return kin.to_body(knee_leg)


def body_state(pose: np.ndarray, stamp: float = 0.0) -> BodyState:
    return BodyState(
        stamp=stamp,
        position=[float(pose[0]), float(pose[1]), 0.0],
        orientation=[math.cos(pose[2] / 2), 0.0, 0.0, math.sin(pose[2] / 2)],
    )
