"""Nodes and connectors of the truss model (paper 003).

``connectors`` finds the nodes of a model: where the ends of two or more members meet;
``end_distance`` compares two members end to end (tracking.py associates members with it).

Nodes as features (ours, for space frames whose members end on connectors of any shape and
size): where member axes meet (``junctions``), the node is the least-squares point nearest
those axes; each member is cut at the nodes on it and its tube ends where the tube's surface
ends next to each node (``node_members``). A member end meeting no other axis whose tube
stops short of its completed end, at a blob of points off the tube's surface, gets the blob's
centre as its node.

Where a tube ends on a connector, the connector's surfaces cross the tube's shell (an oblique
box face, a plate's faces and rim): their points at the tube's radius, normals blurred, read as
tube. A solid tube hides its bore, so an axial slice with points well inside the shell is open:
no tube there, and the tube's end stops at the first open slice. On a noisy surface (the spread
of the tube's points about its radius as wide as the fit tolerance) a slice needs several such
points to be open (``NOISY_OPEN_POINTS``). A connector wider than the tube can hide the
tube's last centimetres from every view (``hidden_end``): the tube then ends at its face.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from climbd.daemon.contract.messages import TrussNode
from climbd.plugins.perception.truss.completion import Member
from climbd.plugins.perception.truss.cylinders import robust_sigma, spread, surface_offset


def end_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Largest end-to-end distance (m) of two members (p0, p1 stacked: 6 values), matching
    their ends either way round."""
    same = max(np.linalg.norm(a[:3] - b[:3]), np.linalg.norm(a[3:] - b[3:]))
    flipped = max(np.linalg.norm(a[:3] - b[3:]), np.linalg.norm(a[3:] - b[:3]))
    return float(min(same, flipped))


def _groups(points: np.ndarray, radius: float) -> list[list[int]]:
    """Indices of ``points`` grouped by distance <= ``radius`` (through any chain of points)."""
    parent = list(range(len(points)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    close = np.linalg.norm(points[:, None] - points[None, :], axis=2) <= radius
    for i, j in zip(*np.nonzero(np.triu(close, 1)), strict=True):
        parent[root(int(i))] = root(int(j))
    groups: dict[int, list[int]] = {}
    for i in range(len(points)):
        groups.setdefault(root(i), []).append(i)
    return list(groups.values())


def connectors(members: Sequence[Member], ids: Sequence[int], radius: float) -> list[TrussNode]:
    """The nodes of the truss: groups of member node ends (``Member.ends``) within ``radius``
    (m) of one another, of two or more members; at the mean of those ends, with the farthest
    tube end of a member there from it (how far the connector keeps the tubes off)."""
    ends = np.array([p for m in members for p in m.ends], float).reshape(-1, 3)
    tubes = np.array([p for m in members for p in (m.p0, m.p1)], float).reshape(-1, 3)
    owner = np.repeat(np.asarray(ids, int), 2)
    nodes = []
    for group in _groups(ends, radius):
        joined = sorted({int(owner[i]) for i in group})
        if len(joined) >= 2:
            position = ends[group].mean(axis=0)
            reach = np.linalg.norm(tubes[group] - position, axis=1).max()
            nodes.append(
                TrussNode(position=position.tolist(), members=joined, reach=round(float(reach), 4))
            )
    return nodes


def axes_point(origins: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """The least-squares point nearest to the lines (origin, unit axis): the solution of
    sum(I - a a^T) x = sum(I - a a^T) o."""
    projectors = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
    return np.linalg.lstsq(projectors.sum(axis=0), np.einsum("kij,kj->i", projectors, origins))[0]


def _closest_on_axes(a: Member, b: Member) -> tuple[float, float, float]:
    """Axial parameters on a and b of the closest points of their axis lines, and their
    distance (m); parallel axes give an infinite distance."""
    ua, ub = a.cylinder.axis, b.cylinder.axis
    w = a.cylinder.point - b.cylinder.point
    c = float(ua @ ub)
    denom = 1.0 - c * c
    if denom < 1e-9:
        return 0.0, 0.0, np.inf
    ta = (c * (ub @ w) - ua @ w) / denom
    tb = (ub @ w - c * (ua @ w)) / denom
    gap = a.cylinder.point + ta * ua - b.cylinder.point - tb * ub
    return float(ta), float(tb), float(np.linalg.norm(gap))


def junctions(
    members: Sequence[Member],
    *,
    reach: float,
    angle_deg: float,
    radius: float,
    slack: Sequence[float],
) -> list[tuple[np.ndarray, list[int]]]:
    """Nodes where member axes meet: pairs of members at ``angle_deg`` or more whose axes pass
    within half their mean radius (scaffold tubes crossing at a coupler pass at the radii sum)
    plus both members' ``slack`` (m; the spread of their points: noisy fits' axes stray by
    about that), at points within ``reach`` (m) of both members' extents, grouped within
    ``radius`` (m). Each node is the least-squares point nearest its members' axes, with
    their indices."""
    meets, pairs = [], []
    for i, a in enumerate(members):
        for j in range(i + 1, len(members)):
            b = members[j]
            if abs(a.cylinder.axis @ b.cylinder.axis) > np.cos(np.radians(angle_deg)):
                continue
            ta, tb, gap = _closest_on_axes(a, b)
            near_a = a.t0 - reach <= ta <= a.t1 + reach
            near_b = b.t0 - reach <= tb <= b.t1 + reach
            tolerance = 0.25 * (a.cylinder.radius + b.cylinder.radius) + slack[i] + slack[j]
            if near_a and near_b and gap < tolerance:
                meets.append(a.cylinder.point + ta * a.cylinder.axis)
                pairs.append((i, j))
    nodes = []
    for group in _groups(np.array(meets).reshape(-1, 3), radius):
        joined = sorted({k for g in group for k in pairs[g]})
        origins = np.array([members[k].cylinder.point for k in joined])
        axes = np.array([members[k].cylinder.axis for k in joined])
        nodes.append((axes_point(origins, axes), joined))
    return nodes


@dataclass(frozen=True)
class Profile:
    """A member's points along its axis, in bins of ``bin_size`` from ``start``: how many lie on
    the tube's surface and how many lie off it within four radii of the axis (a blob). Sorted
    axial positions, of points whose normals lie within twice the surface angle of radial
    (normals blur where the tube meets its connector): ``near``, from the shell's thickness
    inside the tube's radius to the surface distance outside it (voxels straddling the tube and
    its connector); ``shell``, within the shell's thickness of the radius; and of the ``bore``
    points, farther inside. Within four radii, of any normal: the ``wide`` points, farther out
    than the surface distance (a connector), with how far out (``wide_reach``, m beyond the
    radius), and the ``inner`` rest. ``open_points``: the bore points a slice needs to be open
    (1 on a sharp shell; ``NOISY_OPEN_POINTS`` on one as thick as the surface distance, where a
    stray return may lie inside)."""

    start: float
    bin_size: float
    surface: np.ndarray
    blob: np.ndarray
    near: np.ndarray
    shell: np.ndarray
    bore: np.ndarray
    wide: np.ndarray
    wide_reach: np.ndarray
    inner: np.ndarray
    open_points: int

    def t(self, index: int) -> float:
        """The axial position of a bin's lower edge."""
        return self.start + index * self.bin_size

    def index(self, t: float) -> int:
        """The bin holding axial position ``t`` (clipped to the profile)."""
        return int(np.clip((t - self.start) // self.bin_size, 0, len(self.surface) - 1))


def profile(
    member: Member,
    points: np.ndarray,
    normals: np.ndarray,
    *,
    span: tuple[float, float],
    bin_size: float,
    distance: float,
    angle_deg: float,
    foreign: np.ndarray | None = None,
) -> Profile:
    """The surface and blob counts of the points along ``member``'s axis over ``span``,
    leaving out the ``foreign`` points (those of other members meeting it)."""
    cylinder = member.cylinder
    t = (points - cylinder.point) @ cylinder.axis
    inside = (t >= span[0]) & (t < span[1])
    if foreign is not None:
        inside &= ~foreign
    t = t[inside]
    radial, cos = surface_offset(points[inside], normals[inside], cylinder)
    off = np.abs(radial)
    on = (off < distance) & (cos > np.cos(np.radians(angle_deg)))
    section = off + cylinder.radius < 4 * cylinder.radius
    bins = len(np.arange(span[0], span[1] + bin_size, bin_size)) - 1
    index = np.clip(((t - span[0]) / bin_size).astype(np.intp), 0, bins - 1)
    surface = np.bincount(index[on], minlength=bins)
    blob = np.bincount(index[~on & section], minlength=bins)
    thickness = shell_thickness(off[on], floor=bin_size / 4, ceiling=distance)
    blurred = cos > np.cos(np.radians(2 * angle_deg))
    near = blurred & (radial > -thickness) & (radial < distance)
    bore = radial < -thickness
    wide = section & (radial > distance)
    order = np.argsort(t[wide])
    return Profile(
        span[0],
        bin_size,
        surface,
        blob,
        np.sort(t[near]),
        np.sort(t[blurred & (off < thickness)]),
        np.sort(t[bore]),
        t[wide][order],
        radial[wide][order],
        np.sort(t[section & ~wide]),
        1 if thickness < distance else NOISY_OPEN_POINTS,
    )


NOISY_OPEN_POINTS = 3
"""Bore points within half a bin that open a slice of a noisy shell: on the noisy space frames,
one or two stray returns inside thin tubes cut them short (1x balls of 30 mm tubes: 6 % and
63 mm), three or more only where a connector's face crosses the bore."""


def shell_thickness(off: np.ndarray, *, floor: float, ceiling: float) -> float:
    """How far (m) a tube's surface points stray from its radius, given their distances ``off``
    from it: three robust standard deviations (``robust_sigma``), within ``floor`` (voxel
    centroids lie that near the surface they sample) and ``ceiling`` (the fit's tolerance: a
    noisy or poorly fitted shell)."""
    if len(off) == 0:
        return ceiling
    return float(np.clip(3 * robust_sigma(off), floor, ceiling))


def open_slices(prof: Profile, lo: float, hi: float, outward: int) -> np.ndarray:
    """Axial positions in (lo, hi) of bore points with at least as many bore points as shell
    points (and ``open_points``) within half a bin of them ``outward`` (+1/-1, towards the
    node): slices with no tube across them (a solid tube hides its bore), where a connector's
    surface crosses the tube's shell or the tube's end cap faces out."""
    bore = prof.bore[(prof.bore > lo) & (prof.bore < hi)]
    ends = (bore, bore + outward * prof.bin_size / 2)
    a, b = np.minimum(*ends), np.maximum(*ends)
    inner = np.searchsorted(prof.bore, b, "right") - np.searchsorted(prof.bore, a)
    shell = np.searchsorted(prof.shell, b, "right") - np.searchsorted(prof.shell, a)
    return bore[(inner >= shell) & (inner >= prof.open_points)]


def tube_end(
    prof: Profile, node: float, inward: int, reference: float, clearance: float = 0.0
) -> float:
    """Where the tube's surface ends next to a node at ``node`` (ours). Walking ``inward``
    (+1/-1) from ``clearance`` off the node (tubes meeting there cannot interpenetrate), find
    the first bin whose surface count, smoothed over three bins, reaches half the tube's
    typical count ``reference``; from its inner edge, walk back towards the node over points at
    the tube's radius (``Profile.near``) less than two bins apart (a gap rule on those points
    alone), not nearer the node than ``clearance`` nor into an open slice (``open_slices``)."""
    smooth = np.convolve(prof.surface, np.ones(3) / 3, "same")
    last = len(smooth) - 1
    i = prof.index(node + inward * clearance)
    while 0 < i < last and smooth[i] < 0.5 * reference:
        i += inward
    if inward > 0:
        body = prof.t(i + 1)
        stop = max(open_slices(prof, node, body, -1), default=node)
        towards = prof.near[(prof.near > stop) & (prof.near <= body)][::-1]
    else:
        body = prof.t(i)
        stop = min(open_slices(prof, body, node, +1), default=node)
        towards = prof.near[(prof.near < stop) & (prof.near >= body)]
    if len(towards) == 0:
        return body
    end = float(towards[0])
    for t in towards[1:]:
        if abs(t - end) >= 2 * prof.bin_size or (t - node) * inward < clearance:
            break
        end = float(t)
    return end


def hidden_end(prof: Profile, end: float, node: float, inward: int, clearance: float) -> float:
    """A tube ``end`` short of a connector's flat face, moved to the face where the views saw
    nothing of the tube between them: a tube reaches its connector, and a connector that
    overhangs the tube hides its last centimetres from views on its far side (3x cubes on
    80 mm posts seen from above: 30-34 mm). Walking from the end towards the node (``inward``,
    +1/-1, goes from the node to the tube), the connector's points (farther out than the tube's
    surface) start at the face: the first bin with 2k - 1 of them or more (past strays; k, the
    ``open_points``, is 1 on a sharp shell), at its k-th point nearest the tube. A face is an
    edge: within two bins they reach half their median count per bin (a ball thins towards its
    silhouette, and its own underside is what is hidden there), and they reach out from the
    axis by at least the gap. The gap holds fewer than k points on or inside the tube's surface,
    and on a noisy shell spans two bins at least (a noisy end strays that far either way); the
    end stays ``clearance`` off the node."""
    k = prof.open_points
    keep = ((prof.wide - node) * inward >= 0) & ((prof.wide - end) * inward < 0)
    depth = (end - prof.wide[keep]) * inward
    if len(depth) < k:
        return end
    bins = (depth // prof.bin_size).astype(np.intp)
    per_bin = np.bincount(bins)
    least = 2 * k - 1
    first = int(np.argmax(per_bin >= least))
    half = max(least, 0.5 * np.median(per_bin[per_bin > 0]))
    dense = int(np.argmax(per_bin >= half))
    if per_bin[first] < least or dense - first > 1:
        return end
    gap = float(np.sort(depth[bins == first])[k - 1])
    if k > 1 and gap < 2 * prof.bin_size:
        return end
    edge = (bins >= first) & (bins <= dense)
    if prof.wide_reach[keep][edge].max() < gap:
        return end
    inner = (end - prof.inner) * inward
    if np.count_nonzero((inner > prof.bin_size / 2) & (inner < gap)) >= k:
        return end
    face = end - inward * gap
    return face if (face - node) * inward >= clearance else node + inward * clearance


def blob_centre(prof: Profile, end: float, outward: int, reach: float) -> float | None:
    """The axial centre of the blob of off-surface points that starts at a tube ``end`` and
    runs ``outward`` (gaps of up to two bins) within ``reach`` (m); None without one."""
    i = prof.index(end + outward * prof.bin_size / 2)
    stop = prof.index(end + outward * reach)
    far, misses = None, 0
    while misses <= 2 and 0 <= i < len(prof.blob) and (i - stop) * outward <= 0:
        if prof.blob[i] > 0:
            far, misses = i, 0
        else:
            misses += 1
        i += outward
    if far is None:
        return None
    edge = prof.t(far + 1) if outward > 0 else prof.t(far)
    return 0.5 * (end + edge)


@dataclass(frozen=True)
class NodeRules:
    """How ``node_members`` finds nodes and tube ends (m, deg): ``reach``, how far a node may
    lie beyond a member's completed extent; ``angle_deg``, the least angle between members
    meeting at a node; ``radius``, how near meeting points of pairs are one node; profile bins
    of ``bin_size``; surface points within ``distance`` of the tube and normals within
    ``surface_angle_deg`` of radial; tubes shorter than ``min_length`` are no members."""

    reach: float
    angle_deg: float
    radius: float
    bin_size: float
    distance: float
    surface_angle_deg: float
    min_length: float


def node_members(
    members: Sequence[Member], points: np.ndarray, normals: np.ndarray, rules: NodeRules
) -> list[Member]:
    """Members cut at the nodes on their axes, each with its tube extent (t0, t1) and nodes.
    Dropped as the edges of a large connector, fitted as cylinders: a member meeting no node
    whose middle lies within ``reach`` of one, and a member lying within ``reach`` of a node it
    does not meet (the edges of a cube meet at its corners)."""
    nodes = junctions(
        members,
        reach=rules.reach,
        angle_deg=rules.angle_deg,
        radius=rules.radius,
        slack=[spread(points[m.indices], m.cylinder) for m in members],
    )
    centres = np.array([node for node, _ in nodes]).reshape(-1, 3)
    cut = []
    for k, member in enumerate(members):
        on = [
            (node, [members[j] for j in joined if j != k]) for node, joined in nodes if k in joined
        ]
        middle = 0.5 * (member.p0 + member.p1)
        if not on and (np.linalg.norm(centres - middle, axis=1) < rules.reach).any():
            continue
        apart = np.array([k not in joined for _, joined in nodes], bool)
        if (_within(member, centres[apart]) < rules.reach).any():
            continue
        cut += _cut(member, on, points, normals, rules)
    return cut


def _within(member: Member, centres: np.ndarray) -> np.ndarray:
    """The farther of a member's two ends from each of ``centres`` (m): the radius around each
    centre that holds the whole member."""
    return np.maximum(
        np.linalg.norm(centres - member.p0, axis=1), np.linalg.norm(centres - member.p1, axis=1)
    )


def _foreign(
    member: Member,
    points: np.ndarray,
    meeting: list[tuple[np.ndarray, list[Member]]],
    rules: NodeRules,
) -> np.ndarray:
    """Points of the other members meeting ``member`` at a node: within ``reach`` of the node,
    inside (radius + ``distance``) of another member's axis and farther from the node along
    it, on its side, than along ``member``'s axis. A tube ending on another at right angles
    has its end cap at this member's radius; this member's own tube, ending where it clears
    the others (r / tan(θ / 2) from the node), stays."""
    foreign = np.zeros(len(points), bool)
    for node, others in meeting:
        offsets = points - node
        close = np.flatnonzero(np.einsum("ij,ij->i", offsets, offsets) < rules.reach**2)
        w = offsets[close]
        w2 = np.einsum("ij,ij->i", w, w)
        along_own = np.abs(w @ member.cylinder.axis)
        for other in others:
            axis = other.cylinder.axis
            side = np.sign((0.5 * (other.p0 + other.p1) - node) @ axis)
            t = w @ axis
            inside = (w2 - t * t < (other.cylinder.radius + rules.distance) ** 2) & (
                side * t > along_own
            )
            foreign[close[inside]] = True
    return foreign


Bound = tuple[float, np.ndarray | None, list[Member]]
"""Where a member's piece may end: axial position, node (None: a free end), members meeting."""


def clearance(
    radius: float, direction: np.ndarray, node: np.ndarray, others: list[Member]
) -> float:
    """How near a node a tube along ``direction`` (from the node) can end without cutting the
    tubes of ``others`` meeting there: r / tan(θ / 2) for the least angle θ between them, r the
    mean radius of the two tubes."""
    gaps = []
    for other in others:
        side = np.sign((0.5 * (other.p0 + other.p1) - node) @ other.cylinder.axis)
        cos = float(np.clip(direction @ (side * other.cylinder.axis), -1.0, 1.0))
        gaps.append(0.5 * (radius + other.cylinder.radius) / np.tan(np.arccos(cos) / 2))
    return max(gaps)


def _cut(
    member: Member,
    meeting: list[tuple[np.ndarray, list[Member]]],
    points: np.ndarray,
    normals: np.ndarray,
    rules: NodeRules,
) -> list[Member]:
    """The pieces of ``member`` between the nodes on its axis (each with the other members
    meeting there: ``meeting``) and its free ends; a member meeting no other (a scaffold tube
    running through its couplers) stays as completed."""
    if not meeting:
        return [member]
    cylinder = member.cylinder
    at = sorted(
        ((float((n - cylinder.point) @ cylinder.axis), n, o) for n, o in meeting),
        key=lambda x: x[0],
    )
    lo = min([member.t0, *(b[0] for b in at)]) - rules.reach
    hi = max([member.t1, *(b[0] for b in at)]) + rules.reach
    prof = profile(
        member,
        points,
        normals,
        span=(lo, hi),
        bin_size=rules.bin_size,
        distance=rules.distance,
        angle_deg=rules.surface_angle_deg,
        foreign=_foreign(member, points, meeting, rules),
    )
    own = prof.surface[prof.index(member.t0) : prof.index(member.t1) + 1]
    if not (own > 0).any():
        return [member]
    reference = float(np.median(own[own > 0]))
    support = (points[member.indices] - cylinder.point) @ cylinder.axis
    bounds: list[Bound] = [(member.t0, None, []), *at, (member.t1, None, [])]
    pieces = []
    for low, high in zip(bounds[:-1], bounds[1:], strict=True):
        if high[0] > low[0]:
            pieces.append(_piece(member, prof, reference, low, high, support, rules))
    return [p for p in pieces if p is not None]


def _piece(
    member: Member,
    prof: Profile,
    reference: float,
    low: Bound,
    high: Bound,
    support: np.ndarray,
    rules: NodeRules,
) -> Member | None:
    """The tube between two bounds (a node, or a completed free end) of a member, if any."""
    ends, nodes = [], []
    for (t, node, others), inward in ((low, +1), (high, -1)):
        direction = inward * member.cylinder.axis
        gap = clearance(member.cylinder.radius, direction, node, others) if others else 0.0
        end = tube_end(prof, t, inward, reference, gap)
        if node is None:
            node, end = _free_end(member, prof, t, end, -inward, rules)
        else:
            end = hidden_end(prof, end, t, inward, gap)
        ends.append(end)
        nodes.append(node)
    t0, t1 = ends
    if t1 - t0 < rules.min_length:
        return None
    smooth = np.convolve(prof.surface, np.ones(3) / 3, "same")
    covered = smooth[prof.index(t0) : prof.index(t1) + 1] >= 0.5 * reference
    if covered.mean() < 0.3:
        return None
    inside = (support >= t0) & (support <= t1)
    return Member(member.cylinder, t0, t1, member.indices[inside], member.pieces, *nodes)


def _free_end(
    member: Member, prof: Profile, completed: float, tube: float, outward: int, rules: NodeRules
) -> tuple[np.ndarray | None, float]:
    """A free end keeps its completed end, unless the tube's surface stops two bins or more
    short of it at a blob: then the tube ends there and the node is the blob's centre."""
    centre = blob_centre(prof, tube, outward, rules.reach)
    if abs(completed - tube) < 2 * rules.bin_size or centre is None:
        return None, completed
    return member.cylinder.point + centre * member.cylinder.axis, tube
