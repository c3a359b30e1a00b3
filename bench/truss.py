"""Truss modelling (paper 003) per scene of 100k points beside pyransac3d, with both accuracies.

For each truss (the paper's 5- and 7-member experiments, and an 18-member scaffold) a scene
is rendered at Kinect-2 resolution from several poses and 100 000 points are drawn from the
merged cloud (the scaffold keeps its whole cloud). On the same points, in the same run:
- ours: ``TrussModeller.model`` (voxels, plane removal, RANSAC with normals, sliding-box
  completion, merging); its RANSAC-only initial model is scored too, as in the paper;
- the peer: pyransac3d, its own ``Plane`` fit to drop the floor, then one ``Cylinder`` fit per
  ground-truth member, each removing its inliers, ends at the inliers' extent on the axis.
Prints time per scene (median of ``--repeat``; wall and the process's CPU time, which a
loaded shared machine inflates less), the peer/ours time ratio, the load average around the
run, and the paper's metrics; writes a figure like the paper's Figs. 9-11 to bench/out/truss.png.
``--gap-rule paper absolute`` models each scene once per rule of step 7 (the paper's relative
(G_max / G_min) * ε, ε from ``--gap-epsilon``; ours, an absolute gap), on the same points.

``--frames`` benchmarks nodes as features instead (issue 37): space frames whose members end
on connectors (box, sphere, plate) of 1x and 3x the tube diameter, tubes of 30 and 80 mm, seen
from four oblique views all around, noise-free and with ``DepthNoise()``; per connector shape,
noise level and method, the tube extents against the true tubes and the node-to-node ends
against the true nodes, over the four frames of that shape, each on its whole merged cloud
(about 380 000 points at full Kinect-2 resolution; 100 000 drawn from it leave 30 mm tubes too
sparse: 2.9 % worst tube length against 0.3 % on the whole cloud, 1x spheres).

    .venv/bin/python bench/truss.py [--repeat 5] [--peer-iterations 300] [--no-scaffold]
        [--gap-rule paper absolute] [--gap-epsilon 1e-5] [--frames]
"""

from __future__ import annotations

import argparse
import random
import statistics
import time
from pathlib import Path

import numpy as np
import pyransac3d

from climbd.drivers.sim import truss_scene as ts
from climbd.plugins.perception.truss import TrussConfig, TrussModeller
from climbd.plugins.perception.truss.completion import GapRule
from climbd.plugins.perception.truss.evaluate import Accuracy, evaluate

POINTS = 100_000
FRAME_AIM = np.array([-0.4, 0.0, 0.95])
"""The middle of the default space frame (m), which the oblique views look down on."""


def scenes(seed: int, scaffold: bool) -> list[tuple[str, ts.TrussScene, int | None]]:
    """The benchmark trusses at full Kinect-2 resolution, and how many points to draw from
    each (None: the whole cloud; 100k random points leave an 18-member scaffold too sparse)."""
    chosen = [
        ("5 members", ts.render(ts.five_member(), seed=seed), POINTS),
        ("7 members", ts.render(ts.seven_member(), seed=seed), POINTS),
    ]
    if scaffold:
        frame = ts.scaffold(1, 2, 2)
        poses = ts.orbit_poses(frame, count=7, distance=3.5, spread_deg=160)
        chosen.append(
            (f"{len(frame.tubes)} members", ts.render(frame, poses=poses, seed=seed), None)
        )
    return chosen


def peer_model(points: np.ndarray, members: int, iterations: int) -> list[tuple]:
    """pyransac3d: its plane fit removes the floor, then one cylinder per member."""
    random.seed(0)
    _, floor = pyransac3d.Plane().fit(points, thresh=0.02, maxIteration=iterations)
    rest = np.delete(points, floor, axis=0)
    found = []
    for _ in range(members):
        if len(rest) < 3:
            break
        centre, axis, _, inliers = pyransac3d.Cylinder().fit(
            rest, thresh=0.01, maxIteration=iterations
        )
        if len(inliers) < 2:
            break
        axis = np.asarray(axis)
        t = (rest[inliers] - centre) @ axis
        found.append((centre + t.min() * axis, centre + t.max() * axis))
        rest = np.delete(rest, inliers, axis=0)
    return found


def timed(function, repeat: int):
    """Median wall and process CPU time (s) of ``repeat`` calls, and the last result."""
    times, cpu, result = [], [], None
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        result = function()
        times.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return statistics.median(times), statistics.median(cpu), result


def load_average() -> str:
    """The 1, 5 and 15 minute load averages (/proc/loadavg), for reading timings on a shared
    machine."""
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "n/a"


def row(name: str, method: str, seconds: tuple | None, accuracy: Accuracy, total: int) -> str:
    times = (
        "(same run) | (same run)"
        if seconds is None
        else " | ".join(f"{s * 1000:.0f}" for s in seconds)
    )
    errors = [
        f"{accuracy.mean('relative_length_error') * 100:.2f}",
        f"{accuracy.mean('length_error') * 1000:.1f}",
        f"{accuracy.mean('midpoint_error') * 1000:.1f}",
        f"{accuracy.mean('angle_error_deg'):.2f}",
    ]
    if accuracy.found == 0:
        errors = ["–"] * len(errors)
    return (
        f"| {name} | {method} | {times} | {accuracy.found}/{total} "
        f"| {accuracy.false_members} | {' | '.join(errors)} |"
    )


def figure(results: list, path: Path) -> None:
    """Per-member length, midpoint and angle errors of both methods (paper Figs. 9-11);
    an x marks a member the method did not find."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fields = [
        ("relative_length_error", "length error (%)", 100.0),
        ("midpoint_error", "midpoint error (mm)", 1000.0),
        ("angle_error_deg", "axis angle error (deg)", 1.0),
    ]
    fig, axes = plt.subplots(len(fields), len(results), figsize=(4.2 * len(results), 8))
    for col, (name, initial, completed) in enumerate(results):
        for row_, (field, label, scale) in enumerate(fields):
            ax = axes[row_, col]
            index = np.arange(len(completed.members))
            for offset, accuracy, colour, text in (
                (-0.2, initial, "tab:orange", "RANSAC only"),
                (0.2, completed, "tab:blue", "sliding box (ours)"),
            ):
                values = np.array([getattr(m, field) * scale for m in accuracy.members])
                ax.bar(index + offset, np.nan_to_num(values), 0.4, color=colour, label=text)
                missing = np.isnan(values)
                ax.plot(index[missing] + offset, np.zeros(missing.sum()), "x", color=colour)
            ax.set_xticks(index, [str(i + 1) for i in index], fontsize=7)
            if col == 0:
                ax.set_ylabel(label)
            if row_ == 0:
                ax.set_title(name)
        axes[-1, col].set_xlabel("member")
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)


def modellers(rules: list[GapRule], epsilon: float, seed: int) -> dict[GapRule, TrussModeller]:
    """One modeller per gap rule of step 7, otherwise configured alike."""
    return {
        rule: TrussModeller(TrussConfig(seed=seed, gap_rule=rule, gap_epsilon=epsilon))
        for rule in rules
    }


def frame_scene(shape: str, factor: float, diameter: float, noisy: bool, seed: int):
    """A space frame with ``shape`` connectors seen from four views 2.3 m up, all around it."""
    frame = ts.space_frame(shape, factor, diameter)
    poses = [
        ts.look_at_pose(FRAME_AIM + [3.0 * np.cos(a), 2.6 * np.sin(a), 1.35], FRAME_AIM)
        for a in np.radians([20, 110, 200, 290])
    ]
    quiet = ts.DepthNoise(0.0, 0.0, 0.0, 0.0, dropout=0.0, pose_translation=0.0, pose_rotation=0.0)
    return ts.render(frame, poses, noise=ts.DepthNoise() if noisy else quiet, seed=seed)


def frame_errors(detected: list, geometry: ts.TrussGeometry) -> tuple[Accuracy, Accuracy | None]:
    """Tube extents (p0, p1) against the true tubes; node ends, if any, against the nodes."""
    tubes = evaluate(
        [(d[0], d[1]) for d in detected], [(t.p0, t.p1, t.radius) for t in geometry.tubes]
    )
    if not detected or len(detected[0]) < 4:
        return tubes, None
    radius = geometry.tubes[0].radius
    truth = [(geometry.nodes[a], geometry.nodes[b], radius) for a, b in geometry.links]
    return tubes, evaluate([(d[2], d[3]) for d in detected], truth)


def frame_row(shape: str, noise: str, method: str, results: list) -> str:
    """One table row: found/false over the frames, and the mean and worst errors of each kind."""
    found = sum(t.found for t, _ in results)
    total = sum(len(t.members) for t, _ in results)
    false = sum(t.false_members for t, _ in results)

    def stat(kind: int, field: str, scale: float, how: str, digits: int) -> str:
        values = [getattr(r[kind], how)(field) for r in results if r[kind] is not None]
        values = [v for v in values if np.isfinite(v)]
        if not values:
            return "–"
        value = np.mean(values) if how == "mean" else np.max(values)
        return f"{value * scale:.{digits}f}"

    cells = [
        stat(0, "relative_length_error", 100, "mean", 2),
        stat(0, "relative_length_error", 100, "max", 2),
        stat(0, "end_error", 1000, "max", 1),
        stat(1, "relative_length_error", 100, "mean", 2),
        stat(1, "relative_length_error", 100, "max", 2),
        stat(1, "end_error", 1000, "max", 1),
        stat(0, "angle_error_deg", 1, "max", 2),
    ]
    return f"| {shape} | {noise} | {method} | {found}/{total} | {false} | {' | '.join(cells)} |"


def frames_table(args: argparse.Namespace) -> None:
    """Issue 37's table: per connector shape and noise level, ours by each gap rule and the
    peer, over frames of 1x and 3x connectors and 30 and 80 mm tubes."""
    by_rule = modellers(args.gap_rule, args.gap_epsilon, args.seed)
    lines = [
        "| connector | noise | method | found | false | tube len err % mean | max "
        "| tube end err mm max | node len err % mean | max | node end err mm max "
        "| axis err deg max |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for shape in ("box", "sphere", "plate"):
        for noisy in (False, True):
            results: dict[str, list] = {}
            for factor in (1.0, 3.0):
                for diameter in (0.03, 0.08):
                    scene = frame_scene(shape, factor, diameter, noisy, args.seed)
                    cloud = scene.cloud
                    for rule, modeller in by_rule.items():
                        members = modeller.model(cloud).members
                        found = [(m.p0, m.p1, *m.ends) for m in members]
                        results.setdefault(f"ours (gap rule: {rule})", []).append(
                            frame_errors(found, scene.geometry)
                        )
                    peer = peer_model(cloud, len(scene.members), args.peer_iterations)
                    results.setdefault("pyransac3d", []).append(frame_errors(peer, scene.geometry))
            noise = "DepthNoise()" if noisy else "none"
            lines += [frame_row(shape, noise, method, r) for method, r in results.items()]
    print("\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="timed runs of ours per scene")
    parser.add_argument("--peer-iterations", type=int, default=300, help="pyransac3d iterations")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("bench/out/truss.png"))
    parser.add_argument(
        "--no-scaffold",
        action="store_true",
        help="skip the 18-member scaffold (pyransac3d takes minutes on its 507k points)",
    )
    parser.add_argument(
        "--gap-rule",
        nargs="+",
        choices=["absolute", "paper"],
        default=["absolute"],
        help="step 7's gap rule(s) to model with, each on the same points",
    )
    parser.add_argument(
        "--gap-epsilon",
        type=float,
        default=TrussConfig().gap_epsilon,
        help="the paper rule's ε (m)",
    )
    parser.add_argument(
        "--frames",
        action="store_true",
        help="nodes as features: space frames with box, sphere and plate connectors (issue 37)",
    )
    args = parser.parse_args()
    if args.frames:
        frames_table(args)
        return

    rng = np.random.default_rng(args.seed)
    by_rule = modellers(args.gap_rule, args.gap_epsilon, args.seed)
    lines = [
        "| truss | method | ms/scene | CPU ms/scene | found | false | length err % "
        "| length err mm | midpoint err mm | axis err deg |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    print(f"load average before: {load_average()}")
    ratios, plotted = [], []
    for name, scene, points in scenes(args.seed, not args.no_scaffold):
        cloud = scene.cloud
        if points is not None:
            cloud = cloud[rng.choice(len(cloud), points, replace=False)]
        name = f"{name}, {len(cloud) // 1000}k points"
        truth = [(t.p0, t.p1, t.radius) for t in scene.members]
        count = len(truth)
        peer_s, peer_cpu, peer = timed(
            lambda cloud=cloud, n=count: peer_model(cloud, n, args.peer_iterations), 1
        )
        for rule, modeller in by_rule.items():
            modeller.model(cloud)  # warm-up
            ours_s, ours_cpu, model = timed(lambda m=modeller, c=cloud: m.model(c), args.repeat)
            initial = evaluate([(m.p0, m.p1) for m in model.initial], truth)
            completed = evaluate([(m.p0, m.p1) for m in model.members], truth)
            tag = f"gap rule: {rule}"
            lines.append(
                row(name, f"ours, RANSAC only (initial model, {tag})", None, initial, count)
            )
            lines.append(
                row(name, f"ours, sliding box (TEM, {tag})", (ours_s, ours_cpu), completed, count)
            )
            ratios.append((f"{name}, {tag}", peer_s / ours_s, peer_cpu / ours_cpu))
            if rule == args.gap_rule[0]:
                plotted.append((name, initial, completed))
        lines.append(row(name, "pyransac3d", (peer_s, peer_cpu), evaluate(peer, truth), count))
    print(f"load average after: {load_average()}")
    print(f"median of {args.repeat} runs (ours), 1 run (peer); paper ε = {args.gap_epsilon}\n")
    print("\n".join(lines))
    print()
    for name, ratio, cpu_ratio in ratios:
        print(f"{name}: pyransac3d / ours time = {ratio:.1f}x (CPU time {cpu_ratio:.1f}x)")
    figure(plotted, args.out)
    print(f"figure: {args.out}")


if __name__ == "__main__":
    main()
