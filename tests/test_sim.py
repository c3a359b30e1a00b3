"""Physics twin: models from profiles, worlds from files, standing physics, determinism, depth."""

from __future__ import annotations

import math
import time

import msgspec
import mujoco
import numpy as np
import pyrealsense2 as rs
import pytest
from conftest import ROOT

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.profile import load
from climbd.drivers.sim import servos
from climbd.drivers.sim.depth import NOISE
from climbd.drivers.sim.model import GRIP_FORCE, build
from climbd.drivers.sim.topview import render_top_view
from climbd.drivers.sim.twin import IMU_WINDOW, Twin
from climbd.drivers.sim.worlds import JoistRow, World, WorldError, holds_heightfield, stock_worlds
from climbd.drivers.sim.worlds import load as load_world


@pytest.fixture(scope="module")
def widowx():
    return load(ROOT / "robots" / "widowx.toml")


def _rot(quat: np.ndarray) -> np.ndarray:
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, quat)
    return m.reshape(3, 3)


@pytest.mark.parametrize("robot", ["widowx", "hubrobo", "qingzhui"])
def test_model_mass_and_feet_match_profile_kinematics(robot):
    """Total mass is the profile's; sim feet equal daemon FK at random joint vectors."""
    profile = load(ROOT / "robots" / f"{robot}.toml")
    twin = Twin(profile, "attic", stepped=True, bus=False)
    assert sum(twin.model.body_mass) == pytest.approx(profile.mass, rel=1e-6)
    kin = Kinematics(profile)
    rng = np.random.default_rng(1)
    lo = np.array([j.limits.lower for j in profile.joints])
    hi = np.array([j.limits.upper for j in profile.joints])
    d = twin.data
    for _ in range(5):
        q = rng.uniform(lo, hi)
        d.qpos[twin.robot.qpos_adr] = twin.map.hinge(q)
        mujoco.mj_kinematics(twin.model, d)
        pos, quat = d.qpos[:3], d.qpos[3:7]
        feet_body = (d.site_xpos[twin.robot.foot_sites] - pos) @ _rot(quat)
        np.testing.assert_allclose(feet_body, kin.fk(q), atol=1e-6)


def test_servo_law_follows_the_datasheet():
    """AX-18A: stall torque at rest, zero at 97 rpm, braking torque capped at stall."""
    ax = servos.servo_model("AX-18A")
    assert ax.stall_torque == 1.8 and ax.no_load_speed == pytest.approx(97 * 2 * math.pi / 60)
    one = np.ones(1)

    def tau(err, vel):
        return servos.servo_torque(
            err * one, vel * one, ax.kp * one, ax.stall_torque * one, ax.no_load_speed * one, 1.8
        )[0]

    assert tau(1.0, 0.0) == pytest.approx(1.8)
    assert tau(1.0, ax.no_load_speed) == pytest.approx(0.0, abs=1e-12)
    assert tau(-1.0, ax.no_load_speed) == pytest.approx(-1.8)
    assert tau(math.radians(4.7), 0.0) == pytest.approx(0.9, rel=1e-6)
    with pytest.raises(ValueError, match=r"\$\.bus\.model.*MX-64"):
        servos.servo_model("MX-64")


def test_widowx_stands_and_holds_height_in_stepped_mode(widowx):
    """From belly-down rest, a smoothed rise to the stand pose lifts the body to its stand
    height (feet are spheres of radius r under the kinematic foot point) and holds it."""
    twin = Twin(widowx, "attic", stepped=True, bus=False)
    twin.advance_to(0.2)
    assert twin.base_contacts()
    rest = twin.joint_positions()
    stand = Kinematics(widowx).stand_joints()
    for k in range(1, 151):
        s = min(1.0, k / 100)
        twin.command(rest + (stand - rest) * (3 * s * s - 2 * s**3))
        twin.advance_to(0.2 + k * 0.01)
    twin.advance_to(3.0)
    target = widowx.stand.body_height + twin.robot.foot_radius
    assert abs(twin.body_pose()[0][2] - target) < 0.01
    assert twin.foot_contacts().all() and not twin.base_contacts()
    assert not twin.fallen(widowx.stand.body_height)
    efforts = twin.joint_efforts()
    assert np.all(np.abs(efforts) < 1.8)
    # Weight is carried: vertical foot forces balance gravity within 5 %.
    total = 0.0
    force = np.zeros(6)
    d = twin.data
    for i in range(d.ncon):
        mujoco.mj_contactForce(twin.model, d, i, force)
        total += force[0] * abs(d.contact[i].frame[2])
    assert total == pytest.approx(widowx.mass * 9.80665, rel=0.05)


def test_the_accelerometer_integrates_to_the_velocity_the_base_gains(widowx):
    """As the WidowX rises from rest on its servos, the accelerometer's readings (less gravity,
    turned into the world) sum over time to the velocity the base gains: what the body does,
    not the solver's explicit acceleration, which the implicit integrator does not apply."""
    twin = Twin(widowx, "attic", stepped=True, bus=False)
    twin.advance_to(0.2)
    rest = twin.joint_positions()
    stand = Kinematics(widowx).stand_joints()
    v0 = twin.data.qvel[:3].copy()
    gained, rose = np.zeros(3), []
    period = IMU_WINDOW * twin.model.opt.timestep
    for k in range(1, 101):
        twin.command(rest + (stand - rest) * min(1.0, k / 60))
        twin.advance_to(0.2 + k * period)
        world = rotation(twin.body_pose()[1])
        gained += (world @ twin.imu_sample().accel + twin.model.opt.gravity) * period
        rose.append(np.linalg.norm(twin.data.qvel[:3] - v0))
        assert np.linalg.norm(gained - (twin.data.qvel[:3] - v0)) < 0.005, k
    assert max(rose) > 0.05  # the base really moved


def _sway_log(profile, seed: int) -> np.ndarray:
    twin = Twin(profile, "attic", stepped=True, bus=False, seed=seed)
    start = twin.joint_positions()
    log = []
    for k in range(1, 61):
        t = k * 0.01
        twin.command(start + 0.2 * math.sin(2 * math.pi * t) * np.ones_like(start))
        twin.advance_to(t)
        log.append(twin.joint_positions())
    return np.array(log)


def test_stepped_mode_is_deterministic(widowx):
    """Two stepped runs with the same inputs give bit-identical joint logs."""
    a, b = _sway_log(widowx, 0), _sway_log(widowx, 0)
    assert np.array_equal(a, b)
    assert np.ptp(a[:, 1]) > 0.1  # the joints really moved


def test_worlds_load_and_build():
    """Every stock world builds with the WidowX; bad files name the field."""
    profile = load(ROOT / "robots" / "widowx.toml")
    assert {"attic", "attic_6in", "attic_8in", "attic_paper", "stairs", "slope", "truss"} <= set(
        stock_worlds()
    )
    for name in ("attic_paper", "stairs", "truss"):
        model = build(profile, load_world(name)).model
        assert model.ngeom > 20
    attic = build(profile, load_world("attic")).model
    joists = [attic.geom(i) for i in range(attic.ngeom) if attic.geom(i).name.startswith("joist")]
    assert len(joists) == 4
    assert joists[0].size[2] * 2 == pytest.approx(0.1016)
    assert joists[1].pos[0] - joists[0].pos[0] == pytest.approx(0.4064)
    stairs = build(profile, load_world("stairs")).model
    steps = sorted(
        (stairs.geom(i) for i in range(stairs.ngeom) if stairs.geom(i).name.startswith("stair")),
        key=lambda g: g.pos[0],
    )
    tops = [2 * g.size[2] for g in steps]
    fronts = [g.pos[0] - g.size[0] for g in steps]
    np.testing.assert_allclose(tops, [0.13, 0.26, 0.39])
    np.testing.assert_allclose(np.diff(fronts), [0.30, 0.30])
    truss = build(profile, load_world("truss")).model
    members = [truss.geom(i) for i in range(truss.ngeom) if truss.geom(i).name.startswith("member")]
    assert len(members) == 19 and all(g.size[0] == pytest.approx(0.025) for g in members)
    with pytest.raises(WorldError, match=r"\$\.joists\[0\]\.height"):
        load_world("attic", joists=[{"height": -0.1, "distance": 1.0}])
    with pytest.raises(WorldError, match="no such file"):
        load_world("nowhere")


def test_holds_slope_from_the_point_cloud_at_incline_and_gravity():
    """The tiled cloud keeps the holds' relief (cm-scale), sits at 30°, gravity G/6."""
    world = load_world("slope")
    heights, length, width = holds_heightfield(world.holds, stock_worlds()["slope"].parent)
    assert heights.shape[0] > 100 and heights.shape[1] > 100
    assert 0.03 < np.ptp(heights) < 0.1
    assert length == pytest.approx(3 * 0.58, abs=0.1)
    hubrobo = load(ROOT / "robots" / "hubrobo.toml")
    twin = Twin(hubrobo, world, stepped=True, bus=False)
    assert twin.model.opt.gravity[2] == pytest.approx(-9.80665 / 6)
    hf = twin.model.geom("holds")
    up = _rot(hf.quat) @ [0, 0, 1]
    assert math.degrees(math.acos(up[2])) == pytest.approx(30.0)


def _pull_off(world: str, grip: bool, pull: float) -> float:
    """Press a standing HubRobo onto ``world`` in zero gravity, set its grippers, pull the body
    away along its normal with ``pull`` N for 0.6 s; returns how far it moved (m)."""
    hubrobo = load(ROOT / "robots" / "hubrobo.toml")
    stand = Kinematics(hubrobo).stand_joints()
    twin = Twin(
        hubrobo, load_world(world, gravity=0.0), stepped=True, bus=False, initial_joints=stand
    )
    twin.command(stand)
    normal = _rot(twin.body_pose()[1])[:, 2]
    push = twin.data.xfrc_applied[twin.robot.base_body, :3]
    push[:] = -10.0 * normal
    twin.advance_to(0.3)
    assert twin.foot_contacts().all()
    twin.grip[:] = grip
    push[:] = 0.0
    twin.advance_to(0.5)  # the gripper servos close the fingers in 0.13 s
    start = twin.body_pose()[0]
    push[:] = pull * normal
    twin.advance_to(1.0)
    return float(np.linalg.norm(twin.body_pose()[0] - start))


def test_gripper_holds_only_when_closed_on_a_graspable_shape():
    """Four closed grippers on the holds resist a 20 N pull; open ones do not; 45 N (more than
    4 × 9 N) tears them off; closed on the plain floor they do not hold."""
    assert GRIP_FORCE == 9.0
    assert _pull_off("slope", True, 20.0) < 0.02
    assert _pull_off("slope", False, 20.0) > 0.3
    assert _pull_off("slope", True, 45.0) > 0.3
    assert _pull_off("attic", True, 20.0) > 0.3


def _box_world(x: float) -> World:
    """Floor plus one 0.2 m tall, 0.3 m deep box centred ``x`` ahead (a joist row of one)."""
    return msgspec.convert(
        {
            "name": "box",
            "joists": [
                msgspec.to_builtins(JoistRow(height=0.2, distance=x, width=0.3, length=0.6))
            ],
        },
        World,
    )


def _box_sdf(p: np.ndarray, x: float) -> np.ndarray:
    centre, half = np.array([x, 0.0, 0.1]), np.array([0.15, 0.3, 0.1])
    q = np.abs(p - centre) - half
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)


@pytest.mark.parametrize(("robot", "x"), [("widowx", 0.9), ("hubrobo", 0.55)])
def test_depth_of_a_known_box_deprojects_onto_its_surface(robot, x):
    """Pixels deprojected through pyrealsense2's intrinsics land on the box or floor within
    4σ of the camera's noise model; the box is seen; the noise has the model's spread."""
    profile = load(ROOT / "robots" / f"{robot}.toml")
    twin = Twin(profile, _box_world(x), stepped=True, bus=False, seed=3)
    cam = profile.cameras[0]
    frame = twin.depth_frame(cam.name)
    assert frame.depth.dtype == np.uint16 and frame.depth.shape == (cam.height, cam.width)
    i = frame.intrinsics
    intr = rs.intrinsics()
    intr.width, intr.height, intr.fx, intr.fy, intr.ppx, intr.ppy = (
        i.width,
        i.height,
        i.fx,
        i.fy,
        i.ppx,
        i.ppy,
    )
    intr.model = rs.distortion.none
    intr.coeffs = [0.0] * 5
    v, u = np.nonzero(frame.depth)
    pick = np.random.default_rng(0).choice(len(u), 3000, replace=False)
    z = frame.depth[v[pick], u[pick]] * frame.depth_scale
    optical = np.array(
        [
            rs.rs2_deproject_pixel_to_point(intr, [float(a), float(b)], float(c))
            for a, b, c in zip(u[pick], v[pick], z, strict=True)
        ]
    )
    rot, pos = twin.cameras[cam.name].pose(twin._render_data)
    world = optical @ rot.T + pos
    dist = np.minimum(np.abs(_box_sdf(world, x)), np.abs(world[:, 2]))
    ray = np.linalg.norm(optical / optical[:, 2:3], axis=1)
    sigma = NOISE[cam.model].sigma(z) * ray + frame.depth_scale
    assert np.mean(dist <= 4 * sigma) > 0.999
    on_box = np.abs(_box_sdf(world, x)) < 4 * sigma
    assert on_box.sum() > 100
    # Spread: residuals on the box's front face against the model's σ.
    face = on_box & (np.abs(world[:, 0] - (x - 0.15)) < 4 * sigma)
    face &= (world[:, 2] > 0.02) & (world[:, 2] < 0.18) & (np.abs(world[:, 1]) < 0.28)
    assert face.sum() > 50
    normal_ray = np.abs(optical[face] @ (rot.T @ [1.0, 0, 0])) / np.linalg.norm(
        optical[face], axis=1
    )
    along_ray = (world[face, 0] - (x - 0.15)) / normal_ray / ray[face]
    model_sigma = np.hypot(NOISE[cam.model].sigma(z[face]), frame.depth_scale / math.sqrt(12))
    assert np.std(along_ray / model_sigma) == pytest.approx(1.0, abs=0.25)


def test_depth_drops_grazing_and_far_returns(widowx):
    """Level camera over a floor: grazing floor pixels near the horizon mostly drop out,
    nothing beyond max range is reported, and the IMU reads gravity at rest."""
    profile = msgspec.structs.replace(
        widowx,
        cameras=[
            msgspec.structs.replace(
                widowx.cameras[0],
                mount=msgspec.structs.replace(widowx.cameras[0].mount, tilt_deg=0.0),
            )
        ],
    )
    twin = Twin(profile, World(name="flat"), stepped=True, bus=False)
    cam = twin.cameras["front"]
    frame = twin.depth_frame("front")
    ideal, _, _, _ = cam.cast(twin._render_data)
    ideal = ideal.reshape(frame.depth.shape)
    grazing = np.isfinite(ideal) & (ideal > 1.5) & (ideal < cam.max_range * 0.9)
    assert grazing.sum() > 100
    assert np.mean(frame.depth[grazing] == 0) > 0.5
    assert frame.depth.max() * frame.depth_scale <= cam.max_range
    twin.advance_to(1.0)
    imu = twin.imu_sample()
    assert np.linalg.norm(imu.accel) == pytest.approx(9.80665, rel=0.05)


def test_depth_enters_pyrealsense2_through_the_software_device(widowx):
    """Frames the stepped twin renders at the camera rate come out of the RealSense driver's
    software device unchanged, with the camera's intrinsics and depth units."""
    twin = Twin(widowx, _box_world(0.9), stepped=True, bus=False)
    pushed = []
    twin.on_depth(lambda name, frame: pushed.append(frame))
    camera = twin.software_camera("front", timeout=5.0)
    camera.open()
    try:
        twin.advance_to(0.1)
        frames = camera.frames()
        got = next(frames)
    finally:
        camera.close()
    assert len(pushed) in (3, 4)  # every 1/30 s of simulated time
    match = [f for f in pushed if np.array_equal(f.depth, got.depth)]
    assert match, "a delivered frame equals a rendered one, pixel for pixel"
    assert got.intrinsics == twin.cameras["front"].intrinsics
    assert got.depth_scale == pytest.approx(0.00025)


def test_real_time_mode_runs_physics_and_cameras_in_threads(widowx):
    """Started without ``stepped``, simulated time advances on its own and depth callbacks
    arrive; stop() ends both threads."""
    twin = Twin(widowx, "attic", bus=False)
    frames = []
    twin.on_depth(lambda name, frame: frames.append(frame.timestamp))
    with twin:
        deadline = time.monotonic() + 10.0
        while (twin.time < 0.3 or len(frames) < 3) and time.monotonic() < deadline:
            time.sleep(0.05)
    assert twin.time >= 0.3 and len(frames) >= 3
    assert np.all(np.diff(frames) > 0)
    stopped = twin.time
    time.sleep(0.05)
    assert twin.time == stopped


def test_top_view_png(tmp_path):
    """The demo's snapshot: a PNG of the attic, a path and a detected joist."""
    path = np.stack([np.linspace(0, 1.2, 20), np.zeros(20)], axis=1)
    out = render_top_view(
        load_world("attic"), path, tmp_path / "top.png", detected=[((1.5, -1), (1.5, 1))]
    )
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
