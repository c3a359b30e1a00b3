"""Truss environment modelling (TEM, paper 003 Fig. 2): a pure object from a cloud to members.

Dense cloud -> voxel downsampling -> plane removal -> isolated-point removal -> normals ->
RANSAC cylinder segments (the initial model), each completed by the sliding boxes as soon as
it is found (the points in its boxes then leave the RANSAC pool) -> merging of split pieces -> a
final refit of each member on all its surface points -> nodes as features (ours, nodes.py):
members cut at the nodes where their axes meet, each with its tube extent and its nodes.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import get_args

import msgspec
import numpy as np
from scipy.spatial import cKDTree

from climbd.plugins.perception.truss.cloud import ball_normals, voxel_downsample, voxel_normals
from climbd.plugins.perception.truss.completion import (
    GapRule,
    Member,
    complete,
    from_segment,
    merge_members,
    node_ends,
    suppress_duplicates,
)
from climbd.plugins.perception.truss.cylinders import (
    Cylinder,
    Segment,
    refine,
    segment_cylinders,
    surface_fit,
    within_radii,
)
from climbd.plugins.perception.truss.nodes import NodeRules, node_members
from climbd.plugins.perception.truss.planes import (
    accept_plane,
    find_planes,
    plane_heights,
    principal_axes,
)

logger = logging.getLogger(__name__)


class TrussConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Truss modelling parameters (m, deg). ``slide_lambda`` is the paper's λ ≈ 2.5 (eq. 2);
    ``gap_rule`` picks step 7's threshold: "absolute" (ours) stops at a gap of ``gap`` (m);
    "paper" at G_j >= (G_max / G_min) * ``gap_epsilon`` (the paper's ε, whose value it does not
    give; 1e-5 m lets the rule act in about a third of the boxes of our test scenes);
    ``gap`` also bounds how near the far face of a box the points must run for it to slide
    again. The rest are ours, for a Kinect-2-like cloud.
    ``linker`` is the size of the linkers members end in, for a space frame (its members end
    at the nodes), a hint; 0 (default): find the nodes where member axes meet, of any connector,
    and report each member's tube extent and its nodes (nodes.py); ``node_reach``: how far a
    node may lie beyond a member's completed extent; ``node_angle_deg``: the least angle between
    members meeting at a node.
    ``track_gate``: a member re-modelled with both ends within this of a member of the
    persistent model fuses into it (keeps its id); ``track_expiry``: model updates in view
    without a member drop it; ``node_radius``: member ends this close meet at one connector.
    ``max_points`` bounds a model's time and memory (a cloud of noise peaks near 1.2 GB at the
    default): a larger cloud is cut to its voxel centroids (the resolution modelled anyway),
    then, if still too large, to 1 in k of them, which may lose members; either is logged.
    ``completion_passes``: slides of the completion, each after the first along a refitted
    axis (3: a member segmented short and tilted reaches its tube's far end only after two
    refits; ``bench/truss_seeds.py``)."""

    voxel: float = 0.01
    max_range: float = 4.5
    max_points: int = 1_000_000
    normal_reach: float = 2.0
    outlier_neighbours: int = 3
    plane_distance: float = 0.02
    plane_angle_deg: float = 20.0
    plane_voxel: float = 0.08
    plane_sample: int = 30000
    plane_cell: float = 0.05
    plane_min_points: int = 30
    plane_min_area: float = 0.25
    plane_min_width: float = 0.3
    max_planes: int = 3
    radius_min: float = 0.01
    radius_max: float = 0.042
    partner_radius: float = 0.05
    cylinder_distance: float = 0.008
    cylinder_angle_deg: float = 25.0
    min_member_points: int = 40
    min_member_length: float = 0.15
    segment_gap: float = 0.03
    hypotheses: int = 32
    probe: int = 1000
    max_failures: int = 4
    max_segments: int = 64
    slide_lambda: float = 2.5
    gap: float = 0.12
    gap_rule: GapRule = "absolute"
    gap_epsilon: float = 1e-5
    linker: float = 0.0
    box_margin: float = 0.01
    max_slides: int = 3
    merge_distance: float = 0.1
    merge_angle_deg: float = 5.0
    merge_line: float = 0.03
    completion_passes: int = 3
    seed: int = 0
    model_every: int = 1
    track_gate: float = 0.1
    track_expiry: int = 3
    node_radius: float = 0.05
    node_reach: float = 0.25
    node_angle_deg: float = 20.0

    def __post_init__(self) -> None:
        if not 0 < self.radius_min < self.radius_max:
            raise ValueError(
                f"truss: radius_min ({self.radius_min}) must be > 0 and < radius_max "
                f"({self.radius_max})"
            )
        if self.slide_lambda < 1.0:
            raise ValueError(
                f"truss: slide_lambda must be >= 1 (paper: about 2.5), got {self.slide_lambda}"
            )
        if self.gap_rule not in get_args(GapRule):
            raise ValueError(
                f"truss: gap_rule must be one of {get_args(GapRule)}, got {self.gap_rule!r}"
            )
        if self.linker < 0:
            raise ValueError(f"truss: linker must be >= 0 (0: members end free), got {self.linker}")
        names = ("voxel", "gap", "cylinder_distance", "plane_distance", "segment_gap")
        for name in (
            *names,
            "gap_epsilon",
            "track_gate",
            "track_expiry",
            "node_radius",
            "node_reach",
            "max_points",
        ):
            if getattr(self, name) <= 0:
                raise ValueError(f"truss: {name} must be > 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class TrussModel:
    """Members after completion and merging, the initial RANSAC-only members, the cloud used."""

    members: list[Member]
    initial: list[Member]
    points: np.ndarray


STEADY_COS = float(np.cos(np.radians(0.5)))
"""A support's principal axis within half a degree of a member's fit (half the axis goal of
issue 37) starts no second fit."""
FIT_ROUNDS = 4
SETTLED_COS = float(np.cos(np.radians(0.1)))
"""A refit picks the support's points on its cylinder's surface and refines the cylinder on
them, up to ``FIT_ROUNDS`` times while the axis turns by more than 0.1 degrees: the points on
a tilted axis's surface keep most of its tilt (one round per completion pass left a noisy
30 mm tube of the space frame 2 degrees off)."""
RESTART_GAIN = 1.1
"""How many times the surface points of a member's own refit a refit from its support's
principal axis must hold to replace it: a tilted fit holds a fraction of its tube's points,
while two fits of one tube differ by a few points, which a connector's points can tip
(``bench/truss_seeds.py``; ``tests/test_truss_nodes.py``'s diagonals with 1.0)."""


class TrussModeller:
    """Builds the truss model of a dense cloud (odometry frame); deterministic for ``seed``."""

    def __init__(self, config: TrussConfig | None = None) -> None:
        self.config = config or TrussConfig()

    def model(self, cloud: np.ndarray) -> TrussModel:
        """Members of the truss in ``cloud`` (N x 3, m), with the RANSAC-only initial model."""
        c = self.config
        cloud = np.asarray(cloud, dtype=float)
        if cloud.ndim != 2 or cloud.shape[1] != 3:
            raise ValueError(f"truss: cloud must be N x 3, got shape {cloud.shape}")
        finite = np.isfinite(cloud).all(axis=1)
        if not finite.all():
            cloud = cloud[finite]
        if len(cloud) > c.max_points:
            cloud = self._decimated(cloud)
        rng = np.random.default_rng(c.seed)
        points, normals = self._without_planes(cloud, rng)
        if len(points) < c.min_member_points:
            return TrussModel([], [], points)
        completed: list[Member] = []

        def claim(segment: Segment) -> np.ndarray:
            completed.append(self._complete(segment, points, normals))
            return np.concatenate([segment.indices, completed[-1].indices])

        segments = segment_cylinders(
            points,
            normals,
            cKDTree(points),
            rng,
            radius_min=c.radius_min,
            radius_max=c.radius_max,
            partner_radius=c.partner_radius,
            distance=c.cylinder_distance,
            angle_deg=c.cylinder_angle_deg,
            min_points=c.min_member_points,
            min_length=c.min_member_length,
            segment_gap=c.segment_gap,
            hypotheses_per_round=c.hypotheses,
            probe=c.probe,
            max_failures=c.max_failures,
            max_segments=c.max_segments,
            claim=claim,
        )
        merged = merge_members(
            completed,
            distance=c.merge_distance,
            angle_deg=c.merge_angle_deg,
            line=c.merge_line,
        )
        members = suppress_duplicates(
            [
                node_ends(
                    self._refit(m, points, normals),
                    points,
                    distance=c.cylinder_distance,
                    bin_size=c.voxel,
                    linker=c.linker,
                )
                for m in merged
            ]
        )
        if c.linker == 0:
            members = node_members(members, points, normals, self._node_rules())
        return TrussModel(members, [from_segment(s) for s in segments], points)

    def _decimated(self, cloud: np.ndarray) -> np.ndarray:
        """At most ``max_points`` of ``cloud``, deterministic, with a logged note: its voxel
        centroids, then every k-th of them (in voxel order, so spread evenly) if still too many."""
        c = self.config
        centroids = voxel_downsample(cloud, c.voxel)
        step = -(-len(centroids) // c.max_points)
        kept = centroids[::step]
        logger.log(
            logging.INFO if step == 1 else logging.WARNING,
            "truss: %d finite points in, over max_points (%d): %d kept, centroids of %g m voxels%s",
            len(cloud),
            c.max_points,
            len(kept),
            c.voxel,
            "" if step == 1 else f", then 1 in {step} of those: members may be missed",
        )
        return kept

    def _node_rules(self) -> NodeRules:
        """The configured rules for nodes as features: bins of a voxel, the cylinder
        surface tolerances, the shortest member."""
        c = self.config
        return NodeRules(
            reach=c.node_reach,
            angle_deg=c.node_angle_deg,
            radius=c.node_radius,
            bin_size=c.voxel,
            distance=c.cylinder_distance,
            surface_angle_deg=c.cylinder_angle_deg,
            min_length=c.min_member_length,
        )

    def _without_planes(
        self, cloud: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """Remove planes, voxel-downsample the rest, drop isolated points; normals of the rest.

        Every point within ``plane_distance`` of a plane goes, and within twice that if its
        normal is the plane's. Planes are found (per-voxel normals of a coarse grid) and judged
        on every k-th point, at most ``plane_sample``: the full cloud is read by a few passes."""
        c = self.config
        candidates: list = []
        sample = cloud[:: max(1, len(cloud) // c.plane_sample)]
        coarse, coarse_normals = voxel_normals(sample, c.plane_voxel)
        if len(coarse) >= c.plane_min_points:
            candidates = find_planes(
                coarse,
                coarse_normals,
                rng,
                distance=c.plane_distance,
                angle_deg=c.plane_angle_deg,
                min_points=c.plane_min_points,
                max_planes=c.max_planes,
            )
        planes = []
        for candidate in candidates:
            plane, real = accept_plane(
                sample,
                candidate,
                distance=c.plane_distance,
                min_width=c.plane_min_width,
                min_area=c.plane_min_area,
                cell=c.plane_cell,
            )
            if real:
                planes.append(plane)
        height, _ = plane_heights(cloud, planes)
        points = voxel_downsample(cloud[height >= c.plane_distance], c.voxel)
        height, nearest = plane_heights(points, planes)
        if len(points) == 0:
            return points, np.zeros_like(points)
        normals, neighbours = ball_normals(points, c.voxel, c.normal_reach)
        keep = (neighbours >= c.outlier_neighbours) & (height >= c.plane_distance)
        if planes:
            plane_normals = np.array([n for n, _ in planes])[nearest]
            along = np.abs((normals * plane_normals).sum(axis=1))
            keep &= ~(
                (height < 2 * c.plane_distance) & (along > np.cos(np.radians(c.plane_angle_deg)))
            )
        return points[keep], normals[keep]

    def _complete(self, segment: Segment, points: np.ndarray, normals: np.ndarray) -> Member:
        """Complete a segment; between passes refit its axis on the points the completion found
        (the last pass's refit is the modeller's final one, after merging)."""
        c = self.config

        def slide(segment: Segment) -> Member:
            return complete(
                segment,
                points,
                slide_lambda=c.slide_lambda,
                gap=c.gap,
                gap_rule=c.gap_rule,
                gap_epsilon=c.gap_epsilon,
                margin=c.box_margin,
                max_slides=c.max_slides,
            )

        member = slide(segment)
        for _ in range(c.completion_passes - 1):
            refitted = self._refit(member, points, normals)
            surface = self._surface(refitted.indices, refitted.cylinder, points, normals)
            if len(surface) == 0:  # none on its refitted surface: nothing to slide from
                break
            member = slide(Segment(refitted.cylinder, refitted.t0, refitted.t1, surface))
        return member

    def _surface(
        self, support: np.ndarray, cylinder: Cylinder, points: np.ndarray, normals: np.ndarray
    ) -> np.ndarray:
        """The ``support`` points (indices) that lie on ``cylinder``'s surface."""
        c = self.config
        off, cos = surface_fit(points[support], normals[support], cylinder)
        cos_limit = np.cos(np.radians(c.cylinder_angle_deg))
        return support[(off < c.cylinder_distance) & (cos > cos_limit)]

    def _refit(self, member: Member, points: np.ndarray, normals: np.ndarray) -> Member:
        """Refit the member's cylinder on its surface points and re-project its end points;
        kept as it was if the refit leaves the radius limits (widened by the points' spread).
        A fit on the surface points of a tilted axis keeps its tilt (a short first segment's
        axis can be degrees off, while its completed support runs the member's length), so a
        second fit starts from the support's principal axis where that lies apart from the
        first fit's (``STEADY_COS``), and replaces the first with ``RESTART_GAIN`` times its
        surface points."""
        cylinder = self._fit(member.indices, member.cylinder, points, normals)
        if cylinder is None:
            return member
        centroid, axes = principal_axes(points[member.indices])
        if abs(float(axes[0] @ cylinder.axis)) < STEADY_COS:
            start = Cylinder(centroid, axes[0], member.cylinder.radius)
            restart = self._fit(member.indices, start, points, normals)
            if restart is not None:
                count = len(self._surface(member.indices, cylinder, points, normals))
                if len(self._surface(member.indices, restart, points, normals)) > (
                    RESTART_GAIN * count
                ):
                    cylinder = restart
        t = (np.array([member.p0, member.p1]) - cylinder.point) @ cylinder.axis
        return Member(cylinder, float(t.min()), float(t.max()), member.indices, member.pieces)

    def _fit(
        self, support: np.ndarray, start: Cylinder, points: np.ndarray, normals: np.ndarray
    ) -> Cylinder | None:
        """A cylinder refined from ``start`` on the ``support`` points on its surface, rounds
        of both while its axis turns (``FIT_ROUNDS``); None with too few points or a radius
        out of the limits."""
        c = self.config
        cylinder = start
        for _ in range(FIT_ROUNDS):
            surface = self._surface(support, cylinder, points, normals)
            if len(surface) < c.min_member_points:
                return None
            previous, cylinder = cylinder, refine(points[surface], cylinder)
            if abs(float(previous.axis @ cylinder.axis)) > SETTLED_COS:
                break
        if not within_radii(points[surface], cylinder, c.radius_min, c.radius_max):
            return None
        return cylinder


def coverage(member: Member, points: np.ndarray, bin_size: float) -> float:
    """Fraction of the member's length covered by its points, in bins of ``bin_size``: a
    confidence that the member is real and its end points are supported."""
    t = (points[member.indices] - member.cylinder.point) @ member.cylinder.axis
    bins = max(1, int(np.ceil(member.length / bin_size)))
    occupied = np.unique(np.clip(((t - member.t0) / bin_size).astype(int), 0, bins - 1))
    return len(occupied) / bins
