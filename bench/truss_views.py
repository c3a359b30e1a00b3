"""The persistent truss model (issue 37 item 3): accuracy and confidence after 1, 3 and 10 views.

Two scenes, a space frame with sphere connectors of 1x the tube diameter (``space_frame()``) and
the five-member scaffold (``five_member()``), each seen from 10 views all around it at full
Kinect-2 resolution with ``DepthNoise()`` (its per-view pose error included). Views are fed one
by one; after 1, 3 and 10 of them, the tube extents are scored against the true tubes (mean and
worst length error, worst end point error, worst axis error, mean confidence; found: the
fraction of the true members found; false: detections matching none) for:
- accumulated, fused: the plugin's way, the whole accumulated cloud modelled each view and its
  members fused by ``MemberTracks`` (each weighted by its coverage times the views it rests on);
- accumulated, latest: the latest model of the accumulated cloud alone (before issue 37 item 3);
- per view, fused: each view's cloud modelled alone, its members fused;
- per view, latest: the latest view's model alone.
Median over ``--seeds`` seeds with the range (min-max) in brackets.

    .venv/bin/python bench/truss_views.py [--seeds 0 1 2] [--views 10]
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator

import numpy as np

from climbd.drivers.sim import truss_scene as ts
from climbd.plugins.perception.truss import TrussConfig, TrussModeller
from climbd.plugins.perception.truss.cloud import VoxelMap, body_to_odometry, voxel_downsample
from climbd.plugins.perception.truss.completion import Member
from climbd.plugins.perception.truss.evaluate import evaluate
from climbd.plugins.perception.truss.model import coverage
from climbd.plugins.perception.truss.tracking import FieldOfView, MemberTracks, Sighting

AIM = np.array([-0.4, 0.0, 0.95])
"""The middle of the default space frame (m)."""
CHECKPOINTS = (1, 3, 10)
Scored = list[tuple[Member, float]]
"""Members of a model with their confidences."""


def frame_poses(count: int) -> list[np.ndarray]:
    """``count`` oblique views of the space frame, 2.3 m up, all around it."""
    angles = np.radians(20 + np.arange(count) * 360 / count)
    return [
        ts.look_at_pose([AIM[0] + 3.0 * np.cos(a), AIM[1] + 2.6 * np.sin(a), 2.3], AIM)
        for a in angles
    ]


def scene(name: str, seed: int, views: int) -> ts.TrussScene:
    """One of the two scenes seen from ``views`` poses with ``DepthNoise()``."""
    if name == "five members":
        five = ts.five_member()
        return ts.render(five, ts.orbit_poses(five, count=views), seed=seed)
    return ts.render(ts.space_frame("sphere", 1.0), frame_poses(views), seed=seed)


def scored(modeller: TrussModeller, points: np.ndarray, bin_size: float) -> Scored:
    """A model's members, each with its coverage (the plugin's confidence of one model)."""
    model = modeller.model(points)
    return [(m, coverage(m, model.points, bin_size)) for m in model.members]


def fused(
    tracks: MemberTracks, members: Scored, frames: int, view: ts.View, max_range: float
) -> Scored:
    """Fold a model's members into ``tracks`` as the plugin does, its view the one in view."""
    sightings = [Sighting.of(m, c, frames) for m, c in members]
    tracks.update(sightings, view.body.stamp, [FieldOfView(view.points, view.body, max_range)])
    return [(m, t.confidence) for t, m in tracks.members()]


def run(seen: ts.TrussScene, config: TrussConfig) -> Iterator[tuple[str, int, Scored]]:
    """Each method's members after each view."""
    modeller = TrussModeller(config)
    voxels = VoxelMap(config.voxel)
    bin_size = 2 * config.voxel
    accumulated, per_view = (MemberTracks(config.track_gate, config.track_expiry) for _ in range(2))
    for k, view in enumerate(seen.views, start=1):
        points = body_to_odometry(view.points, view.body)
        voxels.add(points)
        whole = scored(modeller, voxels.points, bin_size)
        alone = scored(modeller, voxel_downsample(points, config.voxel), bin_size)
        reach = config.max_range
        yield "accumulated, fused", k, fused(accumulated, whole, k, view, reach)
        yield "accumulated, latest", k, whole
        yield "per view, fused", k, fused(per_view, alone, 1, view, reach)
        yield "per view, latest", k, alone


def figures(members: Scored, seen: ts.TrussScene) -> dict[str, float]:
    """The tube extents' errors against the true tubes, and the mean confidence."""
    truth = [(t.p0, t.p1, t.radius) for t in seen.members]
    accuracy = evaluate([(m.p0, m.p1) for m, _ in members], truth)
    return {
        "found": accuracy.found / len(truth),
        "false": accuracy.false_members,
        "len %": accuracy.mean("relative_length_error") * 100,
        "len % max": accuracy.max("relative_length_error") * 100,
        "end mm max": accuracy.max("end_error") * 1000,
        "axis deg max": accuracy.max("angle_error_deg"),
        "confidence": float(np.mean([c for _, c in members])) if members else float("nan"),
    }


def cell(values: list[float], digits: int) -> str:
    """Median over the seeds, with the range in brackets."""
    values = [v for v in values if np.isfinite(v)]
    if not values:
        return "–"
    median = np.median(values)
    return f"{median:.{digits}f} ({min(values):.{digits}f}–{max(values):.{digits}f})"


DIGITS: dict[str, int] = {
    "found": 2,
    "false": 0,
    "len %": 2,
    "len % max": 2,
    "end mm max": 1,
    "axis deg max": 2,
    "confidence": 2,
}


def table(results: dict[tuple[str, str, int], list[dict[str, float]]]) -> str:
    """The markdown table: a row per scene, method and number of views."""
    lines = [
        f"| scene | method | views | {' | '.join(DIGITS)} |",
        "|---|---|---|" + "---|" * len(DIGITS),
    ]
    for (name, method, views), runs in sorted(results.items()):
        cells = [cell([r[f] for r in runs], d) for f, d in DIGITS.items()]
        lines.append(f"| {name} | {method} | {views} | {' | '.join(cells)} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--views", type=int, default=10)
    args = parser.parse_args()
    results: dict[tuple[str, str, int], list[dict[str, float]]] = {}
    for name in ("space frame, 1x spheres", "five members"):
        for seed in args.seeds:
            seen = scene(name, seed, args.views)
            for method, k, members in run(seen, TrussConfig(seed=seed)):
                if k in CHECKPOINTS:
                    results.setdefault((name, method, k), []).append(figures(members, seen))
    print(table(results))


if __name__ == "__main__":
    main()
