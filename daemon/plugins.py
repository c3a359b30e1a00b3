"""Plugin registry (entry points), plugin base classes, lifecycle and failure isolation.

Plugins are found through the entry-point groups ``climbd.perception``, ``climbd.gaits``
and ``climbd.drivers``, so a third party adds one with ``pip install``. Each plugin class
declares a msgspec ``Config`` whose defaults are its paper's values; the profile overrides
them and the override is validated at start, with the field path in the error.
"""

from __future__ import annotations

import logging
import traceback
from collections.abc import Callable
from importlib.metadata import entry_points
from typing import Any, ClassVar

import msgspec
import numpy as np

from daemon.messages import BodyState, FootTargets, Message, MotionCommand

GROUPS = ("climbd.perception", "climbd.gaits", "climbd.drivers")

log = logging.getLogger("climbd.plugins")


class PluginError(RuntimeError):
    """A plugin that cannot be found, configured or started; names the plugin and the field."""


class EmptyConfig(msgspec.Struct, forbid_unknown_fields=True):
    """Config of a plugin that takes none."""


class PerceptionPlugin:
    """Base of perception plugins: body-frame points in, one feature message (or None) out.

    ``process`` takes a DepthFrame (see drivers/base.py) and the body state at the frame's
    timestamp; ``process_cloud`` takes an N×3 array of body-frame points (m) and is what
    ``climbd perceive`` calls on a file.
    """

    name: ClassVar[str] = ""
    Config: ClassVar[type[msgspec.Struct]] = EmptyConfig

    def __init__(self, config: msgspec.Struct | None = None, profile: Any = None) -> None:
        self.config = config if config is not None else self.Config()
        self.profile = profile

    def process(self, frame: Any, body: BodyState) -> Message | None:
        from daemon.cloud import frame_to_points

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


def available(group: str) -> dict[str, Any]:
    """Entry points of ``group`` by name (not yet imported)."""
    if group not in GROUPS:
        raise PluginError(f"unknown plugin group {group!r}; expected one of {GROUPS}")
    return {ep.name: ep for ep in entry_points(group=group)}


def load_class(group: str, name: str) -> type:
    """Import the class registered as ``name`` in ``group``; a clear error when missing."""
    eps = available(group)
    if name not in eps:
        found = ", ".join(sorted(eps)) or "none installed"
        raise PluginError(f"{group}: no plugin named {name!r} (available: {found})")
    try:
        return eps[name].load()
    except Exception as e:
        raise PluginError(f"{group}: plugin {name!r} failed to import: {e}") from e


def make_config(cls: type, overrides: dict[str, Any], where: str) -> msgspec.Struct:
    """Build a plugin's Config from profile overrides; errors name ``where`` and the field."""
    config_type = getattr(cls, "Config", EmptyConfig)
    try:
        return msgspec.convert(overrides, config_type, strict=False)
    except msgspec.ValidationError as e:
        raise PluginError(f"{where}: {e}") from None


def instantiate(group: str, name: str, overrides: dict[str, Any], profile: Any, where: str):
    """Load, configure and construct plugin ``name``: what the daemon does at start."""
    cls = load_class(group, name)
    config = make_config(cls, overrides, where)
    try:
        return cls(config, profile)
    except Exception as e:
        raise PluginError(f"{where}: plugin {name!r} failed to start: {e}") from e


class Isolated:
    """Runs a plugin's calls so that one that raises is logged once, marked failed, and skipped.

    ``status`` is "ok", "failed: <error>" and goes into Health.plugins. ``on_failure`` lets
    the daemon react (a failed gait puts the robot in HOLD).
    """

    def __init__(
        self, name: str, plugin: Any, on_failure: Callable[[str, BaseException], None] | None = None
    ) -> None:
        self.name = name
        self.plugin = plugin
        self.status = "ok"
        self.failures = 0
        self._on_failure = on_failure

    @property
    def failed(self) -> bool:
        return self.status != "ok"

    def call(self, method: str, *args: Any) -> Any:
        """Call ``plugin.method(*args)``; on an exception return None and mark the plugin failed."""
        if self.failed:
            return None
        try:
            return getattr(self.plugin, method)(*args)
        except Exception as e:
            self.failures += 1
            self.status = f"failed: {type(e).__name__}: {e}"
            log.error(
                "plugin %s failed in %s: %s\n%s", self.name, method, e, traceback.format_exc()
            )
            if self._on_failure is not None:
                self._on_failure(self.name, e)
            return None

    def reset(self) -> None:
        """Re-admit a failed plugin (an explicit operator action)."""
        self.status = "ok"
