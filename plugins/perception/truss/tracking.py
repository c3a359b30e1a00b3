"""The persistent truss model (issue 37 item 3): members and their nodes tracked in the
odometry frame across model updates, fused as they are seen again, split and merged.

Each model update's members are ``Sighting``s. A track keeps a weighted running mean (weights below)
of its tube ends, radius and node ends (an end's node only over the sightings that had one),
the count of its sightings and a confidence that grows with each, 1 − Π(1 − cᵢ), cᵢ a
sighting's coverage. A track the update could have seen (its middle inside the view cone of a
frame since the last update) but did not counts a miss; ``expiry`` misses in a row drop it, so
a member merely out of view is kept. Before association, a track seen as two or more collinear
parts with gaps between them splits (the longest part keeps the id) and tracks seen as one
continuous member merge (the longest keeps the id); either restarts the kept track's mean.

What is modelled each update is the whole accumulated cloud, as before, not each view alone,
and each sighting weighs its coverage times the frames its model rests on: on
``bench/truss_views.py`` (BENCHMARKS.md) after 10 noisy views the accumulated models fused so
err 0.66 % / 0.66 % in length (space frame / five members, medians of 3 seeds), against the
latest accumulated model alone 0.36 % / 0.75 % (fusing keeps the early views' poorer ends in
the mean; weighing by the square of the frames changes nothing) and each view modelled alone
and fused 1.22 % / 4.93 % (one view sees a member partly, and its shortened extents pull the
mean); per-view fusion's worst axes, 0.11° / 0.16°, against 0.18° / 0.12°.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from climbd.daemon.algorithms.tracks import Track, TrackConfig, Tracker
from climbd.daemon.contract.messages import BodyState
from climbd.plugins.perception.truss.completion import Member
from climbd.plugins.perception.truss.cylinders import Cylinder
from climbd.plugins.perception.truss.nodes import end_distance


@dataclass(frozen=True)
class Sighting:
    """One member of a model update (odometry frame, m): tube ends, radius, node ends (None:
    a free end), its confidence (the model's coverage of it) and how many frames the model
    rests on (a model of more frames weighs more in the mean)."""

    p0: np.ndarray
    p1: np.ndarray
    radius: float
    confidence: float
    node0: np.ndarray | None = None
    node1: np.ndarray | None = None
    frames: int = 1

    @classmethod
    def of(cls, member: Member, confidence: float, frames: int = 1) -> Sighting:
        """A modelled member as a sighting."""
        c = member.cylinder
        return cls(member.p0, member.p1, c.radius, confidence, member.node0, member.node1, frames)

    @property
    def ends(self) -> np.ndarray:
        """p0 and p1 stacked (6 values), the tracker's feature vector."""
        return np.concatenate([self.p0, self.p1])

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.p1 - self.p0))

    def flipped(self) -> Sighting:
        """The same member, p0 and p1 (and their nodes) swapped."""
        return Sighting(
            self.p1, self.p0, self.radius, self.confidence, self.node1, self.node0, self.frames
        )


@dataclass
class Fused:
    """A track's weighted sums (``_weight``): tube ends, radius, and each end's node with its
    own weight (nodes are not seen at every sighting)."""

    weight: float
    ends: np.ndarray
    radius: float
    nodes: np.ndarray
    node_weights: np.ndarray

    @classmethod
    def start(cls, sighting: Sighting) -> Fused:
        """The sums of a track's first sighting."""
        w = _weight(sighting)
        nodes = [sighting.node0, sighting.node1]
        node_weights = np.array([0.0 if n is None else w for n in nodes])
        node_sums = np.array([np.zeros(3) if n is None else w * n for n in nodes])
        return cls(w, w * sighting.ends, w * sighting.radius, node_sums, node_weights)

    def add(self, sighting: Sighting) -> None:
        """Add a sighting oriented like the track."""
        w = _weight(sighting)
        self.weight += w
        self.ends = self.ends + w * sighting.ends
        self.radius += w * sighting.radius
        for k, node in enumerate((sighting.node0, sighting.node1)):
            if node is not None:
                self.nodes[k] = self.nodes[k] + w * node
                self.node_weights[k] += w

    def node(self, k: int) -> np.ndarray | None:
        """End k's fused node, None if no sighting put a node there."""
        return None if self.node_weights[k] == 0 else self.nodes[k] / self.node_weights[k]


def _weight(sighting: Sighting) -> float:
    """A sighting's weight in the mean: its confidence (kept off zero) times its frames."""
    return max(float(sighting.confidence), 0.05) * sighting.frames


def oriented(sighting: Sighting, ends: np.ndarray) -> Sighting:
    """``sighting`` with its p0 at the end of ``ends`` (p0, p1 stacked) it lies nearer."""
    same = np.linalg.norm(sighting.ends - ends)
    swapped = np.linalg.norm(sighting.flipped().ends - ends)
    return sighting if same <= swapped else sighting.flipped()


def _start(track: Track, payload: object) -> None:
    """A new track's sums, from its first sighting."""
    assert isinstance(payload, Sighting)
    track.extra["fused"] = Fused.start(payload)


def _fuse(track: Track, detection: np.ndarray, gain: float, payload: object) -> None:
    """Fold a sighting into the track's weighted means (oriented like the track)."""
    assert isinstance(payload, Sighting)
    fused: Fused = track.extra["fused"]
    fused.add(oriented(payload, track.estimate))
    track.estimate = fused.ends / fused.weight


def _restart(track: Track, sighting: Sighting) -> None:
    """Restart a track's mean on one sighting (after a split or merge), keeping its id."""
    track.extra["fused"] = Fused.start(sighting)
    track.estimate = sighting.ends


def _along(ends: np.ndarray, origin: np.ndarray, axis: np.ndarray) -> tuple[float, float]:
    """The interval of a member's ends (p0, p1 stacked) along a line."""
    a, b = sorted([float((ends[:3] - origin) @ axis), float((ends[3:] - origin) @ axis)])
    return a, b


class FieldOfView:
    """Where a frame could see (odometry frame): the cone of directions its body-frame
    ``points`` span from the body at ``body``'s pose (azimuth and elevation, 1st to 99th
    percentile), out to ``max_range`` (m). Not feature_maps.ViewCone: that needs the depth
    frame's intrinsics, and ``process_cloud`` has only the points."""

    def __init__(self, points: np.ndarray, body: BodyState, max_range: float) -> None:
        self.rotation = Rotation.from_quat(body.orientation, scalar_first=True).as_matrix()
        self.origin = np.asarray(body.position, float)
        self.max_range = max_range
        azimuth, elevation, _ = _directions(points)
        if len(azimuth) == 0:
            self.bounds = np.array([[np.inf, -np.inf], [np.inf, -np.inf]])
        else:
            self.bounds = np.percentile([azimuth, elevation], [1, 99], axis=1).T

    def sees(self, positions: np.ndarray) -> np.ndarray:
        """Which odometry-frame ``positions`` (N x 3) lie in the cone and in range."""
        body = (positions - self.origin) @ self.rotation
        azimuth, elevation, distance = _directions(body)
        (a0, a1), (e0, e1) = self.bounds
        return (
            (azimuth >= a0)
            & (azimuth <= a1)
            & (elevation >= e0)
            & (elevation <= e1)
            & (distance <= self.max_range)
        )


def _directions(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Azimuth and elevation (rad) and range (m) of body-frame points."""
    points = np.asarray(points, float).reshape(-1, 3)
    flat = np.hypot(points[:, 0], points[:, 1])
    return (
        np.arctan2(points[:, 1], points[:, 0]),
        np.arctan2(points[:, 2], flat),
        np.linalg.norm(points, axis=1),
    )


class MemberTracks:
    """The truss members in the odometry frame across model updates: a member within ``gate``
    (m, end to end) of a track fuses into it; ``expiry`` updates in view without it drop it.
    Parts are collinear within ``angle_deg`` and ``line`` (m) of the other's axis; a split
    needs gaps of ``min_gap`` (m) or more between the parts."""

    def __init__(
        self,
        gate: float,
        expiry: int = 3,
        *,
        angle_deg: float = 5.0,
        line: float = 0.03,
        min_gap: float = 0.03,
    ) -> None:
        config = TrackConfig(gate=gate, max_misses=expiry, expiry=float("inf"))
        self.tracker = Tracker(config, end_distance, _fuse, _start)
        self.cos = float(np.cos(np.radians(angle_deg)))
        self.line, self.min_gap = line, min_gap

    @property
    def tracks(self) -> list[Track]:
        return self.tracker.tracks

    def update(
        self, sightings: Sequence[Sighting], stamp: float, views: Sequence[FieldOfView] = ()
    ) -> list[int]:
        """Fold one update's sightings in (split and merge first); ``views``: the frames since
        the last update (none: every track counts as in view). The sightings' ids, in order."""
        for sighting in sightings:
            self._merge(sighting)
        for track in list(self.tracks):
            self._split(track, sightings)
        in_view = None if not views else self._in_view(views)
        ends = [s.ends for s in sightings]
        confidences = [s.confidence for s in sightings]
        tracks = self.tracker.update(ends, confidences, stamp, in_view, list(sightings))
        return [t.id for t in tracks]

    def members(self) -> list[tuple[Track, Member]]:
        """Each track's fused member (tube extent, radius, nodes), with its track."""
        return [(t, fused_member(t)) for t in self.tracks]

    def _in_view(self, views: Sequence[FieldOfView]) -> Callable[[list[Track]], np.ndarray]:
        """Which tracks' middles one of ``views`` could see."""

        def visible(tracks: list[Track]) -> np.ndarray:
            middles = np.array([0.5 * (t.estimate[:3] + t.estimate[3:]) for t in tracks])
            seen = np.zeros(len(tracks), bool)
            for view in views:
                seen |= view.sees(middles.reshape(-1, 3))
            return seen

        return visible

    def _parts(self, ends: np.ndarray, candidates: Sequence[np.ndarray]) -> list[int]:
        """Indices of ``candidates`` (ends stacked) collinear with ``ends`` and lying mostly
        (more than half their length) within its extent."""
        origin, axis = ends[:3], ends[3:] - ends[:3]
        length = float(np.linalg.norm(axis))
        axis = axis / length
        parts = []
        for k, other in enumerate(candidates):
            direction = other[3:] - other[:3]
            size = float(np.linalg.norm(direction))
            if size == 0 or abs(direction @ axis) / size < self.cos:
                continue
            off = [np.linalg.norm(np.cross(p - origin, axis)) for p in (other[:3], other[3:])]
            if max(off) > self.line:
                continue
            a, b = _along(other, origin, axis)
            if min(b, length) - max(a, 0.0) > 0.5 * size:
                parts.append(k)
        return parts

    def _covers_alone(self, ends: np.ndarray, candidates: Sequence[np.ndarray]) -> bool:
        gate = self.tracker.config.gate
        return any(end_distance(ends, c) <= gate for c in candidates)

    def _merge(self, sighting: Sighting) -> None:
        """Tracks seen as parts of one continuous member merge into the longest of them."""
        estimates = [t.estimate for t in self.tracks]
        parts = self._parts(sighting.ends, estimates)
        if len(parts) < 2 or self._covers_alone(sighting.ends, [estimates[k] for k in parts]):
            return
        merged = [self.tracks[k] for k in parts]
        keeper = max(merged, key=lambda t: np.linalg.norm(t.estimate[3:] - t.estimate[:3]))
        _restart(keeper, oriented(sighting, keeper.estimate))
        self.tracker.tracks = [t for t in self.tracks if t is keeper or t not in merged]

    def _split(self, track: Track, sightings: Sequence[Sighting]) -> None:
        """A track seen as collinear parts with gaps between them keeps the longest part; the
        others start tracks of their own at association."""
        ends = [s.ends for s in sightings]
        parts = self._parts(track.estimate, ends)
        if len(parts) < 2 or self._covers_alone(track.estimate, [ends[k] for k in parts]):
            return
        origin = track.estimate[:3]
        axis = track.estimate[3:] - origin
        axis = axis / np.linalg.norm(axis)
        spans = sorted(_along(ends[k], origin, axis) for k in parts)
        gaps = [b[0] - a[1] for a, b in zip(spans[:-1], spans[1:], strict=True)]
        if min(gaps) < self.min_gap:
            return
        longest = max((sightings[k] for k in parts), key=lambda s: s.length)
        _restart(track, oriented(longest, track.estimate))


def fused_member(track: Track) -> Member:
    """A track's fused estimate as a member: tube extent p0 -> p1, mean radius, fused nodes."""
    fused: Fused = track.extra["fused"]
    p0, p1 = track.estimate[:3], track.estimate[3:]
    length = float(np.linalg.norm(p1 - p0))
    cylinder = Cylinder(p0, (p1 - p0) / length, fused.radius / fused.weight)
    return Member(cylinder, 0.0, length, np.zeros(0, int), 1, fused.node(0), fused.node(1))
