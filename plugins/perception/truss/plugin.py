"""The truss perception plugin: accumulate body-frame clouds in the odometry frame, model them,
and, for a profile with a gripper, find where it may grasp the members."""

from __future__ import annotations

from typing import Any, ClassVar

import msgspec
import numpy as np

from climbd.daemon.algorithms.cloud import CloudPerception, within_range
from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.messages import BodyState, TrussGrasps, TrussMember, TrussMembers
from climbd.plugins.perception.truss.cloud import VoxelMap, body_to_odometry
from climbd.plugins.perception.truss.completion import Member
from climbd.plugins.perception.truss.grasp import GraspConfig, truss_grasps
from climbd.plugins.perception.truss.model import TrussConfig, TrussModeller, coverage
from climbd.plugins.perception.truss.nodes import connectors
from climbd.plugins.perception.truss.tracking import FieldOfView, MemberTracks, Sighting


def to_message(member: Member, confidence: float, ident: int) -> TrussMember:
    """A member of the persistent model as the wire TrussMember (odometry frame, axis from p0
    to p1): its tube extent and, where an end meets a node, that node."""
    return TrussMember(
        p0=member.p0.tolist(),
        p1=member.p1.tolist(),
        radius=float(member.cylinder.radius),
        axis=member.cylinder.axis.tolist(),
        confidence=round(confidence, 3),
        id=ident,
        node0=[] if member.node0 is None else member.node0.tolist(),
        node1=[] if member.node1 is None else member.node1.tolist(),
    )


class TrussPerceptionConfig(TrussConfig, kw_only=True):
    """The truss modeller's parameters and, under ``grasp``, the grasp targets'."""

    grasp: GraspConfig = msgspec.field(default_factory=GraspConfig)


class TrussPerception(CloudPerception):
    """Builds the truss model from every frame so far (the paper's dense SLAM cloud, here our
    odometry poses) every ``model_every`` frames, fuses its members into the persistent model
    (tracking.py: ids, fused estimates, confidence, expiry, splits and merges) and publishes
    that model's members and nodes; with the profile's gripper, the grasp targets on them too,
    each with the legs that reach it from the frame's body pose."""

    name: ClassVar[str] = "truss"
    publishes = (TrussMembers, TrussGrasps)
    Config: ClassVar[type[TrussConfig]] = TrussPerceptionConfig

    def __init__(self, config: TrussConfig | None = None, profile: Any = None) -> None:
        super().__init__(config, profile)
        self.modeller = TrussModeller(self.config)
        grasping = isinstance(self.config, TrussPerceptionConfig)
        self.grasp = self.config.grasp if grasping else GraspConfig()
        self.gripper = None if profile is None else profile.gripper
        self.kinematics = None if self.gripper is None else Kinematics(profile)
        self.reset()

    def reset(self) -> None:
        """Forget the accumulated cloud and the persistent model (e.g. after the odometry frame
        was reset)."""
        self.map = VoxelMap(self.config.voxel)
        self.tracks = MemberTracks(self.config.track_gate, self.config.track_expiry)
        self.views: list[FieldOfView] = []
        self.frames = 0

    def process_cloud(
        self, points: np.ndarray, body: BodyState, stamp: float
    ) -> TrussMembers | tuple[TrussMembers, TrussGrasps] | None:
        """Add body-frame points (N x 3, m) seen at ``body``'s pose; model when it is time
        (with the grasp targets, for a profile with a gripper)."""
        points = np.asarray(points, dtype=float)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"truss: points must be N x 3 (m), got shape {points.shape}")
        if len(body.position) != 3 or len(body.orientation) != 4:
            raise ValueError(
                "truss: BodyState needs position (x, y, z) and orientation (w, x, y, z)"
            )
        points = within_range(points, self.config.max_range)
        if len(points):
            self.map.add(body_to_odometry(points, body))
        self.views.append(FieldOfView(points, body, self.config.max_range))
        self.frames += 1
        if self.frames % self.config.model_every:
            return None
        self.fuse(stamp)
        fused = self.tracks.members()
        members = [to_message(m, t.confidence, t.id) for t, m in fused]
        nodes = connectors([m for _, m in fused], [t.id for t, _ in fused], self.config.node_radius)
        truss = TrussMembers(stamp=stamp, frame_stamp=stamp, members=members, nodes=nodes)
        if self.kinematics is None:
            return truss
        return truss, truss_grasps(truss, self.gripper, self.grasp, body, self.kinematics)

    def fuse(self, stamp: float) -> None:
        """Model the accumulated cloud and fold its members into the persistent model, each
        weighted by its coverage and the frames the cloud holds."""
        model = self.modeller.model(self.map.points)
        bin_size = 2 * self.config.voxel
        sightings = [
            Sighting.of(m, coverage(m, model.points, bin_size), self.frames) for m in model.members
        ]
        self.tracks.update(sightings, stamp, self.views)
        self.views = []
