"""Every registered perception plugin finds nothing, and raises nothing, on degenerate input.

Each plugin is loaded through its entry point with each stock profile that runs it (or the
WidowX profile) and fed, through ``process`` and ``process_cloud``, what a blank lens, a
covered camera, a corrupt depth scale or a garbage file gives: it returns its empty feature
message (or None), never an exception, and no numeric warning. The elevation grid is a map,
not a detector: a few valid points are a few measured cells, and nothing beyond them.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib.metadata import entry_points
from pathlib import Path

import numpy as np
import pytest

from climbd.daemon.algorithms.cloud import frame_to_points
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.hardware import DepthFrame, Intrinsics, mount_extrinsics
from climbd.daemon.contract.messages import (
    BodyState,
    ElevationGrid,
    GraspablePoints,
    Joists,
    Message,
    Stairs,
    TrussGrasps,
    TrussMembers,
)
from climbd.daemon.contract.plugins import PerceptionPlugin
from climbd.daemon.runtime.loader import instantiate

ROBOTS = Path(__file__).resolve().parent.parent / "robots"
FALLBACK = "widowx.toml"
GROUP = "climbd.perception"

EMPTY: dict[type[Message], Callable[[Message, int], bool]] = {
    ElevationGrid: lambda m, valid: np.isfinite(np.frombuffer(m.heights, "<f4")).sum() <= valid,
    GraspablePoints: lambda m, _: m.points == [],
    Joists: lambda m, _: m.joists == [],
    Stairs: lambda m, _: m.steps == [],
    TrussMembers: lambda m, _: m.members == [],
    TrussGrasps: lambda m, _: m.grasps == [],
}
"""How each feature type says "nothing found" of an input with ``valid`` points in range."""


def plugin_profiles() -> list[tuple[str, str]]:
    """(plugin, profile file) for every registered plugin and every stock profile that runs
    it; the WidowX profile for a plugin no stock profile lists."""
    stock = {path.name: profiles.load(path) for path in sorted(ROBOTS.glob("*.toml"))}
    pairs = []
    for name in sorted(ep.name for ep in entry_points(group=GROUP)):
        running = [f for f, p in stock.items() if name in {s.name for s in p.plugins.perception}]
        pairs += [(name, f) for f in running or [FALLBACK]]
    return pairs


def start(name: str, robot: str) -> tuple[PerceptionPlugin, profiles.Profile]:
    """The plugin as the perception role starts it: entry point, profile overrides, profile."""
    profile = profiles.load(ROBOTS / robot)
    specs = {s.name: s.config for s in profile.plugins.perception}
    plugin = instantiate(GROUP, name, specs.get(name, {}), profile, f"{robot}: {name}")
    return plugin, profile


def frame(profile: profiles.Profile, depth: np.ndarray, depth_scale: float) -> DepthFrame:
    """A depth frame of the profile's first camera (a plain pinhole, 60° across)."""
    camera = profile.cameras[0]
    h, w = depth.shape
    focal = w / (2 * np.tan(np.radians(30)))
    intrinsics = Intrinsics(w, h, focal, focal, w / 2, h / 2)
    return DepthFrame(depth, depth_scale, intrinsics, mount_extrinsics(camera), 1.0)


def blank(shape: tuple[int, int]) -> tuple[np.ndarray, float]:
    """No return anywhere (a covered lens)."""
    return np.zeros(shape, np.uint16), 0.001


def five_pixels(shape: tuple[int, int]) -> tuple[np.ndarray, float]:
    """Five valid pixels at 1 m, scattered over the image."""
    depth = np.zeros(shape, np.uint16)
    h, w = shape
    for k in range(5):
        depth[h // 3 + 7 * k, w // 3 + 11 * k] = 1000
    return depth, 0.001


def far(metres: float) -> Callable[[tuple[int, int]], tuple[np.ndarray, float]]:
    """Every pixel at ``metres`` (a corrupt depth scale)."""

    def make(shape: tuple[int, int]) -> tuple[np.ndarray, float]:
        return np.full(shape, 1000, np.uint16), metres / 1000

    return make


FRAMES = {
    "blank": blank,
    "five_pixels": five_pixels,
    "far_1e6": far(1e6),
    "far_1e30": far(1e30),
}


def floor(scale: float) -> np.ndarray:
    """A 1 m × 1 m floor patch ahead of the body with a 10 cm step, its coordinates × scale."""
    x, y = np.meshgrid(np.linspace(0.3, 1.3, 60), np.linspace(-0.5, 0.5, 60))
    z = np.where(x > 0.8, 0.1, 0.0)
    return np.column_stack([x.ravel(), y.ravel(), z.ravel()]) * scale


def no_finite_row() -> np.ndarray:
    """NaN, +inf, -inf and rows mixing them with finite values: no point is whole."""
    bad = [np.nan, np.inf, -np.inf]
    rows = [[a, b, c] for a in [*bad, 0.5] for b in [*bad, 0.0] for c in [*bad, 0.1]]
    return np.array([r for r in rows if not np.isfinite(r).all()] * 20)


CLOUDS = {
    "empty": np.zeros((0, 3)),
    "one_point": np.array([[0.5, 0.0, 0.0]]),
    "five_points": floor(1.0)[::720][:5],
    "all_nan": np.full((500, 3), np.nan),
    "nan_inf_rows": no_finite_row(),
    "huge_1e6": floor(1e6),
    "huge_1e30": floor(1e30),
}

PAIRS = plugin_profiles()


def assert_empty(
    plugin: PerceptionPlugin, result: Message | tuple[Message, ...] | None, valid: int
) -> None:
    """None, or the plugin's feature types (one or a tuple) holding nothing (given ``valid``
    points)."""
    for message in result if isinstance(result, tuple) else (result,):
        if message is not None:
            assert type(message) in plugin.publishes
            assert EMPTY[type(message)](message, valid), message


def in_range(points: np.ndarray) -> int:
    """How many points are finite and within 10 m of the body."""
    with np.errstate(invalid="ignore", over="ignore"):
        return int((np.linalg.norm(points, axis=1) <= 10.0).sum())


def test_every_registered_plugin_is_covered() -> None:
    names = {name for name, _ in PAIRS}
    assert names == {ep.name for ep in entry_points(group=GROUP)}
    for name, robot in PAIRS:
        plugin, _ = start(name, robot)
        assert set(plugin.publishes) <= set(EMPTY), f"{name}: say what its nothing looks like"


@pytest.mark.filterwarnings("error::RuntimeWarning")
@pytest.mark.parametrize("case", FRAMES)
@pytest.mark.parametrize(("name", "robot"), PAIRS)
def test_degenerate_frame_finds_nothing(name: str, robot: str, case: str) -> None:
    plugin, profile = start(name, robot)
    camera = profile.cameras[0]
    depth, depth_scale = FRAMES[case]((camera.height, camera.width))
    depth_frame = frame(profile, depth, depth_scale)
    message = plugin.process(depth_frame, BodyState())
    assert_empty(plugin, message, in_range(frame_to_points(depth_frame)))


@pytest.mark.filterwarnings("error::RuntimeWarning")
@pytest.mark.parametrize("case", CLOUDS)
@pytest.mark.parametrize(("name", "robot"), PAIRS)
def test_degenerate_cloud_finds_nothing(name: str, robot: str, case: str) -> None:
    plugin, _ = start(name, robot)
    points = CLOUDS[case]
    assert_empty(plugin, plugin.process_cloud(points, BodyState(), 1.0), in_range(points))
