"""Worlds of the twin as data: the schema of worlds/*.toml, loading, and the PCD terrain.

A world is a floor plus any of: rows of joists (paper 000's attic), stairs (paper 004),
a slope of climbing holds tiled from a real point cloud (paper 001) and a truss of cylinder
members with linkers (paper 003). Lengths in metres, angles in degrees as written in the
file. ``load("attic")`` reads a stock world; a path reads any file; keyword overrides
replace top-level tables, e.g. ``load("slope", gravity=9.80665 / 6)``.
"""

from __future__ import annotations

import functools
import math
import sys
from pathlib import Path
from typing import Literal

import msgspec
import numpy as np

from climbd.daemon.contract.cloudio import CloudFileError, read_cloud
from climbd.daemon.contract.geometry import regression_frame
from climbd.drivers.sim.worlds.hold_tiles import (
    REGENERATE,
    read_tile,
    tile_copies,
    tile_file,
    tile_map,
    tile_relief,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

HERE = Path(__file__).resolve().parent
DATA = HERE / "data"
"""Real point clouds shipped with the twin (ClimbLab's hold clouds, BSD-3, license beside them)."""
INCH = 0.0254
GRIPPER_REACH = 0.045
"""How far from a hold (m) a closing spine gripper reaches: its mask's half-width, 44 mm
(paper 001 §2.2: palm-joint circle 14 + finger 15 + spine 15 mm)."""


class WorldError(ValueError):
    """A world file that cannot be used; the message names the file and the field."""


class Floor(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """The ground plane: half-size (m), friction coefficient, colour (RGBA)."""

    size: float = 5.0
    friction: float = 0.9
    rgba: list[float] = msgspec.field(default_factory=lambda: [0.55, 0.5, 0.45, 1.0])


class JoistRow(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """A row of ``count`` parallel joists, the first ``distance`` ahead of the start (centre line).

    ``spacing`` is centre to centre (16 in in U.S. attics); ``yaw_deg`` turns the row about
    the first joist's centre (paper 000's ψ, eq. 2); ``height`` is the joist's depth.
    """

    height: float
    distance: float
    count: int = 1
    spacing: float = 16 * INCH
    width: float = 1.5 * INCH
    length: float = 2.4
    yaw_deg: float = 0.0
    offset: float = 0.0
    rgba: list[float] = msgspec.field(default_factory=lambda: [0.85, 0.7, 0.45, 1.0])


class Staircase(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``count`` steps of ``rise`` × ``tread`` (paper 004: 130 × 300 mm), ``distance`` ahead.

    ``landing`` is the depth of the top platform; ``yaw_deg`` turns the flight about its foot.
    """

    rise: float = 0.13
    tread: float = 0.30
    count: int = 3
    distance: float = 0.8
    width: float = 1.2
    landing: float = 1.0
    yaw_deg: float = 0.0
    rgba: list[float] = msgspec.field(default_factory=lambda: [0.7, 0.7, 0.72, 1.0])


class HoldsSlope(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Climbing holds from a point cloud, tiled into a height field on a slope of ``incline_deg``.

    ``cloud`` is a PCD path, relative to the world file. The cloud's regression plane becomes
    the slope's surface; ``tiles`` copies it (mirrored, so edges meet) along and across
    it; ``resolution`` is the height-field cell (m).
    Holds are graspable; the slope rises along +x from ``distance`` ahead of the start.
    """

    cloud: str
    incline_deg: float = 30.0
    tiles: list[int] = msgspec.field(default_factory=lambda: [3, 3])
    resolution: float = 0.01
    distance: float = -0.6
    friction: float = 1.0
    rgba: list[float] = msgspec.field(default_factory=lambda: [0.6, 0.45, 0.35, 1.0])


class HoldMap(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Paper 001 §4.1's slope: a board at ``incline_deg`` carrying one hold per graspable point
    of a hold map, tiled (seeded) from the detection on ``cloud`` (PCD, relative to the file),
    read from the tile shipped beside it (``<stem>.tile.txt``, see ``hold_tiles``).

    ``relief = "columns"``: each hold is a column of the palm's radius ``hold_radius``
    standing on the board as high as its point stood above the cloud's board, so the graspable
    set and the relief are the same geoms. ``relief = "rock"``: each copy of the tile carries
    the rock it was detected on (the cloud as a height field of cell ``resolution``), so a
    camera sees rock, and a gripper holds on it only where a hold of the map is. The wall frame
    (x up the slope, y left, z out of the board) spans ``along`` × ``across`` (m); its lower
    edge touches the floor at the origin. ``extra`` adds holds (wall x, y) at the mean height,
    e.g. where the robot starts, as columns on either relief.
    """

    cloud: str
    seed: int = 0
    incline_deg: float = 30.0
    along: list[float] = msgspec.field(default_factory=lambda: [-0.3, 0.7])
    across: list[float] = msgspec.field(default_factory=lambda: [-0.35, 0.35])
    hold_radius: float = 0.016
    relief: Literal["columns", "rock"] = "columns"
    resolution: float = 0.003
    extra: list[list[float]] = []
    friction: float = 1.0
    rgba: list[float] = msgspec.field(default_factory=lambda: [0.6, 0.45, 0.35, 1.0])
    hold_rgba: list[float] = msgspec.field(default_factory=lambda: [0.9, 0.75, 0.2, 1.0])


class TrussMember(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """One member of a truss: node indices of its ends."""

    a: int
    b: int


class Truss(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Cylinder members between nodes (m, world frame) with a cubic linker at every node."""

    nodes: list[list[float]]
    members: list[TrussMember]
    radius: float = 0.025
    linker: float = 0.07
    rgba: list[float] = msgspec.field(default_factory=lambda: [0.75, 0.75, 0.8, 1.0])


class Start(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Where the robot starts: position on the floor (m) and heading (deg)."""

    x: float = 0.0
    y: float = 0.0
    yaw_deg: float = 0.0


class World(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """A whole world file."""

    name: str
    gravity: float = 9.80665
    floor: Floor = msgspec.field(default_factory=Floor)
    start: Start = msgspec.field(default_factory=Start)
    joists: list[JoistRow] = []
    stairs: list[Staircase] = []
    holds: HoldsSlope | None = None
    hold_map: HoldMap | None = None
    truss: Truss | None = None
    source: str = ""


def stock_worlds() -> dict[str, Path]:
    """The worlds shipped with climbd, by name."""
    return {p.stem: p for p in sorted(HERE.glob("*.toml"))}


def _check(world: World) -> World:
    src = world.source or world.name

    def need(cond: bool, field: str, message: str) -> None:
        if not cond:
            raise WorldError(f"{src}: {field}: {message}")

    need(world.gravity >= 0, "$.gravity", f"expected >= 0 m/s², found {world.gravity}")
    for i, row in enumerate(world.joists):
        at = f"$.joists[{i}]"
        need(row.height > 0, f"{at}.height", f"expected > 0 m, found {row.height}")
        need(row.count >= 1, f"{at}.count", f"expected >= 1, found {row.count}")
        need(row.spacing > row.width, f"{at}.spacing", f"expected > width {row.width}")
    for i, st in enumerate(world.stairs):
        at = f"$.stairs[{i}]"
        need(st.count >= 1, f"{at}.count", f"expected >= 1, found {st.count}")
        need(st.rise > 0 and st.tread > 0, f"{at}", "expected rise > 0 and tread > 0")
    if world.holds is not None:
        h = world.holds
        need(
            0 <= h.incline_deg < 90, "$.holds.incline_deg", f"expected 0..90, found {h.incline_deg}"
        )
        need(
            len(h.tiles) == 2 and min(h.tiles) >= 1,
            "$.holds.tiles",
            f"expected [along, across] >= 1, found {h.tiles}",
        )
    if world.hold_map is not None:
        h = world.hold_map
        need(
            0 <= h.incline_deg < 90,
            "$.hold_map.incline_deg",
            f"expected 0..90, found {h.incline_deg}",
        )
        for key in ("along", "across"):
            span = getattr(h, key)
            need(
                len(span) == 2 and span[0] < span[1],
                f"$.hold_map.{key}",
                f"expected [low, high] with low < high, found {span}",
            )
        need(h.hold_radius > 0, "$.hold_map.hold_radius", f"expected > 0, found {h.hold_radius}")
        need(
            0 < h.resolution <= 0.01,
            "$.hold_map.resolution",
            f"expected a cell of 0..0.01 m (the palm is 32 mm across), found {h.resolution}",
        )
        need(
            all(len(p) == 2 for p in h.extra),
            "$.hold_map.extra",
            "expected [x, y] pairs (m, wall frame)",
        )
    if world.truss is not None:
        n = len(world.truss.nodes)
        for i, m in enumerate(world.truss.members):
            need(
                0 <= m.a < n and 0 <= m.b < n and m.a != m.b,
                f"$.truss.members[{i}]",
                f"expected two distinct node indices < {n}, found a={m.a} b={m.b}",
            )
    return world


def load(name_or_path: str | Path, **overrides: object) -> World:
    """Load a stock world by name or a world file by path; ``overrides`` replace top-level keys."""
    stock = stock_worlds()
    path = stock.get(str(name_or_path)) or Path(name_or_path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise WorldError(
            f"world {str(name_or_path)!r}: no such file and no stock world; stock: {sorted(stock)}"
        ) from None
    except tomllib.TOMLDecodeError as e:
        raise WorldError(f"{path}: not valid TOML: {e}") from None
    data.update(overrides)
    try:
        world = msgspec.convert({**data, "source": str(path)}, World)
    except msgspec.ValidationError as e:
        raise WorldError(f"{path}: {e}") from None
    return _check(world)


def holds_heightfield(holds: HoldsSlope, base: Path) -> tuple[np.ndarray, float, float]:
    """Height field (rows along the slope, metres above the lowest cell) of the tiled cloud.

    Returns (heights, length along, width across). The cloud's regression plane (SVD) is
    the slope surface; empty cells take the nearest measured height.
    """
    from scipy.interpolate import NearestNDInterpolator

    path = Path(holds.cloud)
    if not path.is_absolute():
        path = (base / path).resolve()
    try:
        pts = read_cloud(path)
    except CloudFileError as e:
        raise WorldError(f"$.holds.cloud: {e}") from None
    centre = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centre, full_matrices=False)
    normal = vt[2] if vt[2] @ (-centre) > 0 else -vt[2]
    along, across = vt[0], np.cross(normal, vt[0])
    local = (pts - centre) @ np.stack([along, across, normal], axis=1)
    res = holds.resolution
    lo = local[:, :2].min(axis=0)
    shape = np.ceil((local[:, :2].max(axis=0) - lo) / res).astype(int) + 1
    idx = np.floor((local[:, :2] - lo) / res).astype(int)
    tile = np.full(shape, -np.inf)
    np.maximum.at(tile, (idx[:, 0], idx[:, 1]), local[:, 2])
    known = np.isfinite(tile)
    if not known.all():
        fill = NearestNDInterpolator(np.argwhere(known), tile[known])
        empty = np.argwhere(~known)
        tile[~known] = fill(empty)
    strip = np.concatenate(
        [tile if k % 2 == 0 else tile[:, ::-1] for k in range(holds.tiles[1])], axis=1
    )
    field = np.concatenate(
        [strip if k % 2 == 0 else strip[::-1, :] for k in range(holds.tiles[0])], axis=0
    )
    field -= field.min()
    return field, field.shape[0] * res, field.shape[1] * res


def hold_map_tile(cloud: Path) -> np.ndarray:
    """Graspable points detected on ``cloud`` (paper 001 §2) on its regression plane: x, y and
    the height (m) above the cloud's board (its 5th-percentile level). Read from the tile
    shipped beside the cloud (``<stem>.tile.txt``, written by ``bench/hold_tiles.py`` with the
    detector, which the twin may not import)."""
    return _detected_tile(Path(cloud).resolve()).copy()


@functools.lru_cache(maxsize=4)
def _detected_tile(cloud: Path) -> np.ndarray:
    path = tile_file(cloud)
    try:
        tile = read_tile(path)
    except FileNotFoundError:
        raise WorldError(
            f"$.hold_map.cloud: no detected tile {path} for {cloud.name}; "
            f"write it with {REGENERATE} {cloud}"
        ) from None
    except (OSError, ValueError) as e:
        raise WorldError(f"$.hold_map.cloud: detected tile {path}: {e}") from None
    if len(tile) < 2:
        raise WorldError(
            f"$.hold_map.cloud: detected tile {path}: need at least 2 graspable points, "
            f"found {len(tile)}"
        )
    return tile


def hold_map_holds(world: World) -> np.ndarray:
    """The hold map of ``world`` (k×3, wall frame): x, y and the hold's top height (m); the
    tiled holds first, then ``extra``."""
    h = world.hold_map
    tile = hold_map_tile(_hold_cloud(world))
    holds = tile_map(tile, h.seed, tuple(h.along), tuple(h.across), _margin(h))
    extra = np.asarray(h.extra, float).reshape(-1, 2)
    extra = np.column_stack((extra, np.full(len(extra), tile[:, 2].mean())))
    return np.vstack((holds, extra))


def hold_map_relief(world: World) -> np.ndarray:
    """The rock of a ``relief = "rock"`` hold map: heights (m above the board, rows along x
    from ``along[0]``, columns across y from ``across[0]``, cell ``resolution``)."""
    h = world.hold_map
    cloud = _hold_cloud(world)
    return tile_relief(
        _cloud_on_plane(cloud),
        hold_map_tile(cloud),
        h.seed,
        tuple(h.along),
        tuple(h.across),
        h.resolution,
        _margin(h),
    )


def hold_map_seams(world: World) -> tuple[np.ndarray, np.ndarray]:
    """Wall x and y (m) of the lines where the copies of ``world``'s hold-map tile meet."""
    h = world.hold_map
    tile = hold_map_tile(_hold_cloud(world))
    _, pitch, copies = tile_copies(tile, h.seed, tuple(h.along), tuple(h.across), _margin(h))
    xs = np.unique([offset[0] for _, offset in copies]) - pitch / 2
    ys = np.unique([offset[1] for _, offset in copies]) - pitch / 2
    return xs, ys


def hold_map_seam_gap(world: World, xy: np.ndarray) -> np.ndarray:
    """Distance (m, wall plane) from each point ``xy`` (k×2, wall x and y) to the nearest line
    where the copies of ``world``'s hold-map tile meet (``hold_map_seams``)."""
    xs, ys = hold_map_seams(world)
    xy = np.asarray(xy, float).reshape(-1, 2)
    across = np.abs(xy[:, :1] - xs).min(axis=1)
    along = np.abs(xy[:, 1:2] - ys).min(axis=1)
    return np.minimum(across, along)


def hold_map_rock(world: World) -> np.ndarray:
    """The rock relief (``hold_map_relief``) as wall-frame points, one a cell: x, y and the
    height (m) above the board."""
    h = world.hold_map
    heights = hold_map_relief(world)
    i, j = np.indices(heights.shape).reshape(2, -1)
    return np.column_stack(
        (h.along[0] + i * h.resolution, h.across[0] + j * h.resolution, heights.ravel())
    )


def _margin(hold_map: HoldMap) -> float:
    """Rock kept around a tile's outer holds: the gripper's reach on a rock relief (so a seam
    between copies never reaches under a closing gripper), none between columns."""
    return GRIPPER_REACH if hold_map.relief == "rock" else 0.0


def _hold_cloud(world: World) -> Path:
    path = Path(world.hold_map.cloud)
    if not path.is_absolute():
        base = Path(world.source).parent if world.source else Path.cwd()
        path = (base / path).resolve()
    return path


@functools.lru_cache(maxsize=4)
def _cloud_on_plane(cloud: Path) -> np.ndarray:
    """The hold cloud in its tile's frame: x, y on the regression plane (seen from the
    camera that took it), the height above its board (the 5th-percentile level)."""
    try:
        pts = read_cloud(cloud)
    except CloudFileError as e:
        raise WorldError(f"$.hold_map.cloud: {e}") from None
    plane = regression_frame(pts, np.zeros(3)).to_plane(pts)
    plane[:, 2] -= np.percentile(plane[:, 2], 5)
    return plane


def wall_pose(hold_map: HoldMap) -> tuple[np.ndarray, np.ndarray]:
    """World position of the wall frame's origin and its rotation (columns: wall x, y, z)."""
    incline = math.radians(hold_map.incline_deg)
    c, s = math.cos(incline), math.sin(incline)
    rotation = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
    return -rotation @ [hold_map.along[0], 0.0, 0.0], rotation


def yaw_matrix(yaw_deg: float) -> np.ndarray:
    """2-D rotation by ``yaw_deg`` degrees."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return np.array([[c, -s], [s, c]])
