"""Plugin base classes: the typed calls the runtime makes on perception and gait plugins.

Each plugin class declares a msgspec ``Config`` whose defaults are its paper's values; the profile
overrides them and the override is validated at start, with the field path in the error.
"""

from __future__ import annotations

from typing import Any, ClassVar

import msgspec
import numpy as np

from climbd.daemon.contract.hardware import DepthFrame
from climbd.daemon.contract.messages import BodyState, Feature, FootTargets, Message, MotionCommand


class PluginError(RuntimeError):
    """A plugin that cannot be found, configured or started; names the plugin and the field."""


class EmptyConfig(msgspec.Struct, forbid_unknown_fields=True):
    """Config of a plugin that takes none."""


class PerceptionPlugin:
    """Base of perception plugins: a depth frame in, one feature message, a tuple of them (a
    plugin that publishes two topics from one model), or None out.

    ``process`` takes a DepthFrame and the body state at the frame's timestamp;
    ``process_cloud`` takes an N×3 array of body-frame points (m) and is what ``climbd
    perceive`` calls on a file (``climbd.daemon.algorithms.cloud.CloudPerception`` turns the
    one into the other). ``publishes`` declares the feature types the plugin returns: the
    perception role publishes those and the control role subscribes to them, so a third-party
    plugin may bring a message type of its own.
    """

    name: ClassVar[str] = ""
    Config: ClassVar[type[msgspec.Struct]] = EmptyConfig
    publishes: ClassVar[tuple[type[Feature], ...]] = ()

    def __init__(self, config: msgspec.Struct | None = None, profile: Any = None) -> None:
        self.config = config if config is not None else self.Config()
        self.profile = profile

    def process(self, frame: DepthFrame, body: BodyState) -> Message | tuple[Message, ...] | None:
        raise NotImplementedError

    def process_cloud(
        self, points: np.ndarray, body: BodyState, stamp: float
    ) -> Message | tuple[Message, ...] | None:
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
        self.stepped = False
        """Simulated time (the twin's stepped runs, tests, benches): the behaviour waits for a
        plan it needs instead of holding for it, so runs are deterministic. The runtime sets it;
        on a robot it stays False and no plan ever runs in the tick."""

    def start(self, body: BodyState, feet: np.ndarray) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        """Release what ``start`` acquired (e.g. a planning thread); called when the robot
        leaves ACTIVE. A gait that acquires nothing keeps this default."""

    def telemetry(self) -> list[Message]:
        """Messages the behaviour reports besides its targets (plans, decisions); the control
        role publishes them at its state rate. None by default."""
        return []

    def step(
        self,
        t: float,
        dt: float,
        body: BodyState,
        world: dict[str, Message],
        command: MotionCommand | None,
    ) -> FootTargets:
        raise NotImplementedError
