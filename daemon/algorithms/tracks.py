"""Features tracked across frames: identities, fused estimates, confidence, misses and expiry.

Each frame's detections (already in the odometry frame) are associated with the tracks one to
one by the least total distance within a gate (Hungarian assignment); a matched track's estimate
moves toward the detection by 1/n of the difference (a running mean over its last ``memory``
sightings) and its confidence combines the sightings' as independent evidence,
1 − Π(1 − cᵢ); an unmatched detection starts a track. A track that was in the camera's view
but not detected counts a miss; ``max_misses`` misses in a row, or ``expiry`` seconds unseen,
drop it, and at most ``max_tracks`` are kept (the least confident go first), so the map is
bounded however long the robot runs.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import msgspec
import numpy as np
from scipy.optimize import linear_sum_assignment

from climbd.daemon.contract.units import Positive

Distance = Callable[[np.ndarray, np.ndarray], float]
"""Distance between a track's estimate and a detection (both feature vectors), in gate units."""


class TrackConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Association gate (in the distance's units), memory, misses, expiry (s), bound."""

    gate: Positive = 0.05
    memory: Positive = 20.0
    max_misses: int = 5
    expiry: Positive = 600.0
    max_tracks: int = 500

    def __post_init__(self) -> None:
        if self.max_misses < 1 or self.max_tracks < 1:
            raise ValueError("track config: max_misses and max_tracks must be >= 1")


@dataclass
class Track:
    """One feature across frames: its fused estimate and what it rests on."""

    id: int
    estimate: np.ndarray
    confidence: float
    seen: int = 1
    misses: int = 0
    first_seen: float = 0.0
    last_seen: float = 0.0
    extra: dict = field(default_factory=dict)
    """Kind-specific state a fuse step keeps (e.g. a joist's extent along its line)."""


Fuse = Callable[[Track, np.ndarray, float, object], None]
"""Moves a track's estimate toward a detection, given the running-mean gain (1/n) and the
detection's payload (what a kind keeps beside its vector, e.g. a joist's seen edge)."""
Start = Callable[[Track, object], None]
"""Sets up a new track's kind-specific state from its first detection's payload."""


def mean_fuse(track: Track, detection: np.ndarray, gain: float, payload: object) -> None:
    """The running mean: estimate += gain · (detection − estimate)."""
    track.estimate = track.estimate + gain * (detection - track.estimate)


def no_start(track: Track, payload: object) -> None:
    """Kinds with nothing beside their vector."""


def euclidean(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b))


class Tracker:
    """The tracks of one feature kind in the odometry frame."""

    def __init__(
        self,
        config: TrackConfig | None = None,
        distance: Distance = euclidean,
        fuse: Fuse = mean_fuse,
        start: Start = no_start,
    ) -> None:
        self.config = config or TrackConfig()
        self.distance = distance
        self.fuse = fuse
        self.start = start
        self.tracks: list[Track] = []
        self._next_id = 1

    def update(
        self,
        detections: Sequence[np.ndarray],
        confidences: Sequence[float],
        stamp: float,
        in_view: Callable[[list[Track]], np.ndarray] | None = None,
        payloads: Sequence[object] | None = None,
    ) -> list[Track]:
        """Fold one frame's detections in; ``in_view`` marks the tracks the frame could have
        seen (None: all); ``payloads`` go with the detections to ``start`` and ``fuse``.
        Returns the tracks each detection went to, in detection order."""
        c = self.config
        matched = self._associate(detections)
        extras = payloads if payloads is not None else [None] * len(detections)
        out: list[Track] = []
        hit: set[int] = set()
        rows = zip(detections, confidences, extras, strict=True)
        for k, (detection, confidence, payload) in enumerate(rows):
            track = matched.get(k)
            conf = min(max(float(confidence), 0.0), 1.0)
            if track is None:
                track = Track(self._next_id, np.asarray(detection, float), conf, 1, 0, stamp, stamp)
                self.start(track, payload)
                self._next_id += 1
                self.tracks.append(track)
            else:
                track.seen += 1
                gain = 1.0 / min(track.seen, c.memory)
                self.fuse(track, np.asarray(detection, float), gain, payload)
                track.confidence = 1.0 - (1.0 - track.confidence) * (1.0 - conf)
                track.misses = 0
                track.last_seen = stamp
            hit.add(track.id)
            out.append(track)
        visible = in_view(self.tracks) if in_view is not None else np.ones(len(self.tracks), bool)
        for track, seen in zip(self.tracks, visible, strict=True):
            if seen and track.id not in hit:
                track.misses += 1
        self.tracks = [
            t for t in self.tracks if t.misses < c.max_misses and stamp - t.last_seen <= c.expiry
        ]
        if len(self.tracks) > c.max_tracks:
            self.tracks.sort(key=lambda t: (t.confidence, t.last_seen), reverse=True)
            del self.tracks[c.max_tracks :]
        return out

    def _associate(self, detections: Sequence[np.ndarray]) -> dict[int, Track]:
        """Detection index → track, one to one, least total distance within the gate."""
        if not self.tracks or not len(detections):
            return {}
        gate = self.config.gate
        cost = np.array(
            [
                [self.distance(t.estimate, np.asarray(d, float)) for t in self.tracks]
                for d in detections
            ]
        )
        big = gate * 1e3 + 1.0
        cost = np.where(np.isfinite(cost) & (cost <= gate), cost, big)
        rows, cols = linear_sum_assignment(cost)
        pairs = zip(rows, cols, strict=True)
        return {int(r): self.tracks[int(k)] for r, k in pairs if cost[r, k] <= gate}


def wrap(angle: float) -> float:
    """``angle`` in (−π, π]."""
    return math.atan2(math.sin(angle), math.cos(angle))
