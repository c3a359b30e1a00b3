"""Fuzzing of every message decoder and of the profile parser (a few hundred inputs each here;
``bench/soak.py --fuzz 10000`` runs ten thousand each)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.fuzzing import (
    check_decoder,
    check_profile,
    check_profile_text,
    edited_profile,
    payloads,
)
from support.fuzzing import profile_edits as edits_strategy

from climbd.daemon.contract.messages import ALL_MESSAGES

FAST = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.mark.parametrize("message", ALL_MESSAGES, ids=lambda t: t.__name__)
def test_decoder_returns_the_type_or_an_error_the_bus_catches(message) -> None:
    @FAST
    @given(payloads(message))
    def run(payload: bytes) -> None:
        check_decoder(message, payload)

    run()


@FAST
@given(edits_strategy)
def test_edited_profiles_load_or_name_the_problem(edits) -> None:
    check_profile(edited_profile(edits))


@FAST
@given(st.text(max_size=200))
def test_any_profile_text_loads_or_is_a_profile_error(text: str) -> None:
    with tempfile.TemporaryDirectory() as d:
        check_profile_text(Path(d) / "fuzz.toml", text)
