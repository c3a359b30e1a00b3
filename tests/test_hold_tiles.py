"""The twin's shipped hold tiles (drivers/sim/worlds/data/*.tile.txt) are the detector's output
on their clouds, and the twin builds hold maps from them without importing any plugin."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from climbd.drivers.sim.worlds import DATA, WorldError, hold_map_tile, stock_worlds
from climbd.drivers.sim.worlds import load as load_world
from climbd.drivers.sim.worlds.hold_tiles import read_tile, tile_file, tile_map, write_tile

BENCH = Path(__file__).resolve().parent.parent / "bench" / "hold_tiles.py"
CLOUDS = sorted(p.name for p in DATA.glob("*.pcd"))


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_hold_tiles", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_shipped_cloud_has_a_tile():
    assert CLOUDS
    for name in CLOUDS:
        assert tile_file(DATA / name).is_file(), "run .venv/bin/python bench/hold_tiles.py"


@pytest.mark.parametrize("name", CLOUDS)
def test_shipped_tile_is_the_detectors_output(bench, name):
    detected = bench.detect_tile(DATA / name)
    shipped = hold_map_tile(DATA / name)
    assert shipped.shape == detected.shape and len(shipped) >= 2
    np.testing.assert_allclose(shipped, detected, rtol=0, atol=1e-9)
    assert bench.matches(shipped, detected)


def test_stock_hold_map_worlds_use_a_shipped_tile():
    worlds = [load_world(name) for name in stock_worlds()]
    clouds = [Path(w.source).parent / w.hold_map.cloud for w in worlds if w.hold_map]
    assert clouds
    for cloud in clouds:
        assert cloud.resolve().parent == DATA and cloud.name in CLOUDS


def test_tile_round_trips_exactly(tmp_path):
    tile = np.random.default_rng(0).normal(0, 0.1, (7, 3))
    path = write_tile(tmp_path / "holds.pcd", tile, "a header\n\nsecond line")
    assert path == tmp_path / "holds.tile.txt"
    np.testing.assert_array_equal(read_tile(path), tile)


def test_missing_tile_is_a_world_error_naming_the_file(tmp_path):
    cloud = tmp_path / "my_holds.pcd"
    with pytest.raises(WorldError, match=r"my_holds\.tile\.txt.*bench/hold_tiles\.py"):
        hold_map_tile(cloud)


def test_malformed_tile_is_a_world_error(tmp_path):
    (tmp_path / "bad.tile.txt").write_text("# x y height\n0.1 0.2\n")
    with pytest.raises(WorldError, match=r"bad\.tile\.txt: line 2"):
        hold_map_tile(tmp_path / "bad.pcd")
    (tmp_path / "one.tile.txt").write_text("0.1 0.2 0.03\n")
    with pytest.raises(WorldError, match=r"one\.tile\.txt: need at least 2"):
        hold_map_tile(tmp_path / "one.pcd")


def test_tile_map_keeps_the_tiles_heights():
    tile = hold_map_tile(DATA / "leaning_bouldering_holds.pcd")
    holds = tile_map(tile, 0, (-0.3, 0.7), (-0.35, 0.35))
    assert len(holds) % len(tile) == 0
    np.testing.assert_array_equal(holds[:, 2], np.tile(tile[:, 2], len(holds) // len(tile)))


def test_the_twin_builds_a_hold_map_without_plugins():
    code = (
        "import sys\n"
        "from climbd.drivers.sim.worlds import hold_map_holds, load\n"
        "holds = hold_map_holds(load('slope_map'))\n"
        "assert len(holds) > 10, holds.shape\n"
        "print(sorted(m for m in sys.modules if m.startswith('climbd.plugins')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
