"""MuJoCo model of a robot (built from its profile) standing in a world (built from its file).

The MJCF is generated in code. Each leg is a chain of three hinges in the leg frame (mount
position, mount yaw) with daemon/algorithms/kinematics.py's angles: coxa about z, femur and tibia
about −y (+ up, tibia relative to femur); or abduction about the leg's x, thigh and shank about +y
(+ down) where the kinematic shank angle is absolute (paper 004 eqs. 1–3), so the physical
knee hinge turns by θ_s − θ_t (``HingeMap``). At zero a leg lies straight out.
Joint-space ``q`` (what drivers and servos see) relates to the physical hinges through the
profile's ``direction`` and ``zero_offset``: θ = direction · (q − zero_offset).
Links are capsules, the foot a sphere
with friction. Every joint has a motor actuator whose torque the twin computes each step
(servos.py); torque robots also get joint torque sensors; grippers are adhesion actuators
grippers are connect constraints that hold a foot where it closed on a graspable geom and
let go when they would need more than 9 N (paper 001's grip force). The robot collides with
the world, not itself.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from climbd.daemon.contract.profile import Profile, has_grippers
from climbd.drivers.dynamixel.config import DynamixelConfig
from climbd.drivers.sim import servos
from climbd.drivers.sim.worlds import (
    World,
    hold_map_holds,
    hold_map_relief,
    holds_heightfield,
    wall_pose,
    yaw_matrix,
)

GRIP_FORCE = 9.0
"""Maximum grip force of a HubRobo spine gripper (N, paper 001)."""
GRIP_REACH = 0.005
"""Spine depth (m): how far from the surface a closed gripper still holds (ClimbLab: 5 mm)."""

WORLD_GROUP, BODY_GROUP, LEG_GROUP = 0, 1, 2
AXES = {
    "coxa_femur_tibia": ("0 0 1", "0 -1 0", "0 -1 0"),
    "abduction_thigh_shank": ("1 0 0", "0 1 0", "0 1 0"),
}
"""Hinge axes per leg kind, matching daemon/algorithms/kinematics.py: femur/tibia + up, thigh/shank
+ down."""
FOOT_MASS = 0.005
"""Rubber foot tip (kg)."""
BRACKET_MASS = 0.012
"""Frame and brackets carried with each servo (kg)."""


@dataclass
class RobotModel:
    """A compiled twin model plus the index arrays the twin needs, all in profile joint order."""

    model: mujoco.MjModel
    xml: str
    profile: Profile
    world: World
    motors: list[servos.ServoModel]
    torque_legs: bool
    qpos_adr: np.ndarray
    dof_adr: np.ndarray
    base_body: int
    foot_sites: np.ndarray
    foot_geoms: np.ndarray
    motor_actuators: np.ndarray
    graspable_geoms: np.ndarray
    grip_equalities: np.ndarray
    start: np.ndarray
    body_half_height: float
    foot_radius: float
    hfields: dict[str, np.ndarray] = field(default_factory=dict)
    relief_geom: int = -1
    """The rock height field of a hold map (-1: none); a gripper holds on it only at a hold."""
    relief_holds: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    """The holds the relief carries: their tops (m, world frame)."""
    wall_normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))

    @property
    def joint_count(self) -> int:
        return len(self.qpos_adr)

    def motor_array(self, name: str) -> np.ndarray:
        """One servo parameter (e.g. ``stall_torque``) per joint as an array."""
        return np.array([getattr(m, name) for m in self.motors], float)


def _fmt(values) -> str:
    return " ".join(f"{float(v):.10g}" for v in values)


def _quat_z(yaw: float) -> list[float]:
    return [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]


def _quat_y(angle: float) -> list[float]:
    return [math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0]


def _motors(profile: Profile) -> tuple[list[servos.ServoModel], bool]:
    """Per-joint actuator models: Dynamixel datasheets, or MIT motors from the profile limits."""
    if profile.bus.kind == "torque":
        return [
            servos.torque_motor(j.limits.effort, j.limits.velocity) for j in profile.joints
        ], True
    model = servos.servo_model(
        DynamixelConfig.from_profile(profile).model, profile.source or profile.name
    )
    return [model] * len(profile.joints), False


def _link_masses(profile: Profile, motors: list[servos.ServoModel], torque: bool) -> np.ndarray:
    """Mass (kg) of each leg link: the servo it carries plus brackets; torque legs take 35 %."""
    n = len(profile.joints)
    if torque:
        per_leg = 0.35 * profile.mass / len(profile.legs)
        return np.tile([0.4 * per_leg, 0.35 * per_leg, 0.25 * per_leg], len(profile.legs))
    masses = np.array([m.mass + BRACKET_MASS for m in motors])
    if masses.sum() >= 0.8 * profile.mass:
        masses *= 0.8 * profile.mass / masses.sum()
    return masses[:n]


def _add_world(world: World, worldbody: ET.Element, asset: ET.Element, base: Path) -> dict:
    """Append the world's geoms; return height fields to fill after compiling, by name."""
    common = {"contype": "0", "conaffinity": "1", "group": str(WORLD_GROUP)}
    fl = world.floor
    ET.SubElement(
        worldbody,
        "geom",
        name="floor",
        type="plane",
        size=_fmt([fl.size, fl.size, 0.1]),
        friction=_fmt([fl.friction, 0.005, 0.0001]),
        rgba=_fmt(fl.rgba),
        **common,
    )
    for r, row in enumerate(world.joists):
        rot = yaw_matrix(row.yaw_deg)
        for k in range(row.count):
            centre = np.array([row.distance, row.offset]) + rot @ [k * row.spacing, 0.0]
            ET.SubElement(
                worldbody,
                "geom",
                name=f"joist{r}_{k}",
                type="box",
                size=_fmt([row.width / 2, row.length / 2, row.height / 2]),
                pos=_fmt([*centre, row.height / 2]),
                quat=_fmt(_quat_z(math.radians(row.yaw_deg))),
                rgba=_fmt(row.rgba),
                **common,
            )
    for s, st in enumerate(world.stairs):
        rot = yaw_matrix(st.yaw_deg)
        for k in range(st.count):
            depth = st.tread if k < st.count - 1 else st.landing
            x0 = st.distance + k * st.tread
            centre = rot @ [x0 + depth / 2, 0.0]
            top = (k + 1) * st.rise
            ET.SubElement(
                worldbody,
                "geom",
                name=f"stair{s}_{k}",
                type="box",
                size=_fmt([depth / 2, st.width / 2, top / 2]),
                pos=_fmt([*centre, top / 2]),
                quat=_fmt(_quat_z(math.radians(st.yaw_deg))),
                rgba=_fmt(st.rgba),
                **common,
            )
    fields: dict[str, np.ndarray] = {}
    if world.holds is not None:
        h = world.holds
        heights, length, width = holds_heightfield(h, base)
        incline = math.radians(h.incline_deg)
        top = max(float(heights.max()), 1e-3)
        ET.SubElement(
            asset,
            "hfield",
            name="holds",
            nrow=str(heights.shape[1]),
            ncol=str(heights.shape[0]),
            size=_fmt([length / 2, width / 2, top, 0.02]),
        )
        centre = [h.distance + length / 2 * math.cos(incline), 0.0, length / 2 * math.sin(incline)]
        ET.SubElement(
            worldbody,
            "geom",
            name="holds",
            type="hfield",
            hfield="holds",
            pos=_fmt(centre),
            quat=_fmt(_quat_y(-incline)),
            friction=_fmt([h.friction, 0.005, 0.0001]),
            rgba=_fmt(h.rgba),
            **common,
        )
        fields["holds"] = (heights / top).T
    if world.hold_map is not None:
        fields.update(_add_hold_map(world, worldbody, asset))
    if world.truss is not None:
        t = world.truss
        nodes = np.asarray(t.nodes, float)
        for i, m in enumerate(t.members):
            ET.SubElement(
                worldbody,
                "geom",
                name=f"member{i}",
                type="cylinder",
                size=_fmt([t.radius]),
                fromto=_fmt([*nodes[m.a], *nodes[m.b]]),
                rgba=_fmt(t.rgba),
                **common,
            )
        for i, p in enumerate(nodes):
            ET.SubElement(
                worldbody,
                "geom",
                name=f"linker{i}",
                type="box",
                size=_fmt([t.linker / 2] * 3),
                pos=_fmt(p),
                rgba=_fmt([0.4, 0.4, 0.45, 1.0]),
                **common,
            )
    return fields


def _add_hold_map(world: World, worldbody: ET.Element, asset: ET.Element) -> dict[str, np.ndarray]:
    """The board (not graspable), the rock height field ``relief`` of a rock relief, and one
    column geom ``hold_<i>`` per hold the relief does not carry (all of them on columns).
    Returns the height fields' data."""
    h = world.hold_map
    origin, rotation = wall_pose(h)
    quat = _fmt(_quat_y(-math.radians(h.incline_deg)))
    common = {"contype": "0", "conaffinity": "1", "group": str(WORLD_GROUP)}
    friction = _fmt([h.friction, 0.005, 0.0001])
    length, width = h.along[1] - h.along[0], h.across[1] - h.across[0]
    centre = [(h.along[0] + h.along[1]) / 2, (h.across[0] + h.across[1]) / 2, -0.01]
    ET.SubElement(
        worldbody,
        "geom",
        name="board",
        type="box",
        size=_fmt([length / 2, width / 2, 0.01]),
        pos=_fmt(origin + rotation @ centre),
        quat=quat,
        friction=friction,
        rgba=_fmt(h.rgba),
        **common,
    )
    holds = hold_map_holds(world)
    fields: dict[str, np.ndarray] = {}
    if h.relief == "rock":
        heights = hold_map_relief(world)
        top = max(float(heights.max()), 1e-3)
        n_along, n_across = heights.shape
        size = [(n_along - 1) * h.resolution / 2, (n_across - 1) * h.resolution / 2]
        ET.SubElement(
            asset,
            "hfield",
            name="relief",
            nrow=str(n_across),
            ncol=str(n_along),
            size=_fmt([*size, top, 0.005]),
        )
        ET.SubElement(
            worldbody,
            "geom",
            name="relief",
            type="hfield",
            hfield="relief",
            pos=_fmt(origin + rotation @ [h.along[0] + size[0], h.across[0] + size[1], 0.0]),
            quat=quat,
            friction=friction,
            rgba=_fmt(h.hold_rgba),
            **common,
        )
        fields["relief"] = (heights / top).T
    first = len(holds) - len(h.extra) if h.relief == "rock" else 0
    for i, (x, y, top) in enumerate(holds[first:], first):
        ET.SubElement(
            worldbody,
            "geom",
            name=f"hold_{i}",
            type="cylinder",
            size=_fmt([h.hold_radius, top / 2]),
            pos=_fmt(origin + rotation @ [x, y, top / 2]),
            quat=quat,
            friction=friction,
            rgba=_fmt(h.hold_rgba),
            **common,
        )
    return fields


def _add_robot(
    profile: Profile,
    worldbody: ET.Element,
    actuators: ET.Element,
    sensors: ET.Element,
    equality: ET.Element,
    motors: list[servos.ServoModel],
    torque: bool,
    grippers: bool,
) -> tuple[float, float]:
    """Append the robot (a free base box with IMU and camera sites, and its legs).

    Returns the base box's half height and the foot radius (m).
    """
    mounts = np.array([leg.mount for leg in profile.legs])
    half = [
        max(np.abs(mounts[:, 0]).max(), 0.03),
        max(np.abs(mounts[:, 1]).max(), 0.03),
    ]
    hz = 0.15 * max(half)
    masses = _link_masses(profile, motors, torque)
    span = max(sum(leg.links) for leg in profile.legs)
    r_link = 0.045 * span
    r_foot = 0.04 * span if profile.foot_radius is None else profile.foot_radius
    base = ET.SubElement(worldbody, "body", name="base", pos="0 0 1")
    ET.SubElement(base, "freejoint", name="base")
    ET.SubElement(
        base,
        "geom",
        name="base",
        type="box",
        size=_fmt([*half, hz]),
        mass=f"{profile.mass - masses.sum() - FOOT_MASS * len(profile.legs):.6g}",
        rgba="0.2 0.2 0.22 1",
        contype="1",
        conaffinity="0",
        group=str(BODY_GROUP),
    )
    ET.SubElement(base, "site", name="imu", pos="0 0 0", size="0.005")
    for cam in profile.cameras:
        ET.SubElement(base, "site", name=f"camera_{cam.name}", pos=_fmt(cam.mount.position))
    ET.SubElement(sensors, "gyro", name="imu_gyro", site="imu")
    j = 0
    for leg in profile.legs:
        parent = base
        axes = AXES[leg.kind]
        pos = _fmt(leg.mount)
        for k, (joint, length) in enumerate(zip(leg.joints, leg.links, strict=True)):
            body = ET.SubElement(parent, "body", name=joint.name, pos=pos)
            if k == 0:
                body.set("quat", _fmt(_quat_z(leg.yaw)))
            motor = motors[j]
            ET.SubElement(
                body,
                "joint",
                name=joint.name,
                type="hinge",
                axis=axes[k],
                armature=f"{motor.armature:.6g}",
                frictionloss=f"{motor.friction:.6g}",
                damping="0.01",
            )
            ET.SubElement(
                body,
                "geom",
                name=f"{joint.name}_link",
                type="capsule",
                fromto=_fmt([0, 0, 0, length, 0, 0]),
                size=_fmt([r_link if k < 2 else 0.7 * r_link]),
                mass=f"{masses[j]:.6g}",
                rgba="0.15 0.15 0.15 1",
                contype="1",
                conaffinity="0",
                group=str(LEG_GROUP),
            )
            ET.SubElement(
                actuators,
                "motor",
                name=joint.name,
                joint=joint.name,
                ctrlrange=_fmt([-motor.stall_torque, motor.stall_torque]),
                ctrllimited="true",
            )
            if torque:
                ET.SubElement(
                    sensors, "jointactuatorfrc", name=f"{joint.name}_torque", joint=joint.name
                )
            parent, pos, j = body, _fmt([length, 0, 0]), j + 1
        foot = ET.SubElement(
            parent,
            "geom",
            name=f"{leg.name}_foot",
            type="sphere",
            pos=pos,
            size=_fmt([r_foot]),
            mass=f"{FOOT_MASS:.6g}",
            friction="0.8 0.005 0.0001",
            rgba="0.1 0.1 0.1 1",
            contype="1",
            conaffinity="0",
            group=str(LEG_GROUP),
        )
        if grippers:
            # Spines engage within GRIP_REACH: contacts exist there (margin) but push only on
            # touch (gap); the grip itself is a connect constraint, off until the twin closes it.
            foot.set("margin", _fmt([GRIP_REACH]))
            foot.set("gap", _fmt([GRIP_REACH]))
            ET.SubElement(
                equality,
                "connect",
                name=f"{leg.name}_grip",
                body1=leg.joints[-1].name,
                body2="world",
                anchor=pos,
                active="false",
            )
        ET.SubElement(parent, "site", name=f"{leg.name}_foot", pos=pos, size=_fmt([r_foot]))
    return hz, r_foot


def build(profile: Profile, world: World, timestep: float = 0.001) -> RobotModel:
    """Compile the MuJoCo model of ``profile`` in ``world`` with physics step ``timestep`` (s)."""
    motors, torque = _motors(profile)
    grippers = has_grippers(profile)
    root = ET.Element("mujoco", model=f"{profile.name}_in_{world.name}")
    ET.SubElement(
        root,
        "option",
        timestep=f"{timestep:.6g}",
        gravity=_fmt([0, 0, -world.gravity]),
        integrator="implicitfast",
        cone="elliptic",
    )
    ET.SubElement(root, "compiler", angle="radian", autolimits="true")
    ET.SubElement(ET.SubElement(root, "visual"), "global", offwidth="640", offheight="480")
    asset = ET.SubElement(root, "asset")
    worldbody = ET.SubElement(root, "worldbody")
    actuators = ET.SubElement(root, "actuator")
    sensors = ET.SubElement(root, "sensor")
    equality = ET.SubElement(root, "equality")
    base = Path(world.source).parent if world.source else Path.cwd()
    fields = _add_world(world, worldbody, asset, base)
    half_height, foot_radius = _add_robot(
        profile, worldbody, actuators, sensors, equality, motors, torque, grippers
    )
    xml = ET.tostring(root, encoding="unicode")
    try:
        model = mujoco.MjModel.from_xml_string(xml)
    except ValueError as e:
        raise ValueError(f"twin model of {profile.name} in {world.name}: {e}") from None
    for name, data in fields.items():
        hid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_HFIELD, name)
        model.hfield_data[model.hfield_adr[hid] : model.hfield_adr[hid] + data.size] = data.ravel()

    def ids(kind: mujoco.mjtObj, names: list[str]) -> np.ndarray:
        return np.array([mujoco.mj_name2id(model, kind, n) for n in names], int)

    joint_ids = ids(mujoco.mjtObj.mjOBJ_JOINT, profile.joint_names)
    legs = [leg.name for leg in profile.legs]
    graspable = [
        i
        for i in range(model.ngeom)
        if (
            model.geom(i).name in ("holds", "relief")
            or model.geom(i).name.startswith(("hold_", "member", "linker"))
        )
    ]
    return RobotModel(
        model=model,
        xml=xml,
        profile=profile,
        world=world,
        motors=motors,
        torque_legs=torque,
        qpos_adr=model.jnt_qposadr[joint_ids].copy(),
        dof_adr=model.jnt_dofadr[joint_ids].copy(),
        base_body=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "base"),
        foot_sites=ids(mujoco.mjtObj.mjOBJ_SITE, [f"{n}_foot" for n in legs]),
        foot_geoms=ids(mujoco.mjtObj.mjOBJ_GEOM, [f"{n}_foot" for n in legs]),
        motor_actuators=ids(mujoco.mjtObj.mjOBJ_ACTUATOR, profile.joint_names),
        graspable_geoms=np.array(graspable, int),
        grip_equalities=(
            ids(mujoco.mjtObj.mjOBJ_EQUALITY, [f"{n}_grip" for n in legs])
            if grippers
            else np.zeros(0, int)
        ),
        start=start_pose(world),
        body_half_height=half_height,
        foot_radius=foot_radius,
        hfields=fields,
        **_relief(world, model),
    )


def _relief(world: World, model: mujoco.MjModel) -> dict[str, object]:
    """The rock relief's geom, the world tops of the holds it carries and the wall's normal."""
    if world.hold_map is None or world.hold_map.relief != "rock":
        return {}
    origin, rotation = wall_pose(world.hold_map)
    carried = hold_map_holds(world)[: -len(world.hold_map.extra) or None]
    return {
        "relief_geom": mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "relief"),
        "relief_holds": origin + carried @ rotation.T,
        "wall_normal": rotation[:, 2],
    }


def start_pose(world: World) -> np.ndarray:
    """Base position (x, y, ground z) and quaternion (w, x, y, z) of the start, on any slope
    (on a hold map's board, ``start`` x, y are wall-frame coordinates)."""
    s = world.start
    yaw = math.radians(s.yaw_deg)
    q = np.array(_quat_z(yaw))
    ground = 0.0
    if world.hold_map is not None:
        origin, rotation = wall_pose(world.hold_map)
        pitch = np.array(_quat_y(-math.radians(world.hold_map.incline_deg)))
        return np.array([*(origin + rotation @ [s.x, s.y, 0.0]), *_quat_mul(pitch, q)])
    if world.holds is not None:
        h = world.holds
        incline = math.radians(h.incline_deg)
        along = (s.x - h.distance) / math.cos(incline)
        if along > 0:
            ground = along * math.sin(incline)
            pitch = np.array(_quat_y(-incline))
            q = _quat_mul(pitch, q)
    return np.array([s.x, s.y, ground, *q])


def _quat_mul(a, b) -> np.ndarray:
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, np.asarray(a, float), np.asarray(b, float))
    return out
