"""The world model: one rolling elevation map in the odometry frame with its terrain layers,
and the feature maps (holds, joists) of ``feature_maps``, fed by every frame and every feature.

Every depth frame is fused with the body pose at its stamp (ElevationMap); the terrain layers
(normals, slope, roughness, step height, traversability: ``terrain``) are recomputed over the
frame's footprint only, widened by the filters' reach so that every cell whose window changed is
recomputed, so a frame costs its footprint, not the window. The map goes on the wire as a
TerrainMap; ``TerrainView`` answers a behaviour's queries on one (height, traversability and age
at a point) in a few microseconds.

A frame that would spoil the maps is not fused and says why (``Unfused``): no valid depth, a
depth image that is not one, or ground near the body that is not level in the body frame (the
camera's mount in the profile is wrong: ``terrain.ground_tilt``). The maps then keep their last
good state, and the frame's features are not folded in either.
"""

from __future__ import annotations

import enum
import math
import zlib
from dataclasses import dataclass
from typing import Annotated

import msgspec
import numpy as np

from climbd.daemon.algorithms.cloud import frame_to_points
from climbd.daemon.algorithms.elevation import ElevationConfig, ElevationMap, Window
from climbd.daemon.algorithms.feature_maps import (
    HoldTracks,
    JoistTracks,
    StairTracks,
    ViewCone,
    hold_tracking,
    joist_tracking,
    stair_tracking,
)
from climbd.daemon.algorithms.self_filter import SelfFilterConfig
from climbd.daemon.algorithms.terrain import (
    GroundConfig,
    GroundTilt,
    TerrainConfig,
    ground_tilt,
    terrain_layers,
)
from climbd.daemon.algorithms.tracks import TrackConfig
from climbd.daemon.contract.hardware import DepthFrame
from climbd.daemon.contract.messages import (
    MAX_PREVIEW_PIXELS,
    TERRAIN_LAYERS,
    BodyState,
    Feature,
    GraspablePoints,
    Joists,
    Stairs,
    TerrainMap,
    TrussGrasps,
)
from climbd.daemon.contract.profile import Profile, ProfileError, merge_tables
from climbd.daemon.contract.units import NonNegative, Positive

ZLIB_LEVEL = 1
"""Fast compression: the layers are mostly NaN or smooth, level 1 takes most of the gain."""


class WorldConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """The map's extent, cells and fusion (elevation), its terrain filter chain, the depth
    decimation it fuses at, the level-ground check of each frame, the camera range features are
    expected within, its publish period (s), the tracking of each feature map, and the depth
    preview the perception role sends viewers (``DepthPreview``) and its self filter. A
    profile's ``[world]`` table overrides them."""

    elevation: ElevationConfig = msgspec.field(
        default_factory=lambda: ElevationConfig(z_min=-1.0, z_max=0.6)
    )
    """Paper 000's 1 m × 1.2 m crop and 1 cm cells; heights from 1 m below the body (steps
    down, a stair flight) to 0.6 m above it."""
    terrain: TerrainConfig = msgspec.field(default_factory=TerrainConfig)
    decimation: int = 2
    """Every n-th depth row and column: 2 keeps 1 cm cells dense to 1.5 m at 640×480."""
    ground: GroundConfig = msgspec.field(default_factory=GroundConfig)
    """The check that a frame shows the ground near the body level in the body frame (the
    camera's mount is right) before it is fused; ``ground.max_tilt`` in rad."""
    view_range: Positive = 2.0
    """m: a feature farther than this from the camera is not expected in a frame (no miss)."""
    publish_period: Positive = 0.5
    preview_period: NonNegative = 0.5
    """s between the perception role's depth previews (``state/depth``, for ``climbd view``);
    0: none sent."""
    preview_points: Annotated[int, msgspec.Meta(ge=1, le=MAX_PREVIEW_PIXELS)] = 4800
    """Most pixels of a depth preview: the frame at the smallest integer stride that fits
    (80 × 60 of a 640 × 480 frame, stride 8)."""
    holds: TrackConfig = msgspec.field(default_factory=hold_tracking)
    joists: TrackConfig = msgspec.field(default_factory=joist_tracking)
    stairs: TrackConfig = msgspec.field(default_factory=stair_tracking)
    self_filter: SelfFilterConfig = msgspec.field(default_factory=SelfFilterConfig)
    """The pixels that see the robot's own legs, dropped before any plugin or map sees the
    frame (``algorithms.self_filter``); off unless the profile gives a radius."""

    def __post_init__(self) -> None:
        if self.decimation < 1:
            raise ValueError(f"world config: decimation must be >= 1, got {self.decimation}")


def world_config(profile: Profile) -> WorldConfig:
    """The profile's ``[world]`` merged table by table over the defaults (a table it names keeps
    the default's other keys); a ProfileError names the file and the field (``$.world.<field>``).
    """
    merged = merge_tables(msgspec.to_builtins(WorldConfig()), profile.world)
    try:
        return msgspec.convert(merged, WorldConfig, strict=False)
    except (msgspec.ValidationError, ValueError) as e:
        message, _, path = str(e).partition(" - at `$")
        field = "$.world" + path.rstrip("`")
        raise ProfileError(f"{profile.source or profile.name}: {field}: {message}") from None


class Unfusable(enum.Enum):
    """Why the world model did not fuse a frame; the names are the reasons counted in health
    (``Health.refused_frames``, beside the pose history's)."""

    NO_DEPTH = "no_depth"
    """No pixel gave a finite point: a covered or blank lens, a NaN depth scale or mount."""
    MALFORMED_DEPTH = "malformed_depth"
    """The depth image is not raw uint16 depth of the intrinsics' size (a driver's bug)."""
    GROUND_NOT_LEVEL = "ground_not_level"
    """The ground near the body leans more than ``ground.max_tilt`` from the body's xy plane:
    the camera's mount in the profile is likely wrong."""


@dataclass(frozen=True)
class Unfused:
    """A frame the world model did not fuse: why, what it measured, and ``streak``, how many
    frames in a row (this one included) were refused for the same reason."""

    reason: Unfusable
    detail: str
    streak: int
    tilt: GroundTilt | None = None
    """The ground's tilt, for GROUND_NOT_LEVEL."""


class TerrainModel:
    """The rolling elevation map and its terrain layers, updated from every frame."""

    def __init__(self, config: WorldConfig | None = None) -> None:
        self.config = config or WorldConfig()
        self.map = ElevationMap(self.config.elevation)
        side = self.map.side
        self._derived = {name: np.full((side, side), np.nan, np.float32) for name in TERRAIN_LAYERS}
        self._recentred = self.map.recentred
        t = self.config.terrain
        res = self.config.elevation.resolution
        self._reach = int(math.ceil(max(t.plane_radius, t.step_radius) / res)) + 1
        self.stamp = math.nan
        """Stamp of the last frame fused."""

    def update(self, points: np.ndarray, body: BodyState) -> None:
        """Fuse one cloud (N×3, body frame) taken at ``body`` and refresh the layers it moved."""
        window = self.map.integrate(points, body)
        self.stamp = body.stamp
        if window is None:
            return
        if self.map.recentred != self._recentred:
            self._recentred = self.map.recentred
            side = self.map.side
            window = Window(0, side, 0, side)
        self._refresh(window)

    def _refresh(self, window: Window) -> None:
        """Recompute the layers of every cell whose filter window overlaps ``window``."""
        side, k = self.map.side, self._reach
        r0, r1 = max(window.r0 - 2 * k, 0), min(window.r1 + 2 * k, side)
        c0, c1 = max(window.c0 - 2 * k, 0), min(window.c1 + 2 * k, side)
        heights = self.map.heights[r0:r1, c0:c1]
        layers = terrain_layers(heights, self.config.elevation.resolution, self.config.terrain)
        # Cells within k of the block's cut edge saw a truncated window: keep their old values
        # unless the cut is the map's own edge.
        i0 = 0 if r0 == 0 else k
        j0 = 0 if c0 == 0 else k
        i1 = (r1 - r0) if r1 == side else (r1 - r0 - k)
        j1 = (c1 - c0) if c1 == side else (c1 - c0 - k)
        inner = (slice(i0, i1), slice(j0, j1))
        target = (slice(r0 + i0, r0 + i1), slice(c0 + j0, c0 + j1))
        d = self._derived
        d["normal_x"][target] = layers.normals[..., 0][inner]
        d["normal_y"][target] = layers.normals[..., 1][inner]
        d["slope"][target] = layers.slope[inner]
        d["roughness"][target] = layers.roughness[inner]
        d["step"][target] = layers.step[inner]
        d["traversability"][target] = layers.traversability[inner]

    def layer(self, name: str) -> np.ndarray:
        """One of TERRAIN_LAYERS over the whole window (odometry frame), NaN unknown."""
        if name == "height":
            return self.map.heights
        if name == "variance":
            return np.where(np.isnan(self.map.heights), np.nan, self.map.variance)
        if name == "age":
            return self.stamp - self.map.seen
        return self._derived[name]

    def message(self, stamp: float, body: BodyState) -> TerrainMap:
        """The map on the wire: the observed part of the window, every layer, heights less the
        body's height."""
        origin = self.map.origin
        base = float(body.position[2])
        res = self.config.elevation.resolution
        known = ~np.isnan(self.map.heights)
        if origin is None or not known.any():
            return TerrainMap(stamp=stamp, frame_stamp=self.stamp, resolution=res)
        rows = np.flatnonzero(known.any(axis=1))
        cols = np.flatnonzero(known.any(axis=0))
        box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        encoded = {}
        for name in TERRAIN_LAYERS:
            layer = self.layer(name)[box]
            if name == "height":
                layer = layer - base
            encoded[name] = zlib.compress(np.ascontiguousarray(layer, "<f2").tobytes(), ZLIB_LEVEL)
        return TerrainMap(
            stamp=stamp,
            frame_stamp=self.stamp,
            origin_x=float(origin[0] + rows[0] * res),
            origin_y=float(origin[1] + cols[0] * res),
            origin_z=base,
            resolution=res,
            rows=int(rows[-1] - rows[0] + 1),
            cols=int(cols[-1] - cols[0] + 1),
            layers=encoded,
        )


class TerrainView:
    """A behaviour's queries on a received TerrainMap: layers decoded once, then point lookups."""

    def __init__(self, message: TerrainMap) -> None:
        self.message = message
        shape = (message.rows, message.cols)
        self._layers = {}
        for name in TERRAIN_LAYERS:
            data = message.layers.get(name)
            if data is None:
                raise ValueError(f"{message.TOPIC}: layer {name!r} missing")
            array = np.frombuffer(zlib.decompress(data), "<f2")
            if array.size != shape[0] * shape[1]:
                raise ValueError(
                    f"{message.TOPIC}: layer {name!r} holds {array.size} cells, "
                    f"rows × cols is {shape[0] * shape[1]}"
                )
            self._layers[name] = array.astype(np.float32).reshape(shape)
        self._inv = 1.0 / message.resolution

    def layer(self, name: str) -> np.ndarray:
        """One whole layer (rows × cols, float32, NaN unknown; heights less ``origin_z``)."""
        return self._layers[name]

    def _cell(self, x: float, y: float) -> tuple[int, int] | None:
        m = self.message
        row = math.floor((x - m.origin_x) * self._inv)
        col = math.floor((y - m.origin_y) * self._inv)
        if 0 <= row < m.rows and 0 <= col < m.cols:
            return row, col
        return None

    def value(self, name: str, x: float, y: float) -> float:
        """Layer ``name`` at odometry (x, y); NaN outside the map or where unknown."""
        cell = self._cell(x, y)
        return math.nan if cell is None else float(self._layers[name][cell])

    def height_at(self, x: float, y: float) -> float:
        """Terrain height (m, odometry frame) at (x, y); NaN outside or unknown."""
        return self.value("height", x, y) + self.message.origin_z

    def traversability_at(self, x: float, y: float) -> float:
        """[0, 1] at (x, y); NaN outside or unknown."""
        return self.value("traversability", x, y)

    def age_at(self, x: float, y: float, now: float) -> float:
        """Seconds since a frame last saw (x, y), at ``now``; inf where never seen."""
        age = self.value("age", x, y)
        return math.inf if math.isnan(age) else age + (now - self.message.frame_stamp)


class WorldModel:
    """The robot's maps in the odometry frame: terrain from every depth frame, holds and joists
    from the plugins' features, each with the body pose at its frame's time."""

    def __init__(self, config: WorldConfig | None = None) -> None:
        self.config = config or WorldConfig()
        self.terrain = TerrainModel(self.config)
        self.holds = HoldTracks(self.config.holds)
        self.joists = JoistTracks(self.config.joists)
        self.stairs = StairTracks(self.config.stairs)
        self._cone: ViewCone | None = None
        self._body: BodyState | None = None
        self._last: Unfusable | None = None
        self._streak = 0

    def frame(self, frame: DepthFrame, body: BodyState) -> Unfused | None:
        """Fuse one depth frame taken at ``body`` (the pose at its stamp); or, when it would
        spoil the maps, leave them as they are and say why."""
        try:
            with np.errstate(invalid="ignore", over="ignore"):  # a NaN or infinite scale
                points = frame_to_points(frame, decimation=self.config.decimation)
        except ValueError as e:
            return self._refuse(Unfusable.MALFORMED_DEPTH, str(e))
        if not np.isfinite(points).all():
            points = points[np.isfinite(points).all(axis=1)]
        if not len(points):
            return self._refuse(Unfusable.NO_DEPTH, f"no finite point in {frame.depth.size} pixels")
        band = (self.config.elevation.z_min, self.config.elevation.z_max)
        tilt = ground_tilt(points, band, self.config.ground)
        if tilt is not None and tilt.tilt > self.config.ground.max_tilt:
            detail = (
                f"the ground near the body leans {math.degrees(tilt.tilt):.1f}° from the body's "
                f"xy plane (rises {math.degrees(tilt.rise_x):.1f}° along x, "
                f"{math.degrees(tilt.rise_y):.1f}° along y; limit "
                f"{math.degrees(self.config.ground.max_tilt):.1f}°)"
            )
            return self._refuse(Unfusable.GROUND_NOT_LEVEL, detail, tilt)
        self._last, self._streak = None, 0
        self.terrain.update(points, body)
        self._cone = ViewCone(frame, body.position, body.orientation, self.config.view_range)
        self._body = body
        return None

    def _refuse(self, reason: Unfusable, detail: str, tilt: GroundTilt | None = None) -> Unfused:
        """The frame is left out: count the streak of this reason."""
        self._streak = self._streak + 1 if reason is self._last else 1
        self._last = reason
        return Unfused(reason, detail, self._streak, tilt)

    def feature(self, feature: Feature) -> None:
        """Fold a plugin's feature (of the last frame) into its map; other kinds pass by."""
        if isinstance(feature, Joists):
            self.joists.update(feature, self._cone)
        elif isinstance(feature, GraspablePoints):
            self.holds.update(feature, self._cone)
        elif isinstance(feature, Stairs):
            self.stairs.update(feature, self._cone)
        elif isinstance(feature, TrussGrasps):
            self.holds.offer(feature, self._cone)

    def messages(self, stamp: float) -> list[Feature]:
        """The maps to publish (nothing before the first frame)."""
        body = self._body
        if body is None:
            return []
        return [
            self.terrain.message(stamp, body),
            self.holds.message(stamp, body.stamp),
            self.joists.message(stamp, body.stamp),
            self.stairs.message(stamp, body.stamp),
        ]
