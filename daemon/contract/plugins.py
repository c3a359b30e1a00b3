"""Plugin base classes: the typed calls the runtime makes on perception and gait plugins.

Each plugin class declares a msgspec ``Config`` whose defaults are its paper's values; the profile
overrides them and the override is validated at start, with the field path in the error.
"""

from __future__ import annotations

from typing import Any, ClassVar

import msgspec
import numpy as np

from climbd.daemon.contract.messages import BodyState, FootTargets, Message, MotionCommand


class PluginError(RuntimeError):
    """A plugin that cannot be found, configured or started; names the plugin and the field."""


class EmptyConfig(msgspec.Struct, forbid_unknown_fields=True):
    """Config of a plugin that takes none."""


class PerceptionPlugin:
    """Base of perception plugins: body-frame points in, one feature message (or None) out.

    ``process`` takes a DepthFrame (see daemon/contract/hardware.py) and the body state at the
    frame's timestamp; ``process_cloud`` takes an N×3 array of body-frame points (m) and is what
    ``climbd perceive`` calls on a file.
    """

    name: ClassVar[str] = ""
    Config: ClassVar[type[msgspec.Struct]] = EmptyConfig

    def __init__(self, config: msgspec.Struct | None = None, profile: Any = None) -> None:
        self.config = config if config is not None else self.Config()
        self.profile = profile

    def process(self, frame: Any, body: BodyState) -> Message | None:
        from climbd.daemon.algorithms.cloud import frame_to_points

        return self.process_cloud(frame_to_points(frame), body, frame.timestamp)

    def process_cloud(self, points: np.ndarray, body: BodyState, stamp: float) -> Message | None:
        raise NotImplementedError


class GaitPlugin:
    """Base of gait/behaviour plugins: foot targets in the body frame at every control tick.

    ``start(state)`` receives the measured BodyState and current foot positions (n×3, body
    frame); ``step`` returns the FootTargets of this tick; ``stop`` ends it; ``done`` is set
    when a finite behaviour has finished (a periodic gait never sets it). ``world`` maps
    feature topics to their latest messages, already filtered for age by the daemon.
    """

    name: ClassVar[str] = ""
    Config: ClassVar[type[msgspec.Struct]] = EmptyConfig
    needs: ClassVar[tuple[str, ...]] = ()
    """Feature topics (e.g. ``features/joists``) without which the behaviour cannot go on:
    while one is absent or older than the profile's ``safety.feature_max_age`` the robot holds."""

    def __init__(self, config: msgspec.Struct | None = None, profile: Any = None) -> None:
        if profile is None:  # every gait plans with the robot's kinematics
            raise PluginError(f"gait {self.name}: needs the robot profile")
        self.config = config if config is not None else self.Config()
        self.profile = profile
        self.done = False

    def start(self, body: BodyState, feet: np.ndarray) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        """Release what ``start`` acquired (e.g. a planning thread); called when the robot
        leaves ACTIVE. A gait that acquires nothing keeps this default."""

    def step(
        self,
        t: float,
        dt: float,
        body: BodyState,
        world: dict[str, Message],
        command: MotionCommand | None,
    ) -> FootTargets:
        raise NotImplementedError
