"""Plugins: found through entry points, configured with validated Configs, isolated on failure."""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import msgspec
import pytest

from climbd.daemon.contract.messages import BodyState, Joists
from climbd.daemon.contract.plugins import PerceptionPlugin
from climbd.daemon.runtime import loader


@pytest.fixture()
def third_party(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A separately 'installed' distribution registering a perception plugin by entry point."""
    pkg = tmp_path / "acme_perception"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        textwrap.dedent(
            '''
            import msgspec
            from climbd.daemon.contract.messages import Joist, Joists
            from climbd.daemon.algorithms.cloud import CloudPerception

            class Config(msgspec.Struct, forbid_unknown_fields=True):
                min_height: float = 0.05

            class TallestPoint(CloudPerception):
                """Reports the tallest point as a joist straight ahead."""
                Config = Config
                publishes = (Joists,)

                def process_cloud(self, points, body, stamp):
                    z = float(points[:, 2].max())
                    if z < self.config.min_height:
                        return None
                    return Joists(stamp=stamp, joists=[Joist(
                        distance=float(points[points[:, 2].argmax(), 0]), yaw=0.0, height=z,
                        endpoints=[])])

            class Exploding(CloudPerception):
                def process_cloud(self, points, body, stamp):
                    raise ZeroDivisionError("boom")
            '''
        )
    )
    dist = tmp_path / "acme_perception-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: acme-perception\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(
        "[climbd.perception]\ntallest = acme_perception:TallestPoint\n"
        "exploding = acme_perception:Exploding\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    yield tmp_path
    sys.modules.pop("acme_perception", None)


def test_entry_point_plugin_loads_and_runs(third_party: Path) -> None:
    import numpy as np

    assert "tallest" in loader.available("climbd.perception")
    plugin = loader.instantiate("climbd.perception", "tallest", {"min_height": 0.1}, None, "test")
    assert plugin.config.min_height == 0.1
    points = np.array([[1.0, 0.0, 0.0], [0.8, 0.1, 0.12], [2.0, 0.0, 0.05]])
    out = plugin.process_cloud(points, BodyState(), 3.0)
    assert isinstance(out, Joists) and out.joists[0].distance == 0.8 and out.stamp == 3.0
    assert plugin.process_cloud(points * [1, 1, 0.1], BodyState(), 3.0) is None


def test_bad_config_names_the_field(third_party: Path) -> None:
    with pytest.raises(loader.PluginError, match=r"robots/x.toml: perception tallest.*min_height"):
        loader.instantiate(
            "climbd.perception",
            "tallest",
            {"min_height": "high"},
            None,
            "robots/x.toml: perception tallest",
        )
    with pytest.raises(loader.PluginError, match="unknown field `colour`"):
        loader.instantiate("climbd.perception", "tallest", {"colour": 1}, None, "where")


def test_missing_plugin_lists_what_exists(third_party: Path) -> None:
    with pytest.raises(loader.PluginError, match=r"no plugin named 'nope' \(available: .*tallest"):
        loader.load_class("climbd.perception", "nope")
    with pytest.raises(loader.PluginError, match="unknown plugin group"):
        loader.available("climbd.nothing")


def test_raising_plugin_is_isolated(third_party: Path) -> None:
    import numpy as np

    failures: list[str] = []
    plugin = loader.instantiate("climbd.perception", "exploding", {}, None, "test")
    isolated = loader.Isolated("exploding", plugin, lambda name, e: failures.append(name))
    points = np.zeros((3, 3))
    assert isolated.call(plugin.process_cloud, points, BodyState(), 0.0) is None
    assert isolated.failed and "ZeroDivisionError: boom" in isolated.status
    assert failures == ["exploding"]
    assert isolated.call(plugin.process_cloud, points, BodyState(), 0.0) is None
    assert isolated.failures == 1, "a failed plugin is skipped, not called again"
    isolated.reset()
    assert not isolated.failed


def test_empty_config_refuses_keys() -> None:
    with pytest.raises(loader.PluginError, match="unknown field"):
        loader.make_config(PerceptionPlugin, {"x": 1}, "here")
    assert isinstance(loader.make_config(PerceptionPlugin, {}, "here"), msgspec.Struct)


def test_isolated_times_each_call_and_names_the_slowest() -> None:
    """The runtime's view of a plugin's cost: each call is timed and the slowest kept, for the
    health topic (``plugin_slowest``)."""
    import time

    from climbd.daemon.runtime.loader import slowest

    class Sleepy:
        def quick(self) -> int:
            return 1

        def slow(self, seconds: float) -> int:
            time.sleep(seconds)
            return 2

    a, b = loader.Isolated("a", Sleepy()), loader.Isolated("b", Sleepy())
    assert a.call(a.plugin.quick) == 1 and b.call(b.plugin.slow, 0.05) == 2
    assert b.slowest >= 0.05 and b.slowest_call == "slow"
    fields = slowest([a, b])
    assert fields["plugin_slowest_call"] == "b.slow"
    assert fields["plugin_slowest"] == {"a": a.slowest, "b": b.slowest}
