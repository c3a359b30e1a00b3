"""Point cloud files: every format round-trips, real PCDs read, broken files get clear errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from climbd.daemon.contract import lzf
from climbd.daemon.contract.cloudio import CloudFileError, read_cloud, write_cloud
from climbd.drivers.sim.worlds import DATA

ENCODINGS = [
    ("cloud.pcd", "ascii"),
    ("cloud.pcd", "binary"),
    ("cloud.pcd", "binary_compressed"),
    ("cloud.ply", "ascii"),
    ("cloud.ply", "binary"),
    ("cloud.npy", None),
]


@pytest.fixture
def points():
    rng = np.random.default_rng(7)
    p = rng.uniform(-3, 3, (2000, 3)).astype(np.float32)
    p[::10] = p[0]  # repeats give LZF something to compress
    return p


@pytest.mark.parametrize("name,encoding", ENCODINGS, ids=[f"{n}-{e}" for n, e in ENCODINGS])
def test_each_format_round_trips(tmp_path, points, name, encoding):
    path = tmp_path / name
    write_cloud(path, points, encoding)
    back = read_cloud(path)
    assert back.shape == points.shape and back.dtype == np.float64
    np.testing.assert_array_equal(back.astype(np.float32), points)


def test_binary_compressed_pcd_compresses_and_keeps_only_xyz(tmp_path):
    n = 500
    xyz = np.random.default_rng(3).normal(size=(n, 3)).astype("<f4")
    rgb = np.full(n, 0x00FF8040, "<u4")
    normals = np.zeros((n, 3), "<f4")
    columns = [xyz[:, 0], xyz[:, 1], xyz[:, 2], rgb, normals.ravel()]
    raw = b"".join(c.tobytes() for c in columns)
    packed = lzf.compress(raw)
    assert len(packed) < len(raw)
    header = (
        "VERSION .7\nFIELDS x y z rgb normal\nSIZE 4 4 4 4 4\nTYPE F F F U F\nCOUNT 1 1 1 1 3\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary_compressed\n"
    )
    path = tmp_path / "fields.pcd"
    path.write_bytes(header.encode() + np.array([len(packed), len(raw)], "<u4").tobytes() + packed)
    np.testing.assert_array_equal(read_cloud(path), xyz.astype(np.float64))


@pytest.mark.parametrize("name,count", [("leaning", 18401), ("vertical", 19134)])
def test_real_realsense_pcds(name, count):
    points = read_cloud(DATA / f"{name}_bouldering_holds.pcd")
    assert points.shape == (count, 3)
    # holds a few decimetres in front of the sensor, metres not millimetres
    assert 0.1 < np.median(np.linalg.norm(points, axis=1)) < 2.0


def test_nan_points_are_dropped(tmp_path):
    p = np.array([[1, 2, 3], [np.nan, 0, 0], [4, 5, 6]], np.float32)
    write_cloud(tmp_path / "n.pcd", p)
    np.testing.assert_array_equal(read_cloud(tmp_path / "n.pcd"), [[1, 2, 3], [4, 5, 6]])


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=3000), st.integers(0, 40))
def test_lzf_round_trip(data, repeat):
    data = data + data[:64] * repeat
    assert lzf.decompress(lzf.compress(data), len(data)) == data


def _broken(tmp_path, points, name, encoding, cut=None, replace=None):
    path = tmp_path / name
    write_cloud(path, points, encoding)
    data = path.read_bytes()
    if cut is not None:
        data = data[:cut]
    if replace is not None:
        data = data.replace(*replace)
    path.write_bytes(data)
    return path


CASES = [
    ("cloud.pcd", "binary", -100, None, "PCD binary data truncated"),
    ("cloud.pcd", "binary_compressed", -100, None, "PCD binary_compressed data truncated"),
    ("cloud.pcd", "ascii", -200, None, "PCD ascii data truncated"),
    ("cloud.pcd", "ascii", None, (b"\n1", b"\nx"), "is not a number"),
    ("cloud.pcd", "binary", None, (b"FIELDS x y z", b"FIELDS x y q"), "has no 'z'"),
    ("cloud.pcd", "binary", None, (b"POINTS 2000", b"POINTS 2001"), "WIDTH×HEIGHT"),
    ("cloud.pcd", "binary", None, (b"DATA binary", b"DATA zipped"), "DATA 'zipped' unknown"),
    ("cloud.pcd", "binary", None, (b"DATA", b"MOOP"), "header ends before its DATA line"),
    ("cloud.pcd", "binary", None, (b"TYPE F F F", b"TYPE F F X"), "unsupported TYPE X"),
    ("cloud.ply", "binary", -100, None, "PLY vertex data truncated"),
    ("cloud.ply", "ascii", -200, None, "PLY ascii vertex data truncated"),
    ("cloud.ply", "binary", None, (b"element vertex", b"element point"), "no vertex element"),
    ("cloud.ply", "binary", None, (b"ply\n", b"plx\n"), "not a PLY file"),
    ("cloud.ply", "binary", None, (b"binary_little", b"binary_middle"), "PLY format"),
    ("cloud.npy", None, 60, None, "not a readable .npy array"),
]


@pytest.mark.parametrize("name,encoding,cut,replace,message", CASES)
def test_malformed_files_name_the_file_and_the_problem(
    tmp_path, points, name, encoding, cut, replace, message
):
    path = _broken(tmp_path, points, name, encoding, cut, replace)
    with pytest.raises(CloudFileError) as info:
        read_cloud(path)
    assert str(info.value).startswith(f"{path}: ")
    assert message in str(info.value)


def test_corrupt_lzf_stream_and_wrong_shapes(tmp_path, points):
    path = _broken(tmp_path, points, "c.pcd", "binary_compressed")
    data = bytearray(path.read_bytes())
    header_end = data.index(b"DATA binary_compressed\n") + len("DATA binary_compressed\n")
    data[header_end + 8] = 0xFF  # first control byte: a back-reference before the start
    path.write_bytes(bytes(data))
    with pytest.raises(CloudFileError, match="binary_compressed data corrupt"):
        read_cloud(path)
    np.save(tmp_path / "flat.npy", np.zeros((5, 2)))
    with pytest.raises(
        CloudFileError, match=r"expected an N×3 array of metres, found shape \(5, 2\)"
    ):
        read_cloud(tmp_path / "flat.npy")
    with pytest.raises(CloudFileError, match="unknown point cloud extension"):
        read_cloud(tmp_path / "cloud.xyz")
    with pytest.raises(CloudFileError, match="cannot read"):
        read_cloud(tmp_path / "missing.pcd")
