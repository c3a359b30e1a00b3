"""Grasp targets on truss members (issue #37 item 4): clear of nodes and crossing members, on
the axis, approached perpendicular to it, reachable in the pose they claim, offered to the
free-climb hold map; the profile's gripper section and the wire message."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import msgspec
import numpy as np
import pytest

from climbd.daemon.algorithms.feature_maps import HoldTracks, grasp_holds
from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.algorithms.world import WorldModel
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.geometry import rotation
from climbd.daemon.contract.hardware import DepthFrame, Intrinsics
from climbd.daemon.contract.messages import (
    BodyState,
    HoldMap,
    JointState,
    Joists,
    TrussGrasps,
    TrussMember,
    TrussMembers,
    TrussNode,
    decode,
    encode,
)
from climbd.daemon.contract.plugins import PerceptionPlugin, PluginError
from climbd.daemon.contract.profile import GripperConfig, ProfileError, load
from climbd.daemon.runtime.loader import Isolated, instantiate
from climbd.daemon.runtime.perception_role import PerceptionRole
from climbd.drivers.sim import truss_scene as ts
from climbd.plugins.gaits.free_climb import NORMAL, ClimbConfig, FreeClimb
from climbd.plugins.perception.truss.grasp import GraspConfig, segment_distances, truss_grasps

ROOT = Path(__file__).resolve().parent.parent
HUBROBO = load(ROOT / "robots" / "hubrobo.toml")
GRIPPER = GripperConfig(width=0.04, clearance=0.01)
PROFILE = msgspec.structs.replace(HUBROBO, gripper=GRIPPER)
KIN = Kinematics(PROFILE)
CONFIG = GraspConfig(spacing=0.03)
TURNED = [math.cos(math.pi / 12), 0.0, 0.0, math.sin(math.pi / 12)]  # 30° about z
BODY = BodyState(position=[0.3, 0.05, 0.12], orientation=TURNED)


def member(ident: int, p0, p1, radius: float = 0.02) -> TrussMember:
    axis = np.subtract(p1, p0) / np.linalg.norm(np.subtract(p1, p0))
    return TrussMember(p0=list(p0), p1=list(p1), radius=radius, axis=axis.tolist(), id=ident)


def ladder() -> TrussMembers:
    """A flat ladder in z = 0: rails 1 (y = 0) and 2 (x = 1), rail 3 (x = 0), a rung 6 at
    y = 1, a rung 5 of 0.1 m between two nodes (too short to grasp), and member 4 crossing
    over the rails at x = 0.5, 4 cm above them without a node (too near to grasp under); the
    node at (1, 0, 0) measured its reach, the others take the config's size."""
    members = [
        member(1, [0, 0, 0], [1, 0, 0]),
        member(2, [1, 0, 0], [1, 1, 0]),
        member(3, [0, 0, 0], [0, 1, 0]),
        member(4, [0.5, -0.5, 0.04], [0.5, 1.5, 0.04], radius=0.015),
        member(5, [0, 1, 0], [0.1, 1, 0]),
        member(6, [0.1, 1, 0], [1, 1, 0]),
    ]
    nodes = [
        TrussNode(position=[0, 0, 0], members=[1, 3]),
        TrussNode(position=[1, 0, 0], members=[1, 2], reach=0.08),
        TrussNode(position=[0, 1, 0], members=[3, 5]),
        TrussNode(position=[0.1, 1, 0], members=[5, 6]),
        TrussNode(position=[1, 1, 0], members=[2, 6]),
    ]
    return TrussMembers(stamp=2.0, frame_stamp=2.0, members=members, nodes=nodes)


@pytest.fixture(scope="module")
def grasps() -> TrussGrasps:
    return truss_grasps(ladder(), GRIPPER, CONFIG, BODY, KIN)


def axis_of(m: TrussMember) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    p0, p1 = np.array(m.p0), np.array(m.p1)
    return p0, p1, (p1 - p0) / np.linalg.norm(p1 - p0)


def test_every_grasp_is_on_its_member_clear_of_nodes_and_other_members(grasps):
    truss = ladder()
    by_id = {m.id: m for m in truss.members}
    least = GRIPPER.width / 2 + GRIPPER.clearance
    assert len(grasps.grasps) > 20
    for g in grasps.grasps:
        point = np.array(g.position)[None]
        p0, p1, axis = axis_of(by_id[g.member])
        assert segment_distances(point, p0, p1)[0] <= 1e-3
        for node in truss.nodes:
            size = node.reach or CONFIG.node_radius
            surface = np.linalg.norm(point[0] - node.position) - size
            assert surface >= least - 1e-9
        for other in truss.members:
            if other.id != g.member:
                gap = segment_distances(point, *axis_of(other)[:2])[0] - other.radius
                assert gap >= least - 1e-9
        assert g.clearance >= GRIPPER.clearance
        assert abs(np.dot(g.approach, axis)) < 1e-9
        assert np.linalg.norm(g.approach) == pytest.approx(1.0)
        ends = np.array(g.span)
        assert segment_distances(ends, p0, p1).max() <= 1e-9


def test_the_crossing_member_splits_a_rail_and_a_short_member_gives_none(grasps):
    on = {i: [g for g in grasps.grasps if g.member == i] for i in range(1, 7)}
    assert on[5] == []
    spans = {tuple(map(tuple, g.span)) for g in on[1]}
    assert len(spans) == 2  # either side of member 4
    xs = [g.position[0] for g in on[1]]
    assert min(xs) < 0.5 < max(xs)
    assert all(abs(x - 0.5) > GRIPPER.width / 2 for x in xs)
    assert all(on[i] for i in (1, 2, 3, 4, 6))


def test_grasps_are_approached_from_above(grasps):
    flat = [g for g in grasps.grasps if g.member != 4]
    assert all(np.allclose(g.approach, [0, 0, -1]) for g in flat)


def test_an_upright_member_is_approached_from_the_body_side():
    post = TrussMembers(members=[member(7, [0.5, 0.2, -0.5], [0.5, 0.2, 0.5])])
    body = BodyState(position=[0.5, 0.0, 0.0])
    found = truss_grasps(post, GRIPPER, CONFIG, body, KIN).grasps
    assert found and all(np.allclose(g.approach, [0, 1, 0]) for g in found)


def test_reachable_grasps_are_reached_by_ik_and_unreachable_ones_are_not(grasps):
    """Each grasp's ``limbs`` are the legs whose IK puts the foot on it (FK within 1 mm, joints
    within limits) from the message's body pose; for every other leg, no solution within the
    joint limits reaches it."""
    assert (grasps.frame_position, grasps.frame_orientation) == (BODY.position, BODY.orientation)
    to_body = rotation(grasps.frame_orientation).T
    reachable = [g for g in grasps.grasps if g.limbs]
    assert reachable and len(reachable) < len(grasps.grasps)
    for g in grasps.grasps:
        local = to_body @ (np.array(g.position) - grasps.frame_position)
        q, _ = KIN.ik(np.tile(local, (KIN.n_legs, 1)))
        within = np.clip(q, KIN.lower, KIN.upper)
        feet = KIN.fk(np.nan_to_num(within, nan=0.0))
        for leg in range(KIN.n_legs):
            legal = np.allclose(q[3 * leg : 3 * leg + 3], within[3 * leg : 3 * leg + 3])
            reached = np.linalg.norm(feet[leg] - local) <= 1e-3
            assert (leg in g.limbs) == (legal and reached)


def test_grasps_become_holds_the_free_climb_planner_picks():
    """Rungs across the climb's direction under and ahead of a standing HubRobo, as the only
    holds: the hold map takes the grasp points (heights kept), and the free-climb gait's first
    swing lands on one of them."""
    stand = KIN.stand_feet(ClimbConfig().base_height)
    rungs = sorted({round(x, 3) for x in stand[:, 0]} | {round(x + 0.05, 3) for x in stand[:, 0]})
    truss = TrussMembers(
        frame_stamp=1.0,
        members=[member(i + 1, [x, -0.4, 0.0], [x, 0.4, 0.0]) for i, x in enumerate(rungs)],
    )
    body = BodyState(position=[0.0, 0.0, ClimbConfig().base_height])
    offered = truss_grasps(truss, GRIPPER, GraspConfig(spacing=0.02), body, KIN)
    tracks = HoldTracks()
    tracks.offer(offered, None)
    holds = tracks.message(1.0, 1.0)
    assert isinstance(holds, HoldMap) and len(holds.holds) == len(offered.grasps)
    np.testing.assert_allclose(
        sorted(h.position for h in holds.holds), sorted(grasp_holds(offered).tolist())
    )
    gait = FreeClimb(ClimbConfig(), PROFILE)
    gait.stepped = True
    gait.start(body, stand)
    gait.step(0.0, 0.1, body, {HoldMap.TOPIC: holds}, None)
    gait.stop()
    (step,) = gait.runner.steps
    assert not step.wait
    assert np.linalg.norm(gait.holds - step.target, axis=1).min() < 1e-9
    centre = grasp_holds(offered) + PROFILE.foot_radius * NORMAL  # the foot's, on the grasp
    assert np.linalg.norm(centre - step.target, axis=1).min() < 1e-9


def test_profile_gripper_is_optional_and_range_checked():
    data = msgspec.to_builtins(HUBROBO)
    data.pop("source")
    assert profiles.from_dict(data).gripper is None
    ok = profiles.from_dict({**data, "gripper": {"width": 0.04, "clearance": 0.01}})
    assert ok.gripper == GRIPPER
    for bad, field in (
        ({"width": 0.0, "clearance": 0.01}, r"\$\.gripper\.width: expected 0\.005\.\.0\.3 m"),
        ({"width": 0.04, "clearance": -0.1}, r"\$\.gripper\.clearance: expected 0\.\.0\.2 m"),
        ({"width": 0.04}, r"\$\.gripper.*clearance"),
        ({"width": 0.04, "clearance": 0.01, "grip": 1}, r"\$\.gripper.*grip"),
    ):
        with pytest.raises(ProfileError, match=field):
            profiles.from_dict({**data, "gripper": bad})


def test_grasp_config_errors_name_the_field():
    with pytest.raises(PluginError, match=r"\$\.grasp\.spacing"):
        instantiate("climbd.perception", "truss", {"grasp": {"spacing": 0.0}}, PROFILE, "x")


def test_grasp_message_round_trips(grasps):
    back = decode(encode(grasps), TrussGrasps)
    assert back == grasps and back.width == GRIPPER.width
    assert TrussGrasps.TOPIC == "features/truss_grasps"


def test_the_plugin_publishes_grasps_beside_the_members_only_with_a_gripper():
    scene = ts.render(ts.five_member(), camera=ts.DepthCamera().scaled(0.5), seed=1)
    config = {"model_every": len(scene.views), "seed": 1, "grasp": {"spacing": 0.04}}
    outputs = {}
    for name, profile in (("gripper", PROFILE), ("none", HUBROBO)):
        plugin = instantiate("climbd.perception", "truss", config, profile, "test")
        outputs[name] = [plugin.process_cloud(v.points, v.body, v.body.stamp) for v in scene.views]
    assert isinstance(outputs["none"][-1], TrussMembers)
    truss, found = outputs["gripper"][-1]
    assert truss == outputs["none"][-1] and found.grasps
    body = scene.views[-1].body
    assert found.frame_position == body.position and found.frame_stamp == truss.frame_stamp
    by_id = {m.id: m for m in truss.members}
    for g in found.grasps:
        p0, p1, _ = axis_of(by_id[g.member])
        assert segment_distances(np.array([g.position]), p0, p1)[0] <= 1e-3


class TwoTopics(PerceptionPlugin):
    """Returns members and grasps from one model, and a feature it does not declare."""

    name = "two_topics"
    publishes = (TrussMembers, TrussGrasps)

    def process(self, frame: DepthFrame, body: BodyState) -> tuple:
        return TrussMembers(stamp=frame.timestamp), TrussGrasps(stamp=frame.timestamp), Joists()


def test_the_perception_role_publishes_each_declared_feature_of_a_tuple():
    role = PerceptionRole(PROFILE, argparse.Namespace())
    stand = Kinematics(PROFILE).stand_joints().tolist()
    for stamp in np.arange(0.0, 1.0, 0.01):
        role.on_body(BodyState(stamp=float(stamp), position=[0.1, 0.0, 0.2]))
        role.on_joints(JointState(stamp=float(stamp), position=stand))
    blank = np.zeros((8, 8), np.uint16)
    frame = DepthFrame(blank, 0.001, Intrinsics(8, 8, 4.0, 4.0, 4.0, 4.0), np.eye(4), 0.5)
    published: list = []
    role.perceive(frame, [Isolated("two_topics", TwoTopics())], published.append)
    features = [p for p in published if isinstance(p, (TrussMembers, TrussGrasps))]
    assert [type(f) for f in features] == [TrussMembers, TrussGrasps]
    assert all(f.frame_position == [0.1, 0.0, 0.2] for f in features)
    assert role.undeclared == 1 and role.published == 2


def test_the_world_model_offers_grasps_to_its_hold_map(grasps):
    world = WorldModel()
    world.feature(grasps)
    positions = [t.estimate for t in world.holds.tracker.tracks]
    np.testing.assert_allclose(positions, grasp_holds(grasps))
