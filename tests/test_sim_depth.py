"""Twin depth: rasterised depth samples the rays ``mj_multiRay`` casts, deterministically."""

from __future__ import annotations

import math
import threading

import msgspec
import numpy as np
import pytest
from conftest import ROOT

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.profile import load
from climbd.drivers.sim.camera_process import CameraProcess
from climbd.drivers.sim.depth import RayCastDepth
from climbd.drivers.sim.gl_depth import gl_available
from climbd.drivers.sim.twin import Twin, serve_cameras
from climbd.drivers.sim.worlds import JoistRow, World


def _small_camera(robot: str):
    """The robot's profile with its camera at its model's small stream (L515 320×240, D435
    424×240), so the test's ray casting stays quick."""
    profile = load(ROOT / "robots" / f"{robot}.toml")
    width = 320 if profile.cameras[0].model == "L515" else 424
    camera = msgspec.structs.replace(profile.cameras[0], width=width, height=240)
    return msgspec.structs.replace(profile, cameras=[camera])


def _joist_world() -> World:
    return msgspec.convert(
        {
            "name": "two joists",
            "joists": [
                msgspec.to_builtins(JoistRow(height=0.1, distance=0.5, width=0.05, length=1.0)),
                msgspec.to_builtins(
                    JoistRow(height=0.3, distance=1.2, width=0.05, length=1.0, yaw_deg=20.0)
                ),
            ],
        },
        World,
    )


def test_an_egl_context_is_available():
    """`make` installs Mesa's EGL: the twin's cameras rasterise instead of casting rays."""
    assert gl_available(), "no headless EGL context: install libegl1 libegl-mesa0 libgl1-mesa-dri"


@pytest.mark.parametrize(
    ("robot", "world", "normals_agree"),
    [("widowx", "joists", 0.99), ("hubrobo", "slope", 0.95)],
)
def test_rasterised_depth_matches_ray_casting(robot, world, normals_agree):
    """Per pixel in range, OpenGL and ``mj_multiRay`` see the same geom at one z-depth (1 mm), and
    the grazing dropout the noise model derives from the surface normal agrees (probability
    within 0.1 per pixel; image-gradient normals smooth the facets of the slope's mesh holds
    on a few pixels) and on average within 1 % of the pixels."""
    profile = _small_camera(robot)
    stand = Kinematics(profile).stand_joints()
    scene = _joist_world() if world == "joists" else world
    twin = Twin(profile, scene, stepped=True, bus=False, initial_joints=stand)
    gl = twin.cameras["front"]
    assert gl.backend == "gl"
    rays = RayCastDepth(twin.model, profile.cameras[0], twin.robot.base_body, backend="rays")
    twin.depth_frame("front")
    data = twin._render_data
    gd, gg, gn, vec = gl.cast(data)
    rd, rg, rn, _ = rays.cast(data)
    with np.errstate(invalid="ignore"):  # hits in the camera's range (the rest are not reported)
        hit_gl, hit_rays = gd <= gl.max_range, rd <= gl.max_range
    assert hit_rays.mean() > 0.5
    assert np.mean(hit_gl == hit_rays) > 0.999
    both = hit_gl & hit_rays
    assert np.mean(np.abs(gd[both] - rd[both]) <= 1e-3) > 0.995
    assert np.mean(gg[both] == rg[both]) > 0.995
    if world == "joists":
        assert len(np.unique(rg[both])) >= 3, "floor and both joists in view"
    fade = math.cos(math.radians(gl.noise.grazing_deg))

    def grazing_dropout(normal: np.ndarray) -> np.ndarray:
        cos = np.abs(np.einsum("ij,ij->i", normal[both], vec[both])) / gl.ray_norm[both]
        return np.clip((fade - np.nan_to_num(cos, nan=1.0)) / fade, 0.0, 1.0)

    p_gl, p_rays = grazing_dropout(gn), grazing_dropout(rn)
    assert np.mean(np.abs(p_gl - p_rays) < 0.1) > normals_agree
    assert abs(p_gl.mean() - p_rays.mean()) < 0.01


def test_rasterised_frames_are_deterministic_across_twins_and_threads():
    """Two stepped twins with one seed render identical frames, bit for bit, whichever thread
    renders (the stepped runs' logs compare bit for bit)."""
    profile = _small_camera("widowx")
    frames: list[list[np.ndarray]] = [[], []]
    for k in range(2):
        twin = Twin(profile, "attic", stepped=True, bus=False, seed=5)
        twin.on_depth(lambda name, frame, k=k: frames[k].append(frame.depth.copy()))
        if k == 0:
            twin.advance_to(0.1)
        else:
            worker = threading.Thread(target=twin.advance_to, args=(0.05,))
            worker.start()
            worker.join()
            twin.advance_to(0.1)
        twin.stop()
    assert len(frames[0]) == len(frames[1]) >= 3
    for a, b in zip(*frames, strict=True):
        assert a.any() and np.array_equal(a, b)


def test_camera_process_renders_what_the_twin_would_in_process():
    """The real-time twin's camera process (own model, same seeds) returns, frame after frame,
    the images the twin renders in-process at the same joint state, bit for bit."""
    profile = _small_camera("widowx")
    twin = Twin(profile, _joist_world(), stepped=True, bus=False, seed=7)
    worker = CameraProcess(serve_cameras, profile, twin.world, twin.model.opt.timestep, seed=7)
    try:
        cam = twin.cameras["front"]
        for t in (0.0, 0.05):
            twin.advance_to(t)
            qpos, now = twin.data.qpos.copy(), twin.time
            remote = worker.render(cam, "front", qpos, now)
            local = twin.depth_frame("front")
            assert remote.number + 1 == local.number
            assert remote.timestamp == local.timestamp
            assert local.depth.any() and np.array_equal(remote.depth, local.depth)
    finally:
        worker.close()
        twin.stop()
