"""Depth → body-frame point cloud (with paper 000's crop box) beside pyrealsense2's own conversion.

Synthetic frames (floor and a joist seen by a camera tilted 30°, 5 % dropouts) are recorded
through a software device and played back, so both converters get the very same librealsense
frames. Baseline: ``rs.pointcloud().calculate(frame)`` plus the numpy view of its vertices
(camera frame, every pixel, no crop), and the same followed by what a user must add to get
our result (drop zeros, mount transform, crop): that second row is the goal's comparison, the
same product on the same frames. Ours: ``frame_to_points`` into the body frame, cropped to
1 m × 1.2 m × 0.4 m, and uncropped. The converters take turns frame by frame; reports wall
medians, ours' 90th percentile and thread CPU time (the machine is shared), ratios and the
load average; goal: ≤ 6.67 ms (1/5 of a 30 fps period) at 640×480 and no slower than
rs + body + crop.

    .venv/bin/python bench/depth.py [--repeats 40]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import pyrealsense2 as rs

from climbd.daemon.algorithms.cloud import PAPER_000, crop, frame_to_points
from climbd.daemon.contract.hardware import DepthFrame, Intrinsics, mount_extrinsics
from climbd.daemon.contract.profile import CameraConfig, CameraMount
from climbd.drivers.realsense.models import D435, L515
from climbd.drivers.realsense.software import SoftwareDepthCamera

FRAMES = 8


def scene(intrinsics: Intrinsics, extrinsics: np.ndarray, scale: float, seed: int) -> np.ndarray:
    """Depth of the floor (z = 0) with a 0.15 m joist across x ∈ [0.6, 0.65], noise, dropouts."""
    rng = np.random.default_rng(seed)
    i = intrinsics
    u, v = np.meshgrid(np.arange(i.width), np.arange(i.height))
    rays = np.stack([(u - i.ppx) / i.fx, (v - i.ppy) / i.fy, np.ones(u.shape)], -1)
    body = rays @ extrinsics[:3, :3].T
    cam = extrinsics[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(body[..., 2] < 0, -cam[2] / body[..., 2], 0.0)
        top = np.where(body[..., 2] < 0, (0.15 - cam[2]) / body[..., 2], 0.0)
    x_top = cam[0] + top * body[..., 0]
    z = np.where((x_top >= 0.6) & (x_top <= 0.65), top, z)
    z = np.where((z > 0) & (z < 6.0), z + rng.normal(0, 0.002, z.shape), 0.0)
    z[rng.random(z.shape) < 0.05] = 0.0
    return np.round(z / scale).astype(np.uint16)


def recorded_frames(model, width, height, extrinsics, folder: Path) -> list[rs.depth_frame]:
    """Record synthetic frames through a software device and return them as played back."""
    intrinsics = model.intrinsics(width, height)
    bag = folder / f"{model.name}-{width}x{height}.bag"
    camera = SoftwareDepthCamera(
        intrinsics, model.depth_unit, extrinsics, model=model.name, record_to=bag, queue_size=16
    )
    camera.open()
    for k in range(FRAMES):
        camera.push(scene(intrinsics, extrinsics, model.depth_unit, k), k / 30)
    camera.close()
    context = rs.context()
    device = context.load_device(str(bag))
    device.as_playback().set_real_time(False)
    sensor = device.query_sensors()[0]
    frames: list[rs.frame] = []

    def keep(frame: rs.frame) -> None:
        frame.keep()
        frames.append(frame)

    sensor.open(sensor.get_stream_profiles()[0])
    sensor.start(keep)
    end = time.monotonic() + 10
    while len(frames) < FRAMES and time.monotonic() < end:
        time.sleep(0.01)
    sensor.stop()
    sensor.close()
    return [f.as_depth_frame() for f in frames]


def interleaved_ms(fns: dict, frames, repeats: int, clock=time.perf_counter) -> dict:
    """Times (ms, wall unless another ``clock``) of each of ``fns`` on every frame, ``repeats``
    times over, taking turns frame by frame so a change of machine load hits all of them alike."""
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeats):
        for frame in frames:
            for name, fn in fns.items():
                start = clock()
                fn(frame)
                times[name].append(1e3 * (clock() - start))
    return times


def load_average() -> str:
    return Path("/proc/loadavg").read_text().split(" ", 1)[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=40)
    args = parser.parse_args()
    config = CameraConfig(mount=CameraMount(position=[0.1, 0.0, 0.25], tilt_deg=30.0))
    extrinsics = mount_extrinsics(config)
    pointcloud = rs.pointcloud()
    rotation = extrinsics[:3, :3].astype(np.float32)
    offset = extrinsics[:3, 3].astype(np.float32)
    budget = 1e3 / 30 / 5
    load_before = load_average()
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for model, (w, h) in [(D435, (640, 480)), (L515, (640, 480)), (L515, (1024, 768))]:
            frames = recorded_frames(model, w, h, extrinsics, Path(folder))
            profile = frames[0].get_profile().as_video_stream_profile().get_intrinsics()
            intrinsics = Intrinsics(w, h, profile.fx, profile.fy, profile.ppx, profile.ppy)
            scale = frames[0].get_units()

            def depth_frame(f, intrinsics=intrinsics, scale=scale):
                image = np.asanyarray(f.get_data())
                return DepthFrame(image, scale, intrinsics, extrinsics, f.get_timestamp() / 1e3)

            def baseline(f):
                return np.asanyarray(pointcloud.calculate(f).get_vertices()).view(np.float32)

            def baseline_body(f):
                v = baseline(f).reshape(-1, 3)
                v = v[v[:, 2] > 0]
                body = np.empty_like(v)
                for k in range(3):  # per axis: no BLAS threads fighting a loaded machine
                    r = rotation[k]
                    body[:, k] = v[:, 0] * r[0] + v[:, 1] * r[1] + v[:, 2] * r[2] + offset[k]
                return crop(body, PAPER_000)

            def ours_crop(f, depth_frame=depth_frame):
                return frame_to_points(depth_frame(f), box=PAPER_000)

            def ours_full(f, depth_frame=depth_frame):
                return frame_to_points(depth_frame(f))

            kept = (len(ours_crop(frames[0])), len(baseline_body(frames[0])))
            fns = {"rs": baseline, "rs_body": baseline_body, "ours": ours_crop, "full": ours_full}
            wall = interleaved_ms(fns, frames, args.repeats)
            cpu = interleaved_ms(fns, frames, args.repeats, time.thread_time)
            median = {name: statistics.median(times) for name, times in wall.items()}
            p90 = statistics.quantiles(wall["ours"], n=10)[-1]
            rows.append(
                (f"{model.name} {w}×{h}", median, p90, statistics.median(cpu["ours"]), kept)
            )
    print(
        "| frames | rs.pointcloud (ms) | rs + body + crop (ms) | ours + crop (ms) "
        "| ours + crop p90 (ms) | ours + crop CPU (ms) | ours / rs "
        "| **ours / (rs + body + crop)** | ours, no crop (ms) | points in box (ours, rs) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, m, p90, cpu_ms, (ours_n, rs_n) in rows:
        print(
            f"| {name} | {m['rs']:.2f} | {m['rs_body']:.2f} | {m['ours']:.2f} | {p90:.2f} "
            f"| {cpu_ms:.2f} | {m['ours'] / m['rs']:.1f} | **{m['ours'] / m['rs_body']:.2f}** "
            f"| {m['full']:.2f} | {ours_n}, {rs_n} |"
        )
    at_640 = [row for row in rows if "640×480" in row[0]]
    in_budget = all(row[1]["ours"] <= budget for row in at_640)
    no_slower = all(row[1]["ours"] <= row[1]["rs_body"] for row in rows)
    print(f"budget: 1/5 of a 30 fps period = {budget:.2f} ms; 640×480 within it: {in_budget}")
    print(f"ours no slower than rs + body + crop (the goal's comparison): {no_slower}")
    print(f"load average (1 min): {load_before} before, {load_average()} after")


if __name__ == "__main__":
    main()
