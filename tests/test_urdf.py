"""``climbd urdf``: the URDF written from a profile has the profile's joints and limits, and its
chain of origins and axes, evaluated here as URDF defines them (no climbd code), puts every link
frame, foot and camera where the kinematics and the view's transforms do."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import msgspec
import numpy as np
import pytest

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.cli.main import main
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.hardware import mount_extrinsics
from climbd.daemon.runtime.urdf import urdf


def floats(text: str) -> np.ndarray:
    return np.array([float(v) for v in text.split()])


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = (f(a) for a in (roll, pitch, yaw) for f in (math.cos, math.sin))
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def about(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: rotation of ``angle`` about unit ``axis``."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


class Urdf:
    """A parsed URDF's kinematic tree, evaluated as the URDF specification says."""

    def __init__(self, text: str) -> None:
        self.root = ET.fromstring(text)
        self.joints = {j.get("name"): j for j in self.root.findall("joint")}
        self.parent_joint = {j.find("child").get("link"): j for j in self.joints.values()}
        self.links = [link.get("name") for link in self.root.findall("link")]

    def actuated(self) -> list[ET.Element]:
        return [
            j
            for j in self.joints.values()
            if j.get("type") in ("revolute", "continuous", "prismatic") and j.find("mimic") is None
        ]

    def value(self, joint: ET.Element, q: dict[str, float]) -> float:
        mimic = joint.find("mimic")
        if mimic is None:
            return q[joint.get("name")]
        other = self.joints[mimic.get("joint")]
        multiplier = float(mimic.get("multiplier", "1"))
        return multiplier * self.value(other, q) + float(mimic.get("offset", "0"))

    def pose(self, link: str, q: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """Position and rotation of ``link`` in the root link."""
        p, r = np.zeros(3), np.eye(3)
        while link in self.parent_joint:
            joint = self.parent_joint[link]
            origin = joint.find("origin")
            t = floats(origin.get("xyz", "0 0 0"))
            rot = rpy_matrix(*floats(origin.get("rpy", "0 0 0")))
            if joint.get("type") != "fixed":
                axis = floats(joint.find("axis").get("xyz"))
                rot = rot @ about(axis / np.linalg.norm(axis), self.value(joint, q))
            p, r = rot @ p + t, rot @ r
            link = joint.find("parent").get("link")
        assert link == "body", f"the tree's root is {link}"
        return p, r


def flipped(name: str) -> profiles.Profile:
    """A stock profile with every other joint reversed and turned (direction -1, zero offset),
    so the URDF's axes and origins must carry both."""
    data = msgspec.to_builtins(profiles.load(profiles.stock_profiles()[name]))
    for leg in data["legs"]:
        for k, joint in enumerate(leg["joints"]):
            if k != 1:
                joint["direction"] = -joint.get("direction", 1)
                joint["zero_offset"] = joint.get("zero_offset", 0.0) + 0.3
    return profiles.from_dict(data, f"{name}-flipped")


PROFILES = {
    name: lambda path=path: profiles.load(path) for name, path in profiles.stock_profiles().items()
}
PROFILES |= {f"{name}-flipped": lambda name=name: flipped(name) for name in ("widowx", "qingzhui")}


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_urdf_joints_and_frames_are_the_profile_and_its_kinematics(name: str) -> None:
    profile = PROFILES[name]()
    if not name.endswith("-flipped"):
        assert Path(profile.source).stem == name
    model = Urdf(urdf(profile))
    kin = Kinematics(profile)

    actuated = model.actuated()
    assert [j.get("name") for j in actuated] == [j.name for j in profile.joints]
    for element, joint in zip(actuated, profile.joints, strict=True):
        assert element.get("type") == "revolute"
        limit = element.find("limit")
        for field in ("lower", "upper", "velocity", "effort"):
            assert float(limit.get(field)) == getattr(joint.limits, field), (joint.name, field)
    names = {j.name for j in profile.joints}
    assert names | {f"{leg.name}_foot" for leg in profile.legs} <= set(model.links)

    rng = np.random.default_rng(7)
    zero = np.zeros(kin.n_joints)
    for q in [zero] + [kin.lower + rng.uniform(size=kin.n_joints) * (kin.upper - kin.lower)
                       for _ in range(5)]:  # fmt: skip
        by_name = dict(zip([j.name for j in profile.joints], q.tolist(), strict=True))
        feet = np.array([model.pose(f"{leg.name}_foot", by_name)[0] for leg in profile.legs])
        np.testing.assert_allclose(feet, kin.fk(q), atol=1e-6)
        # every link frame as the view's transforms chain it (Kinematics.link_frames)
        trans, quats = kin.link_frames(q)
        for leg_index, leg in enumerate(profile.legs):
            p, r = np.zeros(3), np.eye(3)
            frames = [*(j.name for j in leg.joints), f"{leg.name}_foot"]
            for frame, t, qk in zip(frames, trans[leg_index], quats[leg_index], strict=True):
                p, r = p + r @ t, r @ rotation(qk)
                up, ur = model.pose(frame, by_name)
                np.testing.assert_allclose(up, p, atol=1e-6, err_msg=frame)
                np.testing.assert_allclose(ur, r, atol=1e-6, err_msg=frame)
    for camera in profile.cameras:
        p, r = model.pose(f"camera_{camera.name}", {})
        t = mount_extrinsics(camera)
        np.testing.assert_allclose(p, t[:3, 3], atol=1e-9)
        np.testing.assert_allclose(r, t[:3, :3], atol=1e-9)


def test_climbd_urdf_writes_the_file(tmp_path, capsys) -> None:
    out = tmp_path / "widowx.urdf"
    assert main(["urdf", "--profile", "widowx", "-o", str(out)]) == 0
    root = ET.parse(out).getroot()
    assert root.tag == "robot" and root.get("name") == "widowx"
    assert main(["urdf", "--profile", str(tmp_path / "missing.toml")]) == 2
    assert "not found" in capsys.readouterr().err
