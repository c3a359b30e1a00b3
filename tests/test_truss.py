"""Truss modelling (paper 003): cylinder fits, the gap rule, completion, merging, the acceptance
figures on generated 5- and 7-member trusses, and the plugin through its entry point."""

from __future__ import annotations

import json
import subprocess
import sys

import msgspec
import numpy as np
import pytest

from climbd.daemon.contract.messages import BodyState, TrussMembers, decode, encode
from climbd.daemon.contract.plugins import PluginError
from climbd.daemon.runtime.loader import instantiate
from climbd.drivers.sim import truss_scene as ts
from climbd.plugins.perception.truss import TrussConfig, TrussModeller, TrussPerception
from climbd.plugins.perception.truss.cloud import ball_normals, voxel_downsample
from climbd.plugins.perception.truss.completion import (
    Member,
    complete,
    gap_reach,
    merge_members,
    node_ends,
    paper_gap_reach,
)
from climbd.plugins.perception.truss.cylinders import Cylinder, Segment, hypotheses, refine
from climbd.plugins.perception.truss.evaluate import evaluate
from climbd.plugins.perception.truss.nodes import connectors, end_distance

CAMERA = ts.DepthCamera().scaled(0.5)
NO_GRAZING = ts.DepthNoise(grazing_from_deg=90.0, grazing_to_deg=90.0)
"""The generator's noise without its loss of returns from grazing surfaces: the acceptance
figures below were set on it; they hold with that loss too
(``test_grazing_loss_keeps_a_post_whole_at_a_coupler``)."""


def _tube_points(p0, p1, radius, rng, noise=0.0, spacing=0.005, visible=np.pi, facing=None):
    """Points on the side of a tube that faces ``facing`` (an arc of ``visible`` rad)."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    axis = (p1 - p0) / np.linalg.norm(p1 - p0)
    facing = np.asarray(facing if facing is not None else [1.0, 0.0, 0.0])
    u = facing - (facing @ axis) * axis
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    t = np.arange(0, np.linalg.norm(p1 - p0), spacing)
    phi = np.arange(-visible / 2, visible / 2, spacing / radius)
    tt, pp = np.meshgrid(t, phi)
    rr = radius + rng.normal(0, noise, tt.shape) if noise else np.full(tt.shape, radius)
    radial = np.cos(pp)[..., None] * u + np.sin(pp)[..., None] * v
    return (p0 + tt[..., None] * axis + rr[..., None] * radial).reshape(-1, 3)


def _angle_deg(a, b) -> float:
    return float(
        np.degrees(np.arccos(min(1.0, abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b))))
    )


# --- the pieces -----------------------------------------------------------------------------


def test_two_oriented_points_give_the_exact_cylinder():
    axis = np.array([0.3, -0.2, 0.93])
    axis /= np.linalg.norm(axis)
    u = np.cross(axis, [1.0, 0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    centre, r = np.array([0.4, 1.0, -0.2]), 0.03
    n1, n2 = u, np.cos(1.2) * u + np.sin(1.2) * v
    p1, p2 = centre + r * n1, centre + 0.25 * axis + r * n2
    c, a, radius, valid = hypotheses(p1[None], n1[None], p2[None], -n2[None])
    assert valid[0]
    assert radius[0] == pytest.approx(r, abs=1e-12)
    assert _angle_deg(a[0], axis) < 1e-6
    w = c[0] - centre
    assert np.linalg.norm(w - (w @ axis) * axis) < 1e-12


def test_radius_fit_on_r_is_unbiased_on_a_half_visible_noisy_tube():
    """The geometric fit (r, not r^2) keeps the radius and axis under Kinect-like noise."""
    rng = np.random.default_rng(0)
    errors, angles = [], []
    for _ in range(10):
        points = _tube_points([0, 0, 0], [0, 0, 1.0], 0.024, rng, noise=0.003, visible=2.6)
        start = Cylinder(np.array([0.005, 0.004, 0.5]), np.array([0.02, -0.01, 1.0]), 0.03)
        fit = refine(points, Cylinder(start.point, start.axis / np.linalg.norm(start.axis), 0.03))
        errors.append(fit.radius - 0.024)
        angles.append(_angle_deg(fit.axis, np.array([0, 0, 1.0])))
    assert abs(np.mean(errors)) < 0.0005
    assert max(angles) < 0.2


@pytest.mark.parametrize("along", [0.0, 0.5, 1.0])
def test_a_fit_started_far_along_the_axis_converges(along):
    """A start whose axis point lies ``along`` m past the points' middle, 2 deg off the axis:
    the fit tilts the axis about the points' centroid, as its Jacobian assumes, and lands on
    the true tube (a tilt about the far start point diverged from 0.5 m on)."""
    rng = np.random.default_rng(1)
    points = _tube_points([0, 0, 0], [0, 0, 1.0], 0.024, rng, visible=np.pi)
    tilt = np.radians(2.0)
    start = Cylinder(
        np.array([0.004, -0.003, 0.5 + along]), np.array([np.sin(tilt), 0, np.cos(tilt)]), 0.03
    )
    fit = refine(points, start)
    assert _angle_deg(fit.axis, np.array([0, 0, 1.0])) < 1e-3
    assert fit.radius == pytest.approx(0.024, abs=1e-5)
    assert np.hypot(*fit.point[:2]) < 1e-5


@pytest.mark.parametrize(
    ("distances", "reach", "open_ended"),
    [
        (np.r_[np.arange(0.01, 0.5, 0.01), np.arange(0.58, 0.7, 0.01), [1.0, 1.05]], 0.69, False),
        (np.r_[np.arange(0.2, 0.5, 0.01)], 0.0, False),
        (np.arange(0.01, 0.4, 0.01), 0.39, True),
        (np.empty(0), 0.0, True),
    ],
)
def test_gap_rule_stops_before_the_first_gap_at_or_above_the_threshold(
    distances, reach, open_ended
):
    rng = np.random.default_rng(0)
    got, got_open = gap_reach(rng.permutation(distances), gap=0.12)
    assert got == pytest.approx(reach)
    assert got_open is open_ended


# Sorted D_j = 0.01, 0.02, 0.04, 0.05, 0.15, 0.16: gaps G_j = |P_j, P_{j+1}| = 0.01, 0.02, 0.01,
# 0.10, 0.01, so G_max / G_min = 10. With ε = 0.005 the threshold is 0.05: the first G_j >= 0.05
# is G_3 (0.05 -> 0.15), the end is P_3 at 0.05. With ε = 0.02 it is 0.2 > G_max: none.
PAPER_DISTANCES = np.array([0.01, 0.02, 0.04, 0.05, 0.15, 0.16])


@pytest.mark.parametrize(
    ("distances", "epsilon", "reach", "open_ended"),
    [
        (PAPER_DISTANCES, 0.005, 0.05, False),
        (PAPER_DISTANCES, 0.02, 0.16, True),
        (np.array([0.01, 0.02, 0.02, 0.3]), 1e-9, 0.3, True),  # G_min = 0
        (np.array([0.07]), 0.005, 0.07, True),
        (np.empty(0), 0.005, 0.0, True),
    ],
)
def test_paper_gap_rule_marks_the_end_at_the_first_gap_over_g_max_over_g_min_times_epsilon(
    distances, epsilon, reach, open_ended
):
    """Paper 003 step 7: e = P_j at the first G_j >= (G_max / G_min) * ε."""
    rng = np.random.default_rng(0)
    got, got_open = paper_gap_reach(rng.permutation(distances), epsilon)
    assert got == pytest.approx(reach)
    assert got_open is open_ended


def test_the_paper_rule_and_ours_place_different_ends_on_the_same_points():
    """On the hand-worked list ours (0.12 m, no gap that large) runs on to D_max = 0.16 m; the
    paper's relative threshold (0.05 m there) stops at 0.05 m."""
    assert paper_gap_reach(PAPER_DISTANCES, 0.005) == (pytest.approx(0.05), False)
    assert gap_reach(PAPER_DISTANCES, 0.12) == (pytest.approx(0.16), True)


def test_sliding_boxes_recover_a_member_cut_by_occlusions():
    """A segment covering a fifth of a tube extends over two 8 cm occlusion gaps to its ends,
    and stops before a crossing tube 20 cm past one end."""
    rng = np.random.default_rng(1)
    tube = _tube_points([0, 0, 0], [0, 0, 1.5], 0.024, rng, noise=0.001)
    z = tube[:, 2]
    tube = tube[~(((z > 0.3) & (z < 0.38)) | ((z > 0.9) & (z < 0.98)))]
    other = _tube_points([0, -0.5, 1.7], [0, 0.5, 1.7], 0.024, rng)
    points = np.concatenate([tube, other])
    piece = np.flatnonzero(
        (points[:, 2] > 0.5) & (points[:, 2] < 0.8) & (np.abs(points[:, 1]) < 0.03)
    )
    segment = Segment(Cylinder(np.zeros(3), np.array([0, 0, 1.0]), 0.024), 0.5, 0.8, piece)
    member = complete(
        segment,
        points,
        slide_lambda=2.5,
        gap=0.12,
        gap_rule="absolute",
        gap_epsilon=1e-5,
        margin=0.01,
        max_slides=3,
    )
    assert member.t0 == pytest.approx(0.0, abs=0.006)
    assert member.t1 == pytest.approx(1.5, abs=0.006)


def test_split_pieces_merge_but_distinct_members_do_not():
    z = np.array([0, 0, 1.0])

    def member(x, y, t0, t1, axis=z):
        return Member(Cylinder(np.array([x, y, 0.0]), axis, 0.024), t0, t1, np.arange(3))

    pieces = [member(0, 0, 0.0, 1.8), member(0.003, 0, 0.02, 1.78)]  # same member twice
    pieces += [member(0, 1.2, 0.0, 1.8)]  # a parallel post 1.2 m away
    pieces += [member(0.0, 0.0, 0.0, 1.5, np.array([0, 1.0, 0]))]  # a crossing ledger
    pieces += [member(0.002, 0.001, 0.6, 1.1)]  # a piece that stopped short, on the axis
    merged = merge_members(pieces, distance=0.1, angle_deg=5.0, line=0.03)
    assert len(merged) == 3
    assert merged[0].pieces == 3
    assert merged[0].t0 == pytest.approx(0.0) and merged[0].t1 == pytest.approx(1.8)


def test_ball_normals_match_the_principal_axes_of_each_ball_and_count_its_points():
    """The voxel-key ball (no KD-tree) holds exactly the points within two voxels' reach and
    gives each point the smallest principal direction of that ball: radial on a tube."""
    rng = np.random.default_rng(3)
    voxel = 0.01
    points = voxel_downsample(
        _tube_points([0.2, 0.1, 0], [0.5, 0.9, 0.4], 0.024, rng, noise=0.001), voxel
    )
    normals, neighbours = ball_normals(points, voxel, 2.0)
    cells = np.floor(points / voxel).astype(int)
    for j in range(0, len(points), 7):
        d = cells - cells[j]
        ball = points[(d * d).sum(axis=1) <= 4]
        assert neighbours[j] == len(ball) - 1
        _, vectors = np.linalg.eigh(np.cov(ball.T))
        assert _angle_deg(vectors[:, 0], normals[j]) < 1e-4
    axis = np.array([0.3, 0.8, 0.4]) / np.linalg.norm([0.3, 0.8, 0.4])
    w = points - np.array([0.2, 0.1, 0])
    radial = w - np.outer(w @ axis, axis)
    cos = np.abs((radial * normals).sum(axis=1)) / np.linalg.norm(radial, axis=1)
    assert np.median(cos) > np.cos(np.radians(10.0))  # the segmentation allows 25 deg


def test_a_member_ending_in_a_linker_ends_at_its_node():
    """A tube from node to node whose ends hide in 70 mm cubes: the gap rule's end is the
    cube's far face, 35 mm past the node; with the linker size the end goes to the node."""
    rng = np.random.default_rng(4)
    linker, radius = 0.07, 0.025
    tube = _tube_points([0, 0, 0], [0.8, 0, 0], radius, rng, noise=0.001, facing=[0, 0, 1])
    tube = tube[(tube[:, 0] > linker / 2) & (tube[:, 0] < 0.8 - linker / 2)]
    faces = []
    for node in (0.0, 0.8):  # the cube faces the camera sees, up and sideways (+z, +y)
        a, b = np.meshgrid(np.arange(-0.035, 0.035, 0.004), np.arange(-0.035, 0.035, 0.004))
        faces.append(np.column_stack([node + a.ravel(), b.ravel(), np.full(a.size, 0.035)]))
        faces.append(np.column_stack([node + a.ravel(), np.full(a.size, 0.035), b.ravel()]))
    points = voxel_downsample(np.concatenate([tube, *faces]), 0.01)
    cylinder = Cylinder(np.zeros(3), np.array([1.0, 0, 0]), radius)
    t = points[:, 0]
    gap_rule = Member(cylinder, float(t.min()), float(t.max()), np.arange(len(points)))
    assert gap_rule.t0 == pytest.approx(-0.035, abs=0.006)
    kept = node_ends(gap_rule, points, distance=0.008, bin_size=0.01, linker=0.0)
    assert (kept.t0, kept.t1) == (gap_rule.t0, gap_rule.t1)
    at_nodes = node_ends(gap_rule, points, distance=0.008, bin_size=0.01, linker=linker)
    assert at_nodes.t0 == pytest.approx(0.0, abs=0.008)
    assert at_nodes.t1 == pytest.approx(0.8, abs=0.008)


# --- acceptance on generated trusses --------------------------------------------------------


@pytest.fixture(scope="module", params=["five", "seven"])
def modelled(request):
    geometry = ts.five_member() if request.param == "five" else ts.seven_member()
    scene = ts.render(geometry, camera=CAMERA, noise=NO_GRAZING, seed=7)
    model = TrussModeller(TrussConfig(seed=7)).model(scene.cloud)
    truth = [(t.p0, t.p1, t.radius) for t in scene.members]
    return scene, model, truth


def test_every_member_found_within_the_acceptance_figures(modelled):
    """Issue 10: mean relative length error <= 2 %, midpoint <= 20 mm, axis angle <= 1 deg, every
    member found (paper 003: 3.46 % / 3.7 %, 37 / 73.84 mm, 1.13 / 2.67 deg)."""
    scene, model, truth = modelled
    accuracy = evaluate([(m.p0, m.p1) for m in model.members], truth)
    assert accuracy.all_found
    assert accuracy.false_members == 0
    assert accuracy.mean("relative_length_error") <= 0.02
    assert accuracy.mean("midpoint_error") <= 0.020
    assert accuracy.mean("angle_error_deg") <= 1.0
    radii = [m.cylinder.radius for m in model.members]
    assert np.mean(radii) == pytest.approx(ts.SCAFFOLD_TUBE_RADIUS, abs=0.002)


def test_ransac_alone_cuts_members_short_and_the_completion_repairs_them(modelled):
    """The paper's Figs. 9-10: the initial model's members are far shorter than the truth."""
    _, model, truth = modelled
    initial = evaluate([(m.p0, m.p1) for m in model.initial], truth)
    completed = evaluate([(m.p0, m.p1) for m in model.members], truth)
    assert initial.mean("relative_length_error") > 0.15
    assert initial.mean("relative_length_error") > 5 * completed.mean("relative_length_error")
    assert initial.mean("midpoint_error") > 2 * completed.mean("midpoint_error")


@pytest.mark.parametrize(
    ("geometry", "length_error", "midpoint_error"),
    [(ts.five_member, 0.01, 0.010), (ts.seven_member, 0.04, 0.035)],
)
def test_the_paper_gap_rule_finds_every_member_at_its_measured_accuracy(
    geometry, length_error, midpoint_error
):
    """Step 7 by the paper's relative rule (ε = 1e-5 m) on the acceptance scenes: every member,
    no false one, measured 0.64 % / 6.9 mm on five members but 3.42 % / 30.6 mm on seven, past
    issue 10's 2 % / 20 mm that ours (0.93 % / 8.2 mm) meets; the bounds are those figures."""
    scene = ts.render(geometry(), camera=CAMERA, noise=NO_GRAZING, seed=7)
    model = TrussModeller(TrussConfig(seed=7, gap_rule="paper")).model(scene.cloud)
    truth = [(t.p0, t.p1, t.radius) for t in scene.members]
    accuracy = evaluate([(m.p0, m.p1) for m in model.members], truth)
    assert accuracy.all_found
    assert accuracy.false_members == 0
    assert accuracy.mean("relative_length_error") <= length_error
    assert accuracy.mean("midpoint_error") <= midpoint_error


def test_grazing_loss_keeps_a_post_whole_at_a_coupler():
    """Seven members with the generator's full noise (grazing surfaces lose their returns),
    seed 7, where the post at y = -0.6 m once split at the diagonal's coupler: the acceptance
    figures. Measured: seeds 0-15 all meet them, mean length error 0.59-0.96 % (0.89 % here)."""
    scene = ts.render(ts.seven_member(), camera=CAMERA, noise=ts.DepthNoise(), seed=7)
    model = TrussModeller(TrussConfig(seed=7)).model(scene.cloud)
    truth = [(t.p0, t.p1, t.radius) for t in scene.members]
    accuracy = evaluate([(m.p0, m.p1) for m in model.members], truth)
    assert accuracy.all_found and accuracy.false_members == 0
    assert accuracy.mean("relative_length_error") <= 0.02


def test_a_member_first_segmented_tilted_is_refit_along_its_whole_support():
    """``bench/truss_seeds.py``'s seed 0 (bench/truss.py's main table): 100 000 points of the
    full-resolution 7-member scene. Its transom was first segmented over its short overhang,
    degrees off, and refits on the surface of that tilted axis kept the tilt: it stopped 566 mm
    short (42 %). A refit from the support's principal axis, settled refits and a third
    completion pass: every member within 2 %, axes within 1 degree (1.6 %, 0.16 degrees)."""
    rng = np.random.default_rng(0)
    five = ts.render(ts.five_member(), seed=0)
    rng.choice(len(five.cloud), 100_000, replace=False)  # the bench draws the five first
    scene = ts.render(ts.seven_member(), seed=0)
    cloud = scene.cloud[rng.choice(len(scene.cloud), 100_000, replace=False)]
    members = TrussModeller(TrussConfig(seed=0)).model(cloud).members
    truth = [(t.p0, t.p1, t.radius) for t in scene.members]
    accuracy = evaluate([(m.p0, m.p1) for m in members], truth)
    assert accuracy.all_found and accuracy.false_members == 0
    assert accuracy.max("relative_length_error") <= 0.02
    assert accuracy.max("angle_error_deg") <= 1.0


def test_same_seed_same_model_and_another_seed_the_same_members():
    scene = ts.render(ts.five_member(), camera=CAMERA, seed=2)
    first = TrussModeller(TrussConfig(seed=5)).model(scene.cloud)
    again = TrussModeller(TrussConfig(seed=5)).model(scene.cloud)
    other = TrussModeller(TrussConfig(seed=6)).model(scene.cloud)
    assert [m.p0.tolist() + m.p1.tolist() for m in first.members] == [
        m.p0.tolist() + m.p1.tolist() for m in again.members
    ]
    truth = [(t.p0, t.p1, t.radius) for t in scene.members]
    assert evaluate([(m.p0, m.p1) for m in other.members], truth).all_found


def test_a_cloud_without_a_truss_gives_no_members():
    rng = np.random.default_rng(0)
    floor = np.column_stack(
        [rng.uniform(-2, 2, 20000), rng.uniform(-2, 2, 20000), rng.normal(0, 0.003, 20000)]
    )
    assert TrussModeller().model(floor).members == []
    assert TrussModeller().model(np.empty((0, 3))).members == []
    with pytest.raises(ValueError, match="N x 3"):
        TrussModeller().model(np.zeros((10, 2)))


# --- the plugin -----------------------------------------------------------------------------


def test_plugin_accumulates_views_with_their_poses_and_publishes_members():
    scene = ts.render(ts.seven_member(), camera=CAMERA, seed=4)
    plugin = instantiate(
        "climbd.perception", "truss", {"model_every": len(scene.views), "seed": 4}, None, "test"
    )
    assert isinstance(plugin, TrussPerception)
    outputs = [plugin.process_cloud(v.points, v.body, v.body.stamp) for v in scene.views]
    assert outputs[:-1] == [None] * (len(scene.views) - 1)
    message = decode(encode(outputs[-1]), TrussMembers)
    assert message.stamp == scene.views[-1].body.stamp
    truth = [(t.p0, t.p1, t.radius) for t in scene.members]
    detected = [(np.array(m.p0), np.array(m.p1)) for m in message.members]
    accuracy = evaluate(detected, truth)
    assert accuracy.all_found and accuracy.mean("relative_length_error") <= 0.02
    for m in message.members:
        direction = np.subtract(m.p1, m.p0)
        assert np.dot(direction, m.axis) > 0
        assert _angle_deg(direction, np.array(m.axis)) < 1e-4
        assert np.linalg.norm(m.axis) == pytest.approx(1.0)
        assert 0.5 < m.confidence <= 1.0


def test_plugin_refuses_bad_input_and_bad_config_naming_the_field():
    plugin = TrussPerception()
    with pytest.raises(ValueError, match="N x 3"):
        plugin.process_cloud(np.zeros((5, 4)), BodyState(), 0.0)
    with pytest.raises(ValueError, match="orientation"):
        plugin.process_cloud(np.zeros((5, 3)), BodyState(orientation=[1.0, 0.0, 0.0]), 0.0)
    with pytest.raises(PluginError, match="slide_lambda"):
        instantiate("climbd.perception", "truss", {"slide_lambda": 0.5}, None, "robots/x.toml")
    with pytest.raises(PluginError, match="gap_rule"):
        instantiate("climbd.perception", "truss", {"gap_rule": "relative"}, None, "robots/x.toml")
    with pytest.raises(PluginError, match="gap_epsilon"):
        instantiate("climbd.perception", "truss", {"gap_epsilon": 0.0}, None, "robots/x.toml")
    with pytest.raises(PluginError, match="gapp"):
        instantiate("climbd.perception", "truss", {"gapp": 0.1}, None, "robots/x.toml")
    assert msgspec.to_builtins(TrussConfig())["slide_lambda"] == 2.5


def test_climbd_perceive_truss_prints_members_as_json(tmp_path):
    scene = ts.render(ts.five_member(), camera=CAMERA, seed=1)
    path = tmp_path / "truss.npy"
    np.save(path, scene.cloud.astype(np.float32))
    done = subprocess.run(
        [sys.executable, "-m", "climbd.daemon.cli", "perceive", "truss", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    members = json.loads(done.stdout)["members"]
    truth = [(t.p0, t.p1, t.radius) for t in scene.members]
    detected = [(np.array(m["p0"]), np.array(m["p1"])) for m in members]
    assert evaluate(detected, truth).all_found


def test_members_keep_their_ids_across_model_updates():
    """The truss is re-modelled from the accumulated cloud at every update; a member that comes
    back (both ends within the gate, either way round) keeps its id, and ids stay unique."""
    scene = ts.render(ts.seven_member(), camera=CAMERA, seed=4)
    plugin = TrussPerception(TrussConfig(model_every=1, seed=4))
    messages = [plugin.process_cloud(v.points, v.body, v.body.stamp) for v in scene.views]
    before, after = messages[-2], messages[-1]
    assert len({m.id for m in after.members}) == len(after.members)
    kept = 0
    for member in after.members:
        ends = np.concatenate([member.p0, member.p1])
        for old in before.members:
            if end_distance(ends, np.concatenate([old.p0, old.p1])) <= plugin.config.track_gate:
                assert member.id == old.id
                kept += 1
    assert kept >= len(scene.members) - 1


def test_connectors_join_member_ends_that_meet():
    """Three members of a triangle and one free: the three corners are nodes of two members
    each, the free member's ends none."""
    corners = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    pairs = [(0, 1), (1, 2), (2, 0)]
    ends = [(corners[a] + [0.01, 0.0, 0.0], corners[b]) for a, b in pairs]
    ends.append((np.array([3.0, 3.0, 0.0]), np.array([3.0, 4.0, 0.0])))
    members = []
    for p0, p1 in ends:
        axis = (p1 - p0) / np.linalg.norm(p1 - p0)
        length = float(np.linalg.norm(p1 - p0))
        members.append(Member(Cylinder(p0, axis, 0.02), 0.0, length, np.zeros(0, int)))
    nodes = connectors(members, [11, 12, 13, 14], radius=0.05)
    assert len(nodes) == 3
    found = {tuple(n.members): np.array(n.position) for n in nodes}
    assert set(found) == {(11, 13), (11, 12), (12, 13)}
    np.testing.assert_allclose(found[(11, 13)], [0.005, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(found[(12, 13)], corners[2] + [0.005, 0.0, 0.0], atol=1e-12)
