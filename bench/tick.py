"""One full motion tick for 18 joints: gait + IK + ruckig + guard, pipeline vs joint by joint.

The pipeline tick is what the controller runs: ``PeriodicGait.step`` then
``MotionPipeline.feet_step`` (scalar IK of each leg, target clipping on lists, one 18-DOF
ruckig call, guard). The baseline computes the same tick in a plain Python loop: the same gait
object (one call per tick either way), then leg by leg scalar IK with ``math``, joint by joint
finite differences, target clipping, one single-DOF ruckig per joint and the position clamp.
Both run interleaved in the same process on the same foot targets, and every tick's commands
are checked equal.

``--against REV`` also times the whole controller tick (read, estimate, behave, IK, smooth,
feed-forward, guard, write; fake joint bus, stepped clock, tripod walking ACTIVE under a teleop
session, Qingzhui with its estimator and feed-forward, the collector frozen after start-up as
``climbd run`` does) of this tree and of git revision REV,
each in processes of its own, alternated over ``--rounds`` rounds, and prints each round's
medians and their ratio: the same machine state for old and new.

    .venv/bin/python bench/tick.py --robot qingzhui --ticks 5000
    .venv/bin/python bench/tick.py --against 890449e --rounds 6
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

import numpy as np
import ruckig

from climbd.daemon.algorithms.kinematics import LIMIT_TOLERANCE
from climbd.daemon.algorithms.motion import MotionPipeline
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import BodyState, MotionCommand
from climbd.daemon.runtime.loader import instantiate

ROOT = Path(__file__).resolve().parent.parent
ROBOTS = ROOT / "robots"
MARGIN = 0.999


class LoopTick:
    """The motion tick written joint by joint: scalar IK per leg, one ruckig per joint."""

    def __init__(self, pipeline: MotionPipeline) -> None:
        kin = pipeline.kinematics
        self.kin = kin
        self.dt = pipeline.dt
        smoother = pipeline.smoother
        self.legs = []
        for i, leg in enumerate(kin.profile.legs):
            self.legs.append(
                (
                    leg.kind,
                    kin.mount[i].tolist(),
                    math.cos(kin.yaw[i]),
                    math.sin(kin.yaw[i]),
                    float(kin.l1[i]),
                    float(kin.l2[i]),
                    float(kin.l3[i]),
                    float(kin.knee_sign[i]),
                )
            )
        self.joints = []
        for j, joint in enumerate(kin.profile.joints):
            otg = ruckig.Ruckig(1, self.dt)
            inp = ruckig.InputParameter(1)
            out = ruckig.OutputParameter(1)
            inp.synchronization = ruckig.Synchronization.No
            inp.max_velocity = [float(smoother.v_lim[j])]
            inp.max_acceleration = [joint.limits.acceleration]
            inp.max_jerk = [joint.limits.jerk]
            self.joints.append((otg, inp, out, joint))
        self.direction = kin.direction.tolist()
        self.offset = kin.zero_offset.tolist()

    def start(self, q: list[float]) -> None:
        for (otg, inp, _out, _joint), qj in zip(self.joints, q, strict=True):
            inp.current_position = [qj]
            inp.current_velocity = [0.0]
            inp.current_acceleration = [0.0]
            otg.reset()
        self.target = list(q)
        self.target_qd = [0.0] * len(q)
        self.streaming = False

    def ik_leg(self, i: int, foot: list[float]) -> tuple[list[float], bool]:
        kind, mount, c, s, l1, l2, l3, k = self.legs[i]
        dx, dy, dz = foot[0] - mount[0], foot[1] - mount[1], foot[2] - mount[2]
        x, y, z = c * dx + s * dy, c * dy - s * dx, dz
        if kind == "coxa_femur_tibia":
            u, w, first_angle = math.hypot(x, y) - l1, z, math.atan2(y, x)
        else:
            u, w, first_angle = x - l1, math.hypot(y, z), math.atan2(y, -z)
        cos_rel = (u * u + w * w - l2 * l2 - l3 * l3) / (2.0 * l2 * l3)
        if abs(cos_rel) > 1.0:
            return [math.nan] * 3, False
        rel = k * math.acos(cos_rel)
        second = math.atan2(w, u) - math.atan2(l3 * math.sin(rel), l2 + l3 * math.cos(rel))
        third = rel if kind == "coxa_femur_tibia" else second + rel
        return [first_angle, second, third], True

    def step(self, positions: list[list[float]]) -> list[float]:
        dt = self.dt
        q = []
        for i, foot in enumerate(positions):
            theta, ok = self.ik_leg(i, foot)
            leg_q = []
            for k in range(3):
                j = 3 * i + k
                qj = theta[k] * self.direction[j] + self.offset[j]
                lim = self.joints[j][3].limits
                ok = ok and lim.lower - LIMIT_TOLERANCE <= qj <= lim.upper + LIMIT_TOLERANCE
                leg_q.append(qj)
            q.extend(leg_q if ok else self.target[3 * i : 3 * i + 3])
        command = []
        for j, (otg, inp, out, joint) in enumerate(self.joints):
            qd = (q[j] - self.target[j]) / dt
            lim = joint.limits
            if self.streaming:
                qdd = (qd - self.target_qd[j]) / dt
                a_lim = lim.acceleration * MARGIN
                qdd = min(max(qdd, -a_lim), a_lim)
            else:
                qdd = 0.0
            v_lim = max(inp.max_velocity[0] * MARGIN - qdd * qdd * 0.5 / lim.jerk, 0.0)
            inp.target_position = [q[j]]
            inp.target_velocity = [min(max(qd, -v_lim), v_lim)]
            inp.target_acceleration = [qdd]
            otg.update(inp, out)
            out.pass_to_input(inp)
            command.append(min(max(out.new_position[0], lim.lower), lim.upper))
            self.target_qd[j] = qd
        self.target = q
        self.streaming = True
        return command


def run(robot: str, ticks: int, speed: float) -> dict:
    profile = profiles.load(ROBOTS / f"{robot}.toml")
    dt = 1.0 / profile.rate_hz
    pipeline = MotionPipeline(profile, dt)
    kin = pipeline.kinematics
    stand = kin.stand_joints()
    gaits = [instantiate("climbd.gaits", "tripod", {}, profile, "bench") for _ in range(2)]
    pipeline.start(stand)
    loop = LoopTick(pipeline)
    loop.start(stand.tolist())
    for gait in gaits:
        gait.start(BodyState(), kin.fk(stand))
    command, body = MotionCommand(vx=speed), BodyState()
    gait_t, pipeline_t, loop_t = np.empty(ticks), np.empty(ticks), np.empty(ticks)
    warm = int(10.0 * profile.rate_hz)
    worst = 0.0
    clock = time.perf_counter
    for k in range(ticks + warm):
        t = k * dt
        t0 = clock()
        targets = gaits[0].step(t, dt, body, {}, command)
        t1 = clock()
        cmd = pipeline.feet_step(targets)
        t2 = clock()
        ref = loop.step(gaits[1].step(t, dt, body, {}, command).positions)
        t3 = clock()
        worst = max(worst, float(np.max(np.abs(np.array(cmd.position) - ref))))
        if k >= warm:
            i = k - warm
            gait_t[i], pipeline_t[i], loop_t[i] = t1 - t0, t2 - t0, t3 - t2
    if worst > 1e-9:
        raise SystemExit(f"{robot}: pipeline and loop ticks differ by {worst:.3g} rad")
    return {
        "robot": robot,
        "joints": kin.n_joints,
        "rate": profile.rate_hz,
        "gait": np.median(gait_t) * 1e6,
        "pipeline": np.percentile(pipeline_t, [50, 99]) * 1e6,
        "loop": np.percentile(loop_t, [50, 99]) * 1e6,
        "worst": worst,
    }


WHOLE_TICK = """
import gc, json, sys, time
import numpy as np
old = sys.argv[1] == "old"
if old:  # the layout before climbd.* (one import name): top-level daemon, drivers, plugins
    from daemon.control import Controller
    from daemon.estimation import EstimatorConfig, StateEstimator
    from daemon.loop import SteppedClock
    from daemon.messages import Heartbeat, MotionCommand, Mode, SessionClaim
    from daemon.plugins import Isolated
    from daemon.profile import load
    from daemon.safety import Safety
    from drivers.base import FakeJointBus
    from plugins.gaits.periodic import Tripod
else:
    from climbd.daemon.algorithms.estimation import EstimatorConfig, StateEstimator
    from climbd.daemon.contract.messages import Heartbeat, MotionCommand, Mode, SessionClaim
    from climbd.daemon.contract.profile import load
    from climbd.daemon.runtime.loader import Isolated
    from climbd.daemon.runtime.loop import SteppedClock
    from climbd.daemon.runtime.stack import control_stack
    from climbd.drivers.fake import FakeJointBus
    from climbd.plugins.gaits.periodic import Tripod
profile = load(sys.argv[2])
ticks = int(sys.argv[3])
clock = SteppedClock()
bus = FakeJointBus(profile, tau=0.005, clock=clock.now)
bus.open()
gait = Isolated("tripod", Tripod(None, profile))
estimator = StateEstimator(profile, EstimatorConfig())
if old:
    safety = Safety(profile)
    controller = Controller(
        profile, bus, safety, clock.now, gait, estimator=estimator, feed_forward=True
    )
else:
    stack = control_stack(profile, bus, clock, gait, estimator=estimator, feed_forward=True)
    safety, controller = stack.safety, stack.controller
dt = 1.0 / profile.rate_hz
every = round(0.05 * profile.rate_hz)
times = []
t = 0.0
gc.collect()
gc.freeze()  # as climbd run does once started: start-up objects leave the collector's scans
safety.request(Mode.STAND, t)
controller.on_claim(SessionClaim(session="bench", client="bench"))
for k in range(int(3 * profile.safety.stand_time * profile.rate_hz) + ticks):
    if k % every == 0:
        controller.on_heartbeat(Heartbeat(session="bench", seq=k + 1, stamp=t))
        controller.on_motion(MotionCommand(vx=0.1, session="bench"))
    if safety.mode == Mode.HOLD and safety.reason == "stand complete":
        safety.request(Mode.ACTIVE, t, "bench")
    start = time.perf_counter()
    controller.tick(t, dt)
    times.append(time.perf_counter() - start)
    t += dt
    clock.advance(dt)
times = np.array(times[-ticks:]) * 1e6
print(json.dumps({"mode": safety.mode.value, "p50": float(np.median(times)),
                  "p99": float(np.percentile(times, 99))}))
"""


def whole_tick(rev: str, robot: str, ticks: int, rounds: int) -> None:
    """The controller's whole tick of this tree and of ``rev``, alternated in fresh processes."""
    archive = subprocess.run(
        ["git", "archive", rev], cwd=ROOT, check=True, capture_output=True
    ).stdout
    with (
        tempfile.TemporaryDirectory() as old_root,
        tarfile.open(fileobj=BytesIO(archive)) as tar,
    ):
        tar.extractall(old_root, filter="data")
        trees = {"old": old_root, "new": str(ROOT)}
        print(f"\n## whole controller tick, {robot}, {ticks} ticks a run: this tree vs {rev}\n")
        print("| round | old p50 µs | old p99 µs | new p50 µs | new p99 µs | new / old (p50) |")
        print("|---|---|---|---|---|---|")
        ratios = []
        for k in range(rounds):
            row = {}
            for which in ("old", "new") if k % 2 == 0 else ("new", "old"):
                env = dict(os.environ, PYTHONPATH=trees[which] if which == "old" else "")
                profile = Path(trees[which]) / "robots" / f"{robot}.toml"
                done = subprocess.run(
                    [sys.executable, "-c", WHOLE_TICK, which, str(profile), str(ticks)],
                    cwd=trees[which],
                    env=env,
                    check=True,
                    capture_output=True,
                    text=True,
                )
                row[which] = json.loads(done.stdout.strip().splitlines()[-1])
                if row[which]["mode"] != "ACTIVE":
                    raise SystemExit(f"{which}: the robot is {row[which]['mode']}, not walking")
            ratios.append(row["new"]["p50"] / row["old"]["p50"])
            print(
                f"| {k + 1} | {row['old']['p50']:.1f} | {row['old']['p99']:.1f} "
                f"| {row['new']['p50']:.1f} | {row['new']['p99']:.1f} | {ratios[-1]:.3f} |"
            )
        q = np.percentile(ratios, [0, 50, 100])
        print(
            f"\nnew / old (p50) over {rounds} rounds: min {q[0]:.3f}, median {q[1]:.3f}, "
            f"max {q[2]:.3f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", action="append", help="robot profile (repeatable)")
    parser.add_argument("--ticks", type=int, default=5000)
    parser.add_argument("--speed", type=float, default=0.1, help="commanded vx, m/s")
    parser.add_argument("--against", metavar="REV", help="also time the whole tick against REV")
    parser.add_argument("--rounds", type=int, default=6, help="old/new rounds for --against")
    args = parser.parse_args()
    if args.against:
        whole_tick(args.against, (args.robot or ["qingzhui"])[0], args.ticks, args.rounds)
        return
    print(
        "| robot | joints | rate Hz | gait median µs | pipeline tick median µs | p99 µs "
        "| loop tick median µs | p99 µs | loop / pipeline (median) | pipeline / period "
        "| max Δq rad |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for robot in args.robot or ["qingzhui", "widowx"]:
        r = run(robot, args.ticks, args.speed)
        (vm, vp), (lm, lp) = r["pipeline"], r["loop"]
        share = vm * 1e-6 * r["rate"]
        print(
            f"| {robot} | {r['joints']} | {r['rate']:.0f} | {r['gait']:.1f} | {vm:.1f} | {vp:.1f} "
            f"| {lm:.1f} "
            f"| {lp:.1f} | {lm / vm:.2f} | {share:.1%} | {r['worst']:.1e} |"
        )


if __name__ == "__main__":
    main()
