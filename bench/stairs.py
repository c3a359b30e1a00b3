"""Paper 004 on the stairs: gait parameters, stair planes beside Open3D, the whole stair run.

Gait-parameter computation, stair plane extraction beside Open3D, and (with ``--full``) the
whole stair run in the twin.

- Parameters: ``StepPlanner.plan`` as the stair gait configures it (its margins and transfer;
  this step's length and height and the next step's length) at every half cycle of a planned
  climb of three 130 × 300 mm stairs; the paper computes its parameters "in almost 100 ms",
  the goal is ≤ 5 ms. Same-run unit: the daemon's IK of all six
  legs (one control tick's IK), so the ratio says how many ticks of IK one plan costs.
- Extraction: ``horizontal_planes`` on a noisy staircase cloud (tests/test_stairs.py's) beside
  Open3D's ``segment_plane`` run until it has found as many planes, same cloud, same run
  (Open3D from the ``bench`` extra: ``pip install -e '.[bench]'``; skipped with a message
  when missing). Goal: no slower than Open3D.
- ``--full``: Qingzhui in the twin, through the torque-leg driver at 1 kHz with the gravity
  feed-forward (what ``climbd run`` uses for torque legs) at kp 300 / kd 4, walks up three
  130 × 300 mm stairs and backward down again (about 50 s simulated, minutes of wall time);
  swing feet's tracking at apex and touch-down, and pass/fail per criterion of issue 11. With
  ``--icp`` the front camera's cloud is aligned by stair ICP every 0.5 s for the estimator's
  filter 2.
- ``--full --perceived`` (issue 35): the same run again with the stairs from perception (the
  front camera's ray-cast depth through the stairs plugin every 0.5 s at the estimated pose,
  into the world model's stair map; the world's geometry only scores it), its figures beside
  the true-stairs run's: per step, the rise, tread and edge the gait planned on when it first
  placed a foot on the step, against the truth (goal: rise and tread within 1 cm), the worst
  over every foothold planned on it, contacts and touch-down margins.

    .venv/bin/python bench/stairs.py [--repeat 20] [--full [--rise 0.13 --tread 0.30] [--icp]
        [--perceived]] [--only-full]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from support.stair_run import StairRun, stair_world, world_stairs  # noqa: E402
from test_stairs import staircase  # noqa: E402

from climbd.daemon.algorithms.estimation import GRAVITY  # noqa: E402
from climbd.daemon.algorithms.kinematics import Kinematics  # noqa: E402
from climbd.daemon.contract import profile as profiles  # noqa: E402
from climbd.plugins.gaits.stair_gait import StairGait, StairGaitConfig  # noqa: E402
from climbd.plugins.gaits.stair_plan import StairModel  # noqa: E402
from climbd.plugins.perception.stairs import StairsConfig, horizontal_planes  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def timed(fn, repeat: int) -> float:
    """Median wall time (s) of ``fn()`` over ``repeat`` runs."""
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return statistics.median(out)


def parameters(repeat: int) -> None:
    profile = profiles.load(ROOT / "robots" / "qingzhui.toml")
    kin = Kinematics(profile)
    planner = StairGait(StairGaitConfig(foot_radius=0.025), profile).planner  # as the gait plans
    feet = kin.stand_feet(planner.geometry.body_height)
    feet[:, 2] = 0.025
    model = StairModel(world_stairs(stair_world()), np.zeros(3), 0.0, feet[:, 1], 0.0)
    groups = [np.array([0, 2, 4]), np.array([1, 3, 5])]
    body, states = 0.0, []
    for k in range(24):
        states.append((feet.copy(), body, groups[k % 2]))
        plan = planner.plan(model, feet, body, groups[k % 2], 1.0, 0.30)
        if plan.length > 0:
            feet[groups[k % 2]] = plan.landing
        body += plan.length / 2
    times = [
        timed(lambda s=s: planner.plan(model, s[0], s[1], s[2], 1.0, 0.30), repeat) for s in states
    ]
    stand = kin.stand_feet()
    ik = timed(lambda: kin.ik(stand), repeat * 20)
    med, worst = statistics.median(times), max(times)
    print("## gait parameters (two steps ahead, 24 half cycles of a 3 x 130x300 mm climb)")
    print("| plan median | plan max | IK of 6 legs (unit) | median / IK | goal <= 5 ms |")
    print("|---|---|---|---|---|")
    verdict = [("met" if x <= 5e-3 else "not met") for x in (med, worst)]
    print(
        f"| {med * 1e3:.2f} ms | {worst * 1e3:.2f} ms | {ik * 1e6:.1f} us | {med / ik:.0f}x | "
        f"median {verdict[0]}, max {verdict[1]} |"
    )
    print(f"(body reached s = {body:.2f} m; paper: 'almost 100 ms')\n")


def extraction(repeat: int) -> None:
    rng = np.random.default_rng(0)
    cloud = staircase(rng)
    config = StairsConfig()
    planes = horizontal_planes(cloud, config)
    ours = timed(lambda: horizontal_planes(cloud, config), repeat)
    print(f"## plane extraction ({len(cloud)} points, {len(planes)} horizontal planes)")
    try:
        import open3d as o3d
    except ImportError:
        print("Open3D not installed (pip install -e '.[bench]'): peer skipped")
        print(f"| ours | {ours * 1e3:.1f} ms |\n")
        return

    def peer() -> int:
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud))
        found = 0
        while found < len(planes) and len(pcd.points) >= config.min_points:
            _, inliers = pcd.segment_plane(config.inlier, 3, config.iterations)
            pcd = pcd.select_by_index(inliers, invert=True)
            found += 1
        return found

    theirs = timed(peer, repeat)
    print("| ours (horizontal_planes) | Open3D segment_plane | Open3D / ours | goal: no slower |")
    print("|---|---|---|---|")
    verdict = "met" if ours <= theirs else "not met"
    print(f"| {ours * 1e3:.1f} ms | {theirs * 1e3:.1f} ms | {theirs / ours:.2f} | {verdict} |\n")


@dataclass
class Climb:
    """One whole stair run, up and back down, and where the body was at the top and the end."""

    label: str
    run: StairRun
    top: np.ndarray
    end: np.ndarray
    wall: float


def climb(label: str, rise: float, tread: float, **options) -> Climb:
    """Up the flight for 24 s and backward down for 24 s (simulated), at kp 300 / kd 4."""
    t0 = time.perf_counter()
    run = StairRun(stair_world(rise, tread), feed_forward=True, **options)
    run.rig.bus.kp, run.rig.bus.kd = 300.0, 4.0
    try:
        run.start()
        run.walk(0.15, 24.0)
        top, _ = run.rig.twin.body_pose()
        run.walk(-0.15, 24.0)
        end, _ = run.rig.twin.body_pose()
    finally:
        run.close()
    return Climb(label, run, top, end, time.perf_counter() - t0)


def full_run(rise: float, tread: float, icp: bool, perceived: bool) -> None:
    runs = [climb("true stairs", rise, tread, icp=icp)]
    report(runs[0], rise, tread, icp)
    if not perceived:
        return
    runs.append(climb("perceived", rise, tread, perceived=True))
    report(runs[-1], rise, tread, True)
    compare(runs)


def report(c: Climb, rise: float, tread: float, icp: bool) -> None:
    """The run's tracking and issue 11's criteria."""
    run, top, end = c.run, c.top, c.end
    pos_err, rot_err = run.log.pose_errors()
    legs_pos, legs_rot = run.log.pose_errors(plain=True)
    margins = run.foothold_margins()
    support = np.array(run.log.support)
    weight = run.rig.profile.mass * GRAVITY
    flight = run.world.stairs[0]
    landing = flight.distance + (flight.count - 1) * flight.tread
    reached = bool(top[2] > 3 * flight.rise + 0.2)
    rows = [
        ("reached the top landing (body z > 3 rises + 0.2 m)", reached),
        (
            "back on the floor from there (body x < first riser - 0.3 m)",
            reached and end[0] < flight.distance - 0.3,
        ),
        ("no shin contact with a stair", not run.log.shin_hits),
        ("no foot contact on an edge or riser", not run.log.foot_edge_hits),
        ("every touch-down >= 5 cm from its tread's ends", bool((margins >= 0.05).all())),
        ("estimate within 2 cm", pos_err.max() < 0.02),
        ("estimate within 2 deg", rot_err.max() < 2.0),
    ]
    print(
        f"## full stair run on {c.label}, 3 x {rise * 1e3:.0f} x {tread * 1e3:.0f} mm "
        f"({run.log.seconds:.0f} s simulated, {c.wall:.0f} s wall; "
        f"mode at the end {run.rig.safety.mode.name}: {run.rig.safety.reason})"
    )
    print(
        f"top body pose x={top[0]:.2f} z={top[2]:.2f} (landing edge at x={landing:.2f}), "
        f"end x={end[0]:.2f} z={end[2]:.2f}"
    )
    print(
        f"shin contacts {len(run.log.shin_hits)} ticks (shank end cap inside the foot sphere: "
        f"{len(run.log.cap_hits)} ticks, counted as the foot's), foot-edge contacts "
        f"{len(run.log.foot_edge_hits)} ticks, smallest touch-down margin {margins.min():.3f} m "
        f"({len(margins)} touch-downs; {len(run.log.scuffs)} lift-off re-contacts), "
        f"estimate error max {pos_err.max() * 100:.1f} cm / {rot_err.max():.1f} deg "
        f"(stance feet alone {legs_pos.max() * 100:.1f} cm / {legs_rot.max():.1f} deg)"
        + f", feet's support {support.min():.0f}-{support.max():.0f} N (weight {weight:.0f} N)"
        + (f", ICP alignments rejected {run.perception.rejected}" if icp else "")
    )
    print("| swing foot error (max) | apex | touch-down |\n|---|---|---|")
    for name, k in (("twin foot vs planned (odometry frame)", 0), ("joint-level (body frame)", 1)):
        apex, touchdown = run.log.swing_tracking(0.45, 0.55), run.log.swing_tracking(0.97, 1.0)
        print(f"| {name} | {apex[k] * 100:.1f} cm | {touchdown[k] * 100:.1f} cm |")
    print("\n| criterion | result |\n|---|---|")
    for name, ok in rows:
        print(f"| {name} | {'pass' if ok else 'FAIL'} |")
    print()


def _mm(x: float) -> str:
    return f"{x * 1e3:+.1f}"


def compare(runs: list[Climb]) -> None:
    """The runs' figures side by side: per step what the gait planned on at its first foothold
    there (and the worst over all), contacts and margins."""
    flight = runs[0].run.world.stairs[0]
    print(
        "## stairs from perception beside the true stairs (issue 35): per step, error of what "
        "the gait planned on at its first foothold there, mm (rise / tread / edge along the "
        "ascent; the top step's tread is the landing, seen only as far as the camera reaches: "
        "not scored)"
    )
    print("| | " + " | ".join(c.label for c in runs) + " |")
    print("|---" * (len(runs) + 1) + "|")

    def row(name: str, cell) -> None:
        print(f"| {name} | " + " | ".join(cell(c) for c in runs) + " |")

    for step in range(1, flight.count + 1):

        def first(c: Climb, step: int = step) -> str:
            m = c.run.log.commits.get(step)
            if m is None:
                return "no foothold"
            tread = _mm(m.tread_error) if step < flight.count else f"({m.tread:.2f} m seen)"
            wrong = "" if m.same_step else ", ON ANOTHER STEP IN THE MAP"
            seen = "" if np.isnan(m.first_seen_x) else f", first seen from x {m.first_seen_x:.2f}"
            return (
                f"{_mm(m.rise_error)} / {tread} / {_mm(m.edge_error)} at body x {m.body_x:.2f} "
                f"m ({m.sightings} sightings{seen}){wrong}"
            )

        def worst(c: Climb, step: int = step) -> str:
            ms = [m for m in c.run.log.placements if m.step == step]
            if not ms:
                return "-"
            treads = [abs(m.tread_error) for m in ms] if step < flight.count else [np.nan]
            return (
                f"{max(abs(m.rise_error) for m in ms) * 1e3:.1f} / {max(treads) * 1e3:.1f} / "
                f"{max(abs(m.edge_error) for m in ms) * 1e3:.1f} ({len(ms)} footholds)"
            )

        row(f"step {step} at first foothold", first)
        row(f"step {step} worst |error| over every foothold", worst)

    def within(c: Climb) -> str:
        ms = c.run.log.commits
        ok = len(ms) == flight.count and all(
            m.same_step
            and abs(m.rise_error) <= 0.01
            and (s == flight.count or abs(m.tread_error) <= 0.01)
            for s, m in ms.items()
        )
        return "met" if ok else "NOT MET"

    row("rise and tread within 1 cm at first foothold (goal)", within)

    def top(c: Climb) -> bool:
        return bool(c.top[2] > 3 * flight.rise + 0.2)

    row("reached the top landing", lambda c: "yes" if top(c) else "NO")
    row(
        "back on the floor from there",
        lambda c: "yes" if top(c) and c.end[0] < flight.distance - 0.3 else "NO",
    )
    row("mode at the end", lambda c: c.run.rig.safety.mode.name)
    row("shin contact (ticks)", lambda c: str(len(c.run.log.shin_hits)))
    row("foot edge/riser contact (ticks)", lambda c: str(len(c.run.log.foot_edge_hits)))

    def margin(c: Climb) -> str:
        m = c.run.foothold_margins()
        if not len(m):
            return "no touch-down"
        return f"{m.min() * 100:.1f} cm ({(m < 0.05).sum()} of {len(m)} under 5 cm)"

    row("smallest touch-down margin", margin)
    row("wall time", lambda c: f"{c.wall:.0f} s")
    print()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--full", action="store_true", help="also the whole stair run in the twin")
    parser.add_argument("--rise", type=float, default=0.13, help="the full run's rise (m)")
    parser.add_argument("--tread", type=float, default=0.30, help="the full run's tread (m)")
    parser.add_argument("--icp", action="store_true", help="the full run with stair ICP")
    parser.add_argument(
        "--perceived", action="store_true", help="the full run again on perceived stairs"
    )
    parser.add_argument(
        "--only-full", action="store_true", help="skip the parameter and extraction benches"
    )
    args = parser.parse_args()
    if not args.only_full:
        parameters(args.repeat)
        extraction(max(3, args.repeat // 4))
    if args.full:
        full_run(args.rise, args.tread, args.icp, args.perceived)
    return 0


if __name__ == "__main__":
    sys.exit(main())
