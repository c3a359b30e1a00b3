"""The world model and the perception role on bad input (issue #32, "Bad input").

Frames are ray-cast here: the profile's camera, on the mount the robot really has, sees a plane
(a level floor, or a 30° slope HubRobo climbs with its body leaning along it), and the frame
carries the mount the profile says. A mount in the profile wrong by 20° shows the ground 20° off
level in the body frame: the frame is not fused (the maps keep every array as it was), the
reason is counted in health and the role warns naming the camera and the tilt; a right mount on
the slope is fused. Frames without valid depth, and frames once the pose stream stops, leave
the maps as they were, and the maps keep going out unchanged.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import logging
import math
from dataclasses import dataclass

import msgspec
import numpy as np
import pytest

from climbd.daemon.algorithms.cloud import frame_to_points
from climbd.daemon.algorithms.terrain import ground_tilt
from climbd.daemon.algorithms.world import (
    TerrainView,
    Unfusable,
    WorldModel,
    world_config,
)
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.hardware import DepthFrame, Intrinsics, mount_extrinsics
from climbd.daemon.contract.messages import (
    BodyState,
    Health,
    Message,
    TerrainMap,
    decode,
    encode,
)
from climbd.daemon.contract.profile import CameraConfig, Profile, stock_profiles
from climbd.daemon.runtime.counting import Tally
from climbd.daemon.runtime.perception_role import PerceptionRole

WIDOWX = profiles.load(stock_profiles()["widowx"])
HUBROBO = profiles.load(stock_profiles()["hubrobo"])
BODY_HEIGHT = 0.15
"""m: the body's origin above the ground it stands on."""
WRONG = 20.0
"""deg: how far the profile's mount is from the camera's real one."""
SLOPE = math.radians(30.0)


@dataclass(frozen=True)
class Ground:
    """A plane in the odometry frame: a point on it and its unit normal."""

    point: np.ndarray
    normal: np.ndarray


FLOOR = Ground(np.zeros(3), np.array([0.0, 0.0, 1.0]))


def pitched(angle: float) -> list[float]:
    """Quaternion (w, x, y, z) of a rotation by ``angle`` about y (negative: nose up)."""
    return [math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0]


def body_at(x: float, stamp: float, pitch: float = 0.0) -> BodyState:
    """The body ``BODY_HEIGHT`` above the plane through the origin it leans with (``pitch``
    about y), ``x`` along it."""
    rot = rotation(pitched(pitch))
    position = rot @ np.array([x, 0.0, BODY_HEIGHT])
    return BodyState(stamp=stamp, position=position.tolist(), orientation=pitched(pitch))


def ground_under(body: BodyState) -> Ground:
    """The plane the body stands on, level in its own frame (a floor or a slope)."""
    rot = rotation(body.orientation)
    return Ground(np.zeros(3), rot @ np.array([0.0, 0.0, 1.0]))


def mounted(camera: CameraConfig, tilt: float = 0.0, roll: float = 0.0) -> CameraConfig:
    """The camera with its mount turned by ``tilt`` and ``roll`` degrees."""
    mount = msgspec.structs.replace(
        camera.mount, tilt_deg=camera.mount.tilt_deg + tilt, roll_deg=camera.mount.roll_deg + roll
    )
    return msgspec.structs.replace(camera, mount=mount)


def depth_frame(
    camera: CameraConfig,
    body: BodyState,
    ground: Ground,
    real: CameraConfig | None = None,
) -> DepthFrame:
    """The frame ``camera`` (the profile's) gives, its real mount ``real``'s (default the
    profile's), of ``ground`` from ``body``: each pixel's ray meets the plane, in mm."""
    w, h = camera.width, camera.height
    focal = w / (2 * math.tan(math.radians(35.0)))
    intrinsics = Intrinsics(w, h, focal, focal, w / 2, h / 2)
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rays = np.stack([(u - w / 2) / focal, (v - h / 2) / focal, np.ones_like(u)], axis=-1)
    truth = mount_extrinsics(real or camera)
    rot = rotation(body.orientation)
    origin = np.asarray(body.position) + rot @ truth[:3, 3]
    directions = rays @ (rot @ truth[:3, :3]).T
    along = directions @ ground.normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ground.point - origin) @ ground.normal / along
    valid = (along < 0) & (t > 0) & (t < camera.max_range)
    depth = np.where(valid, np.round(t / 0.001), 0).astype(np.uint16)
    return DepthFrame(depth, 0.001, intrinsics, mount_extrinsics(camera), body.stamp)


def snapshot(world: WorldModel) -> dict[str, np.ndarray]:
    """Copies of the terrain arrays the world model keeps: fused layers, derived, seen."""
    terrain = world.terrain
    out = {name: terrain.layer(name).copy() for name in ("height", "variance", "slope", "step")}
    out["fused"] = terrain.map._layers.copy()
    out["seen"] = terrain.map.seen.copy()
    return out


def assert_unchanged(before: dict[str, np.ndarray], world: WorldModel) -> None:
    after = snapshot(world)
    for name, array in before.items():
        assert np.array_equal(array, after[name], equal_nan=True), name


def walked(profile: Profile, frames: int = 4, pitch: float = 0.0) -> WorldModel:
    """A world model fed ``frames`` good frames (all fused) of a robot walking 2 cm a frame."""
    world = WorldModel(world_config(profile))
    camera = profile.cameras[0]
    for k in range(frames):
        body = body_at(0.02 * k, 0.1 * k, pitch)
        assert world.frame(depth_frame(camera, body, ground_under(body)), body) is None
    return world


def roll_tilt(camera: CameraConfig) -> float:
    """deg the ground leans when a camera tilted down by its mount is rolled ``WRONG`` about
    its optical axis: asin(sin(roll)·cos(tilt))."""
    tilt = math.radians(camera.mount.tilt_deg)
    return math.degrees(math.asin(math.sin(math.radians(WRONG)) * math.cos(tilt)))


WRONG_MOUNTS = [
    ("widowx-tilt+20", WIDOWX, 0.0, WRONG, 0.0, WRONG),
    ("widowx-tilt-20", WIDOWX, 0.0, -WRONG, 0.0, WRONG),
    ("widowx-roll+20", WIDOWX, 0.0, 0.0, WRONG, roll_tilt(WIDOWX.cameras[0])),
    ("hubrobo-tilt+20", HUBROBO, 0.0, WRONG, 0.0, WRONG),
    ("hubrobo-on-30deg-slope-tilt+20", HUBROBO, -SLOPE, WRONG, 0.0, WRONG),
]


@pytest.mark.parametrize(
    ("profile", "pitch", "tilt", "roll", "expected"),
    [case[1:] for case in WRONG_MOUNTS],
    ids=[case[0] for case in WRONG_MOUNTS],
)
def test_a_mount_wrong_by_20_degrees_is_refused_and_the_map_kept(
    profile: Profile, pitch: float, tilt: float, roll: float, expected: float
) -> None:
    world = walked(profile, pitch=pitch)
    camera = profile.cameras[0]
    body = body_at(0.08, 0.4, pitch)
    bad = depth_frame(camera, body, ground_under(body), real=mounted(camera, tilt, roll))
    spoilt = copy.deepcopy(world)
    spoilt.terrain.update(frame_to_points(bad, decimation=world.config.decimation), body)
    moved = np.abs(spoilt.terrain.layer("height") - world.terrain.layer("height"))
    assert np.nanmax(moved) > 0.02, "fused, the wrong mount's frame would move the map"

    before = snapshot(world)
    for k in range(1, 6):
        unfused = world.frame(bad, body)
        assert unfused is not None and unfused.reason is Unfusable.GROUND_NOT_LEVEL
        assert unfused.streak == k
        assert math.degrees(unfused.tilt.tilt) == pytest.approx(expected, abs=1.0)
    assert_unchanged(before, world)
    good = body_at(0.1, 0.5, pitch)
    assert world.frame(depth_frame(camera, good, ground_under(good)), good) is None
    assert world.terrain.stamp == good.stamp


@pytest.mark.parametrize("pitch", [-SLOPE, SLOPE], ids=["up", "down"])
def test_hubrobo_leaning_with_a_30_degree_slope_is_fused(pitch: float) -> None:
    """The ground is 30° off the odometry frame's horizontal (the map's slope layer says so)
    and level in the body frame: every frame is fused, none refused."""
    world = walked(HUBROBO, frames=6, pitch=pitch)
    slope = world.terrain.layer("slope")
    assert np.degrees(np.nanmedian(slope)) == pytest.approx(30.0, abs=1.0)
    heights = world.terrain.layer("height")
    assert np.isfinite(heights).sum() > 1000


def stair_cloud(pitch: float, on_flight: bool, rise: float = 0.17, run: float = 0.29) -> np.ndarray:
    """Body-frame points (5 mm apart) of a stair flight's treads and risers under a body 0.15 m
    above its line, pitched by ``pitch`` about y (nose up negative): mid-flight, or at its foot
    (the floor behind)."""
    x, y = np.meshgrid(np.arange(-0.6, 0.6, 0.005), np.arange(-0.6, 0.6, 0.005), indexing="ij")
    z = np.floor((x + run / 2) / run) * rise
    if not on_flight:
        z = np.maximum(z, 0.0)
    world = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    position = np.array([0.0, 0.0, BODY_HEIGHT])
    return ((world - position) @ rotation(pitched(pitch))).astype(np.float32)


def test_the_ground_reading_keeps_to_the_dominant_surface_and_to_the_flight() -> None:
    """Level floor with a 10 cm joist across the footprint, and a 30° stair flight: a level body
    before the flight reads its treads level, a body pitched with the flight reads the
    flight's plane level; a floor seen 20° off does not pass either reading."""
    band = (-1.0, 0.6)
    floor = stair_cloud(0.0, on_flight=False, rise=0.0)
    joist = floor.copy()
    joist[np.abs(joist[:, 0] - 0.2) < 0.02, 2] += 0.10
    flight = math.atan2(0.17, 0.29)
    readings = {
        "joist": ground_tilt(joist, band),
        "level body at the flight's foot": ground_tilt(stair_cloud(0.0, False), band),
        "body pitched on the flight": ground_tilt(stair_cloud(-flight, True), band),
        "floor seen 20 deg off": ground_tilt(stair_cloud(math.radians(WRONG), False, 0.0), band),
    }
    degrees = {k: round(math.degrees(r.tilt), 2) for k, r in readings.items()}
    assert degrees["joist"] < 1.0, degrees
    assert degrees["level body at the flight's foot"] < 1.0, degrees
    on_flight = readings["body pitched on the flight"]
    assert math.degrees(on_flight.surface) == pytest.approx(math.degrees(flight), abs=1.0)
    assert degrees["body pitched on the flight"] < 2.0, degrees
    assert degrees["floor seen 20 deg off"] == pytest.approx(WRONG, abs=0.5)
    assert ground_tilt(floor[np.hypot(floor[:, 0], floor[:, 1]) > 0.6], band) is None


def bad_depth(camera: CameraConfig, body: BodyState, case: str) -> DepthFrame:
    """A frame with no valid depth, as ``case`` says."""
    frame = depth_frame(camera, body, ground_under(body))
    if case == "blank":
        return dataclasses.replace(frame, depth=np.zeros_like(frame.depth))
    if case == "nan_scale":
        return dataclasses.replace(frame, depth_scale=math.nan)
    if case == "nan_mount":
        return dataclasses.replace(frame, extrinsics=np.full((4, 4), np.nan))
    depth = frame.depth.astype(np.float64) * frame.depth_scale
    depth[::2] = np.nan
    return dataclasses.replace(frame, depth=depth)


@pytest.mark.filterwarnings("error::RuntimeWarning")
@pytest.mark.parametrize(
    ("case", "reason"),
    [
        ("blank", Unfusable.NO_DEPTH),
        ("nan_scale", Unfusable.NO_DEPTH),
        ("nan_mount", Unfusable.NO_DEPTH),
        ("float_nan_depth", Unfusable.MALFORMED_DEPTH),
    ],
)
def test_a_frame_without_valid_depth_is_counted_and_leaves_the_map(
    case: str, reason: Unfusable
) -> None:
    world = walked(WIDOWX)
    before = snapshot(world)
    messages = world.messages(9.0)
    body = body_at(0.08, 0.4)
    for k in range(1, 4):
        unfused = world.frame(bad_depth(WIDOWX.cameras[0], body, case), body)
        assert unfused is not None and (unfused.reason, unfused.streak) == (reason, k)
    assert_unchanged(before, world)
    assert world.messages(9.0) == messages


def role_frames(role: PerceptionRole, bodies: list[BodyState], frames: list[DepthFrame]) -> list:
    """Feed the role the body states, then each frame through ``perceive`` (no plugins); what
    it published."""
    published: list[Message] = []
    for body in bodies:
        role.on_body(body)
    for frame in frames:
        role.perceive(frame, [], published.append)
    return published


def still(start: float, end: float) -> list[BodyState]:
    """Body states of a robot standing at the origin, every 10 ms over [start, end]."""
    return [body_at(0.0, t) for t in np.arange(start, end + 1e-9, 0.01)]


def test_the_role_counts_a_tilted_ground_in_health_and_warns_naming_the_camera(caplog) -> None:
    role = PerceptionRole(WIDOWX, argparse.Namespace())
    camera = WIDOWX.cameras[0]
    wrong = mounted(camera, WRONG)
    good = [depth_frame(camera, body_at(0.0, 0.1 * k), FLOOR) for k in range(1, 4)]
    bad = [depth_frame(camera, body_at(0.0, 0.4 + 0.1 * k), FLOOR, wrong) for k in range(6)]
    with caplog.at_level(logging.WARNING, logger="climbd.perception"):
        role_frames(role, still(0.0, 1.0), [*good, *bad])
    assert role.refused == {"ground_not_level": 6}
    health = decode(encode(role.health([role.world], Tally())), Health)
    assert health.refused_frames == {"ground_not_level": 6}
    assert role.world.failures == 0 and role.world.status == "ok"
    warnings = [r.getMessage() for r in caplog.records if "ground" in r.getMessage()]
    assert len(warnings) == 1, warnings
    assert "camera front" in warnings[0] and "leans 19.9°" in warnings[0], warnings[0]
    assert "3 frames in a row" in warnings[0], warnings[0]


def test_the_maps_outlive_a_pose_stream_that_stops() -> None:
    """Body states stop at 1 s; frames go on to 4 s and are refused (too_new): the maps keep
    every array, and go out at 2 Hz as before, the same map; when the poses come back, the
    next frame is fused."""
    role = PerceptionRole(WIDOWX, argparse.Namespace())
    camera = WIDOWX.cameras[0]
    frames = [depth_frame(camera, body_at(0.0, t), FLOOR) for t in np.arange(0.1, 4.01, 0.1)]
    before_stop = role_frames(role, still(0.0, 1.0), frames[:10])
    world = role.world.plugin
    kept = snapshot(world)
    last = [m for m in before_stop if isinstance(m, TerrainMap)][-1]
    after_stop = role_frames(role, [], frames[10:])
    assert role.refused == {"too_new": 30}
    assert_unchanged(kept, world)
    maps = [m for m in after_stop if isinstance(m, TerrainMap)]
    assert len(maps) == 6
    for terrain in maps:
        assert terrain.frame_stamp == pytest.approx(1.0)
        assert terrain.layers == last.layers
        assert (terrain.origin_x, terrain.origin_y, terrain.rows) == (
            last.origin_x,
            last.origin_y,
            last.rows,
        )
        assert TerrainView(terrain).height_at(0.5, 0.0) == pytest.approx(0.0, abs=0.002)
    assert role.world.failures == 0

    resumed = role_frames(role, still(4.0, 4.2), [depth_frame(camera, body_at(0.0, 4.1), FLOOR)])
    assert world.terrain.stamp == pytest.approx(4.1)
    assert [m.frame_stamp for m in resumed if isinstance(m, TerrainMap)] == [pytest.approx(4.1)]
