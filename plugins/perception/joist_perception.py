"""Perception plugins of paper 000: ``elevation`` (the fused height grid) and ``joists``.

``process_cloud`` takes points whose origin is on the ground under the body centre (as
``climbd perceive`` files are). A depth frame's points come out of its mount extrinsics in the
body-centre frame, so ``process`` lifts them by the body's height: the attic floor is the
odometry frame's z = 0 plane, and the body's odometry z is its height above it.
"""

from __future__ import annotations

from typing import ClassVar

import msgspec
import numpy as np

from climbd.daemon.algorithms.cloud import frame_to_points
from climbd.daemon.algorithms.elevation import ElevationConfig, ElevationMap, Grid
from climbd.daemon.contract.messages import BodyState, ElevationGrid, Joists
from climbd.daemon.contract.plugins import PerceptionPlugin
from climbd.plugins.perception.joists import JoistConfig, JoistDetector


class JoistPerceptionConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """The grid (crop box, cells, fusion, inpainting) and the detection thresholds."""

    grid: ElevationConfig = msgspec.field(default_factory=ElevationConfig)
    detection: JoistConfig = msgspec.field(default_factory=JoistConfig)


def ground_cloud(frame, body: BodyState) -> tuple[np.ndarray, BodyState]:
    """A depth frame's points and pose moved from the body centre to the ground below it."""
    points = frame_to_points(frame)
    points[:, 2] += np.float32(body.position[2])
    x, y, _ = body.position
    return points, msgspec.structs.replace(body, position=[x, y, 0.0])


class ElevationPerception(PerceptionPlugin):
    """Publishes the fused elevation grid of the crop box (NaN where nothing was seen)."""

    name: ClassVar[str] = "elevation"
    Config: ClassVar[type[msgspec.Struct]] = ElevationConfig
    publishes = (ElevationGrid,)

    def __init__(self, config: ElevationConfig | None = None, profile=None) -> None:
        super().__init__(config, profile)
        self.map = ElevationMap(self.config)

    def process(self, frame, body: BodyState) -> ElevationGrid:
        points, ground = ground_cloud(frame, body)
        return self.process_cloud(points, ground, frame.timestamp)

    def process_cloud(self, points: np.ndarray, body: BodyState, stamp: float) -> ElevationGrid:
        self.map.integrate(points, body)
        return self.map.crop(body, fill=False).to_message(stamp)


class JoistPerception(PerceptionPlugin):
    """Joists ahead of the robot, nearest first; ``grid`` keeps the last filled grid."""

    name: ClassVar[str] = "joists"
    Config: ClassVar[type[msgspec.Struct]] = JoistPerceptionConfig
    publishes = (Joists,)

    def __init__(self, config: JoistPerceptionConfig | None = None, profile=None) -> None:
        super().__init__(config, profile)
        self.map = ElevationMap(self.config.grid)
        self.detector = JoistDetector(self.config.detection)
        self.grid: Grid | None = None

    def process(self, frame, body: BodyState) -> Joists:
        points, ground = ground_cloud(frame, body)
        return self.process_cloud(points, ground, frame.timestamp)

    def process_cloud(self, points: np.ndarray, body: BodyState, stamp: float) -> Joists:
        self.grid = self.map.update(points, body)
        return Joists(stamp=stamp, frame_stamp=stamp, joists=self.detector.detect(self.grid))
