"""The world model's feature maps: holds, joists and stair steps tracked across frames in the
odometry frame; the truss's grasp targets join the holds.

A perception plugin reports what one frame showed, in the body frame at the frame's time; the
feature carries that pose (``frame_position``, ``frame_orientation``), so here it is placed in
the odometry frame and folded into its tracks (``tracks``). A track the frame could have seen
(inside the camera's view cone and range) but did not counts a miss, so what the camera looks
away from is kept and what it looks at and no longer finds is dropped.
"""

from __future__ import annotations

import math

import numpy as np

from climbd.daemon.algorithms.tracks import Track, TrackConfig, Tracker, wrap
from climbd.daemon.contract.geometry import rotation, yaw
from climbd.daemon.contract.hardware import DepthFrame
from climbd.daemon.contract.messages import (
    BodyState,
    GraspablePoints,
    HoldMap,
    Joist,
    JoistMap,
    Joists,
    MappedHold,
    MappedJoist,
    MappedStair,
    Stair,
    StairMap,
    Stairs,
    TrussGrasps,
)

JOIST_MEMORY = 4.0
"""Sightings a joist's estimate averages over. A joist is a landmark in the odometry frame,
which drifts (2-5 cm over a crossing when feet slip); a behaviour localises on it, so the
map must follow the frame within a fraction of a second (4 frames: 0.4 s at 10 Hz), not
smooth the drift away over seconds. The detector's own noise is millimetres."""

LEVER = 0.3
"""m: a joist heading difference counts as this lever times its radians in the gate."""

OCCLUSION = 0.03
"""m: a pixel's return this much nearer than a point hides it (a gripper over a hold; the
depth noise at a hold's range is millimetres)."""
RING = ((0.0, 0.0),) + tuple(
    (math.cos(a), math.sin(a)) for a in np.linspace(0.0, 2.0 * math.pi, 8, endpoint=False)
)
"""Pixel directions ``ViewCone.visible`` looks along: the point's own, then eight around it."""
HOLD_FOOTPRINT = 0.02
"""m: the ground around a hold its detection looks at (a palm's radius, 1.6 cm, rounded up): a
hold whose footprint a frame did not see whole (a gripper's cut pixels beside it, a hole, the
image's edge) is hidden from that frame, not missed by it."""


def to_odometry(points: np.ndarray, position: list[float], orientation: list[float]) -> np.ndarray:
    """Body-frame points (N×3) placed in the odometry frame by the pose they were seen in."""
    return np.asarray(points, float).reshape(-1, 3) @ rotation(orientation).T + position


def to_body(points: np.ndarray, body: BodyState) -> np.ndarray:
    """Odometry-frame points (N×3) in the body frame of ``body``: ``to_odometry`` undone."""
    offset = np.asarray(points, float).reshape(-1, 3) - body.position
    return offset @ rotation(body.orientation)


def joists_seen_from(joists: JoistMap, body: BodyState) -> list[Joist]:
    """The map's joists as joist perception would report them from ``body`` (paper 000): body
    frame, the normal turned to point ahead, the distance along the heading where the line
    crosses the path (the nearest edge point to y = 0), nearest first."""
    out = []
    heading = yaw(body.orientation)
    for joist in joists.joists:
        ends = to_body(joist.endpoints, body)
        psi = wrap(joist.heading - heading)
        if math.cos(psi) < 0.0:
            psi = wrap(psi + math.pi)
        n = np.array([math.cos(psi), math.sin(psi)])
        if abs(n[0]) < 1e-6:
            continue  # along the path: it never crosses it
        ys = np.sort(ends[:, 1])
        y_path = min(max(0.0, ys[0]), ys[1])
        distance = (float(n @ ends[0, :2]) - n[1] * y_path) / n[0]
        out.append(
            Joist(
                distance=float(distance),
                yaw=psi,
                height=joist.height,
                endpoints=ends.tolist(),
                confidence=joist.confidence,
            )
        )
    return sorted(out, key=lambda j: j.distance)


class ViewCone:
    """Which odometry-frame points a frame could have seen: inside its image, in front of the
    lens and within ``max_range``; ``visible`` also asks whether the frame saw the place."""

    def __init__(
        self, frame: DepthFrame, position: list[float], orientation: list[float], max_range: float
    ) -> None:
        body_to_odom = np.eye(4)
        body_to_odom[:3, :3] = rotation(orientation)
        body_to_odom[:3, 3] = position
        self._odom_to_camera = np.linalg.inv(body_to_odom @ frame.extrinsics)
        self.intrinsics = frame.intrinsics
        self.max_range = max_range
        self._depth = frame.depth
        self._scale = frame.depth_scale

    def _project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel column, row and depth (m) of each point."""
        p = np.asarray(points, float).reshape(-1, 3)
        cam = p @ self._odom_to_camera[:3, :3].T + self._odom_to_camera[:3, 3]
        z = cam[:, 2]
        k = self.intrinsics
        with np.errstate(divide="ignore", invalid="ignore"):
            return k.fx * cam[:, 0] / z + k.ppx, k.fy * cam[:, 1] / z + k.ppy, z

    def _inside(self, u: np.ndarray, v: np.ndarray, z: np.ndarray) -> np.ndarray:
        k = self.intrinsics
        return (
            (z > 0) & (z <= self.max_range) & (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)
        )

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Inside the image, in front of the lens, within range (no occlusion test: a hidden
        feature may count a miss)."""
        return self._inside(*self._project(points))

    def visible(self, points: np.ndarray, footprint: float = 0.0) -> np.ndarray:
        """Contained, and the frame saw the place: its pixel, and the pixels ``footprint`` (m)
        around it on a ring, have returns (not holes, not a leg the self filter cut out, not off
        the image) no nearer than ``OCCLUSION`` (plus ``footprint`` on the ring) in front of the
        point. A hold under or beside a swinging gripper is hidden, not missed."""
        u, v, z = self._project(points)
        seen = self._inside(u, v, z)
        at = np.flatnonzero(seen)
        k, rows, cols = self.intrinsics, *self._depth.shape
        reach = footprint * k.fx / z[at]
        for du, dv in RING if footprint > 0.0 else RING[:1]:
            uu = np.round(u[at] + du * reach).astype(int)
            vv = np.round(v[at] + dv * reach).astype(int)
            on = (uu >= 0) & (uu < cols) & (vv >= 0) & (vv < rows)
            depth = np.zeros(len(at))
            depth[on] = self._depth[vv[on], uu[on]] * self._scale
            slack = OCCLUSION + (footprint if du or dv else 0.0)
            seen[at] &= (depth > 0) & (depth >= z[at] - slack)
        return seen


def hold_tracking() -> TrackConfig:
    """Holds: a 2 cm gate (a palm's radius is 1.6 cm: two holds are never closer)."""
    return TrackConfig(gate=0.02)


def joist_tracking() -> TrackConfig:
    """Joists: an 8 cm gate (two joists are 40 cm apart) over ``JOIST_MEMORY`` sightings."""
    return TrackConfig(gate=0.08, memory=JOIST_MEMORY)


def stair_tracking() -> TrackConfig:
    """Stair steps: a 5 cm gate (steps are ≥ 10 cm apart in rise) over ``JOIST_MEMORY``."""
    return TrackConfig(gate=0.05, memory=JOIST_MEMORY)


class HoldTracks:
    """Graspable points tracked in 3-D; each keeps its height."""

    def __init__(self, config: TrackConfig | None = None) -> None:
        self.tracker = Tracker(config or hold_tracking())

    def update(self, seen: GraspablePoints, cone: ViewCone | None, confidence: float = 0.5) -> None:
        """Fold one frame's graspable points in (``confidence`` per sighting: the detector
        gives none)."""
        points = to_odometry(seen.points, seen.frame_position, seen.frame_orientation)
        in_view = (
            None if cone is None else (lambda ts: cone.visible(_estimates(ts), HOLD_FOOTPRINT))
        )
        self.tracker.update(list(points), [confidence] * len(points), seen.frame_stamp, in_view)

    def offer(self, grasps: TrussGrasps, cone: ViewCone | None, confidence: float = 0.5) -> None:
        """Fold the truss's grasp targets in as holds (``grasp_holds``), so a gripper-equipped
        limb may take a member as a hold."""
        points = grasp_holds(grasps)
        in_view = (
            None if cone is None else (lambda ts: cone.visible(_estimates(ts), HOLD_FOOTPRINT))
        )
        self.tracker.update(list(points), [confidence] * len(points), grasps.frame_stamp, in_view)

    def message(self, stamp: float, now: float) -> HoldMap:
        return HoldMap(
            stamp=stamp,
            frame_stamp=now,
            holds=[
                MappedHold(
                    id=t.id,
                    position=t.estimate.tolist(),
                    confidence=t.confidence,
                    seen=t.seen,
                    age=now - t.last_seen,
                )
                for t in self.tracker.tracks
            ],
        )


def grasp_holds(grasps: TrussGrasps) -> np.ndarray:
    """The truss's grasp targets as hold positions (N x 3, odometry frame, heights kept): each
    its point on the member's axis, where the gripper's centre closes."""
    return np.array([g.position for g in grasps.grasps], float).reshape(-1, 3)


def _estimates(tracks: list[Track]) -> np.ndarray:
    return np.array([t.estimate for t in tracks]).reshape(-1, 3)


def _line_distance(track: np.ndarray, seen: np.ndarray) -> float:
    """Gate distance of two edge lines (offset, heading, height, …): either normal direction."""
    same = abs(track[0] - seen[0]) + LEVER * abs(wrap(track[1] - seen[1]))
    flipped = abs(track[0] + seen[0]) + LEVER * abs(wrap(track[1] - seen[1] - math.pi))
    return min(same, flipped) + abs(track[2] - seen[2])


def _extent(heading: float, edge: np.ndarray) -> tuple[float, float]:
    """Where an edge's ends lie along a line of normal ``heading`` (m, signed)."""
    tangent = np.array([-math.sin(heading), math.cos(heading)])
    s = edge[:, :2] @ tangent
    return float(s.min()), float(s.max())


def _line_start(track: Track, edge: object) -> None:
    track.extra["extent"] = _extent(track.estimate[1], np.asarray(edge))


def _line_fuse(track: Track, seen: np.ndarray, gain: float, edge: object) -> None:
    """Running mean of offset, heading (on the circle) and the rest (height, edge z, …), in the
    track's own normal direction; the edge's extent along the line grows to cover what was
    seen."""
    offset, heading = seen[:2]
    if abs(wrap(heading - track.estimate[1])) > math.pi / 2:
        offset, heading = -offset, wrap(heading + math.pi)
    c, h = track.estimate[:2]
    rest = track.estimate[2:] + gain * (seen[2:] - track.estimate[2:])
    track.estimate = np.array([c + gain * (offset - c), wrap(h + gain * wrap(heading - h)), *rest])
    lo, hi = track.extra["extent"]
    s0, s1 = _extent(track.estimate[1], np.asarray(edge))
    track.extra["extent"] = (min(lo, s0), max(hi, s1))


def _line(edge: np.ndarray, heading: float) -> tuple[float, np.ndarray]:
    """Offset of an edge's line of normal ``heading`` (n·p), and the edge's mean point."""
    middle = edge.mean(axis=0)
    return float(np.array([math.cos(heading), math.sin(heading)]) @ middle[:2]), middle


class JoistTracks:
    """Joists tracked as lines in the odometry frame."""

    def __init__(self, config: TrackConfig | None = None) -> None:
        config = config or joist_tracking()
        self.tracker = Tracker(config, _line_distance, _line_fuse, _line_start)

    def update(self, seen: Joists, cone: ViewCone | None) -> None:
        """Fold one frame's joists in."""
        heading0 = yaw(seen.frame_orientation)
        vectors, confidences, edges = [], [], []
        for joist in seen.joists:
            edge = to_odometry(joist.endpoints, seen.frame_position, seen.frame_orientation)
            heading = wrap(joist.yaw + heading0)
            offset, middle = _line(edge, heading)
            vectors.append(np.array([offset, heading, joist.height, middle[2]]))
            confidences.append(joist.confidence)
            edges.append(edge)
        in_view = None if cone is None else (lambda ts: cone.contains(_line_middles(ts)))
        self.tracker.update(vectors, confidences, seen.frame_stamp, in_view, edges)

    def message(self, stamp: float, now: float) -> JoistMap:
        return JoistMap(
            stamp=stamp,
            frame_stamp=now,
            joists=[_mapped_joist(t, now) for t in self.tracker.tracks],
        )


class StairTracks:
    """Stair steps (paper 004) tracked by their edges, as lines in the odometry frame; the
    normal points up the flight, so a step seen again from anywhere is the same line."""

    def __init__(self, config: TrackConfig | None = None) -> None:
        config = config or stair_tracking()
        self.tracker = Tracker(config, _line_distance, _line_fuse, _line_start)

    def update(self, seen: Stairs, cone: ViewCone | None) -> None:
        """Fold one frame's steps in (already in the odometry frame, edges left then right)."""
        vectors, edges = [], []
        for step in seen.steps:
            edge = np.asarray(step.edge, float).reshape(-1, 3)
            if len(edge) < 2:
                continue
            right = edge[-1, :2] - edge[0, :2]  # left end to right end
            heading = math.atan2(right[0], -right[1])  # turned a quarter left: up the flight
            offset, middle = _line(edge, heading)
            top = [step.height, middle[2], step.rise, step.depth]
            vectors.append(np.array([offset, heading, *top]))
            edges.append(edge)
        in_view = None if cone is None else (lambda ts: cone.contains(_line_middles(ts)))
        self.tracker.update(vectors, [1.0] * len(vectors), seen.frame_stamp, in_view, edges)

    def message(self, stamp: float, now: float) -> StairMap:
        tracks = sorted(self.tracker.tracks, key=lambda t: t.estimate[2])
        return StairMap(stamp=stamp, frame_stamp=now, steps=[_mapped_stair(t, now) for t in tracks])


def flight(stairs: StairMap) -> Stairs:
    """The stair map as one flight, bottom step first, for a behaviour's stair model."""
    steps = [Stair(height=s.height, rise=s.rise, depth=s.depth, edge=s.edge) for s in stairs.steps]
    return Stairs(stamp=stairs.stamp, frame_stamp=stairs.frame_stamp, steps=steps)


def _edge(track: Track) -> list[list[float]]:
    """The tracked edge's two ends (x, y, z), odometry frame, in the tangent's direction (for a
    stair, right end then left)."""
    offset, heading, _, z = track.estimate[:4]
    normal = np.array([math.cos(heading), math.sin(heading)])
    tangent = np.array([-normal[1], normal[0]])
    lo, hi = track.extra["extent"]
    return [[*(offset * normal + s * tangent).tolist(), float(z)] for s in (lo, hi)]


def _line_middles(tracks: list[Track]) -> np.ndarray:
    return np.array([np.mean(_edge(t), axis=0) for t in tracks]).reshape(-1, 3)


def _mapped_stair(track: Track, now: float) -> MappedStair:
    _, _, height, _, rise, depth = track.estimate
    return MappedStair(
        id=track.id,
        height=float(height),
        rise=float(rise),
        depth=float(depth),
        edge=[[float(v) for v in e] for e in reversed(_edge(track))],
        confidence=track.confidence,
        seen=track.seen,
        age=now - track.last_seen,
    )


def _mapped_joist(track: Track, now: float) -> MappedJoist:
    offset, heading, height, _ = track.estimate
    return MappedJoist(
        id=track.id,
        heading=float(heading),
        offset=float(offset),
        height=float(height),
        endpoints=[[float(v) for v in e] for e in _edge(track)],
        confidence=track.confidence,
        seen=track.seen,
        age=now - track.last_seen,
    )
