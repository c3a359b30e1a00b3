"""The perception role's self filter on Qingzhui's front camera, beside the cloud every plugin
makes of the same frame.

Frames of the twin's ray-cast D435 (640×480) with the legs standing and at random joint vectors
within the limits; ours: ``SelfFilter.apply`` (the pixels within 4.5 cm of a leg link zeroed);
baseline: ``frame_to_points`` of the same frame, undecimated (the body-frame cloud a plugin
builds of it). They take turns frame by frame; reports wall medians and 90th percentiles, their
ratio, and the leg pixels per frame.

    .venv/bin/python bench/self_filter.py [--repeats 20]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import mujoco
import numpy as np

from climbd.daemon.algorithms.cloud import frame_to_points
from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.algorithms.self_filter import SelfFilter
from climbd.daemon.algorithms.world import world_config
from climbd.daemon.contract import profile as profiles
from climbd.drivers.sim.twin import Twin
from climbd.drivers.sim.worlds import load

ROOT = Path(__file__).resolve().parents[1]
POSES = 6


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20, help="timings per frame and method")
    args = parser.parse_args()
    profile = profiles.load(ROOT / "robots" / "qingzhui.toml")
    twin = Twin(profile, load("stairs"), stepped=True)
    kin = Kinematics(profile)
    ours = SelfFilter(kin, world_config(profile).self_filter.radius)
    rng = np.random.default_rng(0)
    span = kin.upper - kin.lower
    poses = [kin.stand_joints()]
    poses += [kin.lower + rng.uniform(size=kin.n_joints) * span for _ in range(POSES - 1)]
    filtered, baseline, pixels = [], [], []
    load_before = os.getloadavg()[0]
    for q in poses:
        twin.data.qpos[twin.robot.qpos_adr] = twin.map.hinge(q)
        mujoco.mj_kinematics(twin.model, twin.data)
        frame = twin.depth_frame("front")
        measured = twin.joint_positions()
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            _, count = ours.apply(frame, measured)
            t1 = time.perf_counter()
            frame_to_points(frame)
            t2 = time.perf_counter()
            filtered.append(t1 - t0)
            baseline.append(t2 - t1)
        pixels.append(count)

    def p90(x: list[float]) -> float:
        return statistics.quantiles(x, n=10)[-1]

    print(
        f"## self filter, Qingzhui front D435 640x480, {len(poses)} poses x {args.repeats} "
        f"(load {load_before:.2f} -> {os.getloadavg()[0]:.2f})\n"
    )
    print("| method | median ms | p90 ms |\n|---|---|---|")
    print(
        f"| SelfFilter.apply | {statistics.median(filtered) * 1e3:.2f} | "
        f"{p90(filtered) * 1e3:.2f} |"
    )
    print(
        f"| frame_to_points (baseline) | {statistics.median(baseline) * 1e3:.2f} | "
        f"{p90(baseline) * 1e3:.2f} |"
    )
    ratios = [a / b for a, b in zip(filtered, baseline, strict=True)]
    print(
        f"\nfilter / cloud per frame: median {statistics.median(ratios):.2f}, "
        f"p90 {p90(ratios):.2f}; leg pixels per pose: {pixels}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
