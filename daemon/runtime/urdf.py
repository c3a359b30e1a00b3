"""A robot's URDF from its profile (``climbd urdf``), in the frames ``climbd view`` draws.

Links are named as scene.py names its frames, so the URDF and the view's transforms are one
tree: ``body`` is the root; each leg's joints are named as the profile names them and each
moves the link of the same name (``rf_coxa`` → ``rf_femur`` → ``rf_tibia``), whose frame sits
on that joint's axis with x along the link (``Kinematics.link_frames``); ``<leg>_foot`` hangs
``links[2]`` along the last link's x, and ``camera_<name>`` is each camera's optical frame
(x right, y down, z forward) at its mount.

A joint's URDF value is its position as the profile counts it (what ``JointState`` carries):
the joint's ``direction`` flips its axis and its ``zero_offset`` turns its origin, so a URDF
consumer fed a JointState puts every link where the kinematics does, within the profile's
limits. An ``abduction_thigh_shank`` leg's shank turns relative to the thigh by its angle minus
the thigh's (the shank's drive is on the hip, not on the knee): a continuous joint
``<shank>_coupling`` mimics the thigh (``-direction``, offset ``direction · zero_offset``) to
take the thigh's angle back out, so the shank's own joint still takes the shank's position.

Visuals and collisions are the primitives the view draws (scene.RobotScene.geometry): a slab
for the body, a cylinder per link, a sphere per foot, a small box per camera.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Sequence

import numpy as np

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.profile import Profile
from climbd.daemon.runtime.scene import BODY, RobotScene

CFT = "coxa_femur_tibia"


def rpy(r: np.ndarray) -> tuple[float, float, float]:
    """URDF roll, pitch, yaw of rotation matrix ``r`` (r = Rz(yaw) Ry(pitch) Rx(roll))."""
    pitch = math.atan2(-r[2, 0], math.hypot(r[2, 1], r[2, 2]))
    if math.hypot(r[2, 1], r[2, 2]) < 1e-9:  # pitch ±90°: roll and yaw share an axis
        return 0.0, pitch, math.atan2(-r[0, 1], r[1, 1])
    return math.atan2(r[2, 1], r[2, 2]), pitch, math.atan2(r[1, 0], r[0, 0])


def axis_rotation(axis: Sequence[float], angle: float) -> np.ndarray:
    """Rotation matrix of ``angle`` about unit ``axis``."""
    half = angle / 2
    return rotation([math.cos(half), *(math.sin(half) * np.asarray(axis, float))])


def _number(value: float) -> str:
    """The shortest text that reads back as ``value`` exactly (no ``-0``)."""
    return repr(float(value) + 0.0)


def _numbers(values: Sequence[float]) -> str:
    return " ".join(_number(v) for v in values)


class _Writer:
    def __init__(self, name: str) -> None:
        self.root = ET.Element("robot", name=name)
        ET.SubElement(self.root, "material", name="link").append(
            ET.Element("color", rgba="0.55 0.6 0.7 1")
        )
        ET.SubElement(self.root, "material", name="body").append(
            ET.Element("color", rgba="0.3 0.35 0.45 0.9")
        )
        ET.SubElement(self.root, "material", name="camera").append(
            ET.Element("color", rgba="0.1 0.5 0.9 1")
        )

    def link(self, name: str, shape: ET.Element | None = None, at=(0, 0, 0), turn=(0, 0, 0),
             material: str = "link") -> None:  # fmt: skip
        link = ET.SubElement(self.root, "link", name=name)
        if shape is None:
            return
        for part in ("visual", "collision"):
            element = ET.SubElement(link, part)
            ET.SubElement(element, "origin", xyz=_numbers(at), rpy=_numbers(turn))
            ET.SubElement(element, "geometry").append(shape)
            if part == "visual":
                ET.SubElement(element, "material", name=material)

    def joint(self, name: str, kind: str, parent: str, child: str, xyz, r: np.ndarray,
              axis=None, limits=None, mimic=None) -> None:  # fmt: skip
        joint = ET.SubElement(self.root, "joint", name=name, type=kind)
        ET.SubElement(joint, "origin", xyz=_numbers(xyz), rpy=_numbers(rpy(r)))
        ET.SubElement(joint, "parent", link=parent)
        ET.SubElement(joint, "child", link=child)
        if axis is not None:
            ET.SubElement(joint, "axis", xyz=_numbers(axis))
        if limits is not None:
            ET.SubElement(
                joint,
                "limit",
                lower=_number(limits.lower),
                upper=_number(limits.upper),
                velocity=_number(limits.velocity),
                effort=_number(limits.effort),
            )
        if mimic is not None:
            other, multiplier, offset = mimic
            ET.SubElement(
                joint,
                "mimic",
                joint=other,
                multiplier=_number(multiplier),
                offset=_number(offset),
            )


def _shape(kind: str, **attrs: float | Sequence[float]) -> ET.Element:
    return ET.Element(
        kind, {k: _numbers(v) if isinstance(v, Sequence) else _number(v) for k, v in attrs.items()}
    )


def urdf(profile: Profile) -> str:
    """The URDF (XML text) of ``profile``'s robot."""
    robot = RobotScene(profile)
    kin: Kinematics = robot.kinematics
    links = np.stack([kin.l1, kin.l2, kin.l3], 1)
    positive = links[links > 0]
    thickness = max(0.01, 0.15 * float(np.median(positive)) if positive.size else 0.02)
    out = _Writer(profile.name)

    lo, hi = kin.mount.min(0), kin.mount.max(0)
    size = np.maximum(hi - lo, thickness) + [thickness, thickness, 0.0]
    size[2] = max(size[2], 2 * thickness)
    out.link(BODY, _shape("box", size=size.tolist()), at=((lo + hi) / 2).tolist(), material="body")

    along_x = (0.0, math.pi / 2, 0.0)  # a URDF cylinder runs along its z: Ry(90°) lays it on x
    for leg_index, (leg, chain) in enumerate(zip(profile.legs, robot.leg_frames, strict=True)):
        cft = leg.kind == CFT
        # each joint's kinematic axis in its frame, and the fixed turn before it
        axes = ([0, 0, 1], [0, -1, 0], [0, -1, 0]) if cft else ([1, 0, 0], [0, 1, 0], [0, 1, 0])
        fixed = [
            axis_rotation([0, 0, 1], leg.yaw),
            np.eye(3),
            np.eye(3),
        ]
        offsets = [leg.mount, [links[leg_index, 0], 0, 0], [links[leg_index, 1], 0, 0]]
        parent = BODY
        for k, joint in enumerate(leg.joints):
            name = chain[k]
            length = float(links[leg_index, k])
            cylinder = (
                _shape("cylinder", radius=thickness / 2, length=length) if length > 0 else None
            )
            d, zero = float(joint.direction), float(joint.zero_offset)
            if not cft and k == 2:  # the shank turns by its angle minus the thigh's
                thigh = leg.joints[1]
                coupling = f"{name}_coupling"
                out.link(coupling)
                out.joint(
                    coupling,
                    "continuous",
                    parent,
                    coupling,
                    offsets[k],
                    np.eye(3),
                    axis=axes[k],
                    mimic=(
                        thigh.name,
                        -float(thigh.direction),
                        float(thigh.direction) * float(thigh.zero_offset),
                    ),
                )
                parent, origin = coupling, [0.0, 0.0, 0.0]
            else:
                origin = offsets[k]
            # theta = d (q - zero): R(a, theta) = R(a, -d zero) R(d a, q)
            turn = fixed[k] @ axis_rotation(axes[k], -d * zero)
            out.link(name, cylinder, at=(length / 2, 0.0, 0.0), turn=along_x)
            out.joint(
                name,
                "revolute",
                parent,
                name,
                origin,
                turn,
                axis=(d * np.asarray(axes[k], float)).tolist(),
                limits=joint.limits,
            )
            parent = name
        foot = chain[3]
        out.link(foot, _shape("sphere", radius=0.75 * thickness))
        out.joint(f"{foot}_fixed", "fixed", parent, foot, [links[leg_index, 2], 0, 0], np.eye(3))

    for name, t, q in robot.cameras:
        out.link(name, _shape("box", size=[0.09, 0.025, 0.025]), at=(0, 0, -0.0125),
                 material="camera")  # fmt: skip
        out.joint(f"{name}_fixed", "fixed", BODY, name, t, rotation(q))

    ET.indent(out.root)
    source = profile.source or "its profile"
    header = f"<!-- {profile.name}: written by climbd urdf from {source} -->"
    return f"<?xml version='1.0'?>\n{header}\n" + ET.tostring(out.root, encoding="unicode") + "\n"
