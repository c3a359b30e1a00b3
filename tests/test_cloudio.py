"""Point cloud files: every format round-trips, real PCDs read, broken files get clear errors."""

from __future__ import annotations

import io
import os
import warnings

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


def _npy_claiming(shape: tuple[int, int], size: int) -> bytes:
    """An .npy file of ``size`` bytes whose header declares ``shape`` float64."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f8", "fortran_order": False, "shape": shape}
    )
    head = header.getvalue()
    return head + bytes(size - len(head))


def _pcd_claiming(points: int, encoding: str) -> bytes:
    """A PCD header declaring ``points`` points, followed by 64 bytes of data."""
    header = (
        "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {points}\nHEIGHT 1\nPOINTS {points}\nDATA {encoding}\n"
    )
    return header.encode() + bytes(64)


def _ply_claiming(vertices: int, encoding: str) -> bytes:
    """A PLY header declaring ``vertices`` vertices, followed by 64 bytes of data."""
    header = (
        f"ply\nformat {encoding} 1.0\nelement vertex {vertices}\n"
        "property float x\nproperty float y\nproperty float z\nend_header\n"
    )
    return header.encode() + b"0 0 0\n" * 10 + bytes(4)


def _raises_naming(path, *words: str) -> str:
    """The CloudFileError of reading ``path``: it starts with the file, holds ``words``."""
    with pytest.raises(CloudFileError) as info:
        read_cloud(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    for word in words:
        assert word in message
    return message


def test_npy_header_lying_about_its_shape_is_refused_before_allocating(tmp_path):
    path = tmp_path / "lying.npy"
    rows = (2 << 40) // 24  # 2 TiB of float64 x, y, z
    path.write_bytes(_npy_claiming((rows, 3), 193))
    assert path.stat().st_size == 193
    _raises_naming(path, f".npy shape ({rows}, 3)", f"needs {rows * 24} bytes", "holds 65")


def test_npy_header_short_of_its_data_is_refused(tmp_path):
    path = tmp_path / "short.npy"
    path.write_bytes(_npy_claiming((10, 3), 128 + 24 * 9))
    _raises_naming(path, ".npy shape (10, 3)", "needs 240 bytes")


@pytest.mark.parametrize("encoding", ["ascii", "binary", "binary_compressed"])
def test_pcd_claiming_a_trillion_points_is_refused(tmp_path, encoding):
    path = tmp_path / "lying.pcd"
    path.write_bytes(_pcd_claiming(10**12, encoding))
    _raises_naming(path, "PCD POINTS", str(10**12))


@pytest.mark.parametrize("encoding", ["ascii", "binary", "binary_compressed"])
def test_pcd_points_beyond_the_data_are_refused(tmp_path, encoding):
    path = tmp_path / "short.pcd"
    path.write_bytes(_pcd_claiming(10**6, encoding))
    _raises_naming(path, f"PCD {encoding} data truncated", "POINTS 1000000")


@pytest.mark.parametrize("encoding", ["ascii", "binary_little_endian"])
def test_ply_claiming_a_trillion_vertices_is_refused(tmp_path, encoding):
    path = tmp_path / "lying.ply"
    path.write_bytes(_ply_claiming(10**12, encoding))
    _raises_naming(path, "PLY element vertex", str(10**12))


def test_ply_binary_vertices_beyond_the_data_are_refused(tmp_path):
    path = tmp_path / "short.ply"
    path.write_bytes(_ply_claiming(10**6, "binary_little_endian"))
    _raises_naming(path, "PLY vertex data truncated", "element vertex 1000000")


@pytest.mark.parametrize("name", ["cloud.pcd", "cloud.ply", "cloud.npy"])
def test_a_directory_is_not_a_cloud(tmp_path, name):
    path = tmp_path / name
    path.mkdir()
    _raises_naming(path, "is a directory")


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads files whatever their mode")
def test_an_unreadable_file_is_named(tmp_path, points):
    path = tmp_path / "locked.pcd"
    write_cloud(path, points)
    path.chmod(0)
    _raises_naming(path, "cannot read", "Permission denied")


NON_ASCII = [
    ("cloud.pcd", "binary", b"FIELDS x y z", b"FIELDS x y\xff\xfe z", "PCD header line"),
    ("cloud.pcd", "ascii", b"POINTS 2000", b"POINTS \xb2000", "PCD header line"),
    ("cloud.ply", "binary", b"property float x", b"property float \xffx", "PLY header line"),
    ("cloud.ply", "ascii", b"element vertex 2000", b"element vertex \xb2000", "PLY header line"),
    ("cloud.npy", None, b"'descr'", b"'d\xff\xfescr'", "not a readable .npy array"),
]


@pytest.mark.parametrize("name,encoding,old,new,message", NON_ASCII)
def test_non_utf8_headers_are_named(tmp_path, points, name, encoding, old, new, message):
    path = _broken(tmp_path, points, name, encoding, replace=(old, new))
    _raises_naming(path, message)


def test_non_ascii_comments_are_skipped(tmp_path, points):
    path = _broken(tmp_path, points, "c.ply", "binary", replace=(b"climbd", "clîmbd ©".encode()))
    assert read_cloud(path).shape == points.shape


@pytest.mark.parametrize("name,encoding", ENCODINGS, ids=[f"{n}-{e}" for n, e in ENCODINGS])
def test_mutated_files_raise_only_cloud_file_errors(tmp_path, name, encoding):
    """Random byte edits, mostly in the header: every failure is a CloudFileError naming the
    file, and no numeric warning escapes."""
    rng = np.random.default_rng(11)
    path = tmp_path / name
    write_cloud(path, rng.uniform(-1, 1, (40, 3)), encoding)
    clean = path.read_bytes()
    inserts = [b"99999999999999", b"-1", b"\xff\xfe", b"\n", b" ", b"\xb2", b"list", b"(9, 3)"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        warnings.filterwarnings("ignore", "Reading `.npy`", UserWarning)  # a Python 2 header
        for _ in range(300):
            data = bytearray(clean)
            at = int(rng.integers(0, min(len(data), 200)))
            kind = rng.integers(4)
            if kind == 0:
                data[at] = int(rng.integers(256))
            elif kind == 1:
                data[at:at] = inserts[int(rng.integers(len(inserts)))]
            elif kind == 2:
                del data[at : at + int(rng.integers(1, 6))]
            else:
                del data[at:]
            path.write_bytes(bytes(data))
            try:
                read_cloud(path)
            except CloudFileError as e:
                assert str(e).startswith(f"{path}: ")
