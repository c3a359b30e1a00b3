"""Graspable-point detection (paper 001 §2): mask geometry, correlation = the paper's scan,
synthetic holds with known apexes, and the real RealSense clouds of climbing holds."""

from __future__ import annotations

import functools
import json
import math

import msgspec
import numpy as np
import pytest
from scipy import ndimage
from scipy.spatial import Delaunay, cKDTree
from support.graspable_scenes import board_plane, dome_board, hold_cores, pose, unpose

from climbd.daemon.cli import main as climbd
from climbd.daemon.contract.cloudio import read_cloud
from climbd.daemon.contract.geometry import regression_frame
from climbd.daemon.contract.messages import BodyState, GraspablePoints
from climbd.daemon.contract.plugins import PluginError
from climbd.daemon.runtime.loader import instantiate
from climbd.drivers.sim.worlds import DATA
from climbd.plugins.perception.graspable import (
    Correlator,
    GraspableConfig,
    GraspableDetector,
    column_depths,
    interpolate_heights,
    lattice_mask,
    nearest_per_node,
    scan_window,
    terrain_matrix,
    void_known,
)
from climbd.plugins.perception.gripper_mask import GripperGeometry, gripper_mask

CLOUDS = ["leaning_bouldering_holds.pcd", "vertical_bouldering_holds.pcd"]
REACH = 0.044  # mask half-size at 1 mm: palm-joint circle 14 + finger 15 + spine 15 mm

# Four domes wide enough for the closed spines (radius > 23 mm at 15 mm below the apex), one
# dome too narrow for them (22 mm base radius) and a 6 mm pin: (x, y, radius, height) in m.
WIDE = [(-0.09, -0.09, 0.045, 0.035), (0.09, -0.08, 0.05, 0.04), (-0.08, 0.09, 0.045, 0.04)]
WIDE += [(0.09, 0.09, 0.048, 0.045)]
NARROW = [(0.0, 0.0, 0.022, 0.035)]
PINS = [(-0.12, 0.0, 0.006, 0.03)]
ROLL, PITCH, OFFSET = 0.2, -1.0, np.array([0.4, 0.0, 0.05])


@pytest.fixture(scope="module")
def detector() -> GraspableDetector:
    return GraspableDetector(GraspableConfig())


def radial(size: int) -> np.ndarray:
    o = np.arange(size) - size // 2
    return np.hypot(o[:, None], o[None, :])


def test_mask_geometry_from_gripper_parameters():
    mask = gripper_mask(GripperGeometry(), 0.001)
    assert mask.shape == (89, 89, 16)  # 2·(14 + 15 + 15) + 1 columns, 16 mm closing height
    r = radial(89)
    # palm level: the palm (+4 mm margin) disk and beyond the spines' reach are free, between
    # them the opening fingers need void.
    assert mask[:, :, 0][r < 18].all() and not mask[:, :, 0][(r >= 18) & (r <= 44)].any()
    # the free cone widens by (89 - 32) / 2 voxels over clearance tan(15°)·28.5 ≈ 8 layers
    widths = [int((~mask[44, 44:, k]).sum()) for k in range(8)]
    assert widths == sorted(widths, reverse=True) and widths[-1] == 0
    assert mask[:, :, 8:15].all()  # below the clearance the closed fingers wrap everything
    # closing layer: the spine tips meet on a circle of 16 + 16·tan 30° − 2 ≈ 23 mm
    assert not mask[:, :, 15][r <= 23].any() and mask[:, :, 15][r > 23].all()
    coarse = gripper_mask(GripperGeometry(), 0.002)
    assert coarse.shape == (47, 47, 8)


@pytest.mark.parametrize(
    ("field", "value"), [("palm_diameter", 0.0), ("opening_angle", 95.0), ("spine_depth", math.nan)]
)
def test_bad_gripper_geometry_names_the_field(field, value):
    geometry = msgspec.structs.replace(GripperGeometry(), **{field: value})
    with pytest.raises(ValueError, match=f"gripper.{field}"):
        gripper_mask(geometry, 0.001)


def test_correlation_equals_the_papers_per_voxel_scan():
    cloud = dome_board(WIDE + NARROW, PINS, size=0.2, seed=3)
    plane = regression_frame(cloud, np.array([0.0, 0.0, 1.0])).to_plane(cloud)
    for step in (1, 3):
        lattice = interpolate_heights(plane, 0.001 * step)
        depth = column_depths(lattice, 0.001)
        mask = lattice_mask(gripper_mask(GripperGeometry(), 0.001), step)
        ix, iy = np.nonzero(depth >= 0)
        pick = np.random.default_rng(step).choice(len(ix), 400, replace=False)
        at = (ix[pick], iy[pick], depth[ix[pick], iy[pick]])
        hits, solid = Correlator(mask).counts(depth, at[:2])
        scan_hits, scan_solid = scan_window(terrain_matrix(depth), mask, at)
        np.testing.assert_array_equal(hits, scan_hits)
        np.testing.assert_array_equal(solid, scan_solid)
        assert hits.max() > 0 and (hits == 0).any() and solid.min() > 0


def test_void_known_is_the_dilation_of_unknown_terrain():
    """Against scipy's binary dilation (outside the lattice unknown), with a footprint that is
    not symmetric so an orientation slip would show."""
    rng = np.random.default_rng(5)
    known = ndimage.binary_opening(rng.random((60, 70)) > 0.2)
    mask = np.ones((7, 7, 3), dtype=bool)
    mask[1:5, 2:7, 1] = False
    footprint = (~mask).any(axis=2)
    expected = ~ndimage.binary_dilation(~known, structure=footprint, border_value=1)
    np.testing.assert_array_equal(void_known(known, mask), expected)
    assert 0 < expected.sum() < known.sum()


def test_delaunay_fill_is_linear_inside_triangles():
    rng = np.random.default_rng(4)
    xy = rng.uniform(-0.05, 0.05, (300, 2))
    plane = np.column_stack((xy, 0.2 * xy[:, 0] - 0.1 * xy[:, 1] + 0.01))
    lattice = interpolate_heights(plane, 0.002)
    gx = lattice.x0 + 0.002 * np.arange(lattice.heights.shape[0])
    gy = lattice.y0 + 0.002 * np.arange(lattice.heights.shape[1])
    truth = 0.2 * gx[:, None] - 0.1 * gy[None, :] + 0.01
    known = np.isfinite(lattice.heights)
    assert known.mean() > 0.8
    np.testing.assert_allclose(lattice.heights[known], truth[known], atol=1e-12)
    inside = Delaunay(xy).find_simplex(np.stack(np.meshgrid(gx, gy, indexing="ij"), -1)) >= 0
    np.testing.assert_array_equal(known, inside)


def scene_targets(detector: GraspableDetector, seed: int) -> np.ndarray:
    """Targets on the synthetic board, back in the board's own frame."""
    body = pose(dome_board(WIDE + NARROW, PINS, seed=seed), ROLL, PITCH, OFFSET)
    return unpose(detector.detect(body).points, ROLL, PITCH, OFFSET)


@pytest.mark.parametrize("seed", [0, 1])
def test_synthetic_holds_one_target_at_each_wide_apex_none_elsewhere(detector, seed):
    targets = scene_targets(detector, seed)
    apexes = np.array([(x, y, h) for x, y, _, h in WIDE])
    distance, which = cKDTree(apexes[:, :2]).query(targets[:, :2])
    # every target sits on a wide dome within 10 mm of its apex (sampling pitch 3 mm + lattice)
    assert (distance < 0.010).all(), targets
    np.testing.assert_allclose(targets[:, 2], apexes[which, 2], atol=0.004)
    assert sorted(set(which.tolist())) == list(range(len(WIDE)))  # each wide dome: one target
    assert len(targets) == len(WIDE)  # thinned: one per hold; none on narrow dome, pin, board


def test_body_pose_does_not_change_the_targets(detector):
    cloud = dome_board(WIDE + NARROW, PINS, seed=0)
    first = (0.0, -0.5, np.array([0.3, 0.0, 0.0]))
    second = (0.3, -1.2, np.array([0.5, 0.1, 0.2]))
    a = unpose(detector.detect(pose(cloud, *first)).points, *first)
    b = unpose(detector.detect(pose(cloud, *second)).points, *second)
    assert len(a) == len(b) == len(WIDE)
    assert cKDTree(a).query(b)[0].max() < 0.008


def test_flat_board_has_no_graspable_point(detector):
    flat = pose(dome_board([], seed=2), 0.1, -0.8, OFFSET)
    detection = detector.detect(flat)
    assert len(detection.candidates) == 0 and len(detection.points) == 0


class RealCloud:
    """A real cloud with its board plane, the holds identified from it (see hold_cores) and the
    default detector's result on it (computed once, shared by the tests that read it)."""

    def __init__(self, name: str) -> None:
        self.points = read_cloud(DATA / name)
        self.centre, self.normal = board_plane(self.points)
        self.height = (self.points - self.centre) @ self.normal
        self.holds = hold_cores(self.points, self.height)
        self.trees = [cKDTree(self.points[h]) for h in self.holds]
        self.detection = GraspableDetector(GraspableConfig()).detect(self.points)

    def board_uv(self, points: np.ndarray) -> np.ndarray:
        e1 = np.cross(self.normal, [0.0, 0.0, 1.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(self.normal, e1)
        return np.column_stack(((points - self.centre) @ e1, (points - self.centre) @ e2))

    def in_view(self) -> list[int]:
        """Holds whose gripper reach around their highest point lies inside the camera's view."""
        hull = Delaunay(self.board_uv(self.points))
        ring = np.linspace(0, 2 * np.pi, 72, endpoint=False)
        ring = REACH * np.column_stack((np.cos(ring), np.sin(ring)))
        keep = []
        for i, hold in enumerate(self.holds):
            top = self.board_uv(self.points[hold[np.argmax(self.height[hold])]][None])[0]
            if (hull.find_simplex(top + ring) >= 0).all():
                keep.append(i)
        return keep

    def holds_hit(self, targets: np.ndarray) -> set[int]:
        return {i for i, t in enumerate(self.trees) if (t.query(targets)[0] < 0.006).any()}

    def on_hold(self, targets: np.ndarray) -> np.ndarray:
        return np.min([t.query(targets)[0] for t in self.trees], axis=0) < 0.006


@functools.cache
def real_cloud(name: str) -> RealCloud:
    return RealCloud(name)


@pytest.fixture(scope="module", params=CLOUDS)
def real(request) -> RealCloud:
    return real_cloud(request.param)


def test_real_cloud_holds_are_found_by_analysis(real):
    assert len(real.holds) == 10  # ten holds in each photo of the ClimbLab data set
    assert np.mean(np.abs(real.height) < 0.002) > 0.3  # the board is the dominant plane
    for hold in real.holds:  # every hold's top footprint is wider than the 32 mm palm
        uv = real.board_uv(real.points[hold])
        assert np.ptp(uv, axis=0).max() > 0.032


def test_real_cloud_targets_on_hold_tops_never_on_the_board(real):
    detection = real.detection
    targets = detection.points
    height = (targets - real.centre) @ real.normal
    assert real.on_hold(targets).all()
    assert (height > 0.03).all()  # hold tops; the flat board is within ±3 mm of its plane
    candidates = (detection.candidates - real.centre) @ real.normal
    assert (candidates > 0.03).all()
    view = real.in_view()
    assert len(view) >= 9
    assert set(view) <= real.holds_hit(targets)  # every hold in view gets at least one
    # thinned: at most two targets per hold
    assert len(targets) <= 2 * len(real.holds)


def test_real_cloud_stable_under_1mm_jitter(detector, real):
    base = real.detection.points
    view = set(real.in_view())
    rng = np.random.default_rng(7)
    hits = {i: 0 for i in view}
    runs = 5
    moved = []
    for _ in range(runs):
        jittered = real.points + rng.normal(0.0, 0.001, real.points.shape)
        targets = detector.detect(jittered).points
        assert real.on_hold(targets).all()
        assert (((targets - real.centre) @ real.normal) > 0.03).all()
        for i in real.holds_hit(targets) & view:
            hits[i] += 1
        moved.append(cKDTree(targets).query(base)[0])
    assert min(hits.values()) >= runs - 1, hits  # each hold keeps a target in ≥ 4 of 5 runs
    assert np.median(np.concatenate(moved)) < 0.008  # and a target stays within a few mm


def test_plugin_entry_point_and_message(real):
    plugin = instantiate(
        "climbd.perception", "graspable", {"thin_distance": 0.02}, None, "test: graspable"
    )
    message = plugin.process_cloud(real.points, BodyState(), 12.5)
    assert isinstance(message, GraspablePoints) and message.frame_stamp == 12.5
    points = np.array(message.points)
    assert points.shape[1] == 3 and real.on_hold(points).all()


def test_plugin_config_error_names_the_field():
    with pytest.raises(PluginError, match="void_fraction"):
        instantiate("climbd.perception", "graspable", {"void_fraction": 1.5}, None, "profile.toml")
    with pytest.raises(PluginError, match="voxel"):
        instantiate("climbd.perception", "graspable", {"voxel": "big"}, None, "profile.toml")


@pytest.mark.parametrize(
    ("points", "message"),
    [
        (np.zeros((10, 2)), "N×3"),
        (np.full((10, 3), np.nan), "at least 3 finite"),
        (np.column_stack((np.linspace(0, 1, 50), np.zeros(50), np.zeros(50))), "degenerate"),
    ],
)
def test_bad_clouds_get_clear_errors(detector, points, message):
    with pytest.raises(ValueError, match=message):
        detector.detect(points)


def test_perceive_cli_prints_body_frame_json(capsys):
    assert climbd(["perceive", "graspable", str(DATA / CLOUDS[1])]) == 0
    out = json.loads(capsys.readouterr().out)
    points = np.array(out["points"])
    cloud = real_cloud(CLOUDS[1])
    assert len(points) >= 9 and cloud.on_hold(points).all()


def test_a_cloud_denser_than_the_lattice_fills_it_from_the_samples_nearest_its_nodes():
    """A dome sampled every 0.75 mm (16 points a 3 mm node, as the D435 sees a hold at arm's
    length) keeps one point a node, the one nearest it, and the lattice it fills has the same
    heights within a tenth of a millimetre as the lattice filled from every point; a cloud with
    two points a node (ClimbLab's) is kept whole."""
    spacing = 0.003
    g = np.arange(-0.03, 0.03, 0.00075)
    x, y = np.meshgrid(g, g)
    z = 0.02 * np.exp(-(x**2 + y**2) / 0.0002)
    dense = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    kept = nearest_per_node(dense, spacing)
    node = np.rint((kept[:, :2] - dense[:, :2].min(axis=0)) / spacing)
    assert len(np.unique(node, axis=0)) == len(kept)
    nodes = np.rint((dense[:, :2] - dense[:, :2].min(axis=0)) / spacing)
    assert len(kept) == len(np.unique(nodes, axis=0))
    every, thinned = interpolate_heights(dense, spacing), interpolate_heights(kept, spacing)
    assert every.heights.shape == thinned.heights.shape
    both = np.isfinite(every.heights) & np.isfinite(thinned.heights)
    assert both.sum() >= 0.95 * np.isfinite(every.heights).sum()
    assert np.abs(every.heights[both] - thinned.heights[both]).max() < 1e-4
    sparse = dense[::8]
    assert len(nearest_per_node(sparse, spacing)) == len(sparse)
