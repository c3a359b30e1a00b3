"""Synthetic truss scenes (paper 003): scaffold tubes, couplers and a floor seen by a Kinect 2.

Members are continuous tubes, as scaffold tubes are. Where two tubes cross, their axes are
offset by the sum of their radii and a box-shaped coupler (a linker, not a cylinder) clamps
them, so couplers hide part of each tube and tubes occlude each other. Every member runs past
its outermost coupler, so its true ends are tube ends. Depth is ray-cast per view with
Kinect-2-like noise (about 1.5 mm axial at 1-3 m, growing with range and incidence), flying
pixels at depth edges and dropouts; each view's reported body pose can carry odometry noise.

``five_member()``, ``seven_member()`` and ``scaffold()`` build scaffold geometries;
``space_frame()`` builds a space frame instead: members run node to node and end on a connector
(box, sphere or plate) at every node, so the tube extent and the node-to-node length differ.
``render()`` views one from a few poses and returns a ``TrussScene`` with per-view body-frame
clouds, the body poses (BodyState), the merged odometry-frame cloud and the ground-truth tubes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from climbd.daemon.contract.messages import BodyState

SCAFFOLD_TUBE_RADIUS = 0.02415
"""Standard scaffold tube, 48.3 mm outer diameter (EN 39)."""

OPTICAL_TO_BODY = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
"""Camera optical frame (x right, y down, z forward) to body frame (x forward, y left, z up)."""


@dataclass(frozen=True)
class Tube:
    """A cylindrical member: axis end points ``p0``, ``p1`` (m) and radius (m)."""

    p0: np.ndarray
    p1: np.ndarray
    radius: float

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.p1 - self.p0))

    @property
    def axis(self) -> np.ndarray:
        return (self.p1 - self.p0) / self.length

    @property
    def midpoint(self) -> np.ndarray:
        return 0.5 * (self.p0 + self.p1)


@dataclass(frozen=True)
class Block:
    """An oriented box (a coupler): centre (m), rotation (columns = box axes), half sizes (m)."""

    centre: np.ndarray
    rotation: np.ndarray
    half: np.ndarray


@dataclass(frozen=True)
class Ball:
    """A spherical connector: centre (m) and radius (m)."""

    centre: np.ndarray
    radius: float


ConnectorShape = Literal["box", "sphere", "plate"]
"""The connector at a space frame's nodes: a cube, a ball, or a flat disc (a gusset plate)."""


@dataclass(frozen=True)
class TrussGeometry:
    """Tubes (the ground-truth members: their tube extents), couplers or box connectors, ball
    connectors, plates (flat discs, ray-cast as short closed cylinders), and a floor at z = 0.

    A space frame also has its ``nodes`` (m) and, per tube, the two nodes it runs between
    (``links``): the node-to-node truth. Scaffolds have neither. ``occluders``: boxes in view
    that are no part of the truss."""

    tubes: tuple[Tube, ...]
    couplers: tuple[Block, ...]
    floor_half_size: float = 4.0
    balls: tuple[Ball, ...] = ()
    plates: tuple[Tube, ...] = ()
    nodes: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    links: tuple[tuple[int, int], ...] = ()
    occluders: tuple[Block, ...] = ()


@dataclass(frozen=True)
class DepthCamera:
    """Pinhole depth camera; defaults are the Kinect 2 depth stream (512 x 424, 70.6 x 60 deg)."""

    width: int = 512
    height: int = 424
    fx: float = 365.5
    fy: float = 365.5
    ppx: float = 256.0
    ppy: float = 212.0
    min_range: float = 0.5
    max_range: float = 4.5

    def scaled(self, factor: float) -> DepthCamera:
        """The same field of view at ``factor`` times the resolution (for fast tests)."""
        return DepthCamera(
            round(self.width * factor),
            round(self.height * factor),
            self.fx * factor,
            self.fy * factor,
            self.ppx * factor,
            self.ppy * factor,
            self.min_range,
            self.max_range,
        )


@dataclass(frozen=True)
class DepthNoise:
    """Kinect-2-like depth noise: axial sigma = a + b z^2 + c (1 - cos incidence) (m).

    ``flying`` is the chance that a pixel on a depth edge (neighbour step > ``edge_step``)
    takes a depth between foreground and background (0.2: what the driver's edge-aware
    filter, on by default in libfreenect2, lets through); ``dropout`` the chance of no return.
    Grazing surfaces return less: off depth edges (a second difference over ``edge_step``;
    a steep plane steps evenly), the chance of no return grows linearly from
    0 at ``grazing_from_deg`` of incidence to 1 at ``grazing_to_deg`` (time-of-flight and
    stereo sensors lose surfaces seen nearly edge-on).
    ``pose_translation``/``pose_rotation`` (m, rad) perturb each view's reported pose, as
    mapping drift does.
    """

    a: float = 0.0012
    b: float = 0.00025
    c: float = 0.002
    flying: float = 0.2
    edge_step: float = 0.05
    dropout: float = 0.01
    grazing_from_deg: float = 70.0
    grazing_to_deg: float = 85.0
    pose_translation: float = 0.002
    pose_rotation: float = np.radians(0.1)


NO_NOISE = DepthNoise(
    a=0.0,
    b=0.0,
    c=0.0,
    flying=0.0,
    dropout=0.0,
    grazing_from_deg=90.0,
    grazing_to_deg=90.0,
    pose_translation=0.0,
    pose_rotation=0.0,
)
"""Exact depth and poses: the geometry alone."""


@dataclass
class View:
    """One depth view: body-frame points (m) and the body pose reported with it."""

    points: np.ndarray
    body: BodyState
    true_pose: np.ndarray


@dataclass
class TrussScene:
    """Views of a truss, their merged odometry-frame cloud (reported poses), and ground truth."""

    geometry: TrussGeometry
    views: list[View] = field(default_factory=list)
    cloud: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))

    @property
    def members(self) -> tuple[Tube, ...]:
        return self.geometry.tubes


def _segment_distance(p1, q1, p2, q2) -> tuple[float, np.ndarray, np.ndarray]:
    """Closest distance between segments p1-q1 and p2-q2 and the closest points (Ericson 5.1.9)."""
    d1, d2, w = q1 - p1, q2 - p2, p1 - p2
    a, b, c, e, f = d1 @ d1, d1 @ d2, d1 @ w, d2 @ d2, d2 @ w
    denom = a * e - b * b
    s = float(np.clip((b * f - c * e) / denom, 0.0, 1.0)) if denom > 1e-12 else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t, s = 0.0, float(np.clip(-c / a, 0.0, 1.0))
    elif t > 1.0:
        t, s = 1.0, float(np.clip((b - c) / a, 0.0, 1.0))
    pa, pb = p1 + s * d1, p2 + t * d2
    return float(np.linalg.norm(pa - pb)), pa, pb


def assemble(tubes: list[Tube], wall: float = 0.012) -> TrussGeometry:
    """Check that no two tubes intersect and put a coupler where two tubes touch.

    Raises ValueError naming the two tubes when they intersect (axes closer than the sum of
    their radii): such a truss cannot be built and would make ground truth ambiguous.
    """
    couplers = []
    for i, ti in enumerate(tubes):
        for j in range(i + 1, len(tubes)):
            tj = tubes[j]
            dist, pi, pj = _segment_distance(ti.p0, ti.p1, tj.p0, tj.p1)
            contact = ti.radius + tj.radius
            if dist < contact - 1e-6:
                raise ValueError(
                    f"truss: tubes {i} and {j} intersect (axes {dist * 1000:.1f} mm apart, "
                    f"radii sum {contact * 1000:.1f} mm)"
                )
            if dist > contact + 1e-6:
                continue
            e1 = ti.axis
            e3 = (pj - pi) / dist
            e2 = np.cross(e3, e1)
            rotation = np.column_stack([e1, e2, e3])
            half = np.array(
                [
                    tj.radius + wall,
                    ti.radius + wall,
                    contact / 2 + max(ti.radius, tj.radius) + wall / 2,
                ]
            )
            couplers.append(Block(0.5 * (pi + pj), rotation, half))
    return TrussGeometry(tuple(tubes), tuple(couplers))


def _tube(p0, p1, radius: float = SCAFFOLD_TUBE_RADIUS) -> Tube:
    return Tube(np.asarray(p0, float), np.asarray(p1, float), radius)


def _diagonal(start, end, overhang: float, radius: float) -> Tube:
    start, end = np.asarray(start, float), np.asarray(end, float)
    axis = (end - start) / np.linalg.norm(end - start)
    return _tube(start - overhang * axis, end + overhang * axis, radius)


def five_member(radius: float = SCAFFOLD_TUBE_RADIUS) -> TrussGeometry:
    """Two posts, two ledgers in front of them and a diagonal brace behind: 5 members."""
    d = 2 * radius
    return assemble(
        [
            _tube([0, -0.6, 0], [0, -0.6, 1.8], radius),
            _tube([0, 0.6, 0], [0, 0.6, 1.8], radius),
            _tube([d, -0.8, 0.5], [d, 0.8, 0.5], radius),
            _tube([d, -0.8, 1.4], [d, 0.8, 1.4], radius),
            _diagonal([-d, -0.6, 0.25], [-d, 0.6, 1.6], 0.12, radius),
        ]
    )


def seven_member(radius: float = SCAFFOLD_TUBE_RADIUS) -> TrussGeometry:
    """The five-member frame plus a back post and a transom joining it: 7 members in 3-D."""
    d = 2 * radius
    front = five_member(radius).tubes
    return assemble(
        [
            *front,
            _tube([-1.0, -0.6, 0], [-1.0, -0.6, 1.6], radius),
            _tube([-1.15, -0.6 - d, 1.0], [0.15, -0.6 - d, 1.0], radius),
        ]
    )


def scaffold(
    bays_x: int = 1,
    bays_y: int = 2,
    levels: int = 2,
    bay_x: float = 1.0,
    bay_y: float = 1.2,
    lift: float = 0.9,
    overhang: float = 0.15,
    radius: float = SCAFFOLD_TUBE_RADIUS,
) -> TrussGeometry:
    """A scaffold: posts on a grid, ledgers (along y) and transoms (along x) at every lift,
    a diagonal brace in each front bay. Tubes run continuously through their couplers."""
    d = 2 * radius
    xs = np.arange(bays_x + 1) * bay_x
    ys = np.arange(bays_y + 1) * bay_y
    top = levels * lift + 0.4
    tubes = [_tube([x, y, 0], [x, y, top], radius) for x in xs for y in ys]
    for k in range(1, levels + 1):
        z = k * lift
        tubes += [_tube([x + d, -overhang, z], [x + d, ys[-1] + overhang, z], radius) for x in xs]
        tubes += [
            _tube([-overhang, y + d, z + d], [xs[-1] + overhang, y + d, z + d], radius) for y in ys
        ]
    for j in range(bays_y):
        tubes.append(_diagonal([-d, ys[j], 0.3], [-d, ys[j + 1], lift - 0.2], overhang / 2, radius))
    return assemble(tubes)


FRAME_NODES = np.array(
    [
        [0.0, -0.8, 0.5],
        [0.0, 0.0, 0.5],
        [0.0, 0.8, 0.5],
        [0.0, -0.8, 1.4],
        [0.0, 0.0, 1.4],
        [0.0, 0.8, 1.4],
        [-0.8, -0.8, 1.4],
        [-0.8, 0.8, 1.4],
    ]
)
"""Nodes of the default space frame (m): a two-bay front truss in x = 0 and a back chord."""

FRAME_LINKS = (
    (0, 1),
    (1, 2),
    (3, 4),
    (4, 5),
    (0, 3),
    (1, 4),
    (2, 5),
    (0, 4),
    (2, 4),
    (3, 6),
    (5, 7),
    (6, 7),
)
"""Members of the default space frame: chords, posts, two diagonals, transoms, back chord."""


def _exit_distance(
    shape: ConnectorShape, direction: np.ndarray, size: float, radius: float, normal: np.ndarray
) -> float:
    """Distance from a node along ``direction`` to where the tube's surface meets its connector
    of ``size`` (cube edge, ball or plate diameter); a plate is half a tube radius thick either
    side. A ball meets the tube's surface sqrt(R^2 - r^2) from its centre, short of R on the
    axis: the tube's end cap lies inside the ball."""
    if shape == "sphere":
        return float(np.sqrt(max((size / 2) ** 2 - radius**2, 0.0)))
    if shape == "box":
        return size / 2 / float(np.abs(direction).max())
    along = abs(float(direction @ normal))
    across = float(np.linalg.norm(direction - along * normal))
    thickness = radius / 2 / along if along > 1e-9 else np.inf
    return min(thickness, size / 2 / across if across > 1e-9 else np.inf)


def _clearance(direction: np.ndarray, others: list[np.ndarray], radius: float) -> float:
    """How far from the node a tube along ``direction`` must end to clear the tubes along
    ``others`` meeting there: r / tan(θ / 2) for the smallest angle θ between them."""
    angles = [np.arccos(np.clip(direction @ o, -1.0, 1.0)) for o in others]
    return radius / np.tan(min(angles) / 2) if angles else 0.0


def space_frame(
    shape: ConnectorShape = "box",
    factor: float = 2.0,
    diameter: float = 0.048,
    nodes: np.ndarray = FRAME_NODES,
    links: tuple[tuple[int, int], ...] = FRAME_LINKS,
    plate_normal: tuple[float, float, float] = (1.0, 0.0, 0.0),
    occluder: Block | None = None,
) -> TrussGeometry:
    """A space frame: a tube per link, running between its nodes, ending on the connector at
    each node (a ``shape`` of ``factor`` times the tube ``diameter``: a world-aligned cube, a
    ball, or a disc across ``plate_normal``) or, where it would cut another tube meeting there,
    where it clears it; an optional ``occluder`` box in view."""
    nodes = np.asarray(nodes, float)
    radius, size = diameter / 2, factor * diameter
    normal = np.asarray(plate_normal, float) / np.linalg.norm(plate_normal)
    directions: dict[int, list[np.ndarray]] = {i: [] for i in range(len(nodes))}
    for a, b in links:
        axis = (nodes[b] - nodes[a]) / np.linalg.norm(nodes[b] - nodes[a])
        directions[a].append(axis)
        directions[b].append(-axis)

    def end(node: int, direction: np.ndarray) -> np.ndarray:
        others = [o for o in directions[node] if not np.allclose(o, direction)]
        reach = max(
            _exit_distance(shape, direction, size, radius, normal),
            _clearance(direction, others, radius),
        )
        return nodes[node] + reach * direction

    tubes = []
    for a, b in links:
        axis = (nodes[b] - nodes[a]) / np.linalg.norm(nodes[b] - nodes[a])
        tubes.append(Tube(end(a, axis), end(b, -axis), radius))
    blocks = tuple(Block(n, np.eye(3), np.full(3, size / 2)) for n in nodes if shape == "box")
    balls = tuple(Ball(n, size / 2) for n in nodes if shape == "sphere")
    plates = tuple(
        Tube(n - radius / 2 * normal, n + radius / 2 * normal, size / 2)
        for n in nodes
        if shape == "plate"
    )
    return TrussGeometry(
        tuple(tubes),
        blocks,
        balls=balls,
        plates=plates,
        nodes=nodes,
        links=tuple(links),
        occluders=(occluder,) if occluder is not None else (),
    )


def to_mjcf(geometry: TrussGeometry, name: str = "truss") -> str:
    """The geometry as a MuJoCo model (static geoms: floor plane, tube and plate cylinders,
    coupler, connector and occluder boxes, balls),
    for a physics-twin world or to ray-cast it with ``mujoco.mj_multiRay``."""
    geoms = [
        f'<geom name="floor" type="plane" size="{geometry.floor_half_size} '
        f'{geometry.floor_half_size} 0.1"/>'
    ]
    for i, tube in enumerate(geometry.tubes):
        ends = " ".join(f"{x:.6f}" for x in (*tube.p0, *tube.p1))
        geoms.append(
            f'<geom name="member{i}" type="cylinder" size="{tube.radius:.6f}" fromto="{ends}"/>'
        )
    for i, block in enumerate((*geometry.couplers, *geometry.occluders)):
        quat = Rotation.from_matrix(block.rotation).as_quat(scalar_first=True)
        geoms.append(
            f'<geom name="coupler{i}" type="box" size="{" ".join(f"{h:.6f}" for h in block.half)}"'
            f' pos="{" ".join(f"{x:.6f}" for x in block.centre)}"'
            f' quat="{" ".join(f"{q:.9f}" for q in quat)}"/>'
        )
    for i, ball in enumerate(geometry.balls):
        geoms.append(
            f'<geom name="ball{i}" type="sphere" size="{ball.radius:.6f}"'
            f' pos="{" ".join(f"{x:.6f}" for x in ball.centre)}"/>'
        )
    for i, plate in enumerate(geometry.plates):
        ends = " ".join(f"{x:.6f}" for x in (*plate.p0, *plate.p1))
        geoms.append(
            f'<geom name="plate{i}" type="cylinder" size="{plate.radius:.6f}" fromto="{ends}"/>'
        )
    body = "\n    ".join(geoms)
    return f'<mujoco model="{name}">\n  <worldbody>\n    {body}\n  </worldbody>\n</mujoco>\n'


def look_at_pose(eye, target) -> np.ndarray:
    """4x4 body pose at ``eye`` with body x towards ``target`` and body z as upright as possible."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    x = (target - eye) / np.linalg.norm(target - eye)
    y = np.cross([0.0, 0.0, 1.0], x)
    y /= np.linalg.norm(y)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([x, y, np.cross(x, y)])
    pose[:3, 3] = eye
    return pose


def orbit_poses(
    geometry: TrussGeometry,
    count: int = 5,
    distance: float = 2.6,
    height: float = 1.3,
    spread_deg: float = 150.0,
) -> list[np.ndarray]:
    """Body poses on an arc in front (+x) of the truss, all looking at its centre."""
    ends = np.array([p for t in geometry.tubes for p in (t.p0, t.p1)])
    centre = 0.5 * (ends.min(axis=0) + ends.max(axis=0))
    front = ends[:, 0].max()
    angles = np.radians(np.linspace(-spread_deg / 2, spread_deg / 2, count))
    return [
        look_at_pose(
            [front + distance * np.cos(a), centre[1] + distance * np.sin(a), height], centre
        )
        for a in angles
    ]


def _hit_tubes(origin: np.ndarray, dirs: np.ndarray, tubes: tuple[Tube, ...]) -> np.ndarray:
    """Ray parameter of the nearest hit on any closed finite cylinder (inf for none)."""
    best = np.full(len(dirs), np.inf)
    for tube in tubes:
        a, length, r = tube.axis, tube.length, tube.radius
        w = origin - tube.p0
        da = dirs @ a
        wa = w @ a
        dp = dirs - da[:, None] * a
        wp = w - wa * a
        qa = np.einsum("ij,ij->i", dp, dp)
        qb = 2 * dp @ wp
        qc = wp @ wp - r * r
        disc = qb * qb - 4 * qa * qc
        ok = (disc >= 0) & (qa > 1e-12)
        t = np.full(len(dirs), np.inf)
        da = np.where(np.abs(da) < 1e-12, 1e-12, da)
        t[ok] = (-qb[ok] - np.sqrt(disc[ok])) / (2 * qa[ok])
        s = wa + t * da
        t[(s < 0) | (s > length) | (t <= 0)] = np.inf
        with np.errstate(divide="ignore", invalid="ignore"):
            for cap in (0.0, length):
                tc = (cap - wa) / da
                radial = wp + tc[:, None] * dp
                inside = (np.einsum("ij,ij->i", radial, radial) <= r * r) & (tc > 0)
                t = np.where(inside & (tc < t), tc, t)
        best = np.minimum(best, t)
    return best


def _hit_blocks(origin: np.ndarray, dirs: np.ndarray, blocks: tuple[Block, ...]) -> np.ndarray:
    """Ray parameter of the nearest hit on any oriented box (slab test; inf for none)."""
    best = np.full(len(dirs), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        for block in blocks:
            o = block.rotation.T @ (origin - block.centre)
            d = dirs @ block.rotation
            t1 = (-block.half - o) / d
            t2 = (block.half - o) / d
            near = np.nanmax(np.minimum(t1, t2), axis=1)
            far = np.nanmin(np.maximum(t1, t2), axis=1)
            hit = (near <= far) & (near > 0)
            best = np.where(hit & (near < best), near, best)
    return best


def _hit_balls(origin: np.ndarray, dirs: np.ndarray, balls: tuple[Ball, ...]) -> np.ndarray:
    """Ray parameter of the nearest hit on any ball (inf for none)."""
    best = np.full(len(dirs), np.inf)
    for ball in balls:
        w = origin - ball.centre
        qa = np.einsum("ij,ij->i", dirs, dirs)
        qb = 2 * dirs @ w
        disc = qb * qb - 4 * qa * (w @ w - ball.radius**2)
        with np.errstate(invalid="ignore"):
            t = (-qb - np.sqrt(disc)) / (2 * qa)
        hit = (disc >= 0) & (t > 0)
        best = np.where(hit & (t < best), t, best)
    return best


def _hit_floor(origin: np.ndarray, dirs: np.ndarray, half_size: float) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -origin[2] / dirs[:, 2]
    xy = origin[:2] + t[:, None] * dirs[:, :2]
    hit = (t > 0) & (np.abs(xy) <= half_size).all(axis=1)
    return np.where(hit, t, np.inf)


def depth_image(geometry: TrussGeometry, pose: np.ndarray, camera: DepthCamera) -> np.ndarray:
    """Noise-free optical-z depth (m) of the geometry from a body pose (0 where nothing is hit)."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    rays_optical = np.stack(
        [(u - camera.ppx) / camera.fx, (v - camera.ppy) / camera.fy, np.ones(u.shape)], axis=-1
    ).reshape(-1, 3)
    to_world = pose[:3, :3] @ OPTICAL_TO_BODY
    dirs = rays_optical @ to_world.T
    origin = pose[:3, 3]
    t = np.minimum.reduce(
        [
            _hit_tubes(origin, dirs, geometry.tubes),
            _hit_blocks(origin, dirs, (*geometry.couplers, *geometry.occluders)),
            _hit_tubes(origin, dirs, geometry.plates),
            _hit_balls(origin, dirs, geometry.balls),
            _hit_floor(origin, dirs, geometry.floor_half_size),
        ]
    )
    z = np.where(np.isfinite(t), t, 0.0)  # rays have optical z = 1, so t is depth
    z[(z < camera.min_range) | (z > camera.max_range)] = 0.0
    return z.reshape(camera.height, camera.width)


def add_noise(depth: np.ndarray, camera: DepthCamera, noise: DepthNoise, rng) -> np.ndarray:
    """Kinect-2-like noise on a depth image: range/incidence sigma, flying pixels, dropouts,
    no returns from grazing surfaces."""
    z = depth.copy()
    valid = z > 0
    gy, gx = np.gradient(np.where(valid, z, np.nan))
    slope = np.hypot(gx * camera.fx, gy * camera.fy) / np.maximum(z, 1e-6)
    cos_incidence = 1.0 / np.sqrt(1.0 + np.nan_to_num(slope, nan=0.0) ** 2)
    sigma = noise.a + noise.b * z**2 + noise.c * (1.0 - cos_incidence)
    z = np.where(valid, z + rng.normal(size=z.shape) * sigma, 0.0)
    padded = np.pad(depth, 1, mode="edge")
    neighbours = np.stack(
        [padded[1:-1, :-2], padded[1:-1, 2:], padded[:-2, 1:-1], padded[2:, 1:-1]]
    )
    far = neighbours.max(axis=0)
    edge = valid & (far - depth > noise.edge_step) & (rng.random(z.shape) < noise.flying)
    z[edge] = depth[edge] + rng.random(np.count_nonzero(edge)) * (far[edge] - depth[edge])
    z[rng.random(z.shape) < noise.dropout] = 0.0
    if noise.grazing_from_deg >= 90.0:  # off: no draw, so the other noise is as without it
        return z
    incidence = np.degrees(np.arccos(cos_incidence))
    span = max(noise.grazing_to_deg - noise.grazing_from_deg, 1e-9)
    grazing = np.clip((incidence - noise.grazing_from_deg) / span, 0.0, 1.0)
    left, right, up, down = neighbours
    bend = np.maximum(np.abs(left + right - 2 * depth), np.abs(up + down - 2 * depth))
    jump = bend > noise.edge_step  # a depth edge, not a steep plane (flying pixels are there)
    z[valid & ~jump & (rng.random(z.shape) < grazing)] = 0.0
    return z


def deproject(depth: np.ndarray, camera: DepthCamera) -> np.ndarray:
    """Depth image to body-frame points (m) of the pixels with a return."""
    v, u = np.nonzero(depth > 0)
    z = depth[v, u]
    optical = np.column_stack(
        [(u - camera.ppx) / camera.fx * z, (v - camera.ppy) / camera.fy * z, z]
    )
    return optical @ OPTICAL_TO_BODY.T


def _body_state(pose: np.ndarray, stamp: float) -> BodyState:
    w, x, y, z = Rotation.from_matrix(pose[:3, :3]).as_quat(scalar_first=True)
    return BodyState(stamp=stamp, position=pose[:3, 3].tolist(), orientation=[w, x, y, z])


def render(
    geometry: TrussGeometry,
    poses: list[np.ndarray] | None = None,
    camera: DepthCamera | None = None,
    noise: DepthNoise | None = None,
    seed: int = 0,
) -> TrussScene:
    """View ``geometry`` from body ``poses`` (default: five on an arc in front) with noise."""
    camera = camera or DepthCamera()
    noise = noise or DepthNoise()
    rng = np.random.default_rng(seed)
    poses = poses if poses is not None else orbit_poses(geometry)
    scene = TrussScene(geometry)
    clouds = []
    for k, pose in enumerate(poses):
        depth = add_noise(depth_image(geometry, pose, camera), camera, noise, rng)
        reported = pose.copy()
        tilt = Rotation.from_rotvec(rng.normal(size=3) * noise.pose_rotation).as_matrix()
        reported[:3, :3] = tilt @ pose[:3, :3]
        reported[:3, 3] += rng.normal(size=3) * noise.pose_translation
        points = deproject(depth, camera)
        scene.views.append(View(points, _body_state(reported, k * 0.1), pose))
        clouds.append(points @ reported[:3, :3].T + reported[:3, 3])
    scene.cloud = np.concatenate(clouds)
    return scene
