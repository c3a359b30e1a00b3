"""Fuzzing of every message decoder (the bus's msgpack and the recordings' JSON), the profile
parser and the point-cloud readers, with text and raw bytes (a few hundred inputs each here;
``bench/soak.py --fuzz 10000`` runs ten thousand each)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import msgspec
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.fuzzing import (
    check_cloud,
    check_decoder,
    check_json_decoder,
    check_profile,
    check_profile_bytes,
    check_profile_text,
    cloud_files,
    edited_profile,
    json_payloads,
    payloads,
    profile_bytes,
)
from support.fuzzing import profile_edits as edits_strategy

from climbd.daemon.contract.messages import ALL_MESSAGES, decode

FAST = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.mark.parametrize("message", ALL_MESSAGES, ids=lambda t: t.__name__)
def test_decoder_returns_the_type_or_an_error_the_bus_catches(message) -> None:
    @FAST
    @given(payloads(message))
    def run(payload: bytes) -> None:
        check_decoder(message, payload)

    run()


def into_struct(message: type) -> bytes | None:
    """The msgpack head of a payload of ``message`` down to a nested struct (a field that is
    one, may be one, or is a list of them), where a value is expected; None without one."""
    for f in msgspec.inspect.type_info(message).fields:
        kinds = f.type.types if isinstance(f.type, msgspec.inspect.UnionType) else (f.type,)
        for kind in kinds:
            head = b"\x81" + msgspec.msgpack.encode(f.encode_name)
            if isinstance(kind, msgspec.inspect.StructType):
                return head
            if isinstance(kind, msgspec.inspect.ListType) and isinstance(
                kind.item_type, msgspec.inspect.StructType
            ):
                return head + b"\x91"
    return None


NESTING = [t for t in ALL_MESSAGES if into_struct(t) is not None]


@pytest.mark.parametrize("message", NESTING, ids=lambda t: t.__name__)
def test_a_deeply_nested_unknown_key_is_a_decode_error(message) -> None:
    """msgspec recurses to skip an unknown key's value inside a nested struct: 20,000 nested
    maps raised RecursionError past the bus (bench/soak.py's 10,000-input fuzz of Health)."""
    payload = into_struct(message) + b"\x81\xa1k" * 20_000 + b"\xc0"
    with pytest.raises((msgspec.DecodeError, msgspec.ValidationError)):  # the bus's refusals
        decode(payload, message)


@pytest.mark.parametrize("message", ALL_MESSAGES, ids=lambda t: t.__name__)
def test_recorded_json_decodes_to_the_type_or_a_decode_error(message) -> None:
    @settings(FAST, max_examples=40)
    @given(json_payloads(message))
    def run(payload: bytes) -> None:
        check_json_decoder(message, payload)

    run()


@FAST
@given(profile_bytes)
def test_any_profile_bytes_load_or_are_a_profile_error(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as d:
        check_profile_bytes(Path(d) / "fuzz.toml", data)


@FAST
@given(cloud_files)
def test_any_cloud_file_reads_or_is_a_named_error(case: tuple[str, bytes]) -> None:
    with tempfile.TemporaryDirectory() as d:
        check_cloud(Path(d), *case)


@FAST
@given(edits_strategy)
def test_edited_profiles_load_or_name_the_problem(edits) -> None:
    check_profile(edited_profile(edits))


@FAST
@given(st.text(max_size=200))
def test_any_profile_text_loads_or_is_a_profile_error(text: str) -> None:
    with tempfile.TemporaryDirectory() as d:
        check_profile_text(Path(d) / "fuzz.toml", text)
