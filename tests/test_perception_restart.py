"""Perception that keeps going: a plugin error loses one frame, a plugin failing frame after
frame is restarted with back-off, and one that cannot be kept going ends the role non-zero.

The policy (loader.Restarting) on a clock of its own first, then the perception role's worker
on the floor camera with a scripted plugin, and last ``PerceptionRole.run`` on a loopback Zenoh
endpoint with a plugin installed by entry point that fails every frame.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import msgspec
import numpy as np
import pytest
from support.still_body import StillBody

from climbd.daemon.cli.run import make_camera
from climbd.daemon.contract.hardware import DepthFrame, Intrinsics
from climbd.daemon.contract.messages import BodyState, Joists, Message
from climbd.daemon.contract.plugins import PerceptionPlugin, PluginError
from climbd.daemon.contract.profile import NetworkConfig, PluginSpec, Profile, load
from climbd.daemon.runtime.capture import Capture
from climbd.daemon.runtime.counting import Tally
from climbd.daemon.runtime.loader import Restarting, RestartPolicy
from climbd.daemon.runtime.perception_role import GAVE_UP, PerceptionRole

ROBOTS = Path(__file__).resolve().parent.parent / "robots"
WIDOWX = load(ROBOTS / "widowx.toml")


class Script:
    """What a scripted plugin does on each call, counted across its instances: ``fails(n)``
    says whether the n-th call (from 1) raises; every call is noted (instance, time, raised)."""

    def __init__(self, fails: Callable[[int], bool]) -> None:
        self.fails = fails
        self.instances: list[Scripted] = []
        self.calls: list[tuple[Scripted, float, bool]] = []

    def build(self) -> Scripted:
        """A new instance, as at start and at each restart."""
        return Scripted(self)

    def raised(self) -> list[tuple[Scripted, float, bool]]:
        return [c for c in self.calls if c[2]]


class Scripted(PerceptionPlugin):
    """A perception plugin that raises when its script says so and answers every other frame
    with an empty Joists naming it."""

    publishes = (Joists,)

    def __init__(self, script: Script) -> None:
        super().__init__()
        self.script = script
        script.instances.append(self)

    def process(self, frame: DepthFrame, body: BodyState) -> Joists:
        n = len(self.script.calls) + 1
        fails = self.script.fails(n)
        self.script.calls.append((self, time.monotonic(), fails))
        if fails:
            raise RuntimeError(f"bad frame {n}")
        return Joists(stamp=frame.timestamp, frame_stamp=frame.timestamp)


class Clock:
    """A clock the test moves."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


FRAME = DepthFrame(
    depth=np.zeros((4, 4), np.uint16),
    depth_scale=0.001,
    intrinsics=Intrinsics(4, 4, 2.0, 2.0, 2.0, 2.0),
    extrinsics=np.eye(4),
    timestamp=1.0,
)
"""A blank frame: the scripted plugin does not look at it."""


def _call(plugin: Restarting[Scripted]) -> Joists | None:
    """One frame through the plugin as the role's worker calls it."""
    return plugin.call(plugin.plugin.process, FRAME, BodyState())


# --- the policy on a clock of its own ------------------------------------------------------


def test_one_failed_frame_loses_only_its_result() -> None:
    script = Script(lambda n: n == 2)
    plugin = Restarting("flaky", script.build, clock=Clock())
    results = [_call(plugin) for _ in range(4)]
    assert [r is None for r in results] == [False, True, False, False]
    assert plugin.failures == 1 and plugin.status == "ok" and not plugin.failed
    assert len(script.instances) == 1, "one bad frame does not restart the plugin"


def test_a_streak_restarts_with_doubling_back_off_and_gives_up_after_the_last_restart() -> None:
    """Always failing, restart after 2 in a row, 1 s doubling to 3 s, 3 restarts: each back-off
    skips the plugin, each fresh instance fails its first frame and is restarted at once, and
    one failing right after the third restart is given up (``on_failure`` once)."""
    clock = Clock()
    given_up: list[tuple[str, BaseException]] = []
    policy = RestartPolicy(failures_to_restart=2, restarts=3, first_backoff=1.0, max_backoff=3.0)
    script = Script(lambda n: True)
    plugin = Restarting("cracked", script.build, lambda *a: given_up.append(a), policy, clock)
    assert (
        _call(plugin) is None and plugin.status == "failing (1 in a row): RuntimeError: bad frame 1"
    )
    _call(plugin)
    assert plugin.status == "restarting (1): RuntimeError: bad frame 2"
    for k, back_off in enumerate([1.0, 2.0, 3.0], start=1):
        assert len(script.instances) == k + 1, "a fresh instance at each restart"
        calls = len(script.calls)
        clock.now += back_off - 0.01
        assert _call(plugin) is None and len(script.calls) == calls, "skipped while backing off"
        clock.now += 0.01
        _call(plugin)
        assert len(script.calls) == calls + 1, "called again once the back-off is over"
        assert script.calls[-1][0] is script.instances[k], "the k-th restart's instance"
    assert plugin.failed and plugin.status == f"failed: RuntimeError: bad frame {len(script.calls)}"
    assert [name for name, _ in given_up] == ["cracked"] and len(script.instances) == 4
    clock.now += 100.0
    assert _call(plugin) is None and len(script.calls) == 5, "a given-up plugin is not called"


def test_a_success_after_a_restart_makes_the_plugin_healthy_again() -> None:
    clock = Clock()
    script = Script(lambda n: n <= 3)
    policy = RestartPolicy(failures_to_restart=3, restarts=1, first_backoff=1.0)
    plugin = Restarting("flaky", script.build, policy=policy, clock=clock)
    for _ in range(3):
        _call(plugin)
    assert plugin.status.startswith("restarting (1)") and plugin.restarts == 1
    clock.now += 1.0
    assert isinstance(_call(plugin), Joists)
    assert plugin.status == "ok" and plugin.restarts == 0 and plugin.failures == 3


def test_a_plugin_whose_restart_raises_is_given_up() -> None:
    """Building the fresh instance raises (the profile's config no longer loads, the device is
    gone): no back-off helps, the plugin is given up with the construction's error."""
    script = Script(lambda n: True)
    builds = iter([script.build])

    def build() -> Scripted:
        try:
            return next(builds)()
        except StopIteration:
            raise PluginError(
                "plugins.perception cracked: plugin 'cracked' failed to start"
            ) from None

    given_up: list[BaseException] = []
    policy = RestartPolicy(failures_to_restart=1)
    plugin = Restarting("cracked", build, lambda name, e: given_up.append(e), policy, Clock())
    _call(plugin)
    assert plugin.failed and plugin.status.startswith("failed: PluginError: plugins.perception")
    assert len(given_up) == 1 and isinstance(given_up[0], PluginError)


def test_failures_are_logged_once_with_their_traceback_then_summarised(caplog) -> None:
    script = Script(lambda n: n % 2 == 0)  # never twice in a row: no restart
    plugin = Restarting(
        "flaky", script.build, policy=RestartPolicy(summary_every=10), clock=Clock()
    )
    for _ in range(50):
        _call(plugin)
    assert plugin.failures == 25
    assert caplog.text.count("Traceback") == 1
    assert (
        "plugin flaky failed in process: RuntimeError: bad frame 2 (result dropped" in caplog.text
    )
    assert "plugin flaky: 10 calls failed so far" in caplog.text
    assert "plugin flaky: 20 calls failed so far" in caplog.text
    assert len(caplog.records) == 3


# --- the role's worker on the floor camera ------------------------------------------------


def _run_worker(role: PerceptionRole, plugin: Restarting, done: Callable[[list], bool]) -> list:
    """The role's worker on the floor camera with ``plugin`` until ``done(published)`` (10 s at
    most); what it published of the plugin's types (the world model's maps aside)."""
    camera = make_camera(role.profile, "floor", None, None)
    capture = Capture(camera, camera.config.name)
    published: list = []

    def publish(message: Message) -> None:
        if isinstance(message, plugin.plugin.publishes):
            published.append(message)

    capture.start()
    worker = threading.Thread(target=role._work, args=(capture, [plugin], publish))
    worker.start()
    try:
        with StillBody(role):
            end = time.monotonic() + 10.0
            while not done(published) and time.monotonic() < end:
                time.sleep(0.02)
    finally:
        role._stop.set()
        capture.stop()
        worker.join(5.0)
    return published


def test_the_worker_drops_a_failed_frame_and_publishes_the_next_ones() -> None:
    role = PerceptionRole(WIDOWX, argparse.Namespace())
    script = Script(lambda n: n == 2)
    plugin = Restarting("flaky", script.build, role.plugin_failed)
    published = _run_worker(role, plugin, lambda p: len(p) >= 4)
    assert len(published) >= 4 and not role.failure
    answered = [c for c in script.calls if not c[2]]
    assert len(published) == len(answered), "every answer published, the failed frame's none"
    health = role.health([plugin], Tally())
    assert health.plugin_errors == {"flaky": 1} and health.plugins == {"flaky": "ok"}


def test_the_worker_restarts_a_plugin_failing_in_a_row_and_publishes_once_it_is_healthy() -> None:
    """Five failed frames in a row: a fresh instance, not called during its 0.3 s back-off,
    whose answers are published; the health shows the errors and the plugin ok again."""
    role = PerceptionRole(WIDOWX, argparse.Namespace())
    script = Script(lambda n: n <= 5)
    policy = RestartPolicy(failures_to_restart=5, restarts=1, first_backoff=0.3)
    plugin = Restarting("flaky", script.build, role.plugin_failed, policy)
    published = _run_worker(role, plugin, lambda p: len(p) >= 3)
    assert len(published) >= 3 and not role.failure
    first, fresh = script.instances
    failed = script.raised()
    assert len(failed) == 5 and all(c[0] is first for c in failed)
    answers = [c for c in script.calls if not c[2]]
    assert all(c[0] is fresh for c in answers)
    assert answers[0][1] - failed[-1][1] >= 0.3, "the back-off is respected"
    health = role.health([plugin], Tally())
    assert health.plugin_errors == {"flaky": 5} and health.plugins == {"flaky": "ok"}


# --- PerceptionRole.run: a plugin that cannot be kept going ends the role -------------------


@pytest.fixture()
def cracked(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Profile]:
    """WidowX running only ``cracked``, a perception plugin installed by entry point that fails
    every frame; the profile's network without authentication (tests name their endpoints)."""
    pkg = tmp_path / "cracked_lens"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        textwrap.dedent(
            """
            from climbd.daemon.contract.messages import Joists
            from climbd.daemon.contract.plugins import PerceptionPlugin

            class Cracked(PerceptionPlugin):
                publishes = (Joists,)

                def process(self, frame, body):
                    raise RuntimeError("lens cracked")
            """
        )
    )
    dist = tmp_path / "cracked_lens-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: cracked-lens\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[climbd.perception]\ncracked = cracked_lens:Cracked\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    plugins = msgspec.structs.replace(WIDOWX.plugins, perception=[PluginSpec(name="cracked")])
    yield msgspec.structs.replace(WIDOWX, plugins=plugins, network=NetworkConfig())
    sys.modules.pop("cracked_lens", None)


def test_a_plugin_that_fails_after_every_restart_ends_the_role_non_zero(
    cracked: Profile, endpoint: str, capsys
) -> None:
    """Through ``run`` on a loopback endpoint: restarted twice, given up, and the role exits
    with GAVE_UP (its supervisor or systemd restarts it) naming the plugin and its error, long
    before its duration is up."""
    args = argparse.Namespace(plugin=None, duration=15.0, listen=[endpoint], connect=[])
    camera = make_camera(cracked, "floor", None, None)
    policy = RestartPolicy(failures_to_restart=3, restarts=2, first_backoff=0.05)
    role = PerceptionRole(cracked, args, camera, policy=policy)
    start = time.monotonic()
    with StillBody(role):
        code = asyncio.run(role.run())
    assert code == GAVE_UP != 0
    assert time.monotonic() - start < 10.0
    err = capsys.readouterr().err
    assert "perception plugin cracked cannot be kept going (RuntimeError: lens cracked)" in err
