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

    .venv/bin/python bench/stairs.py [--repeat 20] [--full [--rise 0.13 --tread 0.30] [--icp]]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
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


def full_run(rise: float, tread: float, icp: bool) -> None:
    t0 = time.perf_counter()
    run = StairRun(stair_world(rise, tread), feed_forward=True, icp=icp)
    run.rig.bus.kp, run.rig.bus.kd = 300.0, 4.0
    run.start()
    run.walk(0.15, 24.0)
    top, _ = run.rig.twin.body_pose()
    run.walk(-0.15, 24.0)
    end, _ = run.rig.twin.body_pose()
    pos_err, rot_err = run.log.pose_errors()
    legs_pos, legs_rot = run.log.pose_errors(plain=True)
    margins = run.foothold_margins()
    support = np.array(run.log.support)
    weight = run.rig.profile.mass * GRAVITY
    flight = run.world.stairs[0]
    landing = flight.distance + (flight.count - 1) * flight.tread
    rows = [
        ("reached the top landing (body z > 3 rises + 0.2 m)", top[2] > 3 * flight.rise + 0.2),
        ("back on the floor (body x < first riser - 0.3 m)", end[0] < flight.distance - 0.3),
        ("no shin contact with a stair", not run.log.shin_hits),
        ("no foot contact on an edge or riser", not run.log.foot_edge_hits),
        ("every touch-down >= 5 cm from its tread's ends", bool((margins >= 0.05).all())),
        ("estimate within 2 cm", pos_err.max() < 0.02),
        ("estimate within 2 deg", rot_err.max() < 2.0),
    ]
    print(
        f"## full stair run, 3 x {rise * 1e3:.0f} x {tread * 1e3:.0f} mm "
        f"({run.log.seconds:.0f} s simulated, "
        f"{time.perf_counter() - t0:.0f} s wall)"
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
    run.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--full", action="store_true", help="also the whole stair run in the twin")
    parser.add_argument("--rise", type=float, default=0.13, help="the full run's rise (m)")
    parser.add_argument("--tread", type=float, default=0.30, help="the full run's tread (m)")
    parser.add_argument("--icp", action="store_true", help="the full run with stair ICP")
    args = parser.parse_args()
    parameters(args.repeat)
    extraction(max(3, args.repeat // 4))
    if args.full:
        full_run(args.rise, args.tread, args.icp)
    return 0


if __name__ == "__main__":
    sys.exit(main())
