"""Plugin registry: entry points, configuration from the profile, and failure isolation.

Plugins and drivers are found through the entry-point groups ``climbd.perception``,
``climbd.gaits`` and ``climbd.drivers``, so a third party adds one with ``pip install``; the
runtime never imports a plugin or a driver by name.
"""

from __future__ import annotations

import logging
import math
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
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
    skipped for good (Restarting is the perception role's policy); each call is timed
    (``slowest``, s) for the health topic.

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
        try:
            return self._timed(method, *args, **kwargs)
        except Exception as e:
            self.failures += 1
            name = method.__name__
            self.status = f"failed: {type(e).__name__}: {e}"
            log.error("plugin %s failed in %s: %s\n%s", self.name, name, e, traceback.format_exc())
            if self._on_failure is not None:
                self._on_failure(self.name, e)
            return None

    def _timed(self, method: Callable[A, R], *args: A.args, **kwargs: A.kwargs) -> R:
        """``method(*args)``, kept in ``slowest`` when it is the slowest call so far; what it
        raises propagates."""
        start = _clock()
        result = method(*args, **kwargs)
        elapsed = _clock() - start
        if elapsed > self.slowest:
            self.slowest, self.slowest_call = elapsed, method.__name__
        return result

    def reset(self) -> None:
        """Re-admit a failed plugin (an explicit operator action)."""
        self.status = "ok"


@dataclass(frozen=True)
class RestartPolicy:
    """When a perception plugin that keeps raising is rebuilt, and when it is given up.

    ``failures_to_restart`` failed calls in a row restart the plugin (a fresh instance), which
    is then skipped for a back-off: ``first_backoff`` s, doubling with each restart in a row up
    to ``max_backoff``. A fresh instance whose first call fails is restarted again at once; one
    failing right after the ``restarts``-th restart in a row (no call succeeding in between) is
    given up. Failed calls are summarised in the log every ``summary_every``.
    """

    failures_to_restart: int = 5
    restarts: int = 3
    first_backoff: float = 1.0
    max_backoff: float = 30.0
    summary_every: int = 100

    def backoff(self, restart: int) -> float:
        """Seconds the plugin is skipped after its ``restart``-th restart in a row (from 1)."""
        return min(self.first_backoff * 2.0 ** (restart - 1), self.max_backoff)


class Restarting(Isolated[P]):
    """Isolation that keeps a perception plugin going: a call that raises loses only its own
    result (counted in ``failures``; the first logged with its traceback, then a summary every
    ``policy.summary_every``), a plugin failing ``policy.failures_to_restart`` calls in a row is
    rebuilt with ``build`` and skipped for a back-off, and one that fails right after each of
    ``policy.restarts`` restarts, or whose rebuild raises, is given up: ``on_failure`` is called
    once, so that its role exits and its supervisor restarts the role. (The gait keeps
    Isolated's one failure and out: a failed gait must hold the robot.)

    ``status``: "ok", "failing (n in a row): <error>", "restarting (k): <error>" during the k-th
    back-off, "failed: <error>" once given up.
    """

    def __init__(
        self,
        name: str,
        build: Callable[[], P],
        on_failure: Callable[[str, BaseException], None] | None = None,
        policy: RestartPolicy = RestartPolicy(),
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """``build`` makes an instance (what ran at start, again at each restart); what it
        raises at start propagates, as the daemon's start-up errors do."""
        super().__init__(name, build(), on_failure)
        self.policy = policy
        self.in_a_row = 0
        """Calls failed in a row by the current instance."""
        self.restarts = 0
        """Restarts since a call last succeeded."""
        self.resume_at = -math.inf
        """When the back-off after the last restart ends (``clock`` time)."""
        self._build = build
        self._clock = clock
        self._given_up = False

    @property
    def failed(self) -> bool:
        """Given up: never called again (a failing or restarting plugin is not failed)."""
        return self._given_up

    def call(self, method: Callable[A, R], *args: A.args, **kwargs: A.kwargs) -> R | None:
        """``method(*args)``, a bound method of the current instance (``self.plugin``, fresh
        after a restart): its result, or None when it raised or the plugin is skipped (backing
        off, or given up)."""
        if self._given_up or self._clock() < self.resume_at:
            return None
        try:
            result = self._timed(method, *args, **kwargs)
        except Exception as e:
            self._failed_call(method.__name__, e)
            return None
        self._succeeded()
        return result

    def reset(self) -> None:
        """Re-admit a given-up plugin with a clean record (an explicit operator action)."""
        super().reset()
        self.in_a_row = self.restarts = 0
        self.resume_at = -math.inf
        self._given_up = False

    def _succeeded(self) -> None:
        """A call returned: the plugin is healthy again, its restart count starts anew."""
        if self.restarts:
            log.info("plugin %s works again after %d restart(s)", self.name, self.restarts)
        self.in_a_row = self.restarts = 0
        self.status = "ok"

    def _failed_call(self, method: str, error: Exception) -> None:
        """A call raised: count and log it, then restart the plugin when it has failed enough
        calls in a row, or right after its last restart."""
        self.failures += 1
        self.in_a_row += 1
        what = f"{type(error).__name__}: {error}"
        if self.failures == 1:
            log.error(
                "plugin %s failed in %s: %s (result dropped; later failures summarised every "
                "%d)\n%s",
                self.name,
                method,
                what,
                self.policy.summary_every,
                traceback.format_exc(),
            )
        elif self.failures % self.policy.summary_every == 0:
            log.warning(
                "plugin %s: %d calls failed so far, their results dropped (last in %s: %s)",
                self.name,
                self.failures,
                method,
                what,
            )
        if self.restarts:
            self._restart(f"failed again right after restart {self.restarts}: {what}", error)
        elif self.in_a_row >= self.policy.failures_to_restart:
            self._restart(f"failed {self.in_a_row} calls in a row (last: {what})", error)
        else:
            self.status = f"failing ({self.in_a_row} in a row): {what}"

    def _restart(self, why: str, error: Exception) -> None:
        """Replace the plugin with a fresh instance and skip it for the back-off; give it up
        when it has had its restarts or the rebuild raises."""
        if self.restarts >= self.policy.restarts:
            self._give_up(f"{why}; given up after {self.restarts} restart(s)", error)
            return
        try:
            self.plugin = self._build()
        except Exception as e:
            self._give_up(f"{why}; restarting it failed: {type(e).__name__}: {e}", e)
            return
        self.restarts += 1
        self.in_a_row = 0
        delay = self.policy.backoff(self.restarts)
        self.resume_at = self._clock() + delay
        self.status = f"restarting ({self.restarts}): {type(error).__name__}: {error}"
        log.warning(
            "plugin %s %s: restarted (%d of at most %d), skipped for %.1f s",
            self.name,
            why,
            self.restarts,
            self.policy.restarts,
            delay,
        )

    def _give_up(self, why: str, error: Exception) -> None:
        """Stop calling the plugin and tell ``on_failure``."""
        self._given_up = True
        self.status = f"failed: {type(error).__name__}: {error}"
        log.error("plugin %s %s", self.name, why)
        if self._on_failure is not None:
            self._on_failure(self.name, error)


def slowest(plugins: Sequence[Isolated]) -> dict[str, object]:
    """The Health fields of the plugins' call timing: each one's slowest call, and the slowest."""
    worst = max(plugins, key=lambda p: p.slowest, default=None)
    return {
        "plugin_slowest": {p.name: p.slowest for p in plugins},
        "plugin_slowest_call": f"{worst.name}.{worst.slowest_call}" if worst is not None else "",
    }
