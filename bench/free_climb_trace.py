"""One perceived climb of bench/free_climb_perceived.py followed through time: where it loses.

Every ``--every`` seconds of HubRobo's climb on its own hold map (seed ``--seed``): the body's
estimate against the twin's pose (the odometry frame tied to the world at the climb's start;
position in mm and roll, pitch, yaw in degrees, in the start's body frame), the swinging limb
and its phase, the grippers that hold, and why the gait waits or backs off; then the hold map
near the start (odometry x below ``NEAR``: the holds the rear limbs reach): the true holds a
mapped hold lies within the palm's radius of, and the mapped holds that lie on none.

    .venv/bin/python bench/free_climb_trace.py [--seed 5] [--seconds 45] [--every 0.5]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support.climb_driver import DriverClimb  # noqa: E402

from climbd.daemon.contract.geometry import rotation  # noqa: E402
from climbd.drivers.sim.twin import GRASP_OFFSET  # noqa: E402

NEAR = 0.25
"""m (odometry x from the body's start): the stretch the rear limbs climb on in 45 s."""


def near_map(run: DriverClimb) -> str:
    """The hold map below ``NEAR``: true holds covered, mapped holds on no true hold (a gripper
    holds within the palm's radius, ``GRASP_OFFSET``, of a true hold)."""
    check = run.map_check()
    near_true = (check.true[:, 0] < NEAR) & (np.abs(check.true[:, 1]) < 0.35)
    near_mapped = (check.mapped[:, 0] < NEAR) & (np.abs(check.mapped[:, 1]) < 0.35)
    return (
        f"true holds {near_true.sum()}, of them mapped within {GRASP_OFFSET * 100:.1f} cm "
        f"{np.count_nonzero(check.to_mapped[near_true] <= GRASP_OFFSET)}; mapped holds "
        f"{near_mapped.sum()}, on no true hold "
        f"{np.count_nonzero(check.to_true[near_mapped] > GRASP_OFFSET)}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=45.0)
    parser.add_argument("--every", type=float, default=0.5)
    args = parser.parse_args()
    run = DriverClimb(args.seed, relief="rock", perceive=True, duration=args.seconds)
    try:
        run.begin()
        print(f"seed {args.seed}, at the start, below {NEAR} m: {near_map(run)}")
        body, (p0, q0) = run.stack.controller.body, run.twin.body_pose()
        e0, odometry0, world0 = np.array(body.position), rotation(body.orientation), rotation(q0)
        tie = world0 @ odometry0.T  # odometry frame → world, as at the start
        print("   t s  position error mm (x y z)  rpy error deg  swing  phase  holding  reason")
        steps = round(args.seconds / args.every)
        for k in range(steps):
            run.run(args.every)
            body, (p, q) = run.stack.controller.body, run.twin.body_pose()
            error = world0.T @ (tie @ (np.array(body.position) - e0) + p0 - p)
            off = rotation(q).T @ tie @ rotation(body.orientation)
            rpy = np.degrees(
                [
                    np.arctan2(off[2, 1], off[2, 2]),
                    -np.arcsin(np.clip(off[2, 0], -1.0, 1.0)),
                    np.arctan2(off[1, 0], off[0, 0]),
                ]
            )
            runner = run.gait.runner
            swing = "-" if runner.step is None else str(runner.step.limb)
            holding = "".join(str(int(g)) for g in run.twin.grip)
            print(
                f"{(k + 1) * args.every:6.1f}  {error[0] * 1e3:6.1f} {error[1] * 1e3:6.1f} "
                f"{error[2] * 1e3:6.1f}  {rpy[0]:5.2f} {rpy[1]:5.2f} {rpy[2]:5.2f}  {swing:>5}  "
                f"{runner.phase:5.2f}  {holding:>7}  {runner.reason}"
            )
        print(f"at {args.seconds:g} s, below {NEAR} m: {near_map(run)}")
        climbed = float(run.to_wall(run.twin.data.qpos[:3])[0]) - run.x0
        print(f"up the slope {climbed:.3f} m, missed grips {runner.missed}")
    finally:
        run.close()


if __name__ == "__main__":
    main()
