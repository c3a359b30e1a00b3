"""Physics twin benchmark: real-time factor per robot and world, and ray-cast depth per frame.

1. Stepped physics with the twin's motor laws, per robot × world; baseline: bare
   ``mujoco.mj_step`` on the same model in the same run (ratio = the twin's own overhead).
2. Real time with the daemon alongside, per robot, as ``climbd run --sim attic`` runs it: the
   twin in the control role's process (SimHost), the profile's own driver on the twin's pty or
   virtual CAN channel, the Controller at the profile's rate on the monotonic clock, depth
   frames encoded for ``sim/depth``; the profile's camera at its model's 240-line stream
   (L515 320×240, D435 424×240) rasterised (``gl``), ray cast (``rays``) or none
   (the baseline the loop's ticks are compared with); sim/wall time, loop ticks, depth rate.
3. Depth frames at 320×240 and 640×480 (L515) and 424×240 / 640×480 (D435) in the attic,
   rasterised and ray cast, beside the 33.3 ms frame period; baseline: one bare
   ``mj_multiRay`` over the same rays.

Run: ``.venv/bin/python bench/sim.py`` (about two minutes).
"""

from __future__ import annotations

import argparse
import threading
import time

import msgspec
import mujoco
import numpy as np

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.profile import load
from climbd.drivers.sim.depth import GEOM_GROUPS, RayCastDepth
from climbd.drivers.sim.twin import Twin

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


def real_time_with_daemon(robot: str, seconds: float, cameras: str) -> dict:
    """The daemon's control side as ``climbd run --sim attic`` runs it: the SimHost twin in
    real time in this process, the profile's own driver on the twin's port, the Controller at
    the profile's rate on the monotonic clock, depth frames encoded as for ``sim/depth``.
    ``cameras``: ``gl`` (rasterised in the twin's camera process), ``gl-here`` (rasterised in
    this process), ``rays`` (mj_multiRay in this process, as the last release did) or ``none``
    (the baseline)."""
    from climbd.daemon.cli.sim_host import SimHost
    from climbd.daemon.contract.messages import Mode, encode
    from climbd.daemon.runtime.control_role import StartupError, make_joint_bus
    from climbd.daemon.runtime.stack import control_stack

    profile = load(f"robots/{robot}.toml")
    camera = profile.cameras[0]
    width = 320 if camera.model == "L515" else 424
    small = msgspec.structs.replace(camera, width=width, height=240)
    profile = msgspec.structs.replace(profile, cameras=[] if cameras == "none" else [small])
    frames: list[float] = []

    def publish(message) -> None:
        encode(message)
        frames.append(time.monotonic())

    backend = {"none": "auto", "gl-here": "gl"}.get(cameras, cameras)
    host = SimHost(profile, "attic", False, publish, backend)
    host.twin.camera_process = cameras == "gl"
    host.start()
    driver_profile, options = host.driver()
    try:
        bus = make_joint_bus(driver_profile, None, options)
    except StartupError:
        host.stop()
        raise
    clock = host.clock()
    stack = control_stack(profile, bus, clock)
    safety, loop = stack.safety, stack.loop
    thread = threading.Thread(target=loop.run, daemon=True)
    twin = host.twin
    sim0, wall0 = twin.time, time.monotonic()
    thread.start()
    safety.request(Mode.STAND, clock.now())
    time.sleep(seconds)
    sim1, wall1 = twin.time, time.monotonic()
    loop.stop()
    thread.join(2.0)
    stats = loop.stats()
    bus.close()
    host.stop()
    elapsed = wall1 - wall0
    shown = [t for t in frames if wall0 + 1.0 <= t <= wall1]
    return {
        "rtf": (sim1 - sim0) / elapsed,
        "lag": twin.lag,
        "ticks": stats.ticks,
        "expected": round(elapsed * profile.rate_hz),
        "overruns": stats.overruns,
        "late_p99_ms": stats.lateness_p99 * 1e3,
        "depth_hz": len(shown) / (elapsed - 1.0) if profile.cameras else None,
        "camera": profile.cameras[0] if profile.cameras else None,
        "seconds": elapsed,
    }


def depth_times(
    model_name: str, width: int, height: int, frames: int, backend: str
) -> tuple[float, float, float]:
    """(wall ms and CPU ms of this process per frame rendered with ``backend``, wall ms per bare
    mj_multiRay over the same rays) in the attic, WidowX camera mount. CPU time is what a frame
    costs whatever else the machine runs; wall time is what it took here."""
    profile = load("robots/widowx.toml")
    cam_cfg = msgspec.structs.replace(
        profile.cameras[0], model=model_name, width=width, height=height
    )
    profile = msgspec.structs.replace(profile, cameras=[cam_cfg])
    twin = Twin(profile, "attic", stepped=True, bus=False, depth_backend=backend)
    cam: RayCastDepth = twin.cameras[cam_cfg.name]
    twin.depth_frame(cam_cfg.name)
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(frames):
        twin.depth_frame(cam_cfg.name)
    ours = (time.perf_counter() - t0) / frames * 1e3
    cpu = (time.process_time() - c0) / frames * 1e3
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
    return ours, cpu, bare


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per case")
    parser.add_argument("--frames", type=int, default=10, help="depth frames per resolution")
    parser.add_argument("--daemon-seconds", type=float, default=6.0)
    args = parser.parse_args()
    from climbd.daemon.runtime.control_role import StartupError

    print("## real-time factor, stepped (twin alone; baseline bare mj_step, same model)\n")
    print("| robot | world | twin RTF | bare mj_step RTF | twin / bare |")
    print("|---|---|---:|---:|---:|")
    for robot in ROBOTS:
        for world in WORLDS:
            ours, bare = stepped_rtf(robot, world, args.seconds)
            print(f"| {robot} | {world} | {ours:.1f} | {bare:.1f} | {ours / bare:.2f} |")

    print("\n## real time with the daemon alongside (SimHost + profile driver + Controller)\n")
    print(
        "| robot | cameras | wall s | sim/wall | physics lag s | loop ticks (of) | overruns "
        "| lateness p99 ms | ticks / baseline | depth Hz |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for robot in ROBOTS:
        base = None
        for cameras in ("none", "gl", "gl-here", "rays"):
            try:
                r = real_time_with_daemon(robot, args.daemon_seconds, cameras)
            except StartupError as e:
                print(f"| {robot} | {cameras} | driver bring-up failed: {e} |||||||| ")
                continue
            share = r["ticks"] / r["expected"]
            base = share if cameras == "none" else base
            ratio = "–" if base is None else f"{share / base:.3f}"
            cam = r["camera"]
            label = (
                "none (baseline)"
                if cam is None
                else f"{cam.model} {cam.width}×{cam.height} {cameras}"
            )
            hz = "–" if r["depth_hz"] is None else f"{r['depth_hz']:.1f} of {cam.fps}"
            print(
                f"| {robot} | {label} | {r['seconds']:.1f} | {r['rtf']:.3f} | {r['lag']:.3f} | "
                f"{r['ticks']} ({r['expected']}) | {r['overruns']} | {r['late_p99_ms']:.2f} | "
                f"{ratio} | {hz} |"
            )

    print("\n## depth frame (attic, WidowX mount; baseline bare mj_multiRay, same rays)\n")
    print(
        "| camera | resolution | backend | frame ms | frame CPU ms | bare ray cast ms | ratio "
        "| frame period ms | Hz | Hz by CPU |"
    )
    print("|---|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for model_name, (w, h) in (
        ("L515", (320, 240)),
        ("L515", (640, 480)),
        ("D435", (424, 240)),
        ("D435", (640, 480)),
    ):
        for backend in ("gl", "rays"):
            ours, cpu, bare = depth_times(model_name, w, h, args.frames, backend)
            print(
                f"| {model_name} | {w}×{h} | {backend} | {ours:.1f} | {cpu:.1f} | {bare:.1f} | "
                f"{ours / bare:.2f} | {1000 / 30:.1f} | {1000 / ours:.0f} | {1000 / cpu:.0f} |"
            )


if __name__ == "__main__":
    main()
