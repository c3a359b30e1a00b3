"""The world model's terrain map per 640×480 frame (fuse + every layer) and its point queries.

Frames: ray-cast L515 clouds (tests/support/joist_scenes.py, range noise and dropout) of a robot
walking and turning toward a 10 cm joist, rendered before timing. Ours: ``TerrainModel.update``
(cv2 fusion into the rolling odometry window, terrain layers refreshed over the frame's
footprint). Baseline in the same run, on the same frames: ``PlainTerrain``, the same map written
in plain numpy (``np.maximum.at`` fusion, the filter chain over the whole window every frame).
Queries: ``TerrainView.traversability_at`` + ``height_at`` (one foothold check) against numpy
fancy indexing of one cell. Goals (issue #32): update median ≤ 15 ms, a check ≤ 50 µs.
Rounds alternate ours and the baseline; the table gives each round's medians and the spread.

    .venv/bin/python bench/world.py [--rounds 5] [--frames 40]
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from support.joist_scenes import JoistSpec, body_state, render  # noqa: E402

from climbd.daemon.algorithms.elevation import ElevationMap  # noqa: E402
from climbd.daemon.algorithms.terrain import terrain_layers  # noqa: E402
from climbd.daemon.algorithms.world import TerrainModel, TerrainView, WorldConfig  # noqa: E402
from climbd.daemon.contract.geometry import rotation  # noqa: E402
from climbd.daemon.contract.messages import BodyState  # noqa: E402

CONFIG = WorldConfig()


class PlainTerrain:
    """The baseline: the same rolling window and layers in plain numpy, whole window per frame."""

    def __init__(self) -> None:
        self.window = ElevationMap(CONFIG.elevation)  # for its size and origin rule only
        side = self.window.side
        self.height = np.full((side, side), np.nan)
        self.weight = np.zeros((side, side))
        self.origin: np.ndarray | None = None

    def update(self, points: np.ndarray, body: BodyState) -> None:
        c = CONFIG.elevation
        res, side = c.resolution, self.window.side
        keep = (
            (points[:, 0] >= c.x_min)
            & (points[:, 0] < c.x_min + c.length)
            & (np.abs(points[:, 1]) < c.width / 2)
            & (points[:, 2] >= c.z_min)
            & (points[:, 2] <= c.z_max)
        )
        world = points[keep] @ rotation(body.orientation).T + np.asarray(body.position)
        if self.origin is None:
            self.origin = np.floor(np.asarray(body.position[:2]) / res) * res - side // 2 * res
        cells = np.floor((world[:, :2] - self.origin) / res).astype(np.int64)
        inside = np.all((cells >= 0) & (cells < side), axis=1)
        flat = cells[inside, 0] * side + cells[inside, 1]
        top = np.full(side * side, -np.inf)
        np.maximum.at(top, flat, world[inside, 2])
        hit = np.isfinite(top).reshape(side, side)
        w = np.minimum(self.weight + 1.0, c.memory_frames)
        top = np.where(hit, top.reshape(side, side), 0.0)
        old = np.where(self.weight > 0, self.height, top)
        fused = old + (top - old) / w
        self.height = np.where(hit, fused, self.height)
        self.weight = np.where(hit, w, self.weight)
        terrain_layers(self.height, res, CONFIG.terrain)


def scene(count: int) -> list[tuple[np.ndarray, BodyState]]:
    """Clouds and body states of a 0.6 m walk toward a 10 cm joist at 30°, turning ±10°."""
    joist = JoistSpec(distance=1.2, yaw=math.radians(30.0), height=0.10, width=0.04, length=1.8)
    rng = np.random.default_rng(0)
    out = []
    for k in range(count):
        x, yaw = 0.6 * k / count, math.radians(10.0) * math.sin(k / 5)
        body = body_state(x, 0.0, yaw)
        body.stamp = k / 30.0
        out.append((render([joist], x=x, yaw=yaw, rng=rng), body))
    return out


def time_updates(make, frames) -> list[float]:
    model = make()
    times = []
    for points, body in frames:
        t0 = time.perf_counter()
        model.update(points, body)
        times.append(time.perf_counter() - t0)
    return times


def time_queries(view: TerrainView, points: np.ndarray) -> tuple[float, float]:
    """Per-check time (s) of ours (height + traversability) and of numpy indexing of a cell."""
    t0 = time.perf_counter()
    for x, y in points:
        view.traversability_at(x, y)
        view.height_at(x, y)
    ours = (time.perf_counter() - t0) / len(points)
    m = view.message
    grid = view._layers["traversability"]
    t0 = time.perf_counter()
    for x, y in points:
        cell = np.floor((np.array([x, y]) - [m.origin_x, m.origin_y]) / m.resolution).astype(int)
        grid[cell[0], cell[1]]
    return ours, (time.perf_counter() - t0) / len(points)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--frames", type=int, default=40)
    args = parser.parse_args()
    frames = scene(args.frames)
    pixels = max(len(p) for p, _ in frames)
    print(f"{args.frames} frames of up to {pixels} points (640×480 less dropout and sky)")
    rows = []
    for r in range(args.rounds):
        ours = statistics.median(time_updates(lambda: TerrainModel(CONFIG), frames[1:]))
        base = statistics.median(time_updates(PlainTerrain, frames[1:]))
        model = TerrainModel(CONFIG)
        for points, body in frames:
            model.update(points, body)
        view = TerrainView(model.message(frames[-1][1].stamp, frames[-1][1]))
        rng = np.random.default_rng(r)
        x0 = frames[-1][1].position[0]
        checks = np.column_stack(
            [rng.uniform(x0 + 0.2, x0 + 1.0, 5000), rng.uniform(-0.5, 0.5, 5000)]
        )
        q_ours, q_base = time_queries(view, checks)
        rows.append((ours, base, q_ours, q_base))
        print(
            f"round {r + 1}: update {ours * 1e3:6.2f} ms (numpy {base * 1e3:6.2f} ms, "
            f"ratio {ours / base:.2f}); check {q_ours * 1e6:5.2f} µs "
            f"(numpy cell {q_base * 1e6:5.2f} µs, ratio {q_ours / q_base:.2f})"
        )
    cols = list(zip(*rows, strict=True))

    def spread(values, scale: float) -> str:
        v = sorted(x * scale for x in values)
        return f"{statistics.median(v):.2f} ({v[0]:.2f}-{v[-1]:.2f})"

    print("\n| measure | ours | baseline | ratio (median, range) |")
    print("|---|---|---|---|")
    ratio_u = [a / b for a, b in zip(cols[0], cols[1], strict=True)]
    ratio_q = [a / b for a, b in zip(cols[2], cols[3], strict=True)]
    print(
        f"| update per frame (ms, goal ≤ 15) | {spread(cols[0], 1e3)} | "
        f"{spread(cols[1], 1e3)} | {spread(ratio_u, 1.0)} |"
    )
    print(
        f"| foothold check (µs, goal ≤ 50) | {spread(cols[2], 1e6)} | "
        f"{spread(cols[3], 1e6)} | {spread(ratio_q, 1.0)} |"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
