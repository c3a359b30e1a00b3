"""Identities and connectors of the truss model (paper 003), across model updates.

The modeller rebuilds the whole truss from the accumulated cloud at each update, so a member
comes back with other end points and in another order each time; ``MemberTracks`` gives it the
id it had (the least end-to-end distance, either way round, within a gate). ``connectors``
finds the nodes: where the ends of two or more members meet.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from climbd.daemon.algorithms.tracks import Track, TrackConfig, Tracker
from climbd.daemon.contract.messages import TrussNode
from climbd.plugins.perception.truss.completion import Member


def end_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Largest end-to-end distance (m) of two members (p0, p1 stacked: 6 values), matching
    their ends either way round."""
    same = max(np.linalg.norm(a[:3] - b[:3]), np.linalg.norm(a[3:] - b[3:]))
    flipped = max(np.linalg.norm(a[:3] - b[3:]), np.linalg.norm(a[3:] - b[:3]))
    return float(min(same, flipped))


def latest(track: Track, seen: np.ndarray, gain: float, payload: object) -> None:
    """A member's estimate is the latest model's: the modeller already used every frame."""
    track.estimate = seen


class MemberTracks:
    """Member ids across model updates: a member of the new model within ``gate`` (m, end to
    end) of one of the last model keeps its id; one the new model lacks is dropped."""

    def __init__(self, gate: float) -> None:
        config = TrackConfig(gate=gate, memory=1.0, max_misses=1)
        self.tracker = Tracker(config, end_distance, latest)

    def update(self, members: Sequence[Member], stamp: float) -> list[int]:
        """The ids of ``members``, in their order."""
        ends = [np.concatenate([m.p0, m.p1]) for m in members]
        return [t.id for t in self.tracker.update(ends, [1.0] * len(ends), stamp)]


def connectors(members: Sequence[Member], ids: Sequence[int], radius: float) -> list[TrussNode]:
    """The nodes of the truss: groups of member ends within ``radius`` (m) of one another
    (linked through any chain of ends), of two or more members; at the mean of those ends."""
    ends = np.array([p for m in members for p in (m.p0, m.p1)], float).reshape(-1, 3)
    owner = np.repeat(np.asarray(ids, int), 2)
    parent = list(range(len(ends)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    close = np.linalg.norm(ends[:, None] - ends[None, :], axis=2) <= radius
    for i, j in zip(*np.nonzero(np.triu(close, 1)), strict=True):
        parent[root(int(i))] = root(int(j))
    groups: dict[int, list[int]] = {}
    for i in range(len(ends)):
        groups.setdefault(root(i), []).append(i)
    nodes = []
    for group in groups.values():
        joined = sorted({int(owner[i]) for i in group})
        if len(joined) >= 2:
            nodes.append(TrussNode(position=ends[group].mean(axis=0).tolist(), members=joined))
    return nodes
