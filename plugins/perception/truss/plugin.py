"""The truss perception plugin: accumulate body-frame clouds in the odometry frame, model them."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from climbd.daemon.algorithms.cloud import CloudPerception, within_range
from climbd.daemon.contract.messages import BodyState, TrussMember, TrussMembers
from climbd.plugins.perception.truss.cloud import VoxelMap, body_to_odometry
from climbd.plugins.perception.truss.completion import Member
from climbd.plugins.perception.truss.model import TrussConfig, TrussModeller, coverage
from climbd.plugins.perception.truss.nodes import MemberTracks, connectors


def to_message(member: Member, points: np.ndarray, bin_size: float, ident: int) -> TrussMember:
    """A modelled member as the wire TrussMember (odometry frame, axis from p0 to p1)."""
    return TrussMember(
        p0=member.p0.tolist(),
        p1=member.p1.tolist(),
        radius=float(member.cylinder.radius),
        axis=member.cylinder.axis.tolist(),
        confidence=round(coverage(member, points, bin_size), 3),
        id=ident,
    )


class TrussPerception(CloudPerception):
    """Builds the truss model from every frame so far (the paper's dense SLAM cloud, here our
    odometry poses) and publishes its members, with ids kept across updates, and its nodes
    every ``model_every`` frames."""

    name: ClassVar[str] = "truss"
    publishes = (TrussMembers,)
    Config: ClassVar[type[TrussConfig]] = TrussConfig

    def __init__(self, config: TrussConfig | None = None, profile: Any = None) -> None:
        super().__init__(config, profile)
        self.modeller = TrussModeller(self.config)
        self.reset()

    def reset(self) -> None:
        """Forget the accumulated cloud and the members' ids (e.g. after the odometry frame
        was reset)."""
        self.map = VoxelMap(self.config.voxel)
        self.tracks = MemberTracks(self.config.track_gate)
        self.frames = 0

    def process_cloud(
        self, points: np.ndarray, body: BodyState, stamp: float
    ) -> TrussMembers | None:
        """Add body-frame points (N x 3, m) seen at ``body``'s pose; model when it is time."""
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
        self.frames += 1
        if self.frames % self.config.model_every:
            return None
        model = self.modeller.model(self.map.points)
        bin_size = 2 * self.config.voxel
        ids = self.tracks.update(model.members, stamp)
        members = [
            to_message(m, model.points, bin_size, i)
            for m, i in zip(model.members, ids, strict=True)
        ]
        nodes = connectors(model.members, ids, self.config.node_radius)
        return TrussMembers(stamp=stamp, frame_stamp=stamp, members=members, nodes=nodes)
