"""Shared test helpers: free loopback ports for Zenoh, stock profiles."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free right now (Zenoh endpoints in tests)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture()
def endpoint() -> str:
    """A fresh loopback Zenoh endpoint, e.g. ``tcp/127.0.0.1:40123``."""
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture()
def robots() -> Path:
    return ROOT / "robots"
