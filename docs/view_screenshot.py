"""Render the 3-D scene of a ``climbd record --scene`` recording to a PNG (docs/img/view.png).

This is a regenerable stand-in for a screenshot of ``climbd view`` in Foxglove, not a capture
of Foxglove itself: it reads the MCAP with the ``mcap`` library and decodes the scene channels
from the schemas stored in the file, as Foxglove does (protobuf from each channel's
FileDescriptorSet, JSON as JSON), without calling climbd's translation (daemon/runtime/scene.py)
again. What it draws, as it stands at the chosen time (default: the end of the recording):

- ``/tf`` (foxglove.FrameTransforms): the transform tree; each leg as a line chain
  body → coxa → femur → tibia → foot through its frames;
- ``/robot`` (foxglove.SceneUpdate): the body slab, links, feet and cameras, locked to frames;
- ``/joists``, ``/holds``, ``/stairs``, ``/truss`` (foxglove.SceneUpdate): boxes, spheres and
  cylinders in ``odom``, in the colours recorded (confidence: red 0 → yellow → green 1);
- ``/elevation`` (foxglove.Grid): flat cells coloured by height, as Foxglove's grid layer;
- ``/mode`` and ``/health`` (JSON): the mode and the control loop's rate in the title.

The camera looks from above and behind the robot (the body frame's −x side).

Usage (from the repository root, in its venv)::

    python docs/view_screenshot.py RECORDING.mcap [-o docs/img/view.png] [--at SECONDS]
    python docs/view_screenshot.py --make [--seconds 4] [--keep scene.mcap]

``--make`` records one itself, as tests/test_record_scene.py does: ``climbd run`` with the
fake driver (the stock WidowX standing), a Zenoh peer publishing a fixed set of world-model
maps (two joists ahead, holds on them, a flight of three steps on the left, a truss on the
right and an elevation grid), and ``climbd record --scene`` for ``--seconds``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from mcap.reader import make_reader  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_OUTPUT = ROOT / "docs" / "img" / "view.png"
SCENE_TOPICS = ("/tf", "/robot", "/joists", "/holds", "/stairs", "/truss", "/elevation")
JSON_TOPICS = ("/mode", "/health")
MAP_TOPICS = ("/joists", "/holds", "/stairs", "/truss")
LEG_COLOR = "#e8741e"
LIGHT = np.array([-0.4, -0.3, 1.0]) / np.linalg.norm([-0.4, -0.3, 1.0])


# --- decoding, from the schemas in the file -------------------------------------------------

_classes: dict[tuple[str, bytes], type] = {}


def proto_class(name: str, descriptor_set: bytes) -> type:
    """The protobuf message class ``name`` from a channel's serialized FileDescriptorSet."""
    key = (name, descriptor_set)
    if key not in _classes:
        pool = descriptor_pool.DescriptorPool()
        for f in descriptor_pb2.FileDescriptorSet.FromString(descriptor_set).file:
            pool.Add(f)
        _classes[key] = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
    return _classes[key]


def enum_value(message, field: str, name: str) -> int:
    """The number of enum value ``name`` of ``message``'s field ``field``."""
    return message.DESCRIPTOR.fields_by_name[field].enum_type.values_by_name[name].number


class Scene:
    """The scene as it stands after the messages read so far."""

    def __init__(self) -> None:
        self.frames: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}
        """child → (parent, translation, rotation matrix), the latest of each."""
        self.entities: dict[str, dict[str, object]] = {t: {} for t in SCENE_TOPICS}
        """topic → entity id → SceneEntity, after the deletions of each update."""
        self.grid = None
        self.mode: dict | None = None
        self.health: dict | None = None
        self.start: int | None = None
        self.time: int = 0
        self.counts: dict[str, int] = {}

    def add(self, topic: str, schema, encoding: str, data: bytes, log_time: int) -> None:
        self.start = log_time if self.start is None else self.start
        self.time = log_time
        self.counts[topic] = self.counts.get(topic, 0) + 1
        if encoding == "json":
            value = json.loads(data)
            if topic == "/mode":
                self.mode = value
            elif value.get("role") == "control":
                self.health = value
            return
        msg = proto_class(schema.name, schema.data)()
        msg.ParseFromString(data)
        if schema.name == "foxglove.FrameTransforms":
            for t in msg.transforms:
                v, r = t.translation, t.rotation
                self.frames[t.child_frame_id] = (
                    t.parent_frame_id,
                    np.array([v.x, v.y, v.z]),
                    rotation([r.w, r.x, r.y, r.z]),
                )
        elif schema.name == "foxglove.SceneUpdate":
            entities = self.entities[topic]
            for d in msg.deletions:
                if d.type == enum_value(d, "type", "ALL"):
                    entities.clear()
                else:
                    entities.pop(d.id, None)
            for e in msg.entities:
                entities[e.id] = e
        elif schema.name == "foxglove.Grid":
            self.grid = msg

    def pose(self, frame: str) -> tuple[np.ndarray, np.ndarray] | None:
        """Position and rotation of ``frame`` in ``odom``, or None when it does not reach it."""
        p, r = np.zeros(3), np.eye(3)
        seen = set()
        while frame != "odom":
            if frame not in self.frames or frame in seen:
                return None
            seen.add(frame)
            parent, t, rot = self.frames[frame]
            p, r = rot @ p + t, rot @ r
            frame = parent
        return p, r


def read(path: Path, at: float | None = None) -> Scene:
    """The scene of recording ``path`` after ``at`` seconds (default: all of it)."""
    scene = Scene()
    with open(path, "rb") as f:
        reader = make_reader(f)
        until = math.inf if at is None else at * 1e9
        for schema, channel, message in reader.iter_messages(
            topics=[*SCENE_TOPICS, *JSON_TOPICS], log_time_order=True
        ):
            if scene.start is not None and message.log_time - scene.start > until:
                break
            scene.add(
                channel.topic, schema, channel.message_encoding, message.data, message.log_time
            )
    return scene


def rotation(q) -> np.ndarray:
    """Rotation matrix of quaternion (w, x, y, z)."""
    w, x, y, z = np.asarray(q, float) / (np.linalg.norm(q) or 1.0)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


# --- primitives as polygons -----------------------------------------------------------------


def _pose(pose) -> tuple[np.ndarray, np.ndarray]:
    p, q = pose.position, pose.orientation
    return np.array([p.x, p.y, p.z]), rotation([q.w, q.x, q.y, q.z])


def cube_faces(size) -> list[np.ndarray]:
    h = np.array([size.x, size.y, size.z]) / 2
    c = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return [c[list(q)] for q in quads]


def sphere_faces(size, n: int = 10) -> list[np.ndarray]:
    h = np.array([size.x, size.y, size.z]) / 2
    lat = np.linspace(-math.pi / 2, math.pi / 2, n // 2 + 1)
    lon = np.linspace(0, 2 * math.pi, n + 1)

    def point(a, b):
        return h * [math.cos(a) * math.cos(b), math.cos(a) * math.sin(b), math.sin(a)]

    faces = []
    for i in range(len(lat) - 1):
        for j in range(n):
            faces.append(
                np.array(
                    [
                        point(lat[i], lon[j]),
                        point(lat[i], lon[j + 1]),
                        point(lat[i + 1], lon[j + 1]),
                        point(lat[i + 1], lon[j]),
                    ]
                )
            )
    return faces


def cylinder_faces(size, bottom: float, top: float, n: int = 14) -> list[np.ndarray]:
    rx, ry, half = size.x / 2, size.y / 2, size.z / 2
    a = np.linspace(0, 2 * math.pi, n + 1)
    ring_b = np.stack([bottom * rx * np.cos(a), bottom * ry * np.sin(a), -half + 0 * a], 1)
    ring_t = np.stack([top * rx * np.cos(a), top * ry * np.sin(a), half + 0 * a], 1)
    faces = [np.array([ring_b[j], ring_b[j + 1], ring_t[j + 1], ring_t[j]]) for j in range(n)]
    return faces + [ring_b[:-1][::-1], ring_t[:-1]]


def entity_polygons(scene: Scene, entity) -> list[tuple[np.ndarray, tuple]]:
    """(odom-frame polygon, rgba) of every cube, sphere and cylinder of ``entity``."""
    frame = scene.pose(entity.frame_id)
    if frame is None:
        return []
    fp, fr = frame
    out = []
    shapes = [(c, cube_faces(c.size)) for c in entity.cubes]
    shapes += [(s, sphere_faces(s.size)) for s in entity.spheres]
    shapes += [(c, cylinder_faces(c.size, c.bottom_scale, c.top_scale)) for c in entity.cylinders]
    for primitive, faces in shapes:
        pp, pr = _pose(primitive.pose)
        r, t = fr @ pr, fr @ pp + fp
        col = primitive.color
        for face in faces:
            out.append((face @ r.T + t, (col.r, col.g, col.b, col.a)))
    return out


def grid_polygons(grid) -> list[tuple[np.ndarray, tuple]]:
    """Each known cell of a foxglove.Grid's ``height`` field as a flat quad coloured by height
    (turbo), as Foxglove's grid layer draws it in the grid's plane."""
    if grid is None or grid.column_count == 0 or grid.row_stride == 0:
        return []
    field = next((f for f in grid.fields if f.name == "height"), None)
    if field is None or field.type != enum_value(field, "type", "FLOAT32"):
        return []
    rows = len(grid.data) // grid.row_stride
    data = np.frombuffer(grid.data, np.uint8)
    values = np.full((rows, grid.column_count), np.nan)
    for j in range(rows):
        for i in range(grid.column_count):
            k = j * grid.row_stride + i * grid.cell_stride + field.offset
            values[j, i] = data[k : k + 4].view("<f4")[0]
    if not np.isfinite(values).any():
        return []
    lo, hi = np.nanmin(values), np.nanmax(values)
    cmap = plt.get_cmap("turbo")
    t, r = _pose(grid.pose)
    sx, sy = grid.cell_size.x, grid.cell_size.y
    out = []
    for j in range(rows):
        for i in range(grid.column_count):
            v = values[j, i]
            if not math.isfinite(v):
                continue
            quad = np.array(
                [[i * sx, j * sy, 0], [(i + 1) * sx, j * sy, 0], [(i + 1) * sx, (j + 1) * sy, 0]]
                + [[i * sx, (j + 1) * sy, 0]]
            )
            rgba = cmap(0.5 if hi <= lo else (v - lo) / (hi - lo))
            out.append((quad @ r.T + t, (*rgba[:3], 0.35)))
    return out


def shade(polygon: np.ndarray, rgba: tuple) -> tuple:
    """Lambert-ish shading of a face by its normal, so boxes and cylinders read as solids."""
    if len(polygon) < 3:
        return rgba
    n = np.cross(polygon[1] - polygon[0], polygon[2] - polygon[0])
    norm = np.linalg.norm(n)
    k = 0.6 + 0.4 * abs(float(n @ LIGHT) / norm) if norm > 0 else 0.8
    return (rgba[0] * k, rgba[1] * k, rgba[2] * k, rgba[3])


# --- the picture ----------------------------------------------------------------------------


def leg_chains(scene: Scene) -> list[np.ndarray]:
    """Each leg as the odom-frame points body → its link frames → its foot."""
    chains = []
    for foot in sorted(f for f in scene.frames if f.endswith("_foot")):
        names = [foot]
        while names[-1] in scene.frames and scene.frames[names[-1]][0] not in ("odom", ""):
            names.append(scene.frames[names[-1]][0])
        poses = [scene.pose(n) for n in reversed(names)]
        if all(p is not None for p in poses):
            chains.append(np.array([p[0] for p in poses]))
    return chains


def render(scene: Scene, output: Path, source: str) -> None:
    body = scene.pose("body")
    centre, yaw = (body[0], math.atan2(body[1][1, 0], body[1][0, 0])) if body else (np.zeros(3), 0)

    polygons = grid_polygons(scene.grid)
    for topic in ("/robot", *MAP_TOPICS):
        for entity in scene.entities[topic].values():
            polygons += entity_polygons(scene, entity)

    fig = plt.figure(figsize=(11, 7), dpi=100, facecolor="#f4f5f7")
    ax = fig.add_subplot(projection="3d", computed_zorder=False)
    ax.set_facecolor("#f4f5f7")
    if polygons:
        faces = [p for p, _ in polygons]
        colors = [shade(p, c) for p, c in polygons]
        ax.add_collection3d(
            Poly3DCollection(
                faces, facecolors=colors, edgecolors=(0, 0, 0, 0.12), linewidths=0.3, zorder=1
            )
        )
    chains = leg_chains(scene)
    for chain in chains:
        ax.plot(*chain.T, color=LEG_COLOR, lw=2.4, marker="o", ms=3.2, zorder=3)
    if body is not None:
        for axis, col in zip(body[1].T, ("#d62728", "#2ca02c", "#1f77b4"), strict=True):
            ax.plot(*np.stack([centre, centre + 0.12 * axis]).T, color=col, lw=2, zorder=4)

    # a cube around the robot and what is near it, equal scale on every axis
    points = np.concatenate([p for p, _ in polygons] + chains + [centre[None]])
    near = points[np.linalg.norm(points[:, :2] - centre[:2], axis=1) < 1.5]
    lo, hi = near.min(0), near.max(0)
    mid, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 0.3)
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(max(lo[2] - 0.02, mid[2] - half), max(lo[2] - 0.02, mid[2] - half) + half)
    ax.set_box_aspect((2, 2, 1), zoom=1.08)
    ax.view_init(elev=32, azim=math.degrees(yaw) + 180 + 28)
    ax.set_xlabel("x (m, odom)", labelpad=2)
    ax.set_ylabel("y (m, odom)", labelpad=2)
    ax.set_zlabel("z (m)", labelpad=2)
    ax.tick_params(labelsize=7, pad=0)
    for pane in (ax.xaxis.pane, ax.yaxis.pane, ax.zaxis.pane):
        pane.set_facecolor((0.9, 0.91, 0.93, 1.0))

    mode = scene.mode["mode"] if scene.mode else "?"
    rate = scene.health["loop"]["rate_hz"] if scene.health else None
    elapsed = ((scene.time - scene.start) / 1e9) if scene.start is not None else 0.0
    loop = f", control loop {rate:.0f} Hz" if isinstance(rate, (int, float)) else ""
    fig.suptitle(
        f"climbd view: the recorded scene at t = {elapsed:.1f} s (mode {mode}{loop})",
        fontsize=13,
        y=0.965,
    )
    counts = ", ".join(
        f"{t} {len(scene.entities[t])}" for t in ("/robot", *MAP_TOPICS) if scene.entities[t]
    )
    fig.text(
        0.5,
        0.018,
        f"Rendered by docs/view_screenshot.py from {source}: {len(scene.frames)} frames "
        f"from /tf; entities {counts}.\nA rendering of the recorded scene, not a capture of "
        "Foxglove.",
        ha="center",
        fontsize=8,
        color="#444",
    )
    handles = [
        Line2D([], [], color=LEG_COLOR, lw=2.4, marker="o", ms=3, label="legs: /tf chains"),
        Patch(color=(0.55, 0.6, 0.7), label="/robot links, feet, camera"),
        Patch(color=(0.0, 0.8, 0.0), label="confidence 1 (/joists /stairs /truss /holds)"),
        Patch(color=(1.0, 1.0, 0.0), label="confidence 0.5"),
        Patch(color=(1.0, 0.0, 0.0), label="confidence 0"),
        Patch(color=(0.6, 0.6, 0.6), label="truss nodes"),
        Patch(color=plt.get_cmap("turbo")(0.2), alpha=0.5, label="/elevation, by height"),
    ]
    ax.legend(
        handles=handles, loc="upper left", bbox_to_anchor=(0.0, 0.93), fontsize=8, framealpha=0.85
    )
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.07, top=0.95)
    output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(output, dpi=100, facecolor=fig.get_facecolor())
    plt.close(fig)


# --- making a recording ---------------------------------------------------------------------


def demo_maps(floor: float) -> list:
    """One of each map, as a perception role's world model publishes them, on a floor at
    height ``floor`` (odom): two joists across the way ahead with holds on their tops, a flight
    of three steps on the left, a truss bay on the right, and an elevation grid of the floor
    and the joist tops."""
    from climbd.daemon.contract import messages as m

    f = floor
    joists = [
        m.MappedJoist(id=1, confidence=0.95, seen=12, age=0.0, heading=0.0, offset=0.35,
                      height=0.1, endpoints=[[0.35, -0.4, f + 0.1], [0.35, 0.4, f + 0.1]]),
        m.MappedJoist(id=2, confidence=0.55, seen=3, age=0.0, heading=0.0, offset=0.7,
                      height=0.1, endpoints=[[0.7, -0.35, f + 0.1], [0.7, 0.3, f + 0.1]]),
    ]  # fmt: skip
    holds = [
        m.MappedHold(id=i, confidence=c, seen=2, age=0.0, position=[x, y, f + 0.1])
        for i, (x, y, c) in enumerate([(0.37, -0.2, 0.9), (0.37, 0.12, 0.6), (0.72, 0.0, 0.25)], 1)
    ]
    steps = [
        m.MappedStair(id=k + 1, confidence=c, seen=4, age=0.0, height=f + 0.07 * (k + 1),
                      rise=0.07, depth=0.18,
                      edge=[[0.2 + 0.18 * k, 0.72, f + 0.07 * (k + 1)],
                            [0.2 + 0.18 * k, 0.45, f + 0.07 * (k + 1)]])
        for k, c in enumerate((1.0, 0.8, 0.4))
    ]  # fmt: skip
    y = -0.55
    foot0, top0, foot1, top1 = (0.3, y, f), (0.3, y, f + 0.5), (0.8, y, f), (0.8, y, f + 0.5)
    ends = {1: (foot0, top0), 2: (foot1, top1), 3: (top0, top1), 4: (foot0, top1)}
    conf = {1: 0.95, 2: 0.7, 3: 0.85, 4: 0.3}
    members = [
        m.TrussMember(p0=list(a), p1=list(b), radius=0.015, axis=[0, 0, 1], confidence=conf[i],
                      id=i)
        for i, (a, b) in ends.items()
    ]  # fmt: skip
    nodes = [
        m.TrussNode(position=list(ends[1][0]), members=[1, 4]),
        m.TrussNode(position=list(ends[1][1]), members=[1, 3]),
        m.TrussNode(position=list(ends[2][1]), members=[2, 3, 4]),
        m.TrussNode(position=list(ends[2][0]), members=[2]),
    ]
    res, rows, cols, ox, oy = 0.04, 28, 20, -0.2, -0.4
    x = ox + res * (np.arange(rows) + 0.5)
    heights = np.zeros((rows, cols), "<f4")
    for top in (0.35, 0.7):
        heights[(x >= top - 0.02) & (x <= top + 0.06), :] = 0.1
    heights[x > 0.85, :] = np.nan  # behind the far joist: not seen
    grid = m.ElevationGrid(rows=rows, cols=cols, resolution=res, origin_x=ox, origin_y=oy,
                           frame_position=[0.0, 0.0, f], heights=heights.tobytes())  # fmt: skip
    return [
        m.JoistMap(joists=joists),
        m.HoldMap(holds=holds),
        m.StairMap(steps=steps),
        m.TrussMembers(members=members, nodes=nodes),
        grid,
    ]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _climbd(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "climbd.daemon.cli", *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def make_recording(out: Path, seconds: float) -> None:
    """``climbd record --scene`` of the fake-driver WidowX standing and ``demo_maps`` on the
    floor under its feet (its estimated body height less the profile's stand height)."""
    import zenoh

    from climbd.daemon.contract import messages as m
    from climbd.daemon.contract import profile as profiles

    stand = profiles.load(ROOT / "robots/widowx.toml").stand.body_height
    endpoint, maps_ep = (f"tcp/127.0.0.1:{_free_port()}" for _ in range(2))
    robot = _climbd(
        "run", "--profile", "robots/widowx.toml", "--driver", "fake", "--listen", endpoint,
        "--quiet",
    )  # fmt: skip
    cfg = zenoh.Config()
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("listen/endpoints", json.dumps([maps_ep]))
    cfg.insert_json5("connect/endpoints", json.dumps([endpoint]))
    maps = zenoh.open(cfg)
    bodies: list = []
    maps.declare_subscriber(
        m.key("widowx", m.BodyState),
        lambda sample: bodies.append(m.decode(sample.payload.to_bytes(), m.BodyState)),
    )
    rec = None
    try:
        end = time.monotonic() + 60
        while "control role" not in robot.stdout.readline():
            if robot.poll() is not None or time.monotonic() > end:
                raise SystemExit(f"climbd run did not start: {robot.stderr.read()}")
        while not bodies and time.monotonic() < end:
            time.sleep(0.05)
        floor = (bodies[-1].position[2] if bodies else 0.0) - stand
        rec = _climbd(
            "record", "--robot", "widowx", "--connect", endpoint, "--connect", maps_ep,
            "--scene", "--duration", str(seconds), "-o", str(out),
        )  # fmt: skip
        published = demo_maps(floor)
        end = time.monotonic() + seconds + 60
        while rec.poll() is None and time.monotonic() < end:
            for msg in published:
                maps.put(m.key("widowx", type(msg)), m.encode(msg))
            time.sleep(0.25)
        stdout, stderr = rec.communicate(timeout=30)
        if rec.returncode != 0:
            raise SystemExit(f"climbd record failed ({rec.returncode}): {stdout}{stderr}")
    finally:
        maps.close()
        for proc in (rec, robot):
            if proc is not None and proc.poll() is None:
                proc.terminate()
                proc.wait(timeout=30)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recording", nargs="?", help="MCAP written by climbd record --scene")
    parser.add_argument("--make", action="store_true", help="record one first (fake driver)")
    parser.add_argument("--seconds", type=float, default=4.0, help="with --make: its length")
    parser.add_argument("--keep", help="with --make: keep the recording at this path")
    parser.add_argument("--at", type=float, help="seconds into the recording (default: its end)")
    parser.add_argument("-o", "--output", default=str(DEFAULT_OUTPUT), help="PNG to write")
    args = parser.parse_args(argv)
    if args.make == (args.recording is not None):
        parser.error("give a recording or --make (not both)")
    with tempfile.TemporaryDirectory() as tmp:
        if args.make:
            path = Path(args.keep) if args.keep else Path(tmp) / "scene.mcap"
            make_recording(path, args.seconds)
            source = "climbd record --scene (fake-driver WidowX, demo maps)"
        else:
            path = Path(args.recording)
            source = path.name
        scene = read(path, args.at)
        if not scene.frames:
            print(
                f"error: no /tf transforms in {path} (not recorded with --scene?)", file=sys.stderr
            )
            return 1
        render(scene, Path(args.output), source)
    size = os.path.getsize(args.output)
    print(f"wrote {args.output} ({size / 1000:.0f} kB) from {sum(scene.counts.values())} messages")
    return 0


if __name__ == "__main__":
    sys.exit(main())
