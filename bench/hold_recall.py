"""Graspable holds seen by HubRobo's own camera in the twin, against the holds placed there.

For each hold-map seed of ``slope_map`` (the free-climb bench's maps), HubRobo stands gripping
its start holds; the twin ray-casts its D435 (640×480, 45° down) and graspable detection
(paper 001, the perception plugin's defaults) runs on the body-frame cloud. Scored by the twin's
truth: a detection is true when a placed hold's top centre lies within ``--tolerance`` (m, in
the wall plane) of it; recall counts the placed holds in view (inside the image, on the board)
that some detection found. The baseline, in the same run: a flat board with no holds (every
detection there is false). Detection time is the median over the seeds; beside it, the
occlusion-filling stage (Delaunay and interpolation onto the lattice) on every point of the
frame against on the point nearest each lattice node (what detection does), same frame.

``--relief rock`` puts on the board the rock each tile of holds was detected on (worlds.HoldMap)
instead of the holds' columns.

    .venv/bin/python bench/hold_recall.py [--seeds 8] [--tolerance 0.01] [--relief rock]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support.climb_run import SlopeClimb  # noqa: E402

from climbd.daemon.contract.geometry import regression_frame  # noqa: E402
from climbd.daemon.contract.messages import BodyState  # noqa: E402
from climbd.plugins.perception.graspable import (  # noqa: E402
    GraspablePerception,
    interpolate_heights,
    lattice_spacing,
    nearest_per_node,
    within_range,
)


def in_view(climb: SlopeClimb, body_points: np.ndarray) -> np.ndarray:
    """Which body-frame points the front camera's image covers within its range."""
    frame = climb.twin.depth_frame("front")
    k, to_body = frame.intrinsics, np.asarray(frame.extrinsics)
    cam = (body_points - to_body[:3, 3]) @ to_body[:3, :3]
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = k.fx * cam[:, 0] / z + k.ppx
        v = k.fy * cam[:, 1] / z + k.ppy
    return (z > 0.05) & (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)


def filling(plugin: GraspablePerception, cloud: np.ndarray) -> tuple[float, float, int, int]:
    """Seconds of the occlusion-filling stage on ``cloud`` (body frame): on every point, and on
    the point nearest each lattice node; and how many points each was."""
    cfg = plugin.config
    cloud = within_range(cloud, cfg.max_range)
    plane = regression_frame(cloud, np.zeros(3)).to_plane(cloud)
    spacing = lattice_spacing(plane, cfg.voxel, cfg.lattice_spacing)
    start = time.perf_counter()
    interpolate_heights(plane, spacing)
    every = time.perf_counter() - start
    start = time.perf_counter()
    kept = nearest_per_node(plane, spacing)
    interpolate_heights(kept, spacing)
    return every, time.perf_counter() - start, len(plane), len(kept)


def score(
    seed: int, tolerance: float, plugin: GraspablePerception, relief: str
) -> tuple[int, int, int, float, tuple[float, float, int, int]]:
    """(holds in view, of them found, false detections, detection seconds, the filling stage's
    seconds on every point and on one a node with those points' counts) for one map."""
    climb = SlopeClimb(periodic=False, seed=seed, relief=relief)
    try:
        frame = climb.twin.depth_frame("front")
        clouds: list[np.ndarray] = []
        detect = plugin.detector.detect
        plugin.detector.detect = lambda points: clouds.append(points) or detect(points)
        start = time.perf_counter()
        found = np.asarray(plugin.process(frame, BodyState()).points).reshape(-1, 3)
        seconds = time.perf_counter() - start
        plugin.detector.detect = detect
        stage = filling(plugin, clouds[0])
        base = climb.runner.base
        tops = climb.holds.copy()
        tops[:, 2] -= climb.twin.robot.foot_radius  # the top face, not the foot on it
        holds = tops - base
        visible = holds[in_view(climb, holds)]
        if not len(found):
            return len(visible), 0, 0, seconds, stage
        near, _ = cKDTree(found[:, :2]).query(visible[:, :2])
        hits = int(np.count_nonzero(near <= tolerance))
        to_hold, _ = cKDTree(holds[:, :2]).query(found[:, :2])
        false = int(np.count_nonzero(to_hold > tolerance))
        return len(visible), hits, false, seconds, stage
    finally:
        climb.close()


def flat_board(plugin: GraspablePerception) -> int:
    """Detections on a board without holds, seen from the same stance (all false)."""
    climb = SlopeClimb(periodic=False, seed=0)
    try:
        twin = climb.twin
        for g in twin.robot.graspable_geoms:
            twin.model.geom_rgba[g, 3] = 0.0
            twin.model.geom_size[g] = 1e-6
        frame = climb.twin.depth_frame("front")
        return len(plugin.process(frame, BodyState()).points)
    finally:
        climb.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--tolerance", type=float, default=0.01)
    parser.add_argument("--relief", choices=["columns", "rock"], default="columns")
    args = parser.parse_args()
    plugin = GraspablePerception()
    print(
        "| seed | holds in view | found | recall | false detections | detection (s) "
        "| filling, every point / one a node (s) | ratio | points / kept |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    times, ratios, seen, hit = [], [], 0, 0
    for seed in range(args.seeds):
        visible, found, false, seconds, (every, reduced, points, kept) = score(
            seed, args.tolerance, plugin, args.relief
        )
        times.append(seconds)
        ratios.append(every / reduced)
        seen, hit = seen + visible, hit + found
        print(
            f"| {seed} | {visible} | {found} | {found / max(visible, 1):.0%} | {false} "
            f"| {seconds:.2f} | {every:.2f} / {reduced:.2f} | {every / reduced:.1f} "
            f"| {points} / {kept} |"
        )
    print(
        f"all: recall {hit / max(seen, 1):.0%} ({hit}/{seen}), median detection "
        f"{statistics.median(times):.2f} s per 640×480 frame; the filling stage "
        f"{min(ratios):.1f}-{max(ratios):.1f}x faster on one point a node"
    )
    print(f"baseline, the board without holds: {flat_board(plugin)} detections (all false)")


if __name__ == "__main__":
    main()
