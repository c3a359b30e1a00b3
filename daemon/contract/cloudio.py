"""Point cloud files: PCD (ascii, binary, binary_compressed), PLY (ascii, binary), NPY (N×3).

``read_cloud`` returns the finite x, y, z of every point as an (N, 3) float64 array in metres;
a malformed or truncated file raises CloudFileError naming the file and what is wrong. A
header's declared size (NPY shape, PCD POINTS, PLY element count) is checked against the
file's length and ``MAX_POINTS`` before anything is allocated.
"""

from __future__ import annotations

import io
import stat
import tokenize
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from climbd.daemon.contract import lzf

FORMATS = {
    ".pcd": ("ascii", "binary", "binary_compressed"),
    ".ply": ("ascii", "binary"),
    ".npy": ("npy",),
}


MAX_FILE_BYTES = 1 << 30
"""Largest cloud file read (1 GiB): a D435 frame is 4 MB, a dense map of a building ~100 MB."""

MAX_POINTS = 50_000_000
"""Most points a file may declare (1.2 GB as float64 x, y, z): more is a lie or a mistake."""

LZF_MAX_EXPANSION = 88
"""LZF inflates at most 264 bytes from a 3-byte back-reference: a larger ratio is a lie."""


class CloudFileError(ValueError):
    """A point cloud file that cannot be read; the message names the file and the problem."""


def _fail(path: Path, message: str) -> CloudFileError:
    """The error of ``path``: its name, then what is wrong."""
    return CloudFileError(f"{path}: {message}")


def _read_bytes(path: Path) -> bytes:
    """The bytes of a regular file of at most MAX_FILE_BYTES; CloudFileError otherwise."""
    try:
        info = path.stat()
        if stat.S_ISDIR(info.st_mode):
            raise _fail(path, "is a directory, not a point cloud file")
        if not stat.S_ISREG(info.st_mode):
            raise _fail(path, "is not a regular file")
        if info.st_size > MAX_FILE_BYTES:
            raise _fail(path, f"file is {info.st_size} bytes, over the {MAX_FILE_BYTES}-byte limit")
        return path.read_bytes()
    except OSError as e:
        raise _fail(path, f"cannot read: {e.strerror or e}") from None


def _check_points(path: Path, field: str, count: int) -> None:
    """Refuse a header whose ``field`` declares more than MAX_POINTS points."""
    if count > MAX_POINTS:
        raise _fail(path, f"{field} declares {count} points, over the limit of {MAX_POINTS}")


def _metres(columns: Iterable[np.ndarray]) -> np.ndarray:
    """The x, y, z columns as an (N, 3) float64 array; a signalling NaN, which any float
    field of a file may hold, becomes a quiet one (and is dropped) without a warning."""
    with np.errstate(invalid="ignore"):
        return np.stack([c.astype(np.float64) for c in columns], axis=1)


def _header_text(path: Path, line: bytes, number: int, kind: str) -> str:
    """A header line as text; CloudFileError when it is not ASCII (headers are)."""
    try:
        return line.decode("ascii")
    except UnicodeDecodeError:
        raise _fail(path, f"{kind} header line {number} is not ASCII text: {line[:40]!r}") from None


def read_cloud(path: str | Path) -> np.ndarray:
    """The (N, 3) float64 points of a .pcd, .ply or .npy file, points with NaN dropped."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise _fail(path, f"unknown point cloud extension (supported: {', '.join(FORMATS)})")
    data = _read_bytes(path)
    reader = {".pcd": _read_pcd, ".ply": _read_ply, ".npy": _read_npy}[suffix]
    points = reader(path, data)
    return points[np.isfinite(points).all(axis=1)]


def write_cloud(path: str | Path, points: np.ndarray, encoding: str | None = None) -> None:
    """Write (N, 3) points; ``encoding`` is one of FORMATS[suffix] (default: binary/npy)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise _fail(path, f"unknown point cloud extension (supported: {', '.join(FORMATS)})")
    encoding = encoding or ("npy" if suffix == ".npy" else "binary")
    if encoding not in FORMATS[suffix]:
        raise _fail(path, f"{suffix} has no encoding {encoding!r} (one of {FORMATS[suffix]})")
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{path}: points must be N×3, got shape {points.shape}")
    if suffix == ".npy":
        np.save(path, points)
    elif suffix == ".pcd":
        path.write_bytes(_pcd_bytes(points.astype(np.float32), encoding))
    else:
        path.write_bytes(_ply_bytes(points.astype(np.float32), encoding))


# --- NPY ---------------------------------------------------------------------------------


_NPY_HEADERS = {
    (1, 0): np.lib.format.read_array_header_1_0,
    (2, 0): np.lib.format.read_array_header_2_0,
}


def _npy_header(path: Path, stream: io.BytesIO) -> tuple[tuple[int, ...], bool, np.dtype]:
    """Shape, Fortran order and dtype of an .npy header (versions 1.0 and 2.0)."""
    try:
        version = np.lib.format.read_magic(stream)
        if version not in _NPY_HEADERS:
            raise ValueError(f"format version {version[0]}.{version[1]} is not 1.0 or 2.0")
        return _NPY_HEADERS[version](stream)
    except (ValueError, EOFError, OSError, SyntaxError, TypeError, tokenize.TokenError) as e:
        raise _fail(path, f"not a readable .npy array: {e}") from None


def _read_npy(path: Path, data: bytes) -> np.ndarray:
    """An N×3 numeric .npy array; its header's shape is checked before the data is read."""
    stream = io.BytesIO(data)
    shape, fortran, dtype = _npy_header(path, stream)
    if len(shape) != 2 or shape[1] != 3 or shape[0] < 0:
        raise _fail(path, f"expected an N×3 array of metres, found shape {shape}")
    if dtype.kind not in "fiu":
        raise _fail(path, f"expected a numeric array, found dtype {dtype}")
    offset = stream.tell()
    need = shape[0] * 3 * dtype.itemsize
    if len(data) - offset < need:
        raise _fail(
            path,
            f".npy shape {shape} of {dtype} needs {need} bytes of data, "
            f"the file holds {len(data) - offset}",
        )
    _check_points(path, f".npy shape {shape}", shape[0])
    flat = np.frombuffer(data, dtype=dtype, count=shape[0] * 3, offset=offset)
    array = flat.reshape(shape[::-1]).T if fortran else flat.reshape(shape)
    return _metres(array[:, k] for k in range(3))


# --- PCD ---------------------------------------------------------------------------------

_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8"} | {
    (t, s): f"{'i' if t == 'I' else 'u'}{s}" for t in "IU" for s in (1, 2, 4, 8)
}
_PCD_KEYS = ("FIELDS", "SIZE", "TYPE", "WIDTH", "HEIGHT", "POINTS", "DATA")
_PCD_READ = {key.encode() for key in (*_PCD_KEYS, "COUNT")}


def _pcd_header(path: Path, data: bytes) -> tuple[dict[str, list[str]], int]:
    """The values of the header keys climbd reads (``_PCD_READ``) and the offset of the data;
    comments, VERSION, VIEWPOINT and unknown keys are skipped."""
    header: dict[str, list[str]] = {}
    offset = 0
    number = 0
    while True:
        end = data.find(b"\n", offset)
        if end < 0:
            raise _fail(path, "PCD header ends before its DATA line")
        raw = data[offset:end].strip()
        offset = end + 1
        number += 1
        key = raw.split(maxsplit=1)[0].upper() if raw else b""
        if key not in _PCD_READ:
            continue
        header[key.decode()] = _header_text(path, raw, number, "PCD").split()[1:]
        if key == b"DATA":
            break
    missing = [k for k in _PCD_KEYS if k not in header]
    if missing:
        raise _fail(path, f"PCD header lacks {', '.join(missing)}")
    return header, offset


def _pcd_int(path: Path, header: dict[str, list[str]], key: str) -> int:
    """The one non-negative integer of header ``key``."""
    values = header[key]
    if len(values) != 1 or not values[0].isdigit():
        raise _fail(path, f"PCD {key}: expected one non-negative integer, found {values}")
    return int(values[0])


def _pcd_declared(
    path: Path, encoding: str, points: int, itemsize: int, values: int, available: int
) -> None:
    """Refuse POINTS that the data after the header cannot hold, before anything is allocated.

    ``itemsize``: bytes of a binary record; ``values``: numbers of an ascii line (each takes
    a digit and a separator); ``available``: bytes after the header.
    """
    _check_points(path, "PCD POINTS", points)
    if itemsize > MAX_FILE_BYTES:
        raise _fail(path, f"PCD SIZE×COUNT declares {itemsize}-byte points, over the file limit")
    if encoding == "binary" and itemsize * points > available:
        raise _fail(
            path,
            f"PCD binary data truncated: {available} of {itemsize * points} bytes "
            f"for POINTS {points}",
        )
    if encoding == "binary_compressed" and itemsize * points > LZF_MAX_EXPANSION * available:
        raise _fail(
            path,
            f"PCD binary_compressed data truncated: {available} bytes cannot inflate to the "
            f"{itemsize * points} of POINTS {points}",
        )
    if encoding == "ascii" and 2 * values * points - 1 > available:
        raise _fail(
            path,
            f"PCD ascii data truncated: {available} bytes cannot hold POINTS {points} "
            f"of {values} values",
        )


def _read_pcd(path: Path, data: bytes) -> np.ndarray:
    """The x, y, z fields of a PCD file; POINTS is checked before the data is read."""
    header, offset = _pcd_header(path, data)
    fields, sizes, types = header["FIELDS"], header["SIZE"], header["TYPE"]
    counts = header.get("COUNT", ["1"] * len(fields))
    if not len(fields) == len(sizes) == len(types) == len(counts):
        raise _fail(
            path,
            f"PCD FIELDS/SIZE/TYPE/COUNT differ in length "
            f"({len(fields)}/{len(sizes)}/{len(types)}/{len(counts)})",
        )
    for axis in "xyz":
        if axis not in fields:
            raise _fail(path, f"PCD FIELDS {fields} has no {axis!r}")
    dtype_fields = []
    for name, size, kind, count in zip(fields, sizes, types, counts, strict=True):
        code = _PCD_TYPES.get((kind.upper(), int(size) if size.isdigit() else -1))
        if code is None or not count.isdigit() or int(count) < 1:
            raise _fail(
                path, f"PCD field {name!r}: unsupported TYPE {kind} SIZE {size} COUNT {count}"
            )
        dtype_fields.append((name, code, int(count)))
    points = _pcd_int(path, header, "POINTS")
    width, height = _pcd_int(path, header, "WIDTH"), _pcd_int(path, header, "HEIGHT")
    if width * height != points:
        raise _fail(path, f"PCD WIDTH×HEIGHT = {width}×{height} but POINTS = {points}")
    encoding = header["DATA"][0].lower() if header["DATA"] else ""
    if encoding not in FORMATS[".pcd"]:
        raise _fail(path, f"PCD DATA {encoding!r} unknown (ascii, binary, binary_compressed)")
    itemsize = sum(np.dtype(code).itemsize * count for _, code, count in dtype_fields)
    values = sum(count for _, _, count in dtype_fields)
    body = data[offset:]
    _pcd_declared(path, encoding, points, itemsize, values, len(body))
    if encoding == "ascii":
        return _pcd_ascii(path, body, fields, [c for _, _, c in dtype_fields], points)
    names = [f"f{k}" for k in range(len(fields))]
    columns = {
        name: (np.dtype(f"<{code}"), count)
        for name, (_, code, count) in zip(names, dtype_fields, strict=True)
    }
    record = np.dtype([(n, dt, (c,)) if c > 1 else (n, dt) for n, (dt, c) in columns.items()])
    xyz = [names[fields.index(a)] for a in "xyz"]
    if encoding == "binary":
        table = np.frombuffer(body, dtype=record, count=points)
        return _metres(table[n] for n in xyz)
    return _pcd_compressed(path, body, columns, xyz, points, record.itemsize)


def _pcd_ascii(
    path: Path, body: bytes, fields: list[str], counts: list[int], points: int
) -> np.ndarray:
    per_point = sum(counts)
    tokens = body.split()
    if len(tokens) < per_point * points:
        raise _fail(
            path, f"PCD ascii data truncated: {len(tokens)} values, expected {per_point * points}"
        )
    try:
        table = np.array(tokens[: per_point * points], dtype=np.float64)
    except ValueError:
        bad = next(k for k, t in enumerate(tokens) if not _is_number(t))
        raise _fail(
            path,
            f"PCD ascii data: value {bad} ({tokens[bad].decode(errors='replace')!r}) "
            "is not a number",
        ) from None
    table = table.reshape(points, per_point)
    starts = np.cumsum([0, *counts[:-1]])
    return table[:, [starts[fields.index(a)] for a in "xyz"]]


def _is_number(token: bytes) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _pcd_compressed(
    path: Path,
    body: bytes,
    columns: dict[str, tuple[np.dtype, int]],
    xyz: list[str],
    points: int,
    itemsize: int,
) -> np.ndarray:
    if len(body) < 8:
        raise _fail(path, "PCD binary_compressed data truncated before its size words")
    packed, size = np.frombuffer(body[:8], dtype="<u4")
    if size != itemsize * points:
        raise _fail(
            path,
            f"PCD binary_compressed: header says {size} bytes inflated, "
            f"the fields need {itemsize * points}",
        )
    if len(body) < 8 + packed:
        raise _fail(
            path, f"PCD binary_compressed data truncated: {len(body) - 8} of {packed} bytes"
        )
    try:
        raw = lzf.decompress(body[8 : 8 + packed], int(size))
    except lzf.LzfError as e:
        raise _fail(path, f"PCD binary_compressed data corrupt: {e}") from None
    out = {}
    offset = 0
    for name, (dt, count) in columns.items():
        n = dt.itemsize * count * points
        if name in xyz:
            out[name] = np.frombuffer(raw, dtype=dt, count=points * count, offset=offset)[::count]
        offset += n
    return _metres(out[n] for n in xyz)


def _pcd_bytes(points: np.ndarray, encoding: str) -> bytes:
    n = len(points)
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\n"
        f"TYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
        f"POINTS {n}\nDATA {encoding}\n"
    ).encode()
    if encoding == "ascii":
        return header + "".join(f"{x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in points).encode()
    little = points.astype("<f4")
    if encoding == "binary":
        return header + little.tobytes()
    raw = np.ascontiguousarray(little.T).tobytes()
    packed = lzf.compress(raw)
    return header + np.array([len(packed), len(raw)], dtype="<u4").tobytes() + packed


# --- PLY ---------------------------------------------------------------------------------

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}


def _ply_header(
    path: Path, header: bytes
) -> tuple[str, list[tuple[str, int, list[tuple[str, str]]]]]:
    """The format and the elements (name, count, properties) of a PLY header."""
    encoding = ""
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for number, raw in enumerate(header.splitlines()[1:], start=2):
        if raw.split()[:1] in ([b"comment"], [b"obj_info"]):
            continue
        line = _header_text(path, raw, number, "PLY")
        words = line.split()
        if not words:
            continue
        if words[0] == "format" and len(words) >= 2:
            encoding = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements and len(words) == 5 and words[1] == "list":
            elements[-1][2].append((words[4], "list"))
        elif words[0] == "property" and elements and len(words) == 3 and words[1] in _PLY_TYPES:
            name, count, props = elements[-1]
            if words[2] in (p for p, _ in props):
                raise _fail(path, f"PLY element {name!r}: property {words[2]!r} declared twice")
            props.append((words[2], _PLY_TYPES[words[1]]))
        else:
            raise _fail(path, f"PLY header: cannot read {line.strip()!r}")
    return encoding, elements


def _read_ply(path: Path, data: bytes) -> np.ndarray:
    """The vertices' x, y, z of a PLY file; the vertex count is checked before they are read."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise _fail(path, "not a PLY file (no 'ply' magic or no end_header)")
    newline = data.find(b"\n", end)
    if newline < 0:
        raise _fail(path, "PLY header ends without a newline after end_header")
    encoding, elements = _ply_header(path, data[:end])
    body = data[newline + 1 :]
    byte_order = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": ""}
    if encoding not in byte_order:
        raise _fail(path, f"PLY format {encoding!r} unknown ({', '.join(byte_order)})")
    names = [e[0] for e in elements]
    if "vertex" not in names:
        raise _fail(path, "PLY has no vertex element")
    index = names.index("vertex")
    _, count, props = elements[index]
    prop_names = [p for p, _ in props]
    for axis in "xyz":
        if axis not in prop_names:
            raise _fail(path, f"PLY vertex element has no property {axis!r}")
    _check_points(path, "PLY element vertex", count)
    if encoding == "ascii":
        return _ply_ascii(path, body, elements, index)
    order = byte_order[encoding]
    offset = 0
    records = []
    for name, _, eprops in elements[: index + 1]:
        if any(kind == "list" for _, kind in eprops):
            raise _fail(path, f"PLY element {name!r} has list properties ahead of the vertices")
        records.append(np.dtype([(p, order + kind) for p, kind in eprops]))
    offset = sum(r.itemsize * n for r, (_, n, _) in zip(records[:-1], elements, strict=False))
    need = records[-1].itemsize * count
    if len(body) - offset < need:
        raise _fail(
            path,
            f"PLY vertex data truncated: {max(0, len(body) - offset)} of {need} bytes "
            f"for element vertex {count}",
        )
    table = np.frombuffer(body, dtype=records[-1], count=count, offset=offset)
    return _metres(table[a] for a in "xyz")


def _ply_ascii(
    path: Path, body: bytes, elements: list[tuple[str, int, list[tuple[str, str]]]], index: int
) -> np.ndarray:
    lines = body.splitlines()
    skip = sum(n for _, n, _ in elements[:index])
    _, count, props = elements[index]
    rows = lines[skip : skip + count]
    if len(rows) < count:
        raise _fail(path, f"PLY ascii vertex data truncated: {len(rows)} of {count} lines")
    columns = [p for p, _ in props]
    try:
        table = np.array([row.split() for row in rows], dtype=np.float64)
    except ValueError:
        raise _fail(
            path, "PLY ascii vertex data: a line has a wrong number of values or a non-number"
        ) from None
    if table.ndim != 2 or table.shape[1] != len(columns):
        raise _fail(path, f"PLY ascii vertex lines need {len(columns)} values each")
    return table[:, [columns.index(a) for a in "xyz"]]


def _ply_bytes(points: np.ndarray, encoding: str) -> bytes:
    fmt = "ascii" if encoding == "ascii" else "binary_little_endian"
    header = (
        f"ply\nformat {fmt} 1.0\ncomment climbd point cloud, metres\nelement vertex {len(points)}\n"
        "property float x\nproperty float y\nproperty float z\nend_header\n"
    ).encode()
    if encoding == "ascii":
        return header + "".join(f"{x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in points).encode()
    return header + points.astype("<f4").tobytes()
