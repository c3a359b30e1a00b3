"""Issue 37 item 1, nodes as features (paper 003's truss modelling on space frames): members run
node to node and end on a connector (box, sphere or plate) of 1x-3x the tube diameter; the
modeller, told nothing of the connectors, reports each member's tube extent and its node-to-node
ends, checked against the generator's ground truth: lengths of both kinds within 2 %, end points
within 20 mm, axes within 1 deg, from oblique views (from 2.3 m up, looking down on the frame,
all around it) and from a partly occluded one.
"""

from __future__ import annotations

import msgspec
import mujoco
import numpy as np
import pytest

from climbd.daemon.contract.messages import (
    TrussMember,
    TrussMembers,
    TrussNode,
    decode,
    encode,
)
from climbd.drivers.sim import truss_scene as ts
from climbd.plugins.perception.truss import TrussConfig, TrussModeller, TrussPerception
from climbd.plugins.perception.truss.completion import Member
from climbd.plugins.perception.truss.evaluate import Accuracy, evaluate
from climbd.plugins.perception.truss.nodes import axes_point

CAMERA = ts.DepthCamera().scaled(0.75)
"""Three quarters of the Kinect 2 resolution: the same cases meet the goal as at the full one
(measured), in about half the time."""
AIM = np.array([-0.4, 0.0, 0.95])
"""The middle of the default space frame (m)."""


def oblique_poses(
    azimuths_deg: tuple[float, ...] = (20, 110, 200, 290),
    distance: float = 3.0,
    height: float = 2.3,
) -> list[np.ndarray]:
    """Body poses around the frame, 2.3 m up, looking down at its middle."""
    return [
        ts.look_at_pose(
            [AIM[0] + distance * np.cos(a), AIM[1] + 0.87 * distance * np.sin(a), height], AIM
        )
        for a in np.radians(azimuths_deg)
    ]


def tube_accuracy(members: list[Member], geometry: ts.TrussGeometry) -> Accuracy:
    """Tube extents against the true tubes."""
    truth = [(t.p0, t.p1, t.radius) for t in geometry.tubes]
    return evaluate([(m.p0, m.p1) for m in members], truth)


def node_accuracy(members: list[Member], geometry: ts.TrussGeometry) -> Accuracy:
    """Node-to-node ends against the true nodes of each member."""
    radius = geometry.tubes[0].radius
    truth = [(geometry.nodes[a], geometry.nodes[b], radius) for a, b in geometry.links]
    return evaluate([m.ends for m in members], truth)


def assert_goal(tubes: Accuracy, nodes: Accuracy) -> None:
    """Issue 37's figures on every member: both lengths within 2 %, ends within 20 mm, axes
    within 1 deg; every member found, none false."""
    for accuracy in (tubes, nodes):
        assert accuracy.all_found
        assert accuracy.false_members == 0
        assert accuracy.max("relative_length_error") <= 0.02
        assert accuracy.max("end_error") <= 0.020
        assert accuracy.max("angle_error_deg") <= 1.0


# --- the generator ----------------------------------------------------------------------------


@pytest.mark.parametrize("shape", ["box", "sphere", "plate"])
def test_space_frame_tubes_run_node_to_node_and_end_outside_the_connector(shape):
    frame = ts.space_frame(shape, factor=2.0, diameter=0.05)
    assert len(frame.tubes) == len(frame.links) == len(ts.FRAME_LINKS)
    connectors = {"box": frame.couplers, "sphere": frame.balls, "plate": frame.plates}
    assert {s: len(c) for s, c in connectors.items() if c} == {shape: len(frame.nodes)}
    for tube, (a, b) in zip(frame.tubes, frame.links, strict=True):
        axis = (frame.nodes[b] - frame.nodes[a]) / np.linalg.norm(frame.nodes[b] - frame.nodes[a])
        assert tube.axis @ axis == pytest.approx(1.0)
        for end, node in ((tube.p0, frame.nodes[a]), (tube.p1, frame.nodes[b])):
            # on the member's axis, clear of the tubes meeting at right angles (r) and of the
            # connector: a box's face 50 mm out, a 50 mm ball's surface where it meets the
            # tube's (sqrt(R^2 - r^2)), a plate's 25 mm
            assert np.linalg.norm(np.cross(end - node, axis)) < 1e-9
            least = {"box": 0.05, "sphere": np.sqrt(0.05**2 - 0.025**2), "plate": 0.025}[shape]
            assert np.linalg.norm(end - node) >= least - 1e-9


def test_spheres_and_plates_ray_cast_as_mujoco_does():
    """The ray caster's balls and plates (short closed cylinders) against mj_multiRay, at a
    fifth of the resolution."""
    camera = CAMERA.scaled(0.2)
    for shape in ("sphere", "plate"):
        frame = ts.space_frame(shape, factor=3.0, diameter=0.06)
        model = mujoco.MjModel.from_xml_string(ts.to_mjcf(frame))
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        for pose in oblique_poses((20, 200)):
            ours = ts.depth_image(frame, pose, camera)
            v, u = np.mgrid[0 : camera.height, 0 : camera.width]
            rays = np.stack(
                [(u - camera.ppx) / camera.fx, (v - camera.ppy) / camera.fy, np.ones(u.shape)], -1
            ).reshape(-1, 3)
            vec = rays @ (pose[:3, :3] @ ts.OPTICAL_TO_BODY).T
            n = len(vec)
            geom, dist = np.zeros(n, np.int32), np.zeros(n)
            mujoco.mj_multiRay(
                model,
                data,
                pose[:3, 3],
                vec.ravel(),
                None,
                1,
                -1,
                geom,
                dist,
                np.zeros(3 * n),
                n,
                9,
            )
            theirs = np.where(geom >= 0, dist, 0.0).reshape(ours.shape)
            theirs[(theirs < camera.min_range) | (theirs > camera.max_range)] = 0.0
            assert np.array_equal(ours > 0, theirs > 0)
            np.testing.assert_allclose(ours, theirs, atol=1e-5)  # the MJCF's 6 decimals


def test_the_node_is_the_least_squares_point_nearest_the_axes():
    through = np.array([1.0, 2.0, 3.0])
    axes = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8], [0.0, 0.0, 1.0]])
    origins = through - np.array([0.3, -0.5, 1.2])[:, None] * axes
    np.testing.assert_allclose(axes_point(origins, axes), through, atol=1e-12)
    # two skew lines 0.2 m apart: halfway between them
    skew = axes_point(
        np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.2]]), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    )
    np.testing.assert_allclose(skew, [0.0, 0.0, 0.1], atol=1e-12)


# --- detection on noise-free views: the figures --------------------------------------


def _cases():
    for shape in ("box", "sphere", "plate"):
        for factor in (1.0, 3.0):
            for diameter in (0.03, 0.08):
                yield pytest.param(
                    shape, factor, diameter, id=f"{shape}-{factor:g}x-{diameter * 1000:g}mm"
                )


@pytest.mark.parametrize(("shape", "factor", "diameter"), list(_cases()))
def test_tube_extent_and_node_to_node_within_the_goal(shape, factor, diameter):
    frame = ts.space_frame(shape, factor, diameter)
    scene = ts.render(frame, oblique_poses(), CAMERA, ts.NO_NOISE)
    members = TrussModeller().model(scene.cloud).members
    assert_goal(tube_accuracy(members, frame), node_accuracy(members, frame))


def test_the_posts_hidden_under_3x_cubes_meet_the_goal_once_seen_from_below():
    """From above, the posts' top 30-34 mm lie hidden under the 240 mm cubes, and their ends
    are the cubes' faces (``nodes.hidden_end``; 5.08 %, 33.5 mm short before it). Two more
    views from 0.9 m up show those tops: the goal holds on what is seen too."""
    frame = ts.space_frame("box", 3.0, 0.08)
    poses = oblique_poses() + oblique_poses((65, 245), height=0.9)
    scene = ts.render(frame, poses, CAMERA, ts.NO_NOISE)
    members = TrussModeller().model(scene.cloud).members
    assert_goal(tube_accuracy(members, frame), node_accuracy(members, frame))


def test_a_partly_occluded_view_keeps_the_goal():
    """A 0.6 x 0.7 m board 0.5 m in front of the left bay hides the middle of its members in
    all three views (from the front); the completion bridges the gaps, the board goes as a
    plane."""
    board = ts.Block(np.array([0.5, -0.4, 1.0]), np.eye(3), np.array([0.01, 0.3, 0.35]))
    frame = ts.space_frame("sphere", 2.0, 0.05, occluder=board)
    poses = oblique_poses((-40, 0, 40))
    scene = ts.render(frame, poses, CAMERA, ts.NO_NOISE)
    facing_board = np.abs(scene.cloud[:, 0] - 0.51) < 0.005
    assert facing_board.sum() > 1000  # the board is in view, in front of the frame
    members = TrussModeller().model(scene.cloud).members
    assert_goal(tube_accuracy(members, frame), node_accuracy(members, frame))


@pytest.mark.parametrize("shape", ["box", "sphere", "plate"])
def test_a_member_ending_alone_at_a_connector_gets_the_blobs_centre(shape):
    """A member sticking up from the frame ends on a connector no other member meets: its node
    falls back to the blob's centre. (On a plate, before the open-slice rule in nodes.py, the
    tube ran on over the plate's faces, its end 99.6 mm out, and no node was found.)"""
    top = np.array([0.0, 0.8, 2.1])
    nodes = np.vstack([ts.FRAME_NODES, top])
    frame = ts.space_frame(shape, 2.0, 0.05, nodes=nodes, links=(*ts.FRAME_LINKS, (5, 8)))
    scene = ts.render(frame, oblique_poses(), CAMERA, ts.NO_NOISE)
    members = TrussModeller().model(scene.cloud).members
    (alone,) = [m for m in members if max(m.p0[2], m.p1[2]) > 1.6]
    ends = sorted(alone.ends, key=lambda p: p[2])
    assert np.linalg.norm(ends[1] - top) <= 0.020
    assert np.linalg.norm(ends[0] - ts.FRAME_NODES[5]) <= 0.020
    tube = frame.tubes[-1]
    assert np.linalg.norm(max(alone.p0, alone.p1, key=lambda p: p[2]) - tube.p1) <= 0.020


# --- detection with Kinect-2-like noise ------------------------------------------------------


def test_with_depth_noise_the_measured_figures_hold():
    """DepthNoise() (axial noise, flying pixels, dropouts, pose error per view) on a frame of
    48 mm tubes and 2x boxes, seed 3. Measured: every member, none false; tube extent worst
    1.03 % / 9.5 mm (mean 0.66 %), node-to-node worst 0.26 % / 3.3 mm (mean 0.15 %), axes
    worst 0.29 deg (mean 0.11): within the goal's 2 % / 20 mm / 1 deg. The bounds are those
    figures with a margin."""
    frame = ts.space_frame("box", 2.0, 0.048)
    scene = ts.render(frame, oblique_poses(), CAMERA, ts.DepthNoise(), seed=3)
    members = TrussModeller().model(scene.cloud).members
    tubes, nodes = tube_accuracy(members, frame), node_accuracy(members, frame)
    assert tubes.all_found and nodes.all_found
    assert tubes.false_members == 0
    assert tubes.max("relative_length_error") <= 0.02
    assert tubes.max("end_error") <= 0.020
    assert tubes.mean("relative_length_error") <= 0.01
    assert nodes.max("relative_length_error") <= 0.01
    assert nodes.max("end_error") <= 0.010
    assert nodes.mean("relative_length_error") <= 0.005
    assert tubes.max("angle_error_deg") <= 1.0
    assert tubes.mean("angle_error_deg") <= 0.3


def test_with_depth_noise_tubes_stop_at_3x_plates():
    """DepthNoise() on 80 mm tubes ending on plates 3x their diameter, seed 3: the plates'
    faces cross the tubes' bores, and those open slices end the noisy tubes too (the rule was
    off on a shell as thick as the surface tolerance: 18.6 %, 80 mm before). Measured: tube
    extent worst 2.20 % / 16.4 mm, every member, none false; short of the 2 % goal on these
    0.56 m tubes, and bounded here with a margin."""
    frame = ts.space_frame("plate", 3.0, 0.08)
    scene = ts.render(frame, oblique_poses(), CAMERA, ts.DepthNoise(), seed=3)
    tubes = tube_accuracy(TrussModeller().model(scene.cloud).members, frame)
    assert tubes.all_found and tubes.false_members == 0
    assert tubes.max("relative_length_error") <= 0.03
    assert tubes.max("end_error") <= 0.025


def test_the_plugin_publishes_tube_extents_and_nodes():
    """Through the plugin and the wire: each member's node ends and each node's reach."""
    frame = ts.space_frame("box", 2.0, 0.05)
    scene = ts.render(frame, oblique_poses(), CAMERA.scaled(2 / 3), ts.NO_NOISE)
    plugin = TrussPerception(TrussConfig(model_every=len(scene.views)))
    outputs = [plugin.process_cloud(v.points, v.body, v.body.stamp) for v in scene.views]
    message = decode(encode(outputs[-1]), TrussMembers)
    assert len(message.members) == len(frame.tubes)
    assert all(len(m.node0) == 3 and len(m.node1) == 3 for m in message.members)
    assert len(message.nodes) == len(frame.nodes)
    for node in message.nodes:
        assert np.linalg.norm(frame.nodes - node.position, axis=1).min() < 0.020
        assert 0.05 <= node.reach < 0.15


def test_old_messages_without_node_fields_still_decode():
    """A TrussMembers payload from before the node fields decodes with their defaults."""
    message = TrussMembers(
        stamp=1.0,
        members=[TrussMember(p0=[0, 0, 0], p1=[1, 0, 0], radius=0.02, axis=[1, 0, 0])],
        nodes=[TrussNode(position=[0, 0, 0], members=[1, 2])],
    )
    old = msgspec.to_builtins(message)
    for member in old["members"]:
        del member["node0"], member["node1"]
    del old["nodes"][0]["reach"]
    decoded = decode(msgspec.msgpack.encode(old), TrussMembers)
    assert decoded.members[0].node0 == [] and decoded.members[0].node1 == []
    assert decoded.nodes[0].reach == 0.0


def test_a_member_left_without_surface_points_ends_its_completion_without_error():
    """At full Kinect-2 resolution from the bench's views, a 240 mm cube's edge refitted as a
    cylinder kept no point on its surface, and the next slide of the completion raised on the
    empty set (found by bench/truss.py --frames). The model now completes with every member;
    one cube edge stays a false member (measured)."""
    frame = ts.space_frame("box", 3.0, 0.08)
    poses = [
        ts.look_at_pose(AIM + [3.0 * np.cos(a), 2.6 * np.sin(a), 1.35], AIM)
        for a in np.radians([20, 110, 200, 290])
    ]
    scene = ts.render(frame, poses, ts.DepthCamera(), ts.NO_NOISE, seed=0)
    members = TrussModeller().model(scene.cloud).members
    tubes = tube_accuracy(members, frame)
    assert tubes.all_found and tubes.false_members <= 1
