"""Depth on pyrealsense2 software devices: plane → body-frame points, crop, filters, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from climbd.daemon.algorithms.cloud import (
    PAPER_000,
    PAPER_000_TEST_7,
    CropBox,
    crop,
    frame_to_points,
)
from climbd.daemon.contract.hardware import DepthFrame, DriverError, Intrinsics, mount_extrinsics
from climbd.daemon.contract.profile import CameraConfig, CameraMount
from climbd.drivers.realsense import camera as camera_module
from climbd.drivers.realsense.camera import LiveSource, RealSenseCamera
from climbd.drivers.realsense.models import D435, L515
from climbd.drivers.realsense.software import SoftwareDepthCamera


def _plane_depth(intrinsics, extrinsics, normal, offset, depth_scale):
    """uint16 depth of the body-frame plane n·p = offset seen through a pinhole camera.

    Built from the plane in the camera frame (n_c = Rᵀn, d_c = offset − n·t), independent of
    the code under test; pixels whose ray misses the plane ahead of the camera read 0.
    """
    r, t = extrinsics[:3, :3], extrinsics[:3, 3]
    n_c = r.T @ np.asarray(normal, float)
    d_c = offset - np.dot(normal, t)
    u, v = np.meshgrid(np.arange(intrinsics.width), np.arange(intrinsics.height))
    x = (u - intrinsics.ppx) / intrinsics.fx
    y = (v - intrinsics.ppy) / intrinsics.fy
    denom = n_c[0] * x + n_c[1] * y + n_c[2]
    with np.errstate(divide="ignore"):
        z = d_c / denom
    z[(denom == 0) | (z <= 0) | (z > 8.0)] = 0.0
    return np.round(z / depth_scale).astype(np.uint16)


def _stream(camera, images, t0=0.0):
    """Push images through a software camera and read them back as DepthFrames."""
    camera.open()
    try:
        frames = camera.frames()
        out = []
        for k, image in enumerate(images):
            camera.push(image, t0 + k / 30)
            out.append(next(frames))
        return out
    finally:
        camera.close()


PLANES = {
    "floor": ((0.0, 0.0, 1.0), 0.0),
    "ramp 20°": ((-math.sin(math.radians(20)), 0.0, math.cos(math.radians(20))), -0.15),
}


@pytest.mark.parametrize("tilt", [15.0, 30.0, 45.0, 60.0, 90.0])
@pytest.mark.parametrize(
    "model,size", [(L515, (1024, 768)), (D435, (848, 480))], ids=["L515", "D435"]
)
def test_plane_through_software_device_lands_within_1mm(tilt, model, size):
    config = CameraConfig(
        model=model.name,
        width=size[0],
        height=size[1],
        mount=CameraMount(position=[0.1, 0.02, 0.25], tilt_deg=tilt),
    )
    extrinsics = mount_extrinsics(config)
    intrinsics = model.intrinsics(*size)
    images = [
        _plane_depth(intrinsics, extrinsics, n, d, model.depth_unit) for n, d in PLANES.values()
    ]
    camera = SoftwareDepthCamera(
        intrinsics, model.depth_unit, extrinsics, model=model.name, config=config
    )
    for (normal, offset), image, frame in zip(
        PLANES.values(), images, _stream(camera, images), strict=True
    ):
        assert frame.depth_scale == model.depth_unit
        points = frame_to_points(frame)
        assert len(points) == np.count_nonzero(image) > 1000
        distance = points.astype(np.float64) @ np.asarray(normal) - offset
        assert np.abs(distance).max() <= 1e-3


def test_mount_extrinsics_follow_optical_and_body_conventions():
    level = mount_extrinsics(CameraConfig(mount=CameraMount(position=[0.1, 0.0, 0.2])))
    np.testing.assert_allclose(level[:3, 2], [1, 0, 0], atol=1e-12)  # optical z: forward
    np.testing.assert_allclose(level[:3, 0], [0, -1, 0], atol=1e-12)  # optical x: right
    np.testing.assert_allclose(level[:3, 1], [0, 0, -1], atol=1e-12)  # optical y: down
    tilted = mount_extrinsics(CameraConfig(mount=CameraMount(tilt_deg=30.0)))
    s, c = math.sin(math.radians(30)), math.cos(math.radians(30))
    np.testing.assert_allclose(tilted[:3, 2], [c, 0, -s], atol=1e-12)  # pitched down
    np.testing.assert_allclose(tilted[:3, 0], [0, -1, 0], atol=1e-12)


def _random_frame(rng, intrinsics, tilt=30.0, scale=0.001):
    extrinsics = mount_extrinsics(
        CameraConfig(mount=CameraMount(position=[0.1, 0.0, 0.12], tilt_deg=tilt))
    )
    depth = rng.integers(0, 4000, (intrinsics.height, intrinsics.width), dtype=np.uint16)
    return DepthFrame(depth, scale, intrinsics, extrinsics, 0.0)


def _reference_points(frame, decimation=1, lo=0.0, hi=np.inf):
    """Straightforward float64 back-projection, pixel by pixel in row-major order."""
    i = frame.intrinsics
    v, u = np.mgrid[0 : i.height : decimation, 0 : i.width : decimation]
    z = frame.depth[::decimation, ::decimation] * frame.depth_scale
    keep = (frame.depth[::decimation, ::decimation] > 0) & (z >= lo) & (z <= hi)
    optical = np.stack(
        [(u[keep] - i.ppx) / i.fx * z[keep], (v[keep] - i.ppy) / i.fy * z[keep], z[keep]], 1
    )
    return optical @ frame.extrinsics[:3, :3].T + frame.extrinsics[:3, 3]


def test_decimation_and_range_limits_match_reference():
    rng = np.random.default_rng(1)
    frame = _random_frame(rng, D435.intrinsics(640, 480))
    for decimation, lo, hi in [(1, None, None), (2, 0.5, 3.0), (3, None, 1.2), (4, 1.0, None)]:
        got = frame_to_points(frame, decimation, lo, hi)
        want = _reference_points(frame, decimation, lo or 0.0, np.inf if hi is None else hi)
        assert got.shape == want.shape
        np.testing.assert_allclose(got, want, atol=2e-6)


@pytest.mark.parametrize("box", [PAPER_000, PAPER_000_TEST_7], ids=["1m", "3m (test 7)"])
def test_crop_box_in_conversion_equals_cropping_the_cloud(box):
    rng = np.random.default_rng(2)
    frame = _random_frame(rng, L515.intrinsics(1024, 768), tilt=45.0, scale=0.00025)
    frame.depth[:] = rng.integers(0, 14000, frame.depth.shape, dtype=np.uint16)
    full = _reference_points(frame)
    inside = full[_in_box(full, box, 0.0)]
    fused = frame_to_points(frame, box=box)
    assert abs(len(fused) - len(inside)) <= 2  # float32 vs float64 at the box faces
    assert len(inside) > 1000
    np.testing.assert_array_equal(fused, crop(frame_to_points(frame), box))
    tol = 1e-5
    assert (fused[:, 0] >= box.x_min - tol).all() and (fused[:, 0] <= box.x_max + tol).all()
    assert (fused[:, 2] >= box.z_min - tol).all() and (fused[:, 2] <= box.z_max + tol).all()


def _in_box(points, box, margin):
    """Which float64 points lie inside ``box`` grown by ``margin`` (m) on every face."""
    keep = np.ones(len(points), bool)
    for axis, (lo, hi) in enumerate(
        [(box.x_min, box.x_max), (box.y_min, box.y_max), (box.z_min, box.z_max)]
    ):
        keep &= (points[:, axis] >= lo - margin) & (points[:, axis] <= hi + margin)
    return keep


NARROW = CropBox(x_min=0.15, x_max=0.5, y_min=0.05, y_max=0.25, z_min=-0.3, z_max=0.1)
"""A box off to the left: only a window of the image can reach it."""

BEHIND = CropBox(x_min=-2.0, x_max=-1.0, y_min=-0.6, y_max=0.6, z_min=-0.1, z_max=0.3)
"""A box behind the camera: no pixel can reach it."""


@pytest.mark.parametrize("tilt", [0.0, 45.0, 90.0])
@pytest.mark.parametrize("decimation,lo,hi", [(1, None, None), (2, 0.1, 2.5), (3, None, 1.5)])
@pytest.mark.parametrize("box", [PAPER_000, NARROW], ids=["paper 000", "narrow"])
def test_crop_box_with_decimation_and_ranges_equals_cropping_the_cloud(
    tilt, decimation, lo, hi, box
):
    rng = np.random.default_rng(3)
    frame = _random_frame(rng, D435.intrinsics(640, 480), tilt=tilt)
    fused = frame_to_points(frame, decimation, lo, hi, box=box)
    np.testing.assert_array_equal(fused, crop(frame_to_points(frame, decimation, lo, hi), box))
    want = _reference_points(frame, decimation, lo or 0.0, np.inf if hi is None else hi)
    # float32 vs float64 decides points on a face (at 90° the x_min face holds the camera):
    # every point 10 µm inside the box is kept, none 10 µm outside it is
    inside, near = _in_box(want, box, -1e-5), _in_box(want, box, 1e-5)
    assert np.count_nonzero(inside) <= len(fused) <= np.count_nonzero(near)
    assert np.count_nonzero(inside) > 50


SMALL = Intrinsics(width=80, height=60, fx=60.0, fy=60.0, ppx=40.0, ppy=30.0)
"""A small sensor whose centre row and column have rays with exact zero components."""

_corner = st.floats(-1.0, 2.0, allow_nan=False).map(lambda c: round(c, 2))
_size = st.floats(0.01, 2.0, allow_nan=False).map(lambda c: round(c, 2))


@settings(max_examples=60, deadline=None, derandomize=True)
@given(
    tilt=st.sampled_from([0.0, 15.0, 30.0, 45.0, 60.0, 90.0]) | st.floats(-10.0, 95.0),
    height=st.floats(0.0, 0.5),
    scale=st.sampled_from([0.001, 0.00025]),
    decimation=st.integers(1, 3),
    corner=st.tuples(_corner, _corner.map(lambda c: c - 0.5), _corner.map(lambda c: c - 0.5)),
    size=st.tuples(_size, _size, _size),
    seed=st.integers(0, 2**16),
)
@example(  # faces through the camera, met by the centre row and column's exactly zero rays
    tilt=90.0,
    height=0.3,
    scale=0.001,
    decimation=1,
    corner=(0.1, 0.0, -0.5),
    size=(0.5,) * 3,
    seed=0,
)
def test_fused_crop_equals_cropping_the_cloud_for_any_box_and_mount(
    tilt, height, scale, decimation, corner, size, seed
):
    config = CameraConfig(mount=CameraMount(position=[0.1, 0.0, height], tilt_deg=tilt))
    extrinsics = mount_extrinsics(config)
    (x, y, z), (dx, dy, dz) = corner, size
    box = CropBox(x_min=x, x_max=x + dx, y_min=y, y_max=y + dy, z_min=z, z_max=z + dz)
    # half the pixels at random depths, half within a raw step of where their ray crosses a face
    rng = np.random.default_rng(seed)
    shape = (SMALL.height, SMALL.width)
    v, u = np.mgrid[0 : SMALL.height, 0 : SMALL.width]
    optical = np.stack([(u - SMALL.ppx) / SMALL.fx, (v - SMALL.ppy) / SMALL.fy, np.ones(shape)])
    rays = np.einsum("ij,jhw->ihw", extrinsics[:3, :3], optical)
    axis = rng.integers(0, 3, shape)
    faces = np.array([[x, y, z], [x + dx, y + dy, z + dz]])[rng.integers(0, 2, shape), axis]
    ray = np.take_along_axis(rays, axis[None], 0)[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        crossing = (faces - extrinsics[axis, 3]) / ray / scale
    near = np.nan_to_num(np.round(crossing), nan=0, posinf=0, neginf=0) + rng.integers(-1, 2, shape)
    depth = rng.integers(0, int(3.0 / scale), shape)
    depth = np.where((rng.random(shape) < 0.5) & (near > 0) & (near < 65536), near, depth)
    frame = DepthFrame(depth.astype(np.uint16), scale, SMALL, extrinsics, 0.0)
    fused = frame_to_points(frame, decimation, box=box)
    np.testing.assert_array_equal(fused, crop(frame_to_points(frame, decimation), box))


def test_box_out_of_view_gives_no_points():
    rng = np.random.default_rng(4)
    frame = _random_frame(rng, D435.intrinsics(640, 480))
    assert frame_to_points(frame, box=BEHIND).shape == (0, 3)


def test_paper_000_boxes_have_the_papers_dimensions():
    for box, length in [(PAPER_000, 1.0), (PAPER_000_TEST_7, 3.0)]:
        dims = (box.x_max - box.x_min, box.y_max - box.y_min, box.z_max - box.z_min)
        np.testing.assert_allclose(dims, (length, 1.2, 0.4))
    with pytest.raises(ValueError, match="z_max"):
        CropBox(x_min=0, x_max=1, y_min=-1, y_max=1, z_min=0.3, z_max=0.1)


def test_decimation_and_threshold_filters_from_the_profile():
    intrinsics = D435.intrinsics(640, 480)
    config = CameraConfig(filters=["threshold", "decimation"], max_range=1.0)
    camera = SoftwareDepthCamera(intrinsics, 0.001, np.eye(4), config=config)
    image = np.full((480, 640), 800, np.uint16)
    image[:, 320:] = 2000  # beyond max_range: the threshold filter removes it
    (frame,) = _stream(camera, [image])
    assert frame.depth.shape == (240, 320)
    assert frame.intrinsics.fx == pytest.approx(intrinsics.fx / 2, rel=1e-3)
    assert (frame.depth[:, :150] == 800).all()
    assert (frame.depth[:, 170:] == 0).all()


def test_bad_configuration_and_input_get_clear_errors(monkeypatch):
    intrinsics = D435.intrinsics(640, 480)
    with pytest.raises(DriverError, match="fixed depth unit of 0.00025"):
        SoftwareDepthCamera(
            L515.intrinsics(640, 480),
            0.00025,
            np.eye(4),
            config=CameraConfig(model="L515", depth_units=0.001),
        )
    with pytest.raises(DriverError, match="visual_preset: 'hand' is not a L515 preset"):
        RealSenseCamera(
            CameraConfig(model="L515", visual_preset="hand"), LiveSource(CameraConfig())
        )
    with pytest.raises(DriverError, match=r"filters: unknown \['median'\]"):
        RealSenseCamera(CameraConfig(filters=["median"]), LiveSource(CameraConfig()))
    with pytest.raises(DriverError, match="no RealSense with serial 123456; found: none"):
        LiveSource(CameraConfig(serial="123456")).connect()
    monkeypatch.setattr(camera_module, "librealsense_version", lambda: (2, 56, 1))
    with pytest.raises(DriverError, match=r"the L515 needs librealsense <= 2.54, this is 2.56.1"):
        LiveSource(CameraConfig(model="L515")).connect()
    camera = SoftwareDepthCamera(intrinsics, 0.001, np.eye(4))
    with pytest.raises(DriverError, match="before open"):
        camera.push(np.zeros((480, 640), np.uint16), 0.0)
    camera.open()
    try:
        with pytest.raises(DriverError, match=r"expected uint16 depth of shape \(480, 640\)"):
            camera.push(np.zeros((480, 640), np.float32), 0.0)
    finally:
        camera.close()
    wrong = DepthFrame(np.zeros((10, 10), np.uint16), 0.001, intrinsics, np.eye(4), 0.0)
    with pytest.raises(ValueError, match="does not match intrinsics 640x480"):
        frame_to_points(wrong)
    metres = DepthFrame(np.zeros((480, 640), np.float32), 0.001, intrinsics, np.eye(4), 0.0)
    with pytest.raises(ValueError, match="depth must be uint16 raw units, got float32"):
        frame_to_points(metres)


def test_model_data():
    assert L515.depth_unit == 0.00025 and L515.depth_unit_fixed
    assert D435.depth_unit == 0.001 and not D435.depth_unit_fixed
    assert {(1024, 768), (640, 480)} <= set(L515.resolutions)
    assert {(848, 480), (640, 480)} <= set(D435.resolutions)
    i = L515.intrinsics(1024, 768)
    assert 2 * math.degrees(math.atan(i.width / 2 / i.fx)) == pytest.approx(70.0, abs=0.5)
    with pytest.raises(ValueError, match="no depth stream 800x600"):
        D435.intrinsics(800, 600)
