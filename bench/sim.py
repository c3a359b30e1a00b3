"""Physics twin benchmark: real-time factor per robot and world, and ray-cast depth per frame.

1. Stepped physics with the twin's motor laws, per robot × world; baseline: bare
   ``mujoco.mj_step`` on the same model in the same run (ratio = the twin's own overhead).
2. Real time with the daemon alongside (WidowX, one process): DynamixelBus on the pty and
   the Controller in a ControlLoop on the monotonic clock, against the real-time twin with its
   camera, or (baseline) against the bare servo emulator; simulated/wall time, physics lag,
   loop ticks and overruns.
3. Depth frames at 320×240 and 640×480 (L515) and 424×240 / 640×480 (D435) in the attic,
   1 and 2 casting threads, beside the 33.3 ms frame period; baseline: one bare
   ``mj_multiRay`` over the same rays.

Run: ``.venv/bin/python bench/sim.py`` (about a minute).
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import threading
import time

import msgspec
import mujoco
import numpy as np

from daemon.kinematics import Kinematics
from daemon.profile import load
from drivers.sim.depth import GEOM_GROUPS, RayCastDepth
from drivers.sim.twin import Twin

ROBOTS = ("widowx", "hubrobo", "qingzhui")
WORLDS = ("attic", "stairs", "slope", "truss")


def stepped_rtf(robot: str, world: str, seconds: float) -> tuple[float, float]:
    """(twin RTF, bare mj_step RTF) for ``seconds`` of a standing robot in ``world``."""
    profile = load(f"robots/{robot}.toml")
    stand = Kinematics(profile).stand_joints()
    twin = Twin(profile, world, stepped=True, bus=False, initial_joints=stand)
    if twin.robot.torque_legs:
        n = len(stand)
        twin.command_mit(stand, np.zeros(n), np.full(n, 300.0), np.full(n, 5.0), np.zeros(n))
    else:
        twin.command(stand)
    twin.advance_to(0.1)
    t0 = time.perf_counter()
    twin.advance_to(0.1 + seconds)
    ours = seconds / (time.perf_counter() - t0)
    m, d = twin.model, mujoco.MjData(twin.model)
    d.qpos[:] = twin.data.qpos
    steps = round(seconds / m.opt.timestep)
    t0 = time.perf_counter()
    for _ in range(steps):
        mujoco.mj_step(m, d)
    bare = seconds / (time.perf_counter() - t0)
    return ours, bare


def real_time_with_daemon(seconds: float, device_kind: str) -> dict:
    """The WidowX daemon side (driver + controller at 100 Hz on the monotonic clock) against
    the real-time twin with its camera in the same process (``twin``), in its own process
    (``process``, ``python -m drivers.sim``) or, as the baseline, the bare servo emulator with
    its built-in motor model (``emulator``)."""
    from daemon.control import Controller
    from daemon.loop import ControlLoop, MonotonicClock
    from daemon.messages import Mode
    from daemon.safety import Safety
    from drivers.dynamixel.bus import DynamixelBus
    from drivers.sim.dynamixel import DynamixelEmulator, ServoChain

    profile = load("robots/widowx.toml")
    physics = device_kind == "twin"
    if device_kind.startswith("process"):
        cameras = [] if device_kind == "process" else ["--no-cameras"]
        device = subprocess.Popen(
            [sys.executable, "-m", "drivers.sim", "--profile", "robots/widowx.toml"]
            + ["--world", "attic", "--fold-zero-offsets", *cameras],
            stdout=subprocess.PIPE,
            text=True,
        )
        port = device.stdout.readline().strip()
    else:
        if physics:
            device = Twin(profile, "attic", initial_joints=Kinematics(profile).stand_joints())
            device.on_depth(lambda name, frame: None)
        else:
            device = DynamixelEmulator(ServoChain.from_profile(profile))
        device.start()
        port = device.port
    bus = DynamixelBus.from_profile(profile, port=port)
    bus.open()
    clock = MonotonicClock()
    safety = Safety(profile)
    controller = Controller(profile, bus, safety, clock.now, None, lambda m: None)
    loop = ControlLoop(profile.rate_hz, clock, controller.tick)
    thread = threading.Thread(target=loop.run, daemon=True)
    sim0 = device.time if physics else 0.0
    wall0 = time.monotonic()
    thread.start()
    safety.request(Mode.STAND, clock.now())
    time.sleep(seconds)
    wall1 = time.monotonic()
    sim1 = device.time if physics else wall1 - wall0
    loop.stop()
    thread.join(2.0)
    stats = loop.stats()
    bus.close()
    elapsed = wall1 - wall0
    if device_kind.startswith("process"):
        device.send_signal(signal.SIGTERM)
        out, _ = device.communicate(timeout=10)
        simulated, wall = (float(w) for w in out.split()[1:6:3])
        sim0, sim1, wall0, wall1 = 0.0, simulated, 0.0, wall
    else:
        device.stop()
    return {
        "rtf": (sim1 - sim0) / (wall1 - wall0),
        "lag": device.lag if physics else 0.0,
        "ticks": stats.ticks,
        "overruns": stats.overruns,
        "late_p99_ms": stats.lateness_p99 * 1e3,
        "compute_p50_ms": stats.compute_p50 * 1e3,
        "frames": device.cameras["front"].number if physics else "–",
        "seconds": elapsed,
    }


def depth_times(
    model_name: str, width: int, height: int, frames: int, threads: int
) -> tuple[float, float]:
    """(ms per rendered frame, ms per bare mj_multiRay) in the attic, WidowX camera mount."""
    profile = load("robots/widowx.toml")
    cam_cfg = msgspec.structs.replace(
        profile.cameras[0], model=model_name, width=width, height=height
    )
    profile = msgspec.structs.replace(profile, cameras=[cam_cfg])
    twin = Twin(profile, "attic", stepped=True, bus=False, depth_threads=threads)
    cam: RayCastDepth = twin.cameras[cam_cfg.name]
    twin.depth_frame(cam_cfg.name)
    t0 = time.perf_counter()
    for _ in range(frames):
        twin.depth_frame(cam_cfg.name)
    ours = (time.perf_counter() - t0) / frames * 1e3
    d = twin._render_data
    rot, pos = cam.pose(d)
    vec = (cam.rays @ rot.T).ravel()
    n = len(cam.rays)
    geom, dist = np.zeros(n, np.int32), np.zeros(n)
    t0 = time.perf_counter()
    for _ in range(frames):
        mujoco.mj_multiRay(
            twin.model, d, pos, vec, GEOM_GROUPS, 1, cam.body, geom, dist, None, n, 10.0
        )
    bare = (time.perf_counter() - t0) / frames * 1e3
    return ours, bare


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per case")
    parser.add_argument("--frames", type=int, default=10, help="depth frames per resolution")
    parser.add_argument("--daemon-seconds", type=float, default=8.0)
    args = parser.parse_args()

    print("## real-time factor, stepped (twin alone; baseline bare mj_step, same model)\n")
    print("| robot | world | twin RTF | bare mj_step RTF | twin / bare |")
    print("|---|---|---:|---:|---:|")
    for robot in ROBOTS:
        for world in WORLDS:
            ours, bare = stepped_rtf(robot, world, args.seconds)
            print(f"| {robot} | {world} | {ours:.1f} | {bare:.1f} | {ours / bare:.2f} |")

    print("\n## real time, WidowX daemon side (DynamixelBus + Controller, 100 Hz) alongside\n")
    print(
        "| device | wall s | sim/wall | physics lag s | loop ticks (of) | overruns "
        "| tick compute p50 ms | lateness p99 ms | depth frames |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for kind, label in (
        ("emulator", "bare emulator (baseline)"),
        ("twin", "twin + L515 640×480, same process"),
        ("process", "twin + L515 640×480, own process"),
        ("process-no-cameras", "twin without cameras, own process"),
    ):
        r = real_time_with_daemon(args.daemon_seconds, kind)
        print(
            f"| {label} | {r['seconds']:.1f} | {r['rtf']:.3f} | {r['lag']:.3f} | {r['ticks']} "
            f"({round(r['seconds'] * 100)}) | {r['overruns']} | {r['compute_p50_ms']:.2f} | "
            f"{r['late_p99_ms']:.2f} | {r['frames']} |"
        )

    print("\n## depth frame (attic, WidowX mount; baseline bare mj_multiRay, same rays)\n")
    print(
        "| camera | resolution | threads | frame ms | bare ray cast ms (1 thread) | ratio "
        "| frame period ms | Hz |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for model_name, (w, h) in (
        ("L515", (320, 240)),
        ("L515", (640, 480)),
        ("D435", (424, 240)),
        ("D435", (640, 480)),
    ):
        for threads in (1, 2):
            ours, bare = depth_times(model_name, w, h, args.frames, threads)
            print(
                f"| {model_name} | {w}×{h} | {threads} | {ours:.1f} | {bare:.1f} | "
                f"{ours / bare:.2f} | {1000 / 30:.1f} | {1000 / ours:.0f} |"
            )


if __name__ == "__main__":
    main()
