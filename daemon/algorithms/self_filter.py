"""The self filter: depth pixels that see the robot's own legs, dropped before perception.

A body camera looks down past the front legs. A plugin that stitches those pixels into its map
takes a link for terrain: the stairs plugin made a fourth 'step' of Qingzhui's middle-front
thigh, a quarter of the front camera's pixels 6-25 cm away. As robot_self_filter does for ROS
with link meshes, every pixel whose point lies within ``radius`` of a leg link's axis (the
segment from joint to joint, and on to the foot's centre) at the measured joint angles gets
depth 0 (no return). Each link is tested only over the pixels of its bounding box in the image,
so a frame costs the pixels near the legs, not the whole image.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from collections import deque

import msgspec
import numpy as np

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.hardware import DepthFrame, Intrinsics
from climbd.daemon.contract.units import NonNegative, Positive

NO_JOINTS = "no_joints"
"""The refusal counted for a frame with no joint reading within ``max_age`` of its stamp."""
SPAN = 1.0
"""s of joint readings kept: beyond a camera's and the network's delay."""
NEAR = 0.02
"""m: links are clipped to this depth in front of the camera before they are projected."""


class SelfFilterConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True, frozen=True):
    """``radius`` (m): a point this close to a leg link's axis is the robot's (the link's own
    radius plus the joint readings' and the mount's error); 0 turns the filter off.
    ``max_age`` (s): the joint reading used is the one nearest the frame's stamp; a frame with
    none this close is refused, since where the legs are in it is not known."""

    radius: NonNegative = 0.0
    max_age: Positive = 0.1


class SelfFilter:
    """Zeroes a depth frame's pixels within ``radius`` of the legs at joint vector ``q``."""

    def __init__(self, kinematics: Kinematics, radius: float) -> None:
        self.kinematics = kinematics
        self.radius = radius

    def links(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Start and end of every leg link in the body frame, (3 × n_legs, 3) each."""
        points = self.kinematics.link_points(q)
        return points[:, :-1].reshape(-1, 3), points[:, 1:].reshape(-1, 3)

    def mask(self, frame: DepthFrame, q: np.ndarray) -> np.ndarray:
        """Boolean (H, W): the pixels with a return that see a leg (a link with a NaN joint is
        skipped)."""
        starts, ends = self.links(q)
        rot, origin = frame.extrinsics[:3, :3], frame.extrinsics[:3, 3]
        a = (starts - origin) @ rot  # body -> optical: R^T (p - t)
        b = (ends - origin) @ rot
        i = frame.intrinsics
        depth = frame.depth
        hit = np.zeros(depth.shape, bool)
        r = self.radius
        for p, s in zip(a, b, strict=True):
            box = self._box(p, s, i)
            if box is None:
                continue
            u0, u1, v0, v1 = box
            raw = depth[v0:v1, u0:u1]
            z = raw * frame.depth_scale
            u = (np.arange(u0, u1) - i.ppx) / i.fx
            v = (np.arange(v0, v1) - i.ppy) / i.fy
            x, y = u[None, :] * z, v[:, None] * z
            d = s - p
            t = ((x - p[0]) * d[0] + (y - p[1]) * d[1] + (z - p[2]) * d[2]) / max(d @ d, 1e-12)
            t = np.clip(t, 0.0, 1.0)
            dx, dy, dz = x - p[0] - t * d[0], y - p[1] - t * d[1], z - p[2] - t * d[2]
            near = (dx * dx + dy * dy + dz * dz <= r * r) & (raw > 0)
            hit[v0:v1, u0:u1] |= near
        return hit

    def _box(self, p: np.ndarray, s: np.ndarray, i: Intrinsics) -> tuple[int, int, int, int] | None:
        """Pixel bounds (u0, u1, v0, v1) of the link from optical-frame ``p`` to ``s`` widened
        by the radius at its nearest depth, or None when it is off the image or within
        ``NEAR`` of the lens plane or behind it (closer than any depth camera's least range)."""
        r = self.radius
        if not (np.isfinite(p).all() and np.isfinite(s).all()):
            return None
        if p[2] < NEAR and s[2] < NEAR:
            return None
        ends = []
        for e, o in ((p, s), (s, p)):
            if e[2] >= NEAR:
                ends.append(e)
            else:  # clip the link where it crosses the near plane
                ends.append(e + (o - e) * (NEAR - e[2]) / (o[2] - e[2]))
        ends = np.array(ends)
        zmin = max(ends[:, 2].min() - r, NEAR)
        us = ends[:, 0] / ends[:, 2] * i.fx + i.ppx
        vs = ends[:, 1] / ends[:, 2] * i.fy + i.ppy
        pad_u, pad_v = r * i.fx / zmin, r * i.fy / zmin
        u0 = max(int(math.floor(us.min() - pad_u)), 0)
        u1 = min(int(math.ceil(us.max() + pad_u)) + 1, i.width)
        v0 = max(int(math.floor(vs.min() - pad_v)), 0)
        v1 = min(int(math.ceil(vs.max() + pad_v)) + 1, i.height)
        if u0 >= u1 or v0 >= v1:
            return None
        return u0, u1, v0, v1

    def apply(self, frame: DepthFrame, q: np.ndarray) -> tuple[DepthFrame, int]:
        """``frame`` with the pixels that see a leg zeroed, and how many there were."""
        hit = self.mask(frame, q)
        count = int(hit.sum())
        if not count:
            return frame, 0
        depth = frame.depth.copy()
        depth[hit] = 0
        return dataclasses.replace(frame, depth=depth), count


class JointHistory:
    """Joint vectors (profile order) of the last ``SPAN`` seconds by stamp; not thread-safe."""

    def __init__(self) -> None:
        self._stamps: deque[float] = deque()
        self._positions: deque[np.ndarray] = deque()

    def add(self, stamp: float, position: np.ndarray) -> None:
        """Keep a reading; one not newer than the newest kept restarts the history (a restarted
        clock) unless it is within the span of it (a reordered reading: dropped)."""
        if self._stamps and stamp <= self._stamps[-1]:
            if stamp > self._stamps[-1] - SPAN:
                return
            self._stamps.clear()
            self._positions.clear()
        self._stamps.append(stamp)
        self._positions.append(position)
        while self._stamps[0] < stamp - SPAN:
            self._stamps.popleft()
            self._positions.popleft()

    def at(self, stamp: float, max_age: float) -> np.ndarray | None:
        """The reading nearest ``stamp``, or None when none is within ``max_age`` of it."""
        k = bisect.bisect_left(self._stamps, stamp)
        near = [j for j in (k - 1, k) if 0 <= j < len(self._stamps)]
        if not near:
            return None
        best = min(near, key=lambda j: abs(self._stamps[j] - stamp))
        if not abs(self._stamps[best] - stamp) <= max_age:
            return None
        return self._positions[best]
