"""The paper's completion: sliding bounding boxes (eq. 2), projection on the axis (eq. 3), the
gap rule for new end points (steps 1-8, Algorithm 1), and merging split pieces of one member.

The gap rule of step 7 comes in two forms (``GapRule``): the paper's relative threshold
G_j >= (G_max / G_min) * ε, and ours (the default), an absolute threshold in metres. Ours
differs because the paper's ratio hangs on G_min, the smallest gap between two projections,
which on a dense cloud is near zero and varies from box to box.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from climbd.plugins.perception.truss.cylinders import Cylinder, Segment, perpendicular_basis


@dataclass(frozen=True)
class Member:
    """A modelled member: its cylinder, axial extent [t0, t1] from ``cylinder.point`` (the tube
    extent), and the indices of the points supporting it (segment points plus completion
    points). ``node0``/``node1``: the nodes its p0/p1 ends meet (None: the end is free)."""

    cylinder: Cylinder
    t0: float
    t1: float
    indices: np.ndarray
    pieces: int = 1
    node0: np.ndarray | None = None
    node1: np.ndarray | None = None

    @property
    def p0(self) -> np.ndarray:
        return self.cylinder.point + self.t0 * self.cylinder.axis

    @property
    def p1(self) -> np.ndarray:
        return self.cylinder.point + self.t1 * self.cylinder.axis

    @property
    def length(self) -> float:
        return self.t1 - self.t0

    @property
    def ends(self) -> tuple[np.ndarray, np.ndarray]:
        """Node-to-node ends: the nodes, or the tube ends where an end is free."""
        return (
            self.p0 if self.node0 is None else self.node0,
            self.p1 if self.node1 is None else self.node1,
        )

    @property
    def node_length(self) -> float:
        """Node-to-node length (axis to axis through the nodes)."""
        a, b = self.ends
        return float(np.linalg.norm(b - a))


def from_segment(segment: Segment) -> Member:
    """A member exactly as RANSAC segmented it (the initial model, before completion)."""
    return Member(segment.cylinder, segment.t0, segment.t1, segment.indices)


def _box_coordinates(points: np.ndarray, cylinder: Cylinder) -> np.ndarray:
    """Points in the member's frame: (along the axis, along u, along v)."""
    frame = np.array([cylinder.axis, *perpendicular_basis(cylinder.axis)])
    return points @ frame.T - frame @ cylinder.point


GapRule = Literal["paper", "absolute"]
"""Step 7's threshold: the paper's (G_max / G_min) * ε, or ours, an absolute gap (m)."""


def gap_reach(distances: np.ndarray, gap: float) -> tuple[float, bool]:
    """Steps 2-7, ours: from the end e, walk the points projected on the axis in order of their
    distance D_j to e; the member stops before the first gap G_j >= ``gap`` (G_0 = D_min).

    An absolute threshold, not the paper's relative (G_max / G_min) * ε of step 7: a gap in
    metres means the same in every box, whatever its smallest gap.

    Returns the distance from e to the new end point and whether no such gap was found.
    """
    d = np.sort(distances)
    gaps = d.copy()
    gaps[1:] -= d[:-1]
    big = np.flatnonzero(gaps >= gap)
    if len(big) == 0:
        return (float(d[-1]) if len(d) else 0.0), True
    first = big[0]
    return (float(d[first - 1]) if first > 0 else 0.0), False


def paper_gap_reach(distances: np.ndarray, epsilon: float) -> tuple[float, bool]:
    """Steps 2-7 as the paper writes them: sort the projections P_j by D_j = |P_j, e|, take the
    gaps G_j = |P_j, P_{j+1}| between neighbours (step 5; none between e and the first point),
    and mark P_j as the new end e at the first G_j >= (G_max / G_min) * ε (step 7).

    Algorithm 1 line 17 reads "e = G_j"; we take it as e = P_j, the point before the gap, at
    the first such gap, as ours (neither text says which if several qualify). Only ε <= G_min
    lets any gap qualify, and G_min = 0 (two equal projections) none. Returns the distance
    from e to the new end point (D_max if no gap qualifies) and whether none did.
    """
    d = np.sort(distances)
    gaps = np.diff(d)
    if len(gaps) == 0 or gaps.min() == 0:
        return (float(d[-1]) if len(d) else 0.0), True
    big = np.flatnonzero(gaps >= gaps.max() / gaps.min() * epsilon)
    if len(big) == 0:
        return float(d[-1]), True
    return float(d[big[0]]), False


def end_reach(
    distances: np.ndarray, *, rule: GapRule, gap: float, epsilon: float
) -> tuple[float, bool]:
    """Step 7 by ``rule``: the paper's relative threshold (``epsilon``) or ours (``gap``)."""
    if rule == "paper":
        return paper_gap_reach(distances, epsilon)
    return gap_reach(distances, gap)


def complete(
    segment: Segment,
    points: np.ndarray,
    *,
    slide_lambda: float,
    gap: float,
    gap_rule: GapRule,
    gap_epsilon: float,
    margin: float,
    max_slides: int,
) -> Member:
    """Slide the segment's bounding box along its axis both ways and extend it to the new ends.

    The box Θ spans the segment's points, padded by ``margin``; each new box Θ_new has the same
    cross-section and ``slide_lambda`` times the segment's length (eq. 2, λ ≈ 2.5), starting at
    the end it slides from. Points in Θ_new are projected on the axis (eq. 3) and the gap rule
    places the new end (step 7, by ``gap_rule``); if no gap stops it and the points run on to
    within ``gap`` of the far face of Θ_new, it slides again (ours, for either rule).
    """
    cylinder = segment.cylinder
    local = _box_coordinates(points, cylinder)
    own = local[segment.indices]
    lo, hi = own[:, 1:].min(axis=0) - margin, own[:, 1:].max(axis=0) + margin
    in_section = np.flatnonzero(((local[:, 1:] >= lo) & (local[:, 1:] <= hi)).all(axis=1))
    t_section = local[in_section, 0]
    length = segment.t1 - segment.t0
    ends = {+1: segment.t1, -1: segment.t0}
    for sign in (+1, -1):
        for _ in range(max_slides):
            e = ends[sign]
            depth = slide_lambda * length
            distances = (t_section - e) * sign
            inside = (distances > 0) & (distances <= depth)
            reach, open_ended = end_reach(
                distances[inside], rule=gap_rule, gap=gap, epsilon=gap_epsilon
            )
            ends[sign] = e + sign * reach
            if not open_ended or depth - reach >= gap:
                break
    t0, t1 = ends[-1], ends[+1]
    within = in_section[(t_section >= t0) & (t_section <= t1)]
    support = np.zeros(len(points), bool)
    support[segment.indices] = True
    support[within] = True
    return Member(cylinder, t0, t1, np.flatnonzero(support))


def node_ends(
    member: Member, points: np.ndarray, *, distance: float, bin_size: float, linker: float
) -> Member:
    """Members of a space frame end at nodes inside linkers of size ``linker`` (ours, after the
    gap rule, which runs on through a linker and into the members crossing at its node).

    Along the axis, in bins of ``bin_size``, the share of points on the cylinder surface is
    high on the tube and low on a linker and on members crossing at the node (smoothed over
    three bins). Within 2.5 linkers of each end, the run of low bins nearest the end, if at
    least half a linker long, is the linker: the end moves to its centre, the node.
    """
    if linker <= 0:
        return member
    cylinder = member.cylinder
    w = points[member.indices] - cylinder.point
    t = w @ cylinder.axis
    radial = np.sqrt(np.maximum((w * w).sum(axis=1) - t * t, 0.0))
    on = np.abs(radial - cylinder.radius) < distance
    edges = np.arange(member.t0, member.t1 + bin_size, bin_size)
    total = np.histogram(t, edges)[0]
    window = np.ones(3)
    share = np.convolve(np.histogram(t[on], edges)[0], window, "same") / np.maximum(
        np.convolve(total, window, "same"), 1
    )
    low = (share < 0.5) & (np.convolve(total, window, "same") > 0)
    reach = int(np.ceil(2.5 * linker / bin_size))
    shortest = int(np.ceil(0.5 * linker / bin_size))
    ends = [member.t0, member.t1]
    for side, run_of in ((0, low[:reach]), (1, low[::-1][:reach])):
        runs = _runs(run_of)
        run = next((r for r in runs if r[1] - r[0] >= shortest), None)
        if run is not None:
            middle = 0.5 * (run[0] + run[1]) * bin_size
            ends[side] = member.t0 + middle if side == 0 else member.t1 - middle
    return Member(cylinder, ends[0], ends[1], member.indices, member.pieces)


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True in ``flags``, in order."""
    padded = np.concatenate([[False], flags, [False]]).astype(np.int8)
    change = np.flatnonzero(np.diff(padded))
    return list(zip(change[::2].tolist(), change[1::2].tolist(), strict=True))


def _aligned_ends(a: Member, b: Member) -> tuple[np.ndarray, np.ndarray]:
    """b's end points ordered to face a's (p0 with p0)."""
    if a.cylinder.axis @ b.cylinder.axis >= 0:
        return b.p0, b.p1
    return b.p1, b.p0


def _on_axis(a: Member, b: Member, distance: float) -> bool:
    """Both of b's end points lie within ``distance`` of a's axis line, and their extents
    overlap or meet along a's axis."""
    axis, origin = a.cylinder.axis, a.cylinder.point
    ends = np.array([b.p0, b.p1]) - origin
    t = ends @ axis
    off = np.linalg.norm(ends - np.outer(t, axis), axis=1)
    return bool(off.max() < distance and t.max() >= a.t0 - distance and t.min() <= a.t1 + distance)


def same_member(a: Member, b: Member, distance: float, angle_deg: float, line: float) -> bool:
    """The merging criterion: parallel axes and both pairs of end points within ``distance``
    (the paper's single Euclidean criterion), or one piece lying on the other's axis within
    ``line`` (ours: a piece whose completion stopped at an occlusion)."""
    cos = abs(a.cylinder.axis @ b.cylinder.axis)
    if cos < np.cos(np.radians(angle_deg)):
        return False
    b0, b1 = _aligned_ends(a, b)
    if np.linalg.norm(a.p0 - b0) < distance and np.linalg.norm(a.p1 - b1) < distance:
        return True
    return _on_axis(a, b, line) or _on_axis(b, a, line)


def merge_members(
    members: list[Member], *, distance: float, angle_deg: float, line: float
) -> list[Member]:
    """Merge pieces of one member (split by RANSAC) into one: the larger piece's axis, end points
    at the outermost projections of the pieces' completed ends, the union of their points."""
    members = list(members)
    i = 0
    while i < len(members):
        partner = next(
            (
                j
                for j in range(i + 1, len(members))
                if same_member(members[i], members[j], distance, angle_deg, line)
            ),
            None,
        )
        if partner is None:
            i += 1
            continue
        a, b = members[i], members.pop(partner)
        base = a if len(a.indices) >= len(b.indices) else b
        t = (np.array([a.p0, a.p1, b.p0, b.p1]) - base.cylinder.point) @ base.cylinder.axis
        support = np.union1d(a.indices, b.indices)
        members[i] = Member(base.cylinder, t.min(), t.max(), support, a.pieces + b.pieces)
    return members


def suppress_duplicates(members: list[Member], shared: float = 0.5) -> list[Member]:
    """Drop a member whose points are mostly (> ``shared``) already claimed by a larger one."""
    kept: list[Member] = []
    size = max((int(m.indices.max()) + 1 for m in members if len(m.indices)), default=0)
    claimed = np.zeros(size, bool)
    for member in sorted(members, key=lambda m: len(m.indices), reverse=True):
        if len(member.indices) and claimed[member.indices].mean() > shared:
            continue
        kept.append(member)
        claimed[member.indices] = True
    return kept
