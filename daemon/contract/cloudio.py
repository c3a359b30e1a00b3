"""Point cloud files: PCD (ascii, binary, binary_compressed), PLY (ascii, binary), NPY (N×3).

``read_cloud`` returns the finite x, y, z of every point as an (N, 3) float64 array in metres;
a malformed or truncated file raises CloudFileError naming the file and what is wrong.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from climbd.daemon.contract import lzf

FORMATS = {
    ".pcd": ("ascii", "binary", "binary_compressed"),
    ".ply": ("ascii", "binary"),
    ".npy": ("npy",),
}


class CloudFileError(ValueError):
    """A point cloud file that cannot be read; the message names the file and the problem."""


def _fail(path: Path, message: str) -> CloudFileError:
    return CloudFileError(f"{path}: {message}")


def read_cloud(path: str | Path) -> np.ndarray:
    """The (N, 3) float64 points of a .pcd, .ply or .npy file, points with NaN dropped."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise _fail(path, f"unknown point cloud extension (supported: {', '.join(FORMATS)})")
    try:
        data = path.read_bytes()
    except OSError as e:
        raise _fail(path, f"cannot read: {e.strerror}") from None
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


def _read_npy(path: Path, data: bytes) -> np.ndarray:
    try:
        array = np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, EOFError, OSError) as e:
        raise _fail(path, f"not a readable .npy array: {e}") from None
    if array.ndim != 2 or array.shape[1] != 3:
        raise _fail(path, f"expected an N×3 array of metres, found shape {array.shape}")
    if array.dtype.kind not in "fiu":
        raise _fail(path, f"expected a numeric array, found dtype {array.dtype}")
    return array.astype(np.float64)


# --- PCD ---------------------------------------------------------------------------------

_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8"} | {
    (t, s): f"{'i' if t == 'I' else 'u'}{s}" for t in "IU" for s in (1, 2, 4, 8)
}
_PCD_KEYS = ("FIELDS", "SIZE", "TYPE", "WIDTH", "HEIGHT", "POINTS", "DATA")


def _pcd_header(path: Path, data: bytes) -> tuple[dict[str, list[str]], int]:
    header: dict[str, list[str]] = {}
    offset = 0
    while True:
        end = data.find(b"\n", offset)
        if end < 0:
            raise _fail(path, "PCD header ends before its DATA line")
        line = data[offset:end].decode("ascii", "replace").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        header[key.upper()] = values
        if key.upper() == "DATA":
            break
    missing = [k for k in _PCD_KEYS if k not in header]
    if missing:
        raise _fail(path, f"PCD header lacks {', '.join(missing)}")
    return header, offset


def _pcd_int(path: Path, header: dict[str, list[str]], key: str) -> int:
    values = header[key]
    if len(values) != 1 or not values[0].isdigit():
        raise _fail(path, f"PCD {key}: expected one non-negative integer, found {values}")
    return int(values[0])


def _read_pcd(path: Path, data: bytes) -> np.ndarray:
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
    body = data[offset:]
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
        need = record.itemsize * points
        if len(body) < need:
            raise _fail(path, f"PCD binary data truncated: {len(body)} of {need} bytes")
        table = np.frombuffer(body, dtype=record, count=points)
        return np.stack([table[n].astype(np.float64) for n in xyz], axis=1)
    if encoding == "binary_compressed":
        return _pcd_compressed(path, body, columns, xyz, points, record.itemsize)
    raise _fail(path, f"PCD DATA {encoding!r} unknown (ascii, binary, binary_compressed)")


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
    return np.stack([out[n].astype(np.float64) for n in xyz], axis=1)


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


def _read_ply(path: Path, data: bytes) -> np.ndarray:
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise _fail(path, "not a PLY file (no 'ply' magic or no end_header)")
    newline = data.find(b"\n", end)
    if newline < 0:
        raise _fail(path, "PLY header ends without a newline after end_header")
    lines = data[:end].decode("ascii", "replace").splitlines()
    body = data[newline + 1 :]
    encoding = ""
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for line in lines[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) >= 2:
            encoding = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            if words[1] == "list":
                elements[-1][2].append((words[-1], "list"))
            elif len(words) == 3 and words[1] in _PLY_TYPES:
                elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
            else:
                raise _fail(path, f"PLY header: cannot read {line.strip()!r}")
        else:
            raise _fail(path, f"PLY header: cannot read {line.strip()!r}")
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
            path, f"PLY vertex data truncated: {max(0, len(body) - offset)} of {need} bytes"
        )
    table = np.frombuffer(body, dtype=records[-1], count=count, offset=offset)
    return np.stack([table[a].astype(np.float64) for a in "xyz"], axis=1)


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
