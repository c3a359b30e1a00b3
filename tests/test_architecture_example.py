"""docs/architecture.md's perception plugin, installed from the page as a third party would: it
loads by its entry point, brings a feature type of its own, runs in the perception role on a
camera, and its messages cross a real Zenoh link to a subscriber of that type, which the control
role takes because the plugin declares it."""

from __future__ import annotations

import argparse
import asyncio
import re
import sys
import threading
import time
from pathlib import Path

import msgspec
import numpy as np
import pytest

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib

from support.still_body import StillBody

from climbd.daemon.cli.run import make_camera
from climbd.daemon.contract import messages as m
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.profile import PluginSpec
from climbd.daemon.runtime.capture import Capture
from climbd.daemon.runtime.control_role import feature_types
from climbd.daemon.runtime.network import Endpoints, Network, zenoh_config
from climbd.daemon.runtime.perception_role import PerceptionRole, make_plugins

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "architecture.md"


def _block(language: str, marker: str) -> str:
    """The fenced ``language`` block of the architecture page that contains ``marker``."""
    for block in re.findall(rf"```{language}\n(.*?)```", DOC.read_text(), re.S):
        if marker in block:
            return block
    raise AssertionError(f"{DOC}: no {language} block with {marker!r}")


@pytest.fixture()
def acme(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    """The page's plugin as an installed distribution (package + dist-info with its entry
    point); the plugin's name."""
    package = tmp_path / "acme_perception"
    package.mkdir()
    (package / "__init__.py").write_text(_block("python", "# acme_perception/__init__.py"))
    entry = tomllib.loads(_block("toml", 'entry-points."climbd.perception"'))
    points = entry["project"]["entry-points"]["climbd.perception"]
    dist = tmp_path / "acme_perception-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: acme-perception\nVersion: 1.0\n")
    lines = "".join(f"{name} = {target}\n" for name, target in points.items())
    (dist / "entry_points.txt").write_text(f"[climbd.perception]\n{lines}")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield next(iter(points))
    sys.modules.pop("acme_perception", None)


def test_the_documented_plugin_runs_in_the_perception_role_and_reaches_a_subscriber(
    acme: str, robots: Path, endpoint: str
) -> None:
    stock = profiles.load(robots / "widowx.toml")
    plugins = msgspec.structs.replace(
        stock.plugins, perception=[PluginSpec(name=acme, config={"min_points": 5})]
    )
    profile = msgspec.structs.replace(stock, plugins=plugins)
    (plugin,) = make_plugins(profile, None, lambda name, error: None)
    lowest = plugin.plugin.publishes[0]
    assert issubclass(lowest, m.Feature) and lowest.TOPIC == "features/acme_lowest"
    assert lowest in feature_types(profile), "the control role would not subscribe to it"

    # The perception role's worker on a camera looking at flat ground a body height below.
    role = PerceptionRole(profile, argparse.Namespace())
    camera = make_camera(profile, "floor", None, None)
    capture = Capture(camera, camera.config.name)
    published: list[m.Message] = []
    capture.start()
    worker = threading.Thread(
        target=role._work,
        args=(capture, [plugin], lambda m: published.append(m) if isinstance(m, lowest) else None),
    )
    worker.start()
    try:
        with StillBody(role):
            end = time.monotonic() + 20.0
            while len(published) < 3 and time.monotonic() < end:
                time.sleep(0.05)
    finally:
        role._stop.set()
        capture.stop()
        worker.join(5.0)
    assert plugin.status == "ok" and len(published) >= 3, (plugin.status, published)
    floor = -profile.stand.body_height
    for message in published:
        assert isinstance(message, lowest)
        assert message.point[2] == pytest.approx(floor, abs=0.002)  # 1 mm depth units

    async def over_zenoh() -> list[m.Message]:
        loop = asyncio.get_running_loop()
        rx = Network(profile.name, zenoh_config(None, "rx", Endpoints([endpoint], [])), loop)
        tx = Network(profile.name, zenoh_config(None, "tx", Endpoints([], [endpoint])))
        got: list[m.Message] = []
        rx.subscribe(lowest, got.append)
        await asyncio.sleep(0.5)
        for message in published:
            tx.put(message)
        end = loop.time() + 10.0
        while len(got) < len(published) and loop.time() < end:
            await asyncio.sleep(0.05)
        tx.close()
        rx.close()
        return got

    got = asyncio.run(over_zenoh())
    assert got == published
    assert np.allclose([g.point for g in got], [p.point for p in published])
