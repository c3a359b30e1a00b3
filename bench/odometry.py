"""Odometry drift of each robot over a straight walk in the twin, through its own driver.

WidowX (tripod) and HubRobo (crawl) on the Dynamixel driver with leg odometry and the twin's IMU;
Qingzhui (tripod) on the MIT-mode torque driver with paper 004's estimator (stance kinematics,
foot forces, IMU). The twin's true pose scores the estimate at the end of the walk: position
error as a share of the distance walked, heading error, each beside the standard deviation the
odometry published for the walk (BodyState.pose_variance), and how far the stance slid over the
ground in truth (what no leg odometry sees). Baseline, same run: dead reckoning of the
commanded velocity. Goal (issue #32): ≤ 2 % of the distance and ≤ 2° over 5 m. HubRobo
walks under G/6, its design gravity (paper 001); at 1 g its servos cannot hold its stand.

    .venv/bin/python bench/odometry.py [--distance 5] [--robots widowx hubrobo qingzhui]
        [--gait-config '{"duty_factor": 0.85}']  (the Dynamixel robots' gait, e.g. a gentler crawl)
        [--ablate]  (replay the Dynamixel robots' odometry inputs into variants of LegOdometry:
                     rolling or point feet, a slip judged from four feet down; same walk, truth)
        [--tilt-time 3 --still-accel 0.02]  (the tilt filter's time constant and its "gravity
                     alone" gate, odometry.TILT_TIME and STILL_ACCEL, set for this run)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT / "tests")]

import numpy as np  # noqa: E402
from support.walk_run import (  # noqa: E402
    OdometryInput,
    Walk,
    dynamixel_walk,
    in_start_frame,
    qingzhui_walk,
)

from climbd.daemon.algorithms import odometry  # noqa: E402
from climbd.daemon.algorithms.kinematics import Kinematics  # noqa: E402
from climbd.daemon.algorithms.odometry import SLIP_FEET, LegOdometry  # noqa: E402
from climbd.daemon.contract import profile as profiles  # noqa: E402
from climbd.daemon.contract.geometry import yaw  # noqa: E402

GAITS = {"widowx": ("tripod", 0.05), "hubrobo": ("crawl", 0.02), "qingzhui": ("tripod", 0.1)}
"""Robot → (gait, commanded speed m/s) of its walk."""


def walk(robot: str, distance: float, config: dict, inputs: list[OdometryInput]) -> Walk:
    gait, vx = GAITS[robot]
    seconds = distance / vx
    if robot == "qingzhui":
        return qingzhui_walk(vx, seconds)
    return dynamixel_walk(robot, gait, vx, seconds, config, inputs)


def replayed_error(w: Walk, inputs: list[OdometryInput], odometry: LegOdometry) -> float:
    """Position error (m) at the walk's end of ``odometry`` fed the recorded ``inputs``,
    its origin its pose when the walk began (as the walk scores the live estimate)."""
    start = end = None
    for u in inputs:
        body = odometry.update(u.q, u.stance, u.t, u.gyro, u.accel)
        pose = (np.asarray(body.position[:2], float), yaw(body.orientation))
        if u.t <= w.started:
            start = pose
        end = pose
    assert start is not None and end is not None, "no odometry input before the walk began"
    return float(np.linalg.norm(in_start_frame(end[0], *start) - w.true_end))


def ablation(robot: str, w: Walk, inputs: list[OdometryInput]) -> None:
    """Print the drift of LegOdometry variants on the same recorded walk."""
    profile = profiles.load(ROOT / "robots" / f"{robot}.toml")
    kin, radius = Kinematics(profile), profile.foot_radius or 0.0
    variants = {
        "as shipped": LegOdometry.from_profile(profile, kin),
        "rolling feet": LegOdometry(kin, foot_radius=radius),
        "point feet": LegOdometry(kin),
        "rolling feet, slip from 4 feet": LegOdometry(kin, foot_radius=radius, slip_feet=4),
        "point feet, slip from 4 feet": LegOdometry(kin, slip_feet=4),
    }
    for name, variant in variants.items():
        error = replayed_error(w, inputs, variant)
        print(f"| {robot} | {name} | {error * 100:.1f} cm ({error / w.distance:.1%}) |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--distance", type=float, default=5.0, help="commanded distance (m)")
    parser.add_argument("--robots", nargs="+", default=list(GAITS), choices=list(GAITS))
    parser.add_argument(
        "--gait-config", type=json.loads, default={}, help="JSON config of the Dynamixel gaits"
    )
    parser.add_argument(
        "--ablate", action="store_true", help="replay the odometry inputs into its variants"
    )
    parser.add_argument(
        "--tilt-time", type=float, default=odometry.TILT_TIME, help="odometry.TILT_TIME (s)"
    )
    parser.add_argument(
        "--still-accel", type=float, default=odometry.STILL_ACCEL, help="odometry.STILL_ACCEL"
    )
    args = parser.parse_args()
    odometry.TILT_TIME, odometry.STILL_ACCEL = args.tilt_time, args.still_accel
    recorded: dict[str, tuple[Walk, list[OdometryInput]]] = {}
    print(
        "| robot (gait, speed) | walked (m) | position error | published σ | heading error "
        "| published σ | stance slid (truth) | dead reckoning of the command | wall time |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for robot in args.robots:
        t0 = time.monotonic()
        inputs: list[OdometryInput] = []
        w = walk(robot, args.distance, args.gait_config, inputs)
        if inputs:
            recorded[robot] = (w, inputs)
        gait, vx = GAITS[robot]
        tuned = ""
        if args.gait_config and robot != "qingzhui":
            tuned = f" {json.dumps(args.gait_config)}"
        per = 1.0 / w.distance if w.distance else float("nan")
        share, base, slid_share = w.position_error * per, w.baseline_error * per, w.slide * per
        error = f"{w.position_error * 100:.1f} cm ({share:.1%})"
        baseline = f"{w.baseline_error * 100:.1f} cm ({base:.1%})"
        slid = f"{w.slide * 100:.1f} cm ({slid_share:.1%})"
        print(
            f"| {robot} ({gait}{tuned}, {vx:g} m/s) | {w.distance:.2f} | {error} | "
            f"{w.sigma_xy * 100:.1f} cm | {w.yaw_error_deg:.2f}° | {w.sigma_yaw_deg:.2f}° | "
            f"{slid} | {baseline} | {time.monotonic() - t0:.0f} s |",
            flush=True,
        )
    if args.ablate and recorded:
        print(f"\n| robot | LegOdometry (slip judged from {SLIP_FEET} feet) | position error |")
        print("|---|---|---|")
        for robot, (w, inputs) in recorded.items():
            ablation(robot, w, inputs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
