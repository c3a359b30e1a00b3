"""Records Qingzhui's whole stair run in the twin (bench/stairs.py --full's run) as the estimator
sees it: the joint positions and torques as the torque-leg driver read them, the IMU sample
and the twin's true body pose, kept every ``KEEP``-th tick (250 Hz); every 0.5 s a depth cloud of
the front camera (body frame, 2 cm voxels, millimetres). tests/test_stair_estimate.py replays it.

    .venv/bin/python tests/support/stair_estimate_record.py [--out tests/data/stair_run.npz]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from climbd.plugins.perception.stairs import voxel_thin  # noqa: E402
from support.stair_run import CLOUD_PERIOD, CLOUD_VOXEL, StairRun, front_cloud, stair_world  # noqa: E402

KEEP = 4
"""Every how many 1 kHz ticks one is kept: the replay runs the estimator at 250 Hz."""
DEFAULT_OUT = Path(__file__).resolve().parents[1] / "data" / "stair_run.npz"


class Recorder:
    """Wraps the run's estimator update to log exactly what the estimator was fed, with truth."""

    def __init__(self, run: StairRun) -> None:
        self.run = run
        self.rows: dict[str, list] = {
            k: [] for k in ("t", "q", "tau", "gyro", "accel", "pos", "quat")
        }
        self.clouds: list[np.ndarray] = []
        self.cloud_ticks: list[int] = []
        est = run.rig.controller.estimator
        self.update = est.update
        est.update = self._update

    def _update(self, q, tau, gyro=None, accel=None, dt=0.0, stamp=0.0):
        twin = self.run.rig.twin
        pos, quat = twin.body_pose()
        for k, v in (
            ("t", stamp),
            ("q", q),
            ("tau", tau),
            ("gyro", gyro),
            ("accel", accel),
            ("pos", pos),
            ("quat", quat),
        ):
            self.rows[k].append(np.array(v, float))
        tick = len(self.rows["t"]) - 1
        if not self.cloud_ticks or stamp - self.rows["t"][self.cloud_ticks[-1]] >= CLOUD_PERIOD:
            points = voxel_thin(front_cloud(twin), CLOUD_VOXEL)
            self.clouds.append(points.astype(np.float32))
            self.cloud_ticks.append(tick)
        return self.update(q, tau, gyro, accel, dt, stamp)

    def save(self, out: Path) -> None:
        arrays = {k: np.array(v) for k, v in self.rows.items()}
        arrays["cloud_ticks"] = np.array(self.cloud_ticks)
        arrays["cloud_sizes"] = np.array([len(c) for c in self.clouds])
        arrays["clouds"] = np.vstack(self.clouds)
        out.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(out, **compact(arrays))


def compact(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Every ``KEEP``-th tick in float32, clouds in int16 millimetres: a 3.5 MB fixture."""
    out = {k: arrays[k][::KEEP].astype(np.float32) for k in ("q", "tau", "gyro", "accel", "pos")}
    out["quat"] = arrays["quat"][::KEEP].astype(np.float32)
    out["t"] = arrays["t"][::KEEP]
    out["cloud_ticks"] = -(-np.asarray(arrays["cloud_ticks"]) // KEEP)
    out["cloud_sizes"] = np.asarray(arrays["cloud_sizes"])
    out["clouds_mm"] = np.round(np.asarray(arrays["clouds"]) * 1000.0).astype(np.int16)
    return out


def record(up: float, down: float, speed: float = 0.15) -> Recorder:
    """The full run (up ``up`` s, back down ``down`` s at ``speed``) with its recorder."""
    run = StairRun(stair_world(), feed_forward=True)
    run.rig.bus.kp, run.rig.bus.kd = 300.0, 4.0
    run.start()
    rec = Recorder(run)
    run.walk(speed, up)
    if down > 0:
        run.walk(-speed, down)
    run.close()
    return rec


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--up", type=float, default=24.0, help="seconds walking up")
    parser.add_argument("--down", type=float, default=24.0, help="seconds walking back down")
    args = parser.parse_args()
    rec = record(args.up, args.down)
    rec.save(args.out)
    print(f"{len(rec.rows['t'])} ticks, {len(rec.clouds)} clouds -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
