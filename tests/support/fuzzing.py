"""Fuzz properties shared by tests/test_fuzz.py (hundreds of inputs) and bench/soak.py (10,000+).

A message decoder may only return a message of its type or raise what the bus catches
(msgspec.DecodeError, msgspec.ValidationError, SchemaMismatch); anything else would escape a
Zenoh callback. The profile parser may only return a Profile or raise ProfileError.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import msgspec
from hypothesis import strategies as st

from climbd.daemon.contract import messages as m
from climbd.daemon.contract.profile import Profile, ProfileError, from_dict, load, tomllib

ROOT = Path(__file__).resolve().parents[2]
DECODE_ERRORS = (msgspec.DecodeError, msgspec.ValidationError, m.SchemaMismatch)

scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**63), max_value=2**64 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.binary(max_size=12),
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)


def field_names(message: type[m.Message]) -> list[str]:
    return [f.name for f in msgspec.structs.fields(message)]


def payloads(message: type[m.Message]) -> st.SearchStrategy[bytes]:
    """Random bytes, maps over the message's own field names, byte-mutated valid payloads, and
    raw bytes a broken or hostile peer could send (raw_payloads)."""
    names = st.sampled_from(field_names(message) + ["schema", "stamp", "bogus"])
    maps = st.dictionaries(names, values, max_size=8).map(msgspec.msgpack.encode)
    valid = m.encode(message())
    mutated = st.lists(
        st.tuples(st.integers(0, max(0, len(valid) - 1)), st.integers(0, 255)), max_size=4
    ).map(lambda edits: _mutate(valid, edits))
    return st.one_of(st.binary(max_size=64), maps, mutated, raw_payloads(message))


def _mutate(data: bytes, edits: list[tuple[int, int]]) -> bytes:
    out = bytearray(data)
    for i, b in edits:
        out[i] = b
    return bytes(out)


def check_decoder(message: type[m.Message], payload: bytes) -> None:
    """The bus's contract with a decoder: a message of the type, or an error it catches."""
    try:
        value = m.decode(payload, message)
    except DECODE_ERRORS:
        return
    assert type(value) is message and value.schema == m.SCHEMA_VERSION


def stock_profile_dict(name: str = "widowx") -> dict:
    return tomllib.loads((ROOT / "robots" / f"{name}.toml").read_text())


def _paths(tree, prefix=()):
    """Every path to a value in a nested dict/list tree."""
    yield prefix
    if isinstance(tree, dict):
        for k, v in tree.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            yield from _paths(v, (*prefix, i))


PROFILE = stock_profile_dict()
PROFILE_PATHS = [p for p in _paths(PROFILE) if p]


def _replace(tree: dict, path: tuple, value) -> dict:
    out = copy.deepcopy(tree)
    node = out
    for k in path[:-1]:
        node = node[k]
    if value is _DELETE:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return out


_DELETE = object()

profile_edits = st.lists(
    st.tuples(st.sampled_from(PROFILE_PATHS), st.one_of(values, st.just(_DELETE))),
    min_size=1,
    max_size=3,
)


def edited_profile(edits) -> dict:
    """The stock WidowX profile with values replaced or deleted at random paths."""
    tree = PROFILE
    for path, value in edits:
        try:
            tree = _replace(tree, path, value)
        except (KeyError, IndexError, TypeError):
            continue  # an earlier edit removed or retyped this path's parent
    return tree


def check_profile(data) -> None:
    """from_dict: a valid Profile (finite, ordered limits) or a ProfileError naming the source."""
    try:
        profile = from_dict(data, "fuzz.toml")
    except ProfileError as e:
        assert str(e).startswith("fuzz.toml"), e
        return
    assert isinstance(profile, Profile)
    for j in profile.joints:
        assert j.limits.lower < j.limits.upper
        assert all(math.isfinite(v) and v > 0 for v in (j.limits.velocity, j.limits.jerk))


def check_profile_text(tmp: Path, text: str) -> None:
    """load() on arbitrary file text: a Profile or a ProfileError, never anything else."""
    tmp.write_text(text)
    try:
        load(tmp)
    except ProfileError:
        return


# --- raw bytes (issue #33): invalid UTF-8, truncated and huge headers, huge declared lengths ---

_INVALID_UTF8 = st.sampled_from(
    [b"\xff", b"\xfe\xff", b"\xc3", b"\xc3\x28", b"\xe2\x82", b"\xed\xa0\x80", b"\xf8\x88\x80"]
    + [b"\xf4\x90\x80\x80", b"\xc0\xaf", b"a\x80b", b"\x00\xff"]
)
"""Byte strings that are not UTF-8: stray continuation bytes, truncated sequences, surrogates,
overlong forms, code points past U+10FFFF."""

_HUGE = st.sampled_from([2**16 - 1, 2**31 - 1, 2**32 - 1])


def _msgpack_str(data: bytes) -> bytes:
    """A msgpack str (str8/str32 header) of raw ``data``, UTF-8 or not."""
    if len(data) < 256:
        return bytes([0xD9, len(data)]) + data
    return b"\xdb" + len(data).to_bytes(4, "big") + data


def _huge_header(kind: int, n: int, tail: bytes) -> bytes:
    """A 32-bit msgpack header (str 0xdb, bin 0xc6, array 0xdd, map 0xdf, ext 0xc9) declaring
    ``n`` items or bytes, followed by only ``tail``."""
    head = bytes([kind]) + n.to_bytes(4, "big")
    return head + (b"\x01" if kind == 0xC9 else b"") + tail


def raw_payloads(message: type[m.Message]) -> st.SearchStrategy[bytes]:
    """Bytes a broken or hostile peer could send: field values and keys that are not UTF-8,
    headers declaring far more than follows (at the top and as a field's value), valid payloads
    cut short, and deep nesting."""
    names = st.sampled_from([n.encode() for n in field_names(message)] + [b"schema", b"x"])
    valid = m.encode(message())
    bad_value = st.tuples(names, st.binary(max_size=6), _INVALID_UTF8, st.binary(max_size=6)).map(
        lambda t: b"\x81" + _msgpack_str(t[0]) + _msgpack_str(t[1] + t[2] + t[3])
    )
    bad_key = st.tuples(st.binary(max_size=4), _INVALID_UTF8).map(
        lambda t: b"\x81" + _msgpack_str(t[0] + t[1]) + b"\x00"
    )
    kinds = st.sampled_from([0xDB, 0xC6, 0xDD, 0xDF, 0xC9])
    huge_top = st.builds(_huge_header, kinds, _HUGE, st.binary(max_size=16))
    huge_field = st.tuples(names, kinds, _HUGE, st.binary(max_size=16)).map(
        lambda t: b"\x81" + _msgpack_str(t[0]) + _huge_header(t[1], t[2], t[3])
    )
    cut = st.integers(0, max(0, len(valid) - 1)).map(lambda k: valid[:k])
    deep = st.tuples(names, st.integers(1, 5000), st.sampled_from([b"\x91", b"\x81\xa1k"])).map(
        lambda t: b"\x81" + _msgpack_str(t[0]) + t[2] * t[1] + b"\xc0"
    )
    return st.one_of(bad_value, bad_key, huge_top, huge_field, cut, deep)


def json_payloads(message: type[m.Message]) -> st.SearchStrategy[bytes]:
    """Inputs of the recording reader's JSON decoder (daemon/cli/record.py from_json): random
    bytes, JSON over the message's field names, strings that are not UTF-8, numbers out of
    range, huge or deep nesting, valid JSON cut short or byte-mutated."""
    names = st.sampled_from(field_names(message) + ["schema", "stamp", "bogus"])
    valid = msgspec.json.encode(message())
    leaf = st.one_of(
        values.map(lambda v: msgspec.json.encode(v, enc_hook=repr)),
        st.sampled_from([b"1e999", b"-1e999", b"1" * 400, b'"\\ud800"', b"NaN", b"null"]),
        st.tuples(_INVALID_UTF8, st.binary(max_size=6)).map(lambda t: b'"' + t[0] + t[1] + b'"'),
        st.integers(1, 5000).map(lambda n: b"[" * n + b"]" * n),
        st.integers(1, 5000).map(lambda n: b'{"k":' * n + b"0" + b"}" * n),
    )
    maps = st.lists(st.tuples(names, leaf), max_size=6).map(
        lambda kv: b"{" + b",".join(msgspec.json.encode(k) + b":" + v for k, v in kv) + b"}"
    )
    cut = st.integers(0, max(0, len(valid) - 1)).map(lambda k: valid[:k])
    mutated = st.lists(
        st.tuples(st.integers(0, max(0, len(valid) - 1)), st.integers(0, 255)), max_size=4
    ).map(lambda edits: _mutate(valid, edits))
    deep = st.integers(1, 100_000).map(lambda n: b"[" * n)
    return st.one_of(st.binary(max_size=64), maps, cut, mutated, deep)


def check_json_decoder(message: type[m.Message], payload: bytes) -> None:
    """The recording reader's contract with from_json: a message of the type, or the errors
    RecordingFile._entry catches (msgspec.DecodeError, msgspec.ValidationError)."""
    from climbd.daemon.cli.record import from_json

    try:
        value = from_json(payload, message)
    except (msgspec.DecodeError, msgspec.ValidationError):
        return
    assert type(value) is message


_PROFILE_BYTES = (ROOT / "robots" / "widowx.toml").read_bytes()

profile_bytes = st.one_of(
    st.binary(max_size=400),
    st.tuples(st.integers(0, len(_PROFILE_BYTES)), _INVALID_UTF8).map(
        lambda t: _PROFILE_BYTES[: t[0]] + t[1] + _PROFILE_BYTES[t[0] :]
    ),
    st.integers(0, len(_PROFILE_BYTES)).map(lambda k: _PROFILE_BYTES[:k]),
    st.sampled_from([b"\xef\xbb\xbf", b"\xff\xfe", b"\xfe\xff"]).map(
        lambda bom: bom + _PROFILE_BYTES
    ),
)
"""Profile files as bytes: random, the stock profile with a non-UTF-8 sequence spliced in or cut
short, or behind a byte-order mark (UTF-8's, and UTF-16's)."""


def check_profile_bytes(tmp: Path, data: bytes) -> None:
    """load() on arbitrary file bytes: a Profile or a ProfileError, never anything else."""
    tmp.write_bytes(data)
    try:
        load(tmp)
    except ProfileError:
        return


def _stock_clouds() -> dict[tuple[str, str], bytes]:
    """A small valid cloud file in every format and encoding, by (suffix, encoding)."""
    import tempfile

    import numpy as np

    from climbd.daemon.contract.cloudio import FORMATS, write_cloud

    points = np.array([[0.0, 0.1, 0.2], [1.0, -1.0, 0.5], [np.nan, 0.0, 0.0], [2.0, 2.0, 2.0]])
    out = {}
    with tempfile.TemporaryDirectory() as d:
        for suffix, encodings in FORMATS.items():
            for encoding in encodings:
                path = Path(d) / f"c{suffix}"
                write_cloud(path, points, encoding)
                out[suffix, encoding] = path.read_bytes()
    return out


def _header_lie(data: bytes, n: int) -> bytes:
    """``data`` with every declared count (PCD POINTS/WIDTH, PLY element vertex, NPY shape)
    replaced by ``n``."""
    import re

    data = re.sub(rb"(POINTS|WIDTH) \d+", lambda mt: mt.group(1) + b" %d" % n, data)
    data = re.sub(rb"element vertex \d+", b"element vertex %d" % n, data)
    return re.sub(rb"'shape': \((\d+),", b"'shape': (%d," % n, data)


CLOUDS = _stock_clouds()

cloud_files = st.sampled_from(sorted(CLOUDS)).flatmap(
    lambda key: st.tuples(
        st.just(key[0]),
        st.one_of(
            st.integers(0, len(CLOUDS[key])).map(lambda k: CLOUDS[key][:k]),
            st.lists(
                st.tuples(st.integers(0, len(CLOUDS[key]) - 1), st.integers(0, 255)), max_size=6
            ).map(lambda edits: _mutate(CLOUDS[key], edits)),
            st.sampled_from([0, 5, 2**31 - 1, 2**63 - 1, 10**30]).map(
                lambda n: _header_lie(CLOUDS[key], n)
            ),
            st.tuples(st.integers(0, 200), _INVALID_UTF8).map(
                lambda t: CLOUDS[key][: t[0]] + t[1] + CLOUDS[key][t[0] :]
            ),
            st.binary(max_size=200),
        ),
    )
)
"""(suffix, bytes) of point cloud files: a valid file of each format and encoding cut short,
byte-mutated, with a header declaring 0 to 10**30 points, with non-UTF-8 bytes in its header,
or random bytes."""


def check_cloud(tmp: Path, suffix: str, data: bytes) -> None:
    """read_cloud on arbitrary file bytes: finite (N, 3) points or a CloudFileError."""
    import numpy as np

    from climbd.daemon.contract.cloudio import CloudFileError, read_cloud

    path = tmp / f"fuzz{suffix}"
    path.write_bytes(data)
    try:
        points = read_cloud(path)
    except CloudFileError:
        return
    assert points.ndim == 2 and points.shape[1] == 3 and np.isfinite(points).all()
