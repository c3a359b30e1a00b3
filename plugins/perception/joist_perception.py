"""Perception plugins of paper 000: ``elevation`` (the fused height grid) and ``joists``."""

from __future__ import annotations

from typing import ClassVar

import msgspec
import numpy as np

from daemon.messages import BodyState, ElevationGrid, Joists
from daemon.plugins import PerceptionPlugin
from plugins.perception.elevation import ElevationConfig, ElevationMap, Grid
from plugins.perception.joists import JoistConfig, JoistDetector


class JoistPerceptionConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """The grid (crop box, cells, fusion, inpainting) and the detection thresholds."""

    grid: ElevationConfig = msgspec.field(default_factory=ElevationConfig)
    detection: JoistConfig = msgspec.field(default_factory=JoistConfig)


class ElevationPerception(PerceptionPlugin):
    """Publishes the fused elevation grid of the crop box (NaN where nothing was seen)."""

    name: ClassVar[str] = "elevation"
    Config: ClassVar[type[msgspec.Struct]] = ElevationConfig

    def __init__(self, config: ElevationConfig | None = None, profile=None) -> None:
        super().__init__(config, profile)
        self.map = ElevationMap(self.config)

    def process_cloud(self, points: np.ndarray, body: BodyState, stamp: float) -> ElevationGrid:
        self.map.integrate(points, body)
        return self.map.crop(body, fill=False).to_message(stamp)


class JoistPerception(PerceptionPlugin):
    """Joists ahead of the robot, nearest first; ``grid`` keeps the last filled grid."""

    name: ClassVar[str] = "joists"
    Config: ClassVar[type[msgspec.Struct]] = JoistPerceptionConfig

    def __init__(self, config: JoistPerceptionConfig | None = None, profile=None) -> None:
        super().__init__(config, profile)
        self.map = ElevationMap(self.config.grid)
        self.detector = JoistDetector(self.config.detection)
        self.grid: Grid | None = None

    def process_cloud(self, points: np.ndarray, body: BodyState, stamp: float) -> Joists:
        self.grid = self.map.update(points, body)
        return Joists(stamp=stamp, frame_stamp=stamp, joists=self.detector.detect(self.grid))
