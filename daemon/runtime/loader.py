"""Plugin registry: entry points, configuration from the profile, and failure isolation.

Plugins and drivers are found through the entry-point groups ``climbd.perception``,
``climbd.gaits`` and ``climbd.drivers``, so a third party adds one with ``pip install``; the
runtime never imports a plugin or a driver by name.
"""

from __future__ import annotations

import logging
import time
import traceback
from collections.abc import Callable
from importlib.metadata import entry_points
from typing import Any, Generic, ParamSpec, TypeVar

import msgspec

from climbd.daemon.contract.plugins import EmptyConfig, PluginError
from climbd.daemon.contract.profile import DriverConfig, Profile

GROUPS = ("climbd.perception", "climbd.gaits", "climbd.drivers")

log = logging.getLogger("climbd.plugins")
_clock = time.perf_counter

P = TypeVar("P")
R = TypeVar("R")
A = ParamSpec("A")


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


def check_driver(profile: Profile) -> DriverConfig:
    """The joint-bus driver the profile names (``bus.kind``) checks its keys of ``[bus]``: its
    ``Config`` decodes and validates them (ProfileError naming ``$.bus.<field>``). A driver
    without a ``Config`` takes no keys of its own."""
    try:
        cls = load_class("climbd.drivers", profile.bus.kind)
    except PluginError as e:
        raise PluginError(f"{profile.source or profile.name}: $.bus.kind: {e}") from None
    config_type = getattr(cls, "Config", DriverConfig)
    return config_type.check(profile)


def instantiate(group: str, name: str, overrides: dict[str, Any], profile: Any, where: str):
    """Load, configure and construct plugin ``name``: what the daemon does at start."""
    cls = load_class(group, name)
    config = make_config(cls, overrides, where)
    try:
        return cls(config, profile)
    except Exception as e:
        raise PluginError(f"{where}: plugin {name!r} failed to start: {e}") from e


class Isolated(Generic[P]):
    """Runs a plugin's typed calls so that one that raises is logged once, marked failed, and
    skipped; each call is timed (``slowest``, s) for the health topic.

    ``status`` is "ok", "failed: <error>" and goes into Health.plugins. ``on_failure`` lets
    the daemon react (a failed gait puts the robot in HOLD).
    """

    def __init__(
        self, name: str, plugin: P, on_failure: Callable[[str, BaseException], None] | None = None
    ) -> None:
        self.name = name
        self.plugin = plugin
        self.status = "ok"
        self.failures = 0
        self.slowest = 0.0
        self.slowest_call = ""
        self._on_failure = on_failure

    @property
    def failed(self) -> bool:
        return self.status != "ok"

    def call(self, method: Callable[A, R], *args: A.args, **kwargs: A.kwargs) -> R | None:
        """``method(*args)``, a bound method of the plugin; on an exception return None and mark
        the plugin failed."""
        if self.failed:
            return None
        start = _clock()
        try:
            result = method(*args, **kwargs)
        except Exception as e:
            self.failures += 1
            name = method.__name__
            self.status = f"failed: {type(e).__name__}: {e}"
            log.error("plugin %s failed in %s: %s\n%s", self.name, name, e, traceback.format_exc())
            if self._on_failure is not None:
                self._on_failure(self.name, e)
            return None
        elapsed = _clock() - start
        if elapsed > self.slowest:
            self.slowest, self.slowest_call = elapsed, method.__name__
        return result

    def reset(self) -> None:
        """Re-admit a failed plugin (an explicit operator action)."""
        self.status = "ok"


def slowest(plugins: list[Isolated]) -> dict[str, object]:
    """The Health fields of the plugins' call timing: each one's slowest call, and the slowest."""
    worst = max(plugins, key=lambda p: p.slowest, default=None)
    return {
        "plugin_slowest": {p.name: p.slowest for p in plugins},
        "plugin_slowest_call": f"{worst.name}.{worst.slowest_call}" if worst is not None else "",
    }
