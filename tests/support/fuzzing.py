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
    """Random bytes, maps over the message's own field names, and byte-mutated valid payloads."""
    names = st.sampled_from(field_names(message) + ["schema", "stamp", "bogus"])
    maps = st.dictionaries(names, values, max_size=8).map(msgspec.msgpack.encode)
    valid = m.encode(message())
    mutated = st.lists(
        st.tuples(st.integers(0, max(0, len(valid) - 1)), st.integers(0, 255)), max_size=4
    ).map(lambda edits: _mutate(valid, edits))
    return st.one_of(st.binary(max_size=64), maps, mutated)


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
