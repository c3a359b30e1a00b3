"""Grasp targets on the truss (issue #37): where a gripper of the profile's width and clearance
may close on a member, and which legs reach there from the body's pose.

The gripper closed on a member is a ball around its grasp point on the member's axis, of
radius ``envelope`` = max(width / 2, the member's radius): its footprint along the axis and
around the tube. A point of the axis is graspable when the footprint lies on the member and
the ball is at least ``clearance`` from every node (a ball of its ``reach``) and every other
member (a capsule of its radius). The clear stretches of each axis are its spans; grasp
targets are spread along them ``spacing`` apart. The gripper approaches from above (the
direction stays put as the body moves, and a climber stands on the truss), or from the body's
side on a near-upright member. All positions are in the odometry frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import msgspec
import numpy as np

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.messages import (
    BodyState,
    TrussGrasp,
    TrussGrasps,
    TrussMember,
    TrussMembers,
)
from climbd.daemon.contract.profile import GripperConfig
from climbd.daemon.contract.units import Positive

UP = np.array([0.0, 0.0, 1.0])
UPRIGHT = 0.17
"""Sine of the least angle (about 10°) between a member and the vertical for it to be grasped
from above; a member closer to upright is grasped from the body's side."""


class GraspConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``spacing`` (m) between grasp targets along a span; ``resolution`` (m) of the axis
    samples spans are found on; ``node_radius`` (m): the size of a node whose ``reach`` was
    not measured."""

    spacing: Positive = 0.05
    resolution: Positive = 0.002
    node_radius: Positive = 0.03


@dataclass(frozen=True)
class MemberAxis:
    """A member as the gripper meets it: its id, axis ends p0 -> p1 (m) and radius (m)."""

    id: int
    p0: np.ndarray
    p1: np.ndarray
    radius: float

    @classmethod
    def of(cls, member: TrussMember) -> MemberAxis:
        """The tube of a published member."""
        p0, p1 = np.asarray(member.p0, float), np.asarray(member.p1, float)
        return cls(member.id, p0, p1, float(member.radius))

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.p1 - self.p0))

    @property
    def axis(self) -> np.ndarray:
        """Unit direction p0 -> p1."""
        return (self.p1 - self.p0) / self.length

    def at(self, along: np.ndarray) -> np.ndarray:
        """Points (N x 3) ``along`` (m) the axis from p0."""
        return self.p0 + np.multiply.outer(along, self.axis)


@dataclass(frozen=True)
class Obstacles:
    """What a gripper must keep clear of: node centres (K x 3) with radii (K,), members."""

    nodes: np.ndarray
    node_radii: np.ndarray
    tubes: Sequence[MemberAxis]


@dataclass(frozen=True)
class Span:
    """A clear stretch of a member's axis, ``start`` to ``end`` m from its p0."""

    member: MemberAxis
    start: float
    end: float

    def ends(self) -> np.ndarray:
        """The span's two end points (2 x 3)."""
        return self.member.at(np.array([self.start, self.end]))


@dataclass(frozen=True)
class Grasp:
    """A grasp target: point on the axis, unit approach (the direction the gripper closes in,
    perpendicular to the axis), clearance achieved (m) and the span it lies on."""

    point: np.ndarray
    approach: np.ndarray
    clearance: float
    span: Span


def segment_distances(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (m) of each point (N x 3) to the segment a-b."""
    ab = b - a
    t = np.clip((points - a) @ ab / max(float(ab @ ab), 1e-18), 0.0, 1.0)
    return np.linalg.norm(points - a - np.multiply.outer(t, ab), axis=1)


def envelope(tube: MemberAxis, gripper: GripperConfig) -> float:
    """Radius (m) of the closed gripper's ball: half its width, or the tube it wraps."""
    return max(gripper.width / 2, tube.radius)


def clearances(points: np.ndarray, tube: MemberAxis, obstacles: Obstacles) -> np.ndarray:
    """Least distance (m) of each point on ``tube``'s axis to a node's or another member's
    surface (inf with none)."""
    out = np.full(len(points), np.inf)
    if len(obstacles.nodes):
        gaps = np.linalg.norm(points[:, None] - obstacles.nodes[None], axis=2)
        out = np.minimum(out, (gaps - obstacles.node_radii).min(axis=1))
    for other in obstacles.tubes:
        if other is not tube:
            gap = segment_distances(points, other.p0, other.p1) - other.radius
            out = np.minimum(out, gap)
    return out


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """First and last index of each run of True in ``mask``."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return list(zip(starts.tolist(), stops.tolist(), strict=True))


def spans(
    tube: MemberAxis, obstacles: Obstacles, gripper: GripperConfig, config: GraspConfig
) -> list[Span]:
    """The clear stretches of ``tube``'s axis (found on samples ``resolution`` apart): the
    footprint on the member, the gripper's ball ``clearance`` from every obstacle."""
    half = gripper.width / 2
    if tube.length < gripper.width:
        return []
    count = int(np.ceil((tube.length - gripper.width) / config.resolution)) + 1
    along = np.linspace(half, tube.length - half, count)
    room = clearances(tube.at(along), tube, obstacles) - envelope(tube, gripper)
    clear = room >= gripper.clearance
    return [Span(tube, float(along[i]), float(along[j])) for i, j in runs(clear)]


def spread(span: Span, spacing: float) -> np.ndarray:
    """Distances along the axis of targets ``spacing`` apart, centred on ``span``."""
    count = int((span.end - span.start) // spacing) + 1
    middle = (span.start + span.end) / 2
    return middle + spacing * (np.arange(count) - (count - 1) / 2)


def approaches(tube: MemberAxis, points: np.ndarray, body: np.ndarray) -> np.ndarray:
    """Unit approach of each point (N x 3): downwards from above the member, or for a member
    within ``UPRIGHT`` of vertical towards it from the body's side (any perpendicular if the
    body is on its axis)."""
    axis = tube.axis
    up = UP - (UP @ axis) * axis
    if np.linalg.norm(up) >= UPRIGHT:
        return np.tile(-up / np.linalg.norm(up), (len(points), 1))
    side = body - points
    side = side - np.outer(side @ axis, axis)
    norm = np.linalg.norm(side, axis=1)
    fallback = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    side[norm < 1e-9] = fallback
    return -side / np.linalg.norm(side, axis=1, keepdims=True)


def grasps(
    obstacles: Obstacles,
    gripper: GripperConfig,
    config: GraspConfig,
    body: np.ndarray,
) -> list[Grasp]:
    """Grasp targets on every member of ``obstacles``: spread along its spans, each kept only
    if its own clearance (checked exactly, not on the samples) is the gripper's."""
    out = []
    for tube in obstacles.tubes:
        for span in spans(tube, obstacles, gripper, config):
            points = tube.at(spread(span, config.spacing))
            room = clearances(points, tube, obstacles) - envelope(tube, gripper)
            directions = approaches(tube, points, body)
            out += [
                Grasp(p, a, float(r), span)
                for p, a, r in zip(points, directions, room, strict=True)
                if r >= gripper.clearance
            ]
    return out


def reaching_limbs(points: np.ndarray, body: BodyState, kinematics: Kinematics) -> list[list[int]]:
    """For each odometry-frame point (N x 3), the legs whose IK reaches it within joint
    limits from ``body``'s pose (profile order)."""
    local = (np.reshape(points, (-1, 3)) - body.position) @ rotation(body.orientation)
    out = []
    for point in local:
        reached = kinematics.ik(np.tile(point, (kinematics.n_legs, 1)))[1]
        out.append(np.flatnonzero(reached).tolist())
    return out


def obstacles_of(truss: TrussMembers, node_radius: float) -> Obstacles:
    """The members and nodes of a published truss model; a node is a ball of its ``reach``,
    or of ``node_radius`` where it has none measured."""
    nodes = np.array([n.position for n in truss.nodes], float).reshape(-1, 3)
    radii = np.array([n.reach if n.reach > 0 else node_radius for n in truss.nodes], float)
    return Obstacles(nodes, radii, [MemberAxis.of(m) for m in truss.members])


def truss_grasps(
    truss: TrussMembers,
    gripper: GripperConfig,
    config: GraspConfig,
    body: BodyState,
    kinematics: Kinematics,
) -> TrussGrasps:
    """The grasp targets of a truss model for ``gripper``, with the legs that reach each from
    ``body`` (the pose the message names as its frame's)."""
    found = grasps(obstacles_of(truss, config.node_radius), gripper, config, body.position)
    points = np.array([g.point for g in found]).reshape(-1, 3)
    limbs = reaching_limbs(points, body, kinematics)
    return TrussGrasps(
        stamp=truss.stamp,
        frame_stamp=truss.frame_stamp,
        frame_position=list(body.position),
        frame_orientation=list(body.orientation),
        width=gripper.width,
        clearance=gripper.clearance,
        grasps=[
            TrussGrasp(
                member=g.span.member.id,
                position=g.point.tolist(),
                approach=g.approach.tolist(),
                clearance=g.clearance,
                span=g.span.ends().tolist(),
                limbs=reach,
            )
            for g, reach in zip(found, limbs, strict=True)
        ],
    )
