"""climbd's messages as Foxglove's well-known schemas, for ``climbd view`` and ``climbd record
--scene``.

Pure translation, no I/O and no clock: every function takes the time to stamp with (``now``,
integer nanoseconds) and returns foxglove-sdk message objects, which the caller logs on its
channels. Foxglove's 3-D panel draws them without configuration. ``SceneStream`` says what goes
on which topic (``TOPICS``) as climbd messages arrive; the live view logs that to its WebSocket
channels, the recorder writes it into the MCAP beside the raw topics, so both show the same
scene under the same topic names and schemas.

Frames (``FrameTransforms``), one tree rooted at the odometry frame:

- ``odom`` → ``body``: the estimated body pose (``BodyState``);
- ``body`` → ``<joint 1>`` → ``<joint 2>`` → ``<joint 3>`` → ``<leg>_foot``: each leg's link
  frames from its joints' positions (``JointState``) and the profile's kinematics, named after
  the profile's joints (``rf_coxa`` → ``rf_femur`` → ``rf_tibia`` → ``rf_foot``); frame k sits
  on joint k's axis with x along the link it moves (``Kinematics.link_frames``);
- ``body`` → ``camera_<name>``: each profile camera's optical frame (x right, y down, z forward)
  at its mount (``mount_extrinsics``).

Scenes (``SceneUpdate``, each replacing the whole of its topic's previous scene): the robot's
links as primitives locked to their frames, and the world model's maps in ``odom``: joists as
boxes, holds as spheres, stair treads as boxes, truss members as cylinders with their nodes as
spheres, all coloured by confidence (red 0 → yellow → green 1). A twin world's ground truth
(drivers/sim/truth.py: the twin's ``sim/truth`` in a ``--sim`` run, or a world given to the
view) is drawn the same way in translucent blue on ``/truth/…``. The gait's plan (``FootTargets``,
body frame) on ``/plan``: each foot's target as a small sphere (stance and swing coloured apart),
and for a swinging foot a line from where the foot is (forward kinematics of the joints) to its
target. Perception's graspable points (``GraspablePoints``, body frame at their depth frame's
pose) as small spheres in ``odom`` on ``/grasp``.

Depth (``PointCloud``): a depth image deprojected in its camera's optical frame, decimated on
a pixel grid to a number of points, at a set rate: a perception role's ``DepthPreview``
(``state/depth``, a real robot's or the twin's camera) with the intrinsics it carries, or the
twin's ``DepthImage`` (``sim/depth``) with the profile camera's nominal ones.

JSON, for an operator to read or plot: ``/mode`` and ``/health`` as the robot sends them,
``/loop`` the control role's loop statistics as a flat message (``Loop``: a Plot panel plots
``/loop.lateness_p99`` without filtering by role), ``/estop`` whether an e-stop is latched and
by whom (``EStopState``, from ``ModeState``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Sequence
from typing import NamedTuple

import foxglove.messages as fg
import msgspec
import numpy as np

from climbd.daemon.algorithms.estimation import quaternion
from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.algorithms.world import TerrainView
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.hardware import Intrinsics, mount_extrinsics
from climbd.daemon.contract.messages import (
    TERRAIN_LAYERS,
    BodyState,
    DepthImage,
    DepthPreview,
    ElevationGrid,
    FootTargets,
    GraspablePoints,
    Health,
    HoldMap,
    JointState,
    JoistMap,
    LoopStats,
    Message,
    Mode,
    ModeState,
    SimTruth,
    StairMap,
    TerrainMap,
    TrussMembers,
)
from climbd.daemon.contract.profile import Profile

ODOM = "odom"
"""The odometry frame: the root of the tree, where the world model's maps live."""
BODY = "body"

JOIST_WIDTH = 0.038
"""Width (m) a joist is drawn with (a 2× joist's 1.5 in): the map keeps its top edge only."""
HOLD_DIAMETER = 0.04
"""Diameter (m) of a hold's sphere."""
NODE_SCALE = 2.5
"""A truss node's sphere, in diameters of its thickest member."""
MIN_THICKNESS = 0.005
"""Smallest extent (m) of a drawn box: a zero rise or height still shows as a slab."""

RGBA = tuple[float, float, float, float]

ROBOT_COLOR = (0.55, 0.6, 0.7, 1.0)
BODY_COLOR = (0.3, 0.35, 0.45, 0.9)
CAMERA_COLOR = (0.1, 0.5, 0.9, 1.0)
STANCE_COLOR = (0.2, 0.8, 0.3, 0.9)
"""A stance foot's target: green."""
SWING_COLOR = (1.0, 0.3, 0.9, 0.9)
"""A swinging foot's target and its path: magenta."""
GRASP_COLOR = (0.0, 0.85, 0.85, 0.8)
"""A graspable point: cyan."""
GRASP_DIAMETER = 0.015
"""Diameter (m) of a graspable point's sphere."""
GRASP_POINTS = 500
"""Most graspable points drawn of one message (evenly thinned beyond)."""


# --- small pieces ---------------------------------------------------------------------------


def stamp(now: int) -> fg.Timestamp:
    """A Foxglove timestamp from integer nanoseconds."""
    sec, nsec = divmod(int(now), 1_000_000_000)
    return fg.Timestamp(sec=sec, nsec=nsec)


def vector(v: Sequence[float]) -> fg.Vector3:
    return fg.Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def point(p: Sequence[float]) -> fg.Point3:
    return fg.Point3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def quat(q: Sequence[float]) -> fg.Quaternion:
    """A Foxglove quaternion (x, y, z, w fields) from climbd's (w, x, y, z)."""
    return fg.Quaternion(w=float(q[0]), x=float(q[1]), y=float(q[2]), z=float(q[3]))


def pose(position: Sequence[float], orientation: Sequence[float] = (1.0, 0.0, 0.0, 0.0)):
    return fg.Pose(position=vector(position), orientation=quat(orientation))


def color(rgba: Sequence[float]) -> fg.Color:
    return fg.Color(r=float(rgba[0]), g=float(rgba[1]), b=float(rgba[2]), a=float(rgba[3]))


def confidence_rgba(confidence: float, alpha: float = 0.9) -> tuple[float, float, float, float]:
    """Red at 0, yellow at 0.5, green at 1 (NaN counts as 0)."""
    c = min(max(confidence, 0.0), 1.0) if math.isfinite(confidence) else 0.0
    return (min(1.0, 2.0 * (1.0 - c)), min(1.0, 2.0 * c), 0.0, alpha)


def yaw_quaternion(yaw: float) -> list[float]:
    """(w, x, y, z) of a rotation by ``yaw`` about z."""
    return [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]


def z_to(direction: Sequence[float]) -> list[float]:
    """(w, x, y, z) of the shortest rotation taking +z onto ``direction`` (a cylinder's axis)."""
    a = np.asarray(direction, float)
    a = a / np.linalg.norm(a)
    if a[2] < -1.0 + 1e-12:
        return [0.0, 1.0, 0.0, 0.0]
    q = np.array([1.0 + a[2], -a[1], a[0], 0.0])
    return (q / np.linalg.norm(q)).tolist()


def _finite(*values) -> bool:
    return all(np.isfinite(np.asarray(v, float)).all() for v in values)


def _points(points: Sequence[Sequence[float]], n: int = 2) -> bool:
    """At least ``n`` finite (x, y, z) points."""
    return len(points) >= n and all(len(p) >= 3 for p in points[:n]) and _finite(*points[:n])


def _replace_all(entities: list[fg.SceneEntity], now: int) -> fg.SceneUpdate:
    """A scene that replaces everything its topic showed before (maps drop what they forgot)."""
    deletion = fg.SceneEntityDeletion(timestamp=stamp(now), type=fg.SceneEntityDeletionType.All)
    return fg.SceneUpdate(deletions=[deletion], entities=entities)


# --- the robot ------------------------------------------------------------------------------


class RobotScene:
    """The frame tree and link geometry of one profile's robot."""

    def __init__(self, profile: Profile) -> None:
        self.profile = profile
        self.kinematics = Kinematics(profile)
        self.joint_names = [j.name for j in profile.joints]
        self.leg_frames = [
            [*(j.name for j in leg.joints), f"{leg.name}_foot"] for leg in profile.legs
        ]
        self.leg_names = [leg.name for leg in profile.legs]
        kin = self.kinematics
        links = np.stack([kin.l1, kin.l2, kin.l3], 1)
        self.links = links
        self.thickness = max(
            0.01, 0.15 * float(np.median(links[links > 0])) if links.any() else 0.02
        )
        """Diameter (m) the links are drawn with; the feet are 1.5 times it."""
        self.cameras: list[tuple[str, list[float], list[float]]] = []
        for camera in profile.cameras:
            t = mount_extrinsics(camera)
            self.cameras.append(
                (camera_frame(camera.name), t[:3, 3].tolist(), quaternion(t[:3, :3]))
            )

    @property
    def frames(self) -> list[str]:
        """Every frame of the tree, root first."""
        names = [ODOM, BODY]
        for chain in self.leg_frames:
            names += chain
        return names + [name for name, _, _ in self.cameras]

    def joint_vector(self, joints: JointState) -> np.ndarray:
        """The profile-ordered joint vector of ``joints`` (NaN for a joint it does not name)."""
        by_name = dict(zip(joints.names, joints.position, strict=False))
        return np.array([by_name.get(n, math.nan) for n in self.joint_names], float)

    def transforms(
        self, body: BodyState | None, joints: JointState | None, now: int
    ) -> fg.FrameTransforms:
        """The tree's transforms at ``now``: odom → body when the body pose is known, each leg's
        links when all its joints are (a leg with a lost or missing joint is left out, so a
        viewer keeps its last pose), and the cameras always."""
        ts = stamp(now)
        out: list[fg.FrameTransform] = []

        def add(parent: str, child: str, t: Sequence[float], q: Sequence[float]) -> None:
            out.append(
                fg.FrameTransform(
                    timestamp=ts,
                    parent_frame_id=parent,
                    child_frame_id=child,
                    translation=vector(t),
                    rotation=quat(q),
                )
            )

        if body is not None and _finite(body.position, body.orientation):
            q = np.asarray(body.orientation, float)
            norm = float(np.linalg.norm(q))
            if len(body.position) == 3 and len(q) == 4 and norm > 0:
                add(ODOM, BODY, body.position, q / norm)
        if joints is not None:
            trans, quats = self.kinematics.link_frames(self.joint_vector(joints))
            for leg, chain in enumerate(self.leg_frames):
                if not _finite(quats[leg]):
                    continue
                parent = BODY
                for k, child in enumerate(chain):
                    add(parent, child, trans[leg, k], quats[leg, k])
                    parent = child
        for name, t, q in self.cameras:
            add(BODY, name, t, q)
        return fg.FrameTransforms(transforms=out)

    def geometry(self, now: int) -> fg.SceneUpdate:
        """The robot drawn as primitives locked to its frames: the body as a slab over its leg
        mounts, each link as a cylinder, each foot as a sphere, each camera as a small box."""
        ts = stamp(now)
        kin = self.kinematics
        links, thickness = self.links, self.thickness
        entities = []
        lo, hi = kin.mount.min(0), kin.mount.max(0)
        size = np.maximum(hi - lo, thickness) + [thickness, thickness, 0.0]
        size[2] = max(size[2], 2 * thickness)
        entities.append(
            fg.SceneEntity(
                timestamp=ts,
                frame_id=BODY,
                id="body",
                frame_locked=True,
                cubes=[
                    fg.CubePrimitive(
                        pose=pose((lo + hi) / 2), size=vector(size), color=color(BODY_COLOR)
                    )
                ],
            )
        )
        along_x = [math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0]  # Ry(90°): z → x
        for leg, chain in enumerate(self.leg_frames):
            for k in range(3):
                length = float(links[leg, k])
                if length <= 0:
                    continue
                cylinder = fg.CylinderPrimitive(
                    pose=pose([length / 2, 0.0, 0.0], along_x),
                    size=vector([thickness, thickness, length]),
                    bottom_scale=1.0,
                    top_scale=1.0,
                    color=color(ROBOT_COLOR),
                )
                entities.append(
                    fg.SceneEntity(
                        timestamp=ts,
                        frame_id=chain[k],
                        id=f"link/{chain[k]}",
                        frame_locked=True,
                        cylinders=[cylinder],
                    )
                )
            foot = fg.SpherePrimitive(
                pose=pose([0.0, 0.0, 0.0]),
                size=vector([1.5 * thickness] * 3),
                color=color(ROBOT_COLOR),
            )
            entities.append(
                fg.SceneEntity(
                    timestamp=ts, frame_id=chain[3], id=chain[3], frame_locked=True, spheres=[foot]
                )
            )
        for name, _, _ in self.cameras:
            box = fg.CubePrimitive(  # optical frame: wide along x, shallow along z (forward)
                pose=pose([0.0, 0.0, -0.0125]),
                size=vector([0.09, 0.025, 0.025]),
                color=color(CAMERA_COLOR),
            )
            entities.append(
                fg.SceneEntity(timestamp=ts, frame_id=name, id=name, frame_locked=True, cubes=[box])
            )
        return _replace_all(entities, now)

    def plan(self, targets: FootTargets, joints: JointState | None, now: int) -> fg.SceneUpdate:
        """The gait's foot targets in the body frame: a sphere per foot (STANCE_COLOR or
        SWING_COLOR, two thirds of a foot's size), and for a swinging foot a line from where it
        is (forward kinematics of ``joints``; none while a joint of its leg is unknown) to its
        target. A leg the message has no finite target for is left out. Each carries its phase
        (and grip and unload flags, when the gait sets them) as metadata."""
        ts = stamp(now)
        feet = None
        if joints is not None:
            feet = self.kinematics.fk(self.joint_vector(joints))
        size = vector([self.thickness] * 3)
        entities = []
        for leg, name in enumerate(self.leg_names):
            if leg >= len(targets.positions):
                break
            target = targets.positions[leg]
            if len(target) < 3 or not _finite(target[:3]):
                continue
            swing = leg < len(targets.stance) and not targets.stance[leg]
            rgba = SWING_COLOR if swing else STANCE_COLOR
            sphere = fg.SpherePrimitive(pose=pose(target[:3]), size=size, color=color(rgba))
            lines = []
            if swing and feet is not None and _finite(feet[leg]):
                lines.append(
                    fg.LinePrimitive(
                        type=fg.LinePrimitiveLineType.LineStrip,
                        pose=pose([0.0, 0.0, 0.0]),
                        thickness=2.0,
                        scale_invariant=True,
                        points=[point(feet[leg]), point(target)],
                        color=color(rgba),
                    )
                )
            meta = [fg.KeyValuePair(key="phase", value="swing" if swing else "stance")]
            for flag, flags in (("grip", targets.grip), ("unload", targets.unload)):
                if flags is not None and leg < len(flags):
                    meta.append(fg.KeyValuePair(key=flag, value=str(bool(flags[leg])).lower()))
            entities.append(
                fg.SceneEntity(
                    timestamp=ts,
                    frame_id=BODY,
                    id=f"target/{name}",
                    frame_locked=True,
                    metadata=meta,
                    spheres=[sphere],
                    lines=lines,
                )
            )
        return _replace_all(entities, now)


# --- the world model's maps -----------------------------------------------------------------


def joists(msg: JoistMap, now: int, rgba: RGBA | None = None) -> fg.SceneUpdate:
    """Each mapped joist as a box: its top along the edge seen so far, ``height`` deep,
    JOIST_WIDTH wide on the side its normal points to (away from where it was first seen)."""
    ts = stamp(now)
    entities = []
    for j in msg.joists:
        if not _points(j.endpoints) or not _finite(j.heading, j.height):
            continue
        p0, p1 = np.asarray(j.endpoints[0][:3], float), np.asarray(j.endpoints[1][:3], float)
        normal = np.array([math.cos(j.heading), math.sin(j.heading), 0.0])
        along = np.array([-normal[1], normal[0], 0.0])
        length = max(abs(float((p1 - p0) @ along)), MIN_THICKNESS)
        height = max(float(j.height), MIN_THICKNESS)
        centre = (p0 + p1) / 2 + normal * (JOIST_WIDTH / 2)
        centre[2] = (p0[2] + p1[2]) / 2 - height / 2
        box = fg.CubePrimitive(
            pose=pose(centre, yaw_quaternion(j.heading)),
            size=vector([JOIST_WIDTH, length, height]),
            color=color(rgba or confidence_rgba(j.confidence)),
        )
        entities.append(_entity(ts, f"joist/{j.id}", j, cubes=[box]))
    return _replace_all(entities, now)


def holds(msg: HoldMap, now: int, rgba: RGBA | None = None) -> fg.SceneUpdate:
    """Each mapped hold as a sphere of HOLD_DIAMETER at its position."""
    ts = stamp(now)
    entities = []
    for h in msg.holds:
        if len(h.position) < 3 or not _finite(h.position):
            continue
        sphere = fg.SpherePrimitive(
            pose=pose(h.position[:3]),
            size=vector([HOLD_DIAMETER] * 3),
            color=color(rgba or confidence_rgba(h.confidence)),
        )
        entities.append(_entity(ts, f"hold/{h.id}", h, spheres=[sphere]))
    return _replace_all(entities, now)


def stairs(msg: StairMap, now: int, rgba: RGBA | None = None) -> fg.SceneUpdate:
    """Each mapped step as a block: its tread ``depth`` deep from the edge up the flight, its
    top at ``height``, ``rise`` tall. The edge runs left to right facing up the flight, so up
    the flight is the edge direction turned a quarter left."""
    ts = stamp(now)
    entities = []
    for s in msg.steps:
        if not _points(s.edge) or not _finite(s.height, s.rise, s.depth):
            continue
        left, right = np.asarray(s.edge[0][:3], float), np.asarray(s.edge[1][:3], float)
        edge = right - left
        width = float(np.hypot(edge[0], edge[1]))
        if width <= 0:
            continue
        up = np.array([-edge[1], edge[0], 0.0]) / width
        rise = max(float(s.rise), MIN_THICKNESS)
        depth = max(float(s.depth), MIN_THICKNESS)
        centre = (left + right) / 2 + up * (depth / 2)
        centre[2] = s.height - rise / 2
        box = fg.CubePrimitive(
            pose=pose(centre, yaw_quaternion(math.atan2(up[1], up[0]))),
            size=vector([depth, width, rise]),
            color=color(rgba or confidence_rgba(s.confidence)),
        )
        entities.append(_entity(ts, f"stair/{s.id}", s, cubes=[box]))
    return _replace_all(entities, now)


def truss(msg: TrussMembers, now: int, rgba: RGBA | None = None) -> fg.SceneUpdate:
    """Each member as a cylinder between its ends, each node as a sphere NODE_SCALE times the
    diameter of its thickest member."""
    ts = stamp(now)
    entities = []
    radius: dict[int, float] = {}
    for i, m in enumerate(msg.members):
        if len(m.p0) < 3 or len(m.p1) < 3 or not _finite(m.p0, m.p1, m.radius):
            continue
        p0, p1 = np.asarray(m.p0[:3], float), np.asarray(m.p1[:3], float)
        length = float(np.linalg.norm(p1 - p0))
        if length <= 0:
            continue
        radius[m.id] = max(radius.get(m.id, 0.0), float(m.radius))
        cylinder = fg.CylinderPrimitive(
            pose=pose((p0 + p1) / 2, z_to(p1 - p0)),
            size=vector([2 * m.radius, 2 * m.radius, length]),
            bottom_scale=1.0,
            top_scale=1.0,
            color=color(rgba or confidence_rgba(m.confidence)),
        )
        name = f"member/{m.id}" if m.id else f"member/#{i}"
        entities.append(_entity(ts, name, m, cylinders=[cylinder]))
    for i, n in enumerate(msg.nodes):
        if len(n.position) < 3 or not _finite(n.position):
            continue
        r = max((radius.get(k, 0.0) for k in n.members), default=0.0) or 0.02
        sphere = fg.SpherePrimitive(
            pose=pose(n.position[:3]),
            size=vector([2 * NODE_SCALE * r] * 3),
            color=color(rgba or (0.6, 0.6, 0.6, 1.0)),
        )
        entities.append(
            fg.SceneEntity(timestamp=ts, frame_id=ODOM, id=f"node/{i}", spheres=[sphere])
        )
    return _replace_all(entities, now)


def _entity(ts: fg.Timestamp, name: str, item, **primitives) -> fg.SceneEntity:
    """An odometry-frame entity with a tracked item's confidence (and sightings) as metadata."""
    meta = [fg.KeyValuePair(key="confidence", value=f"{item.confidence:.3f}")]
    if hasattr(item, "seen"):
        meta.append(fg.KeyValuePair(key="seen", value=str(item.seen)))
    return fg.SceneEntity(timestamp=ts, frame_id=ODOM, id=name, metadata=meta, **primitives)


def grasp(msg: GraspablePoints, now: int, max_points: int = GRASP_POINTS) -> fg.SceneUpdate:
    """Graspable points as small spheres in ``odom``, placed with the body pose of the depth
    frame they were found in (``frame_position``, ``frame_orientation``); at most
    ``max_points``, evenly thinned, non-finite points left out."""
    ts = stamp(now)
    points = np.array([p[:3] for p in msg.points if len(p) >= 3], float).reshape(-1, 3)
    points = points[np.isfinite(points).all(1)]
    if len(points) > max_points:
        points = points[np.linspace(0, len(points) - 1, max_points).round().astype(int)]
    entities = []
    if len(points):
        if not _finite(msg.frame_position, msg.frame_orientation):
            raise ValueError("the frame's body pose is not finite")
        r = rotation(msg.frame_orientation, zero_norm_ok=True)
        placed = points @ r.T + np.asarray(msg.frame_position[:3], float)
        size, rgba = vector([GRASP_DIAMETER] * 3), color(GRASP_COLOR)
        spheres = [fg.SpherePrimitive(pose=pose(p), size=size, color=rgba) for p in placed]
        entities.append(
            fg.SceneEntity(timestamp=ts, frame_id=ODOM, id="graspable", spheres=spheres)
        )
    return _replace_all(entities, now)


# --- grids ----------------------------------------------------------------------------------


def elevation(msg: ElevationGrid, now: int) -> fg.Grid | None:
    """A body-frame height map as a Foxglove grid in ``odom``, placed with the body pose it was
    computed at (``frame_position``, ``frame_orientation``); one float32 field ``height``,
    NaN unknown. None for a grid whose bytes do not match its size."""
    n = msg.rows * msg.cols
    if n == 0 or len(msg.heights) != 4 * n or msg.resolution <= 0:
        return None
    if not _finite(msg.frame_position, msg.frame_orientation):
        return None
    # climbd's rows run along x and its columns along y; Foxglove's columns run along the
    # grid's x, so the cells go over transposed.
    heights = np.frombuffer(msg.heights, "<f4").reshape(msg.rows, msg.cols)
    data = np.ascontiguousarray(heights.T).tobytes()
    r = rotation(msg.frame_orientation, zero_norm_ok=True)
    origin = np.asarray(msg.frame_position, float) + r @ [msg.origin_x, msg.origin_y, 0.0]
    return fg.Grid(
        timestamp=stamp(now),
        frame_id=ODOM,
        pose=pose(origin, quaternion(r)),
        column_count=msg.rows,
        cell_size=fg.Vector2(x=msg.resolution, y=msg.resolution),
        row_stride=4 * msg.rows,
        cell_stride=4,
        fields=[
            fg.PackedElementField(
                name="height", offset=0, type=fg.PackedElementFieldNumericType.Float32
            )
        ],
        data=data,
    )


TERRAIN_FIELDS = [
    fg.PackedElementField(name=name, offset=4 * k, type=fg.PackedElementFieldNumericType.Float32)
    for k, name in enumerate(TERRAIN_LAYERS)
]
"""One float32 field per layer of the world model's terrain map, in TERRAIN_LAYERS' order."""


def terrain(msg: TerrainMap, now: int) -> fg.Grid | None:
    """The world model's terrain map (grid_map-style layers) as a Foxglove grid in ``odom``:
    one float32 field per layer, height in the odometry frame, NaN unknown; the 3-D panel
    colours it by the layer chosen (traversability, slope, step...). None for an empty map; a
    layer that does not decode raises (told once)."""
    if msg.rows * msg.cols == 0 or msg.resolution <= 0:
        return None
    view = TerrainView(msg)
    layers = [
        view.layer(name) + (msg.origin_z if name == "height" else 0.0) for name in TERRAIN_LAYERS
    ]
    cells = np.stack(layers, axis=-1).astype("<f4")  # rows (x) × cols (y) × layers
    data = np.ascontiguousarray(
        cells.transpose(1, 0, 2)
    ).tobytes()  # Foxglove's columns run along x
    size = 4 * len(TERRAIN_LAYERS)
    return fg.Grid(
        timestamp=stamp(now),
        frame_id=ODOM,
        pose=pose([msg.origin_x, msg.origin_y, 0.0]),
        column_count=msg.rows,
        cell_size=fg.Vector2(x=msg.resolution, y=msg.resolution),
        row_stride=size * msg.rows,
        cell_stride=size,
        fields=TERRAIN_FIELDS,
        data=data,
    )


def camera_frame(camera: str) -> str:
    """The frame of the profile camera named ``camera`` (its optical frame)."""
    return f"camera_{camera}"


CLOUD_FIELDS = [
    fg.PackedElementField(name=axis, offset=4 * k, type=fg.PackedElementFieldNumericType.Float32)
    for k, axis in enumerate("xyz")
]


def depth_cloud(
    image: DepthImage | DepthPreview, intrinsics: Intrinsics, max_points: int, now: int
) -> fg.PointCloud | None:
    """A depth image as a point cloud in its camera's optical frame (x right, y down, z
    forward), decimated on a pixel grid coarse enough to keep at most ``max_points`` pixels
    (every pixel when they fit); pixels without a return (0) are left out. None for an image
    whose bytes do not match its size or whose size is not ``intrinsics``'."""
    w, h = image.width, image.height
    if w <= 0 or h <= 0 or len(image.depth) != 2 * w * h or max_points < 1:
        return None
    if (w, h) != (intrinsics.width, intrinsics.height) or not image.depth_scale > 0:
        return None
    step = max(1, math.ceil(math.sqrt(w * h / max_points)))
    while math.ceil(w / step) * math.ceil(h / step) > max_points:
        step += 1
    raw = np.frombuffer(image.depth, "<u2").reshape(h, w)[::step, ::step]
    v, u = np.nonzero(raw)
    z = raw[v, u].astype(np.float32) * np.float32(image.depth_scale)
    u, v = u * step, v * step
    points = np.empty((len(z), 3), np.float32)
    points[:, 0] = (u - intrinsics.ppx) * z / intrinsics.fx
    points[:, 1] = (v - intrinsics.ppy) * z / intrinsics.fy
    points[:, 2] = z
    return fg.PointCloud(
        timestamp=stamp(now),
        frame_id=camera_frame(image.camera),
        pose=pose([0.0, 0.0, 0.0]),
        point_stride=12,
        fields=CLOUD_FIELDS,
        data=points.tobytes(),
    )


def preview_intrinsics(preview: DepthPreview) -> Intrinsics:
    """The pinhole intrinsics a depth preview carries (of its decimated image); ValueError
    for ones no point can be deprojected with."""
    fx, fy, cx, cy = preview.fx, preview.fy, preview.cx, preview.cy
    if not all(math.isfinite(v) for v in (fx, fy, cx, cy)) or fx <= 0 or fy <= 0:
        raise ValueError(f"intrinsics fx {fx} fy {fy} cx {cx} cy {cy}")
    return Intrinsics(preview.width, preview.height, fx, fy, cx, cy)


# --- JSON channels --------------------------------------------------------------------------


class Loop(LoopStats, kw_only=True):
    """The control role's loop statistics (``Health.loop``) as a flat message for a plot:
    ``stamp`` is the Health's (s, the robot's clock); the rest as ``LoopStats`` (s, Hz)."""

    stamp: float = 0.0


class EStopState(msgspec.Struct, kw_only=True):
    """Whether an e-stop is latched (the robot is in ESTOP) and by whom (the sources holding
    the latch), from ``ModeState``: ``stamp`` is its (s, the robot's clock), ``mode`` and
    ``reason`` the mode and why it was entered, ``reset_by`` the session that last reset one."""

    stamp: float = 0.0
    engaged: bool = False
    by: list[str] = []
    mode: Mode = Mode.OFF
    reason: str = ""
    reset_by: str = ""


def loop_of(health: Health) -> Loop | None:
    """The control role's loop statistics of ``health`` (None for another role's)."""
    if health.role != "control":
        return None
    return Loop(stamp=health.stamp, **msgspec.structs.asdict(health.loop))


def estop_of(mode: ModeState) -> EStopState:
    return EStopState(
        stamp=mode.stamp,
        engaged=mode.mode is Mode.ESTOP,
        by=list(mode.estop_by),
        mode=mode.mode,
        reason=mode.reason,
        reset_by=mode.reset_by,
    )


def json_schema(message: type[msgspec.Struct]) -> dict:
    """The JSON Schema a JSON channel of ``message`` advertises: the message's own schema at
    the top (Foxglove reads its fields there), its parts under ``$defs``; every number may be
    null, which is how JSON carries a NaN (a lost joint's temperature)."""
    top = msgspec.json.schema(message)
    defs = top.get("$defs", {})
    schema = {**defs.get(message.__name__, top), "$defs": defs}
    return _nullable_numbers(schema)


def _nullable_numbers(node):
    if isinstance(node, dict):
        out = {k: _nullable_numbers(v) for k, v in node.items()}
        if out.get("type") == "number":
            out["type"] = ["number", "null"]
        return out
    if isinstance(node, list):
        return [_nullable_numbers(v) for v in node]
    return node


def json_payload(msg: msgspec.Struct) -> bytes:
    """``msg`` as JSON (NaN and infinities as null)."""
    return msgspec.json.encode(msg)


# --- the scene's topics, as the view serves them and recordings keep them --------------------

INPUTS: tuple[type[Message], ...] = (
    BodyState,
    JointState,
    FootTargets,
    ModeState,
    Health,
    JoistMap,
    HoldMap,
    StairMap,
    TrussMembers,
    ElevationGrid,
    TerrainMap,
    GraspablePoints,
    SimTruth,
)
"""What the scene is drawn from; all of it the robot publishes whether or not anyone watches."""

GEOMETRY_PERIOD = 1.0
"""Seconds between repeats of the robot's geometry, for clients that join (or seek) later."""

TF = "/tf"
ROBOT = "/robot"
PLAN = "/plan"
GRASP = "/grasp"
LOOP = "/loop"
ESTOP = "/estop"
MAPS: dict[type[Message], tuple[str, Callable]] = {
    JoistMap: ("/joists", joists),
    HoldMap: ("/holds", holds),
    StairMap: ("/stairs", stairs),
    TrussMembers: ("/truss", truss),
    ElevationGrid: ("/elevation", elevation),
    TerrainMap: ("/terrain", terrain),
}
"""Each map's topic and its translation."""
TRUTH: dict[type[Message], str] = {
    JoistMap: "/truth/joists",
    HoldMap: "/truth/holds",
    StairMap: "/truth/stairs",
    TrussMembers: "/truth/truss",
}
"""The topic of each map of a twin world's ground truth, drawn beside perception's."""
TRUTH_COLOR = (0.25, 0.45, 1.0, 0.4)
"""Truth's colour: translucent blue, apart from perception's red → yellow → green."""
JSON: dict[type[Message], str] = {ModeState: "/mode", Health: "/health"}
"""Messages carried as they are, as JSON, for an operator to read or plot."""

TOPICS: dict[str, type] = {
    TF: fg.FrameTransforms,
    ROBOT: fg.SceneUpdate,
    "/joists": fg.SceneUpdate,
    "/holds": fg.SceneUpdate,
    "/stairs": fg.SceneUpdate,
    "/truss": fg.SceneUpdate,
    "/elevation": fg.Grid,
    "/mode": ModeState,
    "/health": Health,
    LOOP: Loop,
    ESTOP: EStopState,
}
"""Every scene topic and what it carries: a Foxglove message (protobuf) or a climbd message
(JSON)."""

CLOUD = "/depth"
OPTIONAL_TOPICS: dict[str, type] = {
    PLAN: fg.SceneUpdate,
    GRASP: fg.SceneUpdate,
    CLOUD: fg.PointCloud,
    "/terrain": fg.Grid,
    **{topic: fg.SceneUpdate for topic in TRUTH.values()},
}
"""Topics drawn only in some runs (the world model's terrain once it has one, the gait's plan
while a gait steps, graspable points of a climber's perception, depth from a perception role's
``state/depth`` or the twin's ``sim/depth``, the twin's ``sim/truth`` in a ``--sim`` run, a twin
world's truth given to the view): a view advertises each, and a recording declares it, when its
first message is drawn."""


class ChannelSchema(NamedTuple):
    """How a scene topic is declared: its schema (name, encoding, bytes) and message encoding."""

    name: str
    encoding: str
    data: bytes
    message_encoding: str


def channel_schema(topic: str) -> ChannelSchema:
    """The schema ``topic`` is declared with: the foxglove-sdk message's own (a protobuf
    FileDescriptorSet), or the JSON Schema of a climbd message or of the view's own (``Loop``,
    ``EStopState``: ``json_schema``)."""
    kind = TOPICS.get(topic) or OPTIONAL_TOPICS[topic]
    if issubclass(kind, msgspec.Struct):
        data = json.dumps(json_schema(kind)).encode()
        return ChannelSchema(f"climbd.{kind.__name__}", "jsonschema", data, "json")
    schema = kind.get_schema()
    return ChannelSchema(schema.name, schema.encoding, bytes(schema.data), "protobuf")


def truth_maps(msg: SimTruth) -> list[Message]:
    """The maps a ``sim/truth`` message carries (those the world has)."""
    return [m for m in (msg.joists, msg.stairs, msg.holds, msg.truss) if m is not None]


def payload(out) -> bytes:
    """The bytes of what ``SceneStream.update`` put on a topic (a Foxglove message or JSON)."""
    return out if isinstance(out, bytes) else out.encode()


class SceneStream:
    """What goes on each scene topic as climbd messages arrive, for one robot.

    Transforms go out whenever the body or the joints moved, at most once per ``tf_period``
    (the latest pose; a move inside the period goes out with the next message after it), and
    with the robot's geometry every ``geometry_period``; the gait's plan with the transforms
    while foot targets come (cleared when the robot leaves ACTIVE); maps, mode, e-stop, health
    and loop statistics on arrival; graspable points at most once per ``grasp_period``; the
    twin's truth on arrival of ``sim/truth``, or, given as ``truth``, with the geometry until
    a ``sim/truth`` arrives; with ``clouds`` (by default: when given ``intrinsics``), each
    camera's depth at most once per ``cloud_period`` and of ``cloud_points`` at most, from a
    ``DepthPreview`` with its own intrinsics or a ``DepthImage`` with ``intrinsics``' (the
    twin's full frame; once one is heard, that camera's previews are not drawn). A
    message that cannot be drawn is left out and ``refused`` is told once per topic, so one
    odd message never stops the scene.
    """

    def __init__(
        self,
        robot: RobotScene,
        refused: Callable[[str], None] | None = None,
        tf_period: float = 0.0,
        geometry_period: float = GEOMETRY_PERIOD,
        intrinsics: Callable[[str, int, int], Intrinsics | None] | None = None,
        cloud_period: float = 0.5,
        cloud_points: int = 20_000,
        truth: Sequence[Message] = (),
        grasp_period: float = 0.5,
        clouds: bool | None = None,
    ) -> None:
        self.truth = [msg for msg in truth if type(msg) in TRUTH]
        self.robot = robot
        self.intrinsics = intrinsics
        self.clouds = intrinsics is not None if clouds is None else clouds
        self.cloud_period = cloud_period
        self.cloud_points = cloud_points
        self.grasp_period = grasp_period
        self._cloud_at: dict[str, float] = {}
        self._full: set[str] = set()
        """Cameras heard as a twin's DepthImage of a known size: their previews (the same
        frames, fewer pixels) are not drawn."""
        self._grasp_at = -math.inf
        self.refused = refused
        self.tf_period = tf_period
        self.geometry_period = geometry_period
        self.body: BodyState | None = None
        self.joints: JointState | None = None
        self.feet: FootTargets | None = None
        self._planned = False
        self._truth_heard = False
        self._moved = False
        self._tf_at = -math.inf
        self._geometry_at = -math.inf
        self._refused: set[str] = set()

    def update(self, fresh: Iterable[Message], now_ns: int, now: float) -> list[tuple[str, object]]:
        """(topic, message) pairs for what arrived (``fresh``), stamped ``now_ns``; ``now``
        (seconds, monotonic) paces the transforms, the plan, the geometry and the clouds."""
        out: list[tuple[str, object]] = []
        for msg in fresh:
            kind = type(msg)
            if kind is BodyState:
                self.body, self._moved = msg, True
            elif kind is JointState:
                self.joints, self._moved = msg, True
            elif kind is FootTargets:
                self.feet, self._moved = msg, True
            elif kind in MAPS:
                topic, translate = MAPS[kind]
                drawn = self._draw(msg.TOPIC, translate, msg, now_ns)
                if drawn is not None:
                    out.append((topic, drawn))
            elif kind is ModeState:
                out.append((JSON[kind], json_payload(msg)))
                out.append((ESTOP, json_payload(estop_of(msg))))
                if msg.mode is not Mode.ACTIVE and self._planned:
                    self.feet, self._planned = None, False
                    out.append((PLAN, _replace_all([], now_ns)))
            elif kind is Health:
                out.append((JSON[kind], json_payload(msg)))
                loop = loop_of(msg)
                if loop is not None:
                    out.append((LOOP, json_payload(loop)))
            elif kind is GraspablePoints:
                if now - self._grasp_at < self.grasp_period:
                    continue
                self._grasp_at = now
                drawn = self._draw(msg.TOPIC, grasp, msg, now_ns)
                if drawn is not None:
                    out.append((GRASP, drawn))
            elif kind is SimTruth:
                self._truth_heard = True
                self.truth = truth_maps(msg)
                out += self._draw_truth(now_ns)
            elif kind in (DepthImage, DepthPreview) and self.clouds:
                if kind is DepthImage:
                    if self.intrinsics is None:
                        continue
                    if self.intrinsics(msg.camera, msg.width, msg.height) is not None:
                        self._full.add(msg.camera)
                elif msg.camera in self._full:
                    continue  # the twin's full frame of this camera is drawn instead
                if now - self._cloud_at.get(msg.camera, -math.inf) < self.cloud_period:
                    continue
                self._cloud_at[msg.camera] = now
                cloud = self._draw(msg.TOPIC, self._cloud, msg, now_ns)
                if cloud is not None:
                    out.append((CLOUD, cloud))
        if now - self._geometry_at >= self.geometry_period:
            self._geometry_at = now
            out.append((ROBOT, self.robot.geometry(now_ns)))
            if not self._truth_heard:
                out += self._draw_truth(now_ns)
            self._moved = True  # the cameras' static transforms go out with it
        if self._moved and now - self._tf_at >= self.tf_period:
            self._moved, self._tf_at = False, now
            tf = self._draw(
                f"{BodyState.TOPIC} and {JointState.TOPIC}",
                self.robot.transforms,
                self.body,
                self.joints,
                now_ns,
            )
            if tf is not None:
                out.append((TF, tf))
            if self.feet is not None:
                plan = self._draw(
                    FootTargets.TOPIC, self.robot.plan, self.feet, self.joints, now_ns
                )
                if plan is not None:
                    self._planned = True
                    out.append((PLAN, plan))
        return out

    def _draw_truth(self, now_ns: int) -> list[tuple[str, object]]:
        out = []
        for msg in self.truth:
            translate = MAPS[type(msg)][1]
            drawn = self._draw(f"truth of {msg.TOPIC}", translate, msg, now_ns, TRUTH_COLOR)
            if drawn is not None:
                out.append((TRUTH[type(msg)], drawn))
        return out

    def _cloud(self, image: DepthImage | DepthPreview, now_ns: int) -> fg.PointCloud:
        if isinstance(image, DepthPreview):
            intrinsics = preview_intrinsics(image)
        else:
            intrinsics = self.intrinsics(image.camera, image.width, image.height)
        if intrinsics is None:
            raise ValueError(f"no camera {image.camera!r} of {image.width}x{image.height}")
        cloud = depth_cloud(image, intrinsics, self.cloud_points, now_ns)
        if cloud is None:
            raise ValueError(f"{len(image.depth)} bytes for {image.width}x{image.height}")
        return cloud

    def _draw(self, what: str, translate, *args):
        """``translate(*args)``, or None once ``refused`` was told (first time per topic) why a
        message of ``what`` cannot be drawn."""
        try:
            return translate(*args)
        except Exception as e:
            if what not in self._refused:
                self._refused.add(what)
                if self.refused is not None:
                    why = f"{type(e).__name__}: {e}"
                    self.refused(f"cannot draw {what}: {why} (further ones dropped quietly)")
            return None
