"""Truss modelling (paper 003) per scene of 100k points beside pyransac3d, with both accuracies.

For each truss (the paper's 5- and 7-member experiments, and an 18-member scaffold) a scene
is rendered at Kinect-2 resolution from several poses and 100 000 points are drawn from the
merged cloud (the scaffold keeps its whole cloud). On the same points, in the same run:
- ours: ``TrussModeller.model`` (voxels, plane removal, RANSAC with normals, sliding-box
  completion, merging); its RANSAC-only initial model is scored too, as in the paper;
- pyransac3d 0.7.0 (the issue's peer), as its README uses it: its ``Plane`` fit drops the
  floor, then one ``Cylinder`` fit per member (the count given, not the positions), each
  removing its inliers, ends at the inliers' extent on the axis; 10 mm inlier distance,
  ``--peer-iterations`` (3000) per member;
- a second baseline of textbook parts, none of ours: the same floor removal, PCA normals,
  sequential two-point cylinder RANSAC with normals (as PCL's SACMODEL_CYLINDER; ours' radius
  range, 10 mm, 25 deg, ``--baseline-iterations``), the longest run of the best hypothesis's
  inliers refitted (PCA axis, least-squares circle); also given the member count.

pyransac3d's ``Cylinder`` finds no member by design, not by its settings: it takes the normal
of the plane through 3 samples as the axis and their circumcircle as the section, right only
when the 3 land in one cross-section of one tube; it has no radius bound. Measured on the
five-member scene (100k points): the floor fit leaves 8 268 points, 1 166-1 739 of them on each
member's surface (within 10 mm); of 2 000 000 samples of 3 of them, 33 (1.7e-5) give an axis
within 10 deg and two radii of a member's (the match rule), 1 also a radius within 50 %
(sampled radii: median 0.74 m, 10-90 % 0.43-1.94 m). RANSAC would need ~280 000 iterations per
member for a 99 % chance of one such sample (~14 min each at the measured ~3 ms per iteration),
and it would still lose: at 300 iterations the five fits are cylinders of radius 1.0-27 m
sweeping across tubes (518-1 933 inliers; the best more than any member's surface holds), axes
2.5-90 deg off the nearest member and 1.0-27 m from it; at 3000 iterations and an inlier
distance of 5, 10 or 24 mm alike, radii 0.9-15 m, 0.9-15 m from any member. The ends (extent of
the inliers on the axis through pyransac3d's centre) and the evaluation are not the cause: the
two best-aligned fits (2.5 and 2.9 deg from a ledger) lie 1.0 and 2.7 m from it. Per-cluster
fitting is no way out here: the trusses are connected (couplers, touching tubes), so connected
components of the rest (20 mm reach) give one cluster of 5 176 points across members, and 15 mm
breaks it into 403 fragments; within one member, 1e-4 of 3-samples give a good axis.

Prints time per scene (median of ``--repeat``; wall and the process's CPU time, which a
loaded shared machine inflates less), each baseline's time over ours, the load average
around the run, and the paper's metrics; writes a figure like the paper's Figs. 9-11 to
bench/out/truss.png.
``--gap-rule paper absolute`` models each scene once per rule of step 7 (the paper's relative
(G_max / G_min) * ε, ε from ``--gap-epsilon``; ours, an absolute gap), on the same points.

``--frames`` benchmarks nodes as features instead (issue 37): space frames whose members end
on connectors (box, sphere, plate) of 1x and 3x the tube diameter, tubes of 30 and 80 mm, seen
from four oblique views all around, noise-free and with ``DepthNoise()``; per connector shape,
noise level and method, the tube extents against the true tubes and the node-to-node ends
against the true nodes, over the four frames of that shape, each on its whole merged cloud
(about 380 000 points at full Kinect-2 resolution; 100 000 drawn from it leave 30 mm tubes too
sparse: 2.9 % worst tube length against 0.3 % on the whole cloud, 1x spheres).

``--frame-timing`` times ours alone against the goal (<= 100 ms median per 100k-point
update): the box space frame (2x connectors, 48 mm tubes) from the four oblique views with
``DepthNoise()``, 100 000 points drawn; median, min and max of ``--repeat`` runs. With
``--against REV`` it times the modeller of ``REV`` (``git archive``) beside this tree's on the
same saved cloud instead, in two processes taking turns update by update (the order swapped
each pair), and prints both distributions and the paired new / old ratios: on this shared,
noisy machine, a ratio from neighbouring updates holds where separate runs drift by 30 %.

    .venv/bin/python bench/truss.py [--repeat 5] [--peer-iterations 3000]
        [--baseline-iterations 2000] [--no-scaffold] [--gap-rule paper absolute]
        [--gap-epsilon 1e-5] [--frames] [--no-baselines] [--frame-timing [--against REV]]
"""

from __future__ import annotations

import argparse
import os
import random
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Callable
from io import BytesIO
from pathlib import Path

import numpy as np
import pyransac3d
from scipy.spatial import cKDTree

from climbd.drivers.sim import truss_scene as ts
from climbd.plugins.perception.truss import TrussConfig, TrussModeller
from climbd.plugins.perception.truss.completion import GapRule
from climbd.plugins.perception.truss.evaluate import Accuracy, evaluate

POINTS = 100_000
Baseline = Callable[[np.ndarray, int, int], list[tuple]]
"""A baseline: (points, member count, iterations) -> member ends (p0, p1)."""
PLANE_ITERATIONS = 300
"""pyransac3d ``Plane`` iterations for the floor (it takes over 90 % of the points: 300 suffice)."""
PEER_THRESHOLD = 0.01
"""Inlier distance to a cylinder's surface (m) of both baselines: 0.4 tube radii."""
RADIUS_RANGE = (TrussConfig().radius_min, TrussConfig().radius_max)
"""The tube radii the normals baseline admits (m): ours' prior, so neither knows more."""
BASELINE_COS = float(np.cos(np.radians(25.0)))
BASELINE_MIN_POINTS = 30
BASELINE_GAP = 0.1
ROOT = Path(__file__).resolve().parent.parent
FRAME_WORKER = """
import sys, time
import numpy as np
from climbd.plugins.perception.truss import TrussConfig, TrussModeller
cloud = np.load(sys.argv[1])
modeller = TrussModeller(TrussConfig(seed=int(sys.argv[2])))
modeller.model(cloud)
print("ready", flush=True)
for _ in sys.stdin:
    start = time.process_time()
    modeller.model(cloud)
    print(time.process_time() - start, flush=True)
"""
"""One modeller in its own process: a warm-up, then one timed update (CPU s) per input line."""
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


def floor_removed(points: np.ndarray) -> np.ndarray:
    """The points off pyransac3d's best plane (the floor, 20 mm either side); both baselines
    start from it."""
    random.seed(0)
    _, floor = pyransac3d.Plane().fit(points, thresh=0.02, maxIteration=PLANE_ITERATIONS)
    return np.delete(points, floor, axis=0)


def peer_model(points: np.ndarray, members: int, iterations: int) -> list[tuple]:
    """pyransac3d as its README uses it: its plane fit removes the floor, then one ``Cylinder``
    fit per member (the count given), each removing its inliers; ends at the inliers' extent on
    the axis. Its cylinder takes the normal of the plane through 3 samples as the axis, which
    on a tube is rarely near the axis (see the module docstring)."""
    rest = floor_removed(points)
    found = []
    for _ in range(members):
        if len(rest) < 3:
            break
        centre, axis, _, inliers = pyransac3d.Cylinder().fit(
            rest, thresh=PEER_THRESHOLD, maxIteration=iterations
        )
        if len(inliers) < 2:
            break
        axis = np.asarray(axis)
        t = (rest[inliers] - centre) @ axis
        found.append((centre + t.min() * axis, centre + t.max() * axis))
        rest = np.delete(rest, inliers, axis=0)
    return found


def pca_normals(points: np.ndarray, neighbours: int = 16) -> np.ndarray:
    """Unit normals: the least principal direction of each point's nearest neighbours."""
    _, near = cKDTree(points).query(points, neighbours)
    local = points[near] - points[near].mean(axis=1, keepdims=True)
    return np.linalg.eigh(np.einsum("nki,nkj->nij", local, local))[1][:, :, 0]


def cylinder_hypotheses(
    points: np.ndarray, normals: np.ndarray, count: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cylinders (centre, axis, radius) from pairs of oriented points, as PCL's
    SACMODEL_CYLINDER: the axis is the cross product of the normals, the centre where the two
    normal lines meet (least squares), the radius their mean distance to it."""
    i, j = rng.integers(0, len(points), (2, count))
    n1, n2 = normals[i], normals[j]
    axis = np.cross(n1, n2)
    axis /= np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), 1e-12)
    d = points[j] - points[i]
    b = (n1 * n2).sum(axis=1)
    s = ((d * n1).sum(axis=1) - b * (d * n2).sum(axis=1)) / np.maximum(1 - b * b, 1e-12)
    t = s * b - (d * n2).sum(axis=1)
    return points[i] + s[:, None] * n1, axis, 0.5 * (np.abs(s) + np.abs(t))


def circle_fit(xy: np.ndarray) -> np.ndarray:
    """Least-squares (Kasa) circle centre of 2-D points."""
    a = np.column_stack([2 * xy, np.ones(len(xy))])
    return np.linalg.lstsq(a, (xy**2).sum(axis=1), rcond=None)[0][:2]


def normals_baseline(points: np.ndarray, members: int, iterations: int) -> list[tuple]:
    """Textbook sequential cylinder RANSAC with normals, no part of ours: pyransac3d's floor
    removal, PCA normals (16 neighbours), ``iterations`` two-point hypotheses per member (the
    count given) within ours' radius range, inliers within 10 mm and 25 deg of the surface
    normal; the best hypothesis's longest run of inliers (split at 0.1 m gaps along the axis)
    is refitted (PCA axis, least-squares circle centre), reported and removed."""
    rng = np.random.default_rng(0)
    rest = floor_removed(points)
    normals = pca_normals(rest)
    found = []
    for _ in range(members):
        if len(rest) < BASELINE_MIN_POINTS:
            break
        best = np.zeros(len(rest), bool)
        hypotheses = cylinder_hypotheses(rest, normals, iterations, rng)
        for c, a, r in zip(*hypotheses, strict=True):
            if not RADIUS_RANGE[0] <= r <= RADIUS_RANGE[1]:
                continue
            w = rest - c
            radial = w - np.outer(w @ a, a)
            distance = np.linalg.norm(radial, axis=1)
            inliers = (np.abs(distance - r) < PEER_THRESHOLD) & (
                np.abs((normals * radial).sum(axis=1)) > BASELINE_COS * distance
            )
            if inliers.sum() > best.sum():
                best, axis = inliers, a
        if best.sum() < BASELINE_MIN_POINTS:
            break
        index = np.flatnonzero(best)
        along = rest[index] @ axis
        order = np.argsort(along)
        runs = np.split(order, np.flatnonzero(np.diff(along[order]) > BASELINE_GAP) + 1)
        run = index[max(runs, key=len)]
        if len(run) < BASELINE_MIN_POINTS:
            break
        mean = rest[run].mean(axis=0)
        axis = np.linalg.svd(rest[run] - mean, full_matrices=False)[2][0]
        u = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(axis, u)
        centre = mean + circle_fit((rest[run] - mean) @ np.column_stack([u, v])) @ np.vstack([u, v])
        t = (rest[run] - centre) @ axis
        found.append((centre + t.min() * axis, centre + t.max() * axis))
        rest, normals = np.delete(rest, run, axis=0), np.delete(normals, run, axis=0)
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
    return ts.render(frame, poses, noise=ts.DepthNoise() if noisy else ts.NO_NOISE, seed=seed)


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
    """One table row: found/false over the frames, the mean and worst errors of each kind, and
    how many tubes meet the goal (tube extent within 2 % in length and 20 mm at its ends)."""
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
    goal = sum(
        e.detected is not None and e.relative_length_error <= 0.02 and e.end_error <= 0.02
        for tubes, _ in results
        for e in tubes.members
    )
    return (
        f"| {shape} | {noise} | {method} | {found}/{total} | {false} | {' | '.join(cells)} "
        f"| {goal}/{total} |"
    )


def baselines(args: argparse.Namespace) -> list[tuple[str, Baseline, int]]:
    """The two baselines (row label, model function, iterations), both given the member count.
    pyransac3d's label says why it finds nothing: its axis comes from 3 points (module
    docstring); none with ``--no-baselines``."""
    if args.no_baselines:
        return []
    return [
        (
            f"pyransac3d Cylinder ({args.peer_iterations} it., count given; 3-point axis)",
            peer_model,
            args.peer_iterations,
        ),
        (
            f"RANSAC with normals ({args.baseline_iterations} it., count given)",
            normals_baseline,
            args.baseline_iterations,
        ),
    ]


def timing_frame(seed: int) -> tuple[ts.TrussScene, np.ndarray]:
    """The time goal's frame: the box space frame (2x connectors, 48 mm tubes) from the four
    oblique views with ``DepthNoise()``, and 100 000 points drawn from its merged cloud."""
    scene = frame_scene("box", 2.0, 0.048, True, seed)
    rng = np.random.default_rng(seed)
    return scene, scene.cloud[rng.choice(len(scene.cloud), POINTS, replace=False)]


def frame_timing(args: argparse.Namespace) -> None:
    """The time goal (<= 100 ms median per 100k-point update) on ``timing_frame``: wall and
    CPU time of each of ``--repeat`` runs after a warm-up, their median, min and max, with
    the load average around them."""
    scene, cloud = timing_frame(args.seed)
    modeller = TrussModeller(TrussConfig(seed=args.seed))
    modeller.model(cloud)  # warm-up
    print(f"load average before: {load_average()}")
    wall, cpu = [], []
    for _ in range(args.repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        members = modeller.model(cloud).members
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    print(f"load average after: {load_average()}")
    tubes, _ = frame_errors([(m.p0, m.p1) for m in members], scene.geometry)
    print(
        f"box space frame, 4 views, {len(cloud)} of {len(scene.cloud)} points; tubes found "
        f"{tubes.found}/{len(tubes.members)}, {tubes.false_members} false; {args.repeat} runs (ms):"
    )
    for name, values in (("wall", wall), ("CPU", cpu)):
        ms = [v * 1000 for v in values]
        print(
            f"{name}: median {statistics.median(ms):.0f}, min {min(ms):.0f}, max {max(ms):.0f}; "
            + " ".join(f"{v:.0f}" for v in ms)
        )


def frame_timing_against(args: argparse.Namespace) -> None:
    """``timing_frame`` modelled by ``REV``'s modeller and this tree's, ``--repeat`` pairs of
    updates taken in turns by two warm processes; CPU ms of each and the paired ratios."""
    _, cloud = timing_frame(args.seed)
    archive = subprocess.run(
        ["git", "archive", args.against], cwd=ROOT, check=True, capture_output=True
    ).stdout
    with tempfile.TemporaryDirectory() as scratch, tarfile.open(fileobj=BytesIO(archive)) as tar:
        old_tree = Path(scratch) / "climbd"  # the one import name, from PYTHONPATH
        tar.extractall(old_tree, filter="data")
        frame = Path(scratch) / "cloud.npy"
        np.save(frame, cloud)
        workers = {}
        for which, path in (("old", scratch), ("new", "")):
            workers[which] = subprocess.Popen(
                [sys.executable, "-c", FRAME_WORKER, str(frame), str(args.seed)],
                cwd=old_tree if which == "old" else ROOT,
                env=dict(os.environ, PYTHONPATH=path),
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
            )
        for worker in workers.values():
            if worker.stdout.readline().strip() != "ready":
                raise SystemExit("a modeller process failed to start")
        print(f"load average before: {load_average()}")
        ms: dict[str, list[float]] = {"old": [], "new": []}
        for k in range(args.repeat):
            for which in ("old", "new") if k % 2 == 0 else ("new", "old"):
                workers[which].stdin.write("go\n")
                workers[which].stdin.flush()
                ms[which].append(1000 * float(workers[which].stdout.readline()))
        for worker in workers.values():
            worker.stdin.close()
            worker.wait()
        print(f"load average after: {load_average()}")
    ratios = [new / old for old, new in zip(ms["old"], ms["new"], strict=True)]
    print(f"\n{args.repeat} pairs of updates, {len(cloud)} points, CPU ms; vs {args.against}\n")
    print("| modeller | median | p10 | p90 | min | max |")
    print("|---|---|---|---|---|---|")
    for name, values in (
        (args.against, ms["old"]),
        ("this tree", ms["new"]),
        ("new / old", ratios),
    ):
        p10, p50, p90 = np.percentile(values, [10, 50, 90])
        digits = 3 if name == "new / old" else 1
        print(
            f"| {name} | {p50:.{digits}f} | {p10:.{digits}f} | {p90:.{digits}f} "
            f"| {min(values):.{digits}f} | {max(values):.{digits}f} |"
        )


def frames_table(args: argparse.Namespace) -> None:
    """Issue 37's table: per connector shape and noise level, ours by each gap rule and both
    baselines, over frames of 1x and 3x connectors and 30 and 80 mm tubes."""
    by_rule = modellers(args.gap_rule, args.gap_epsilon, args.seed)
    lines = [
        "| connector | noise | method | found | false | tube len err % mean | max "
        "| tube end err mm max | node len err % mean | max | node end err mm max "
        "| axis err deg max | tubes within 2 % and 20 mm |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
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
                    count = len(scene.members)
                    for method, fit, iterations in baselines(args):
                        found = fit(cloud, count, iterations)
                        results.setdefault(method, []).append(frame_errors(found, scene.geometry))
            noise = "DepthNoise()" if noisy else "none"
            lines += [frame_row(shape, noise, method, r) for method, r in results.items()]
    print("\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="timed runs of ours per scene")
    parser.add_argument(
        "--peer-iterations",
        type=int,
        default=3000,
        help="pyransac3d Cylinder iterations per member (about 3 ms each on 8k points)",
    )
    parser.add_argument(
        "--baseline-iterations",
        type=int,
        default=2000,
        help="two-point hypotheses per member of the RANSAC-with-normals baseline",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("bench/out/truss.png"))
    parser.add_argument(
        "--no-scaffold",
        action="store_true",
        help="skip the 18-member scaffold (pyransac3d: 103 s at 300 iterations, ~10x at 3000)",
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
    parser.add_argument(
        "--no-baselines",
        action="store_true",
        help="ours alone (the baselines take most of a --frames run)",
    )
    parser.add_argument(
        "--frame-timing",
        action="store_true",
        help="time ours alone on a 100k-point frame of the box space frame (the time goal)",
    )
    parser.add_argument(
        "--against",
        metavar="REV",
        help="with --frame-timing: time REV's modeller beside this tree's, update by update",
    )
    args = parser.parse_args()
    if args.frame_timing and args.against:
        frame_timing_against(args)
        return
    if args.frame_timing:
        frame_timing(args)
        return
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
        peers = [
            (method, *timed(lambda f=fit, c=cloud, n=count, i=iterations: f(c, n, i), 1))
            for method, fit, iterations in baselines(args)
        ]
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
            for method, peer_s, peer_cpu, _ in peers:
                ratios.append((f"{name}, {tag}, {method}", peer_s / ours_s, peer_cpu / ours_cpu))
            if rule == args.gap_rule[0]:
                plotted.append((name, initial, completed))
        for method, peer_s, peer_cpu, found in peers:
            lines.append(row(name, method, (peer_s, peer_cpu), evaluate(found, truth), count))
    print(f"load average after: {load_average()}")
    print(f"median of {args.repeat} runs (ours), 1 run (baselines); paper ε = {args.gap_epsilon}\n")
    print("\n".join(lines))
    print()
    for name, ratio, cpu_ratio in ratios:
        print(f"{name}: baseline / ours time = {ratio:.1f}x (CPU time {cpu_ratio:.1f}x)")
    figure(plotted, args.out)
    print(f"figure: {args.out}")


if __name__ == "__main__":
    main()
