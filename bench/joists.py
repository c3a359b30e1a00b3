"""Joist pipeline per frame (points → grid → inpaint → lines → joists) beside the paper's way.

Frames: 640×480 ray-cast clouds (tests/support/joist_scenes.py) of a robot walking toward a 10 cm
joist at 45°, rendered once before timing. Ours: ``JoistPerception.process_cloud`` (one frame fused
into the odometry-frame map, crop read back, float Telea, Edge Drawing, step heights, merge).
Baseline, in the same run and on the same frames: ``PaperPipeline`` (the accumulated cloud of
the last 10 frames re-gridded from scratch every frame, 8-bit Telea, Edge Drawing, eq. 1
strip means). Both for the 1 m box and the 3 m box of test 7. Goal: our median ≤ 10 ms.
Also writes docs/img/joists_detection.png (one detection overlaid on the grid).
``--accuracy``: Table 1's errors instead (the 10 and 18 cm joists at 30–75°, walked toward from
1 m to 0.55 m, four frames each, as tests/test_joists_tables.py): our largest yaw, height and
distance errors beside the paper's pipeline's yaw error on the same frames.

    .venv/bin/python bench/joists.py [--repeats 5] [--frames 12] [--accuracy]
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from support.joist_scenes import JoistSpec, body_state, render  # noqa: E402

from climbd.daemon.algorithms.elevation import ElevationConfig  # noqa: E402
from climbd.plugins.perception import joists  # noqa: E402
from climbd.plugins.perception.joist_perception import (  # noqa: E402
    JoistPerception,
    JoistPerceptionConfig,
)
from climbd.plugins.perception.joists import height_image  # noqa: E402
from climbd.plugins.perception.joists_paper import PaperPipeline  # noqa: E402


def frames(count: int, joist: JoistSpec, stop: float) -> list[tuple[np.ndarray, object]]:
    """Clouds and body states of a straight walk from x = 0 to ``stop``."""
    rng = np.random.default_rng(0)
    xs = np.linspace(0.0, stop, count)
    return [(render([joist], x=float(x), rng=rng), body_state(float(x))) for x in xs]


def run(make, data, repeats: int) -> list[float]:
    """Per-frame times (s) of ``repeats`` passes over ``data``, a fresh pipeline each pass."""
    times = []
    for _ in range(repeats):
        pipeline = make()
        for points, body in data:
            t0 = time.perf_counter()
            pipeline(points, body)
            times.append(time.perf_counter() - t0)
    return times


def stages(grid: ElevationConfig, data) -> list[tuple[float, float, float]]:
    """Per-frame times (s) of our three stages: fuse, crop + inpaint, lines + joists."""
    plugin = JoistPerception(JoistPerceptionConfig(grid=grid))
    out = []
    for points, body in data:
        t0 = time.perf_counter()
        plugin.map.integrate(points, body)
        t1 = time.perf_counter()
        filled = plugin.map.crop(body)
        t2 = time.perf_counter()
        plugin.detector.detect(filled)
        out.append((t1 - t0, t2 - t1, time.perf_counter() - t2))
    return out


def stats(times: list[float]) -> tuple[float, float]:
    ms = sorted(t * 1e3 for t in times)
    return statistics.median(ms), ms[min(len(ms) - 1, int(math.ceil(0.99 * len(ms))) - 1)]


def overlay(plugin: JoistPerception, path: Path) -> None:
    """PNG of the filled grid (near edge at the bottom), Edge Drawing lines, the joist found."""
    grid = plugin.grid
    d = plugin.detector.config
    scale = 3
    img = cv2.cvtColor(height_image(grid.filled, d.image_floor, d.image_scale), cv2.COLOR_GRAY2BGR)
    img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)

    def px(row: float, col: float) -> tuple[int, int]:
        return int(round((col + 0.5) * scale)), int(round((row + 0.5) * scale))

    for x1, y1, x2, y2 in plugin.detector.last_lines:
        cv2.line(img, px(y1, x1), px(y2, x2), (0, 0, 255), 1, cv2.LINE_AA)
    res = grid.resolution
    for j in plugin.detector.detect(grid):
        (xa, ya, _), (xb, yb, _) = j.endpoints
        a = px((xa - grid.origin_x) / res - 0.5, (ya - grid.origin_y) / res - 0.5)
        b = px((xb - grid.origin_x) / res - 0.5, (yb - grid.origin_y) / res - 0.5)
        cv2.line(img, a, b, (0, 200, 0), 2, cv2.LINE_AA)
    img = np.ascontiguousarray(img[::-1, ::-1])
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img, [cv2.IMWRITE_PNG_COMPRESSION, 9])


def table_1_errors(joist: JoistSpec, seed: int) -> tuple[np.ndarray, list[float]]:
    """Our (yaw °, height m, distance m) errors and the paper's pipeline's yaw errors (°) on
    the four frames of a Table 1 walk."""
    plugin, paper = JoistPerception(), PaperPipeline()
    rng = np.random.default_rng(seed)
    yaw_deg = math.degrees(joist.yaw)
    errors, paper_yaw = [], []
    for x in (0.0, 0.15, 0.3, 0.45):
        points, body = render([joist], x=x, rng=rng), body_state(x)
        (nearest, *_) = plugin.process_cloud(points, body, x).joists
        errors.append(
            (
                abs(math.degrees(nearest.yaw) - yaw_deg),
                abs(nearest.height - joist.height),
                abs(nearest.distance - joist.distance_from(x, 0.0)),
            )
        )
        theirs = paper.process(points, body)
        if theirs:
            paper_yaw.append(min(abs(math.degrees(j.yaw) - yaw_deg) for j in theirs))
    return np.max(errors, axis=0), paper_yaw


def accuracy() -> None:
    """Table 1 errors of ours, of ours without the near edge's refinement (the ablation), and
    of the paper's pipeline, on the same ray-cast frames."""
    print(
        "| height | yaw | ours: yaw error max | height error max | distance error max | "
        "without edge refinement: yaw error max | paper's way: yaw error max |"
    )
    print("|---|---|---|---|---|---|---|")
    for height in (0.10, 0.18):
        for yaw_deg in (30.0, 45.0, 60.0, 70.0, 75.0):
            joist = JoistSpec(distance=1.0, yaw=math.radians(yaw_deg), height=height)
            seed = int(height * 100 + yaw_deg)
            worst, paper_yaw = table_1_errors(joist, seed)
            refine, joists.REFINE_MIN_PIECES = joists.REFINE_MIN_PIECES, sys.maxsize
            try:
                unrefined, _ = table_1_errors(joist, seed)
            finally:
                joists.REFINE_MIN_PIECES = refine
            their = f"{max(paper_yaw):.2f}°" if paper_yaw else "none found"
            print(
                f"| {height * 100:.0f} cm | {yaw_deg:.0f}° | {worst[0]:.2f}° | "
                f"{worst[1] * 1000:.1f} mm | {worst[2] * 1000:.1f} mm | {unrefined[0]:.2f}° | "
                f"{their} |"
            )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--accuracy", action="store_true", help="Table 1's errors, not times")
    args = parser.parse_args()
    if args.accuracy:
        accuracy()
        return 0
    joist = JoistSpec(distance=1.0, yaw=math.radians(45.0), height=0.10)
    rows = []
    for label, length in (("1 m box", 1.0), ("3 m box", 3.0)):
        grid = ElevationConfig(length=length)
        data = frames(args.frames, joist, stop=0.45)
        npts = statistics.median(len(p) for p, _ in data)

        def ours(grid=grid):
            plugin = JoistPerception(JoistPerceptionConfig(grid=grid))
            return lambda points, body: plugin.process_cloud(points, body, 0.0)

        def paper(grid=grid):
            return PaperPipeline(grid=grid).process

        t_ours, t_paper, t_stage = [], [], []
        for _ in range(args.repeats):
            t_ours += run(ours, data, 1)
            t_paper += run(paper, data, 1)
            t_stage += stages(grid, data)
        m_o, p_o = stats(t_ours)
        m_p, p_p = stats(t_paper)
        split = np.median(np.array(t_stage), axis=0) * 1e3
        rows.append((label, npts, m_o, p_o, m_p, p_p, split))

    print(f"frames: 640×480 ray-cast, {args.frames} per walk × {args.repeats} walks")
    print("| crop box | fuse points | crop + float Telea | lines + joists |")
    print("|---|---|---|---|")
    for label, *_, split in rows:
        print(f"| {label} | {split[0]:.2f} ms | {split[1]:.2f} ms | {split[2]:.2f} ms |")
    print()
    print(
        "| crop box | points/frame | ours median | ours p99 | paper's way median | "
        "paper's way p99 | median ratio (paper/ours) |"
    )
    print("|---|---|---|---|---|---|---|")
    for label, npts, m_o, p_o, m_p, p_p, _ in rows:
        print(
            f"| {label} | {npts:,.0f} | {m_o:.2f} ms | {p_o:.2f} ms | {m_p:.2f} ms | "
            f"{p_p:.2f} ms | {m_p / m_o:.1f}× |"
        )
    plugin = JoistPerception()
    for points, body in frames(3, joist, stop=0.2):
        plugin.process_cloud(points, body, 0.0)
    out = ROOT / "docs" / "img" / "joists_detection.png"
    overlay(plugin, out)
    print(f"overlay: {out.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
