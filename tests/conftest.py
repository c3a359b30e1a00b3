"""Shared test helpers: free loopback ports for Zenoh, lossless publishers, stock profiles."""

from __future__ import annotations

from pathlib import Path

import pytest
import zenoh
from support.ports import free_port

from climbd.daemon.contract import messages as m
from climbd.daemon.runtime.network import Network, Publisher

ROOT = Path(__file__).resolve().parent.parent


def lossless(bus: Network, message: type[m.Message]) -> Publisher:
    """A publisher that blocks rather than drops (the control streams' QoS drops under load),
    for tests that count what arrived against what was sent."""
    k = m.key(bus.robot, message)
    return Publisher(
        bus.session.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK)
    )


@pytest.fixture()
def endpoint() -> str:
    """A fresh loopback Zenoh endpoint, e.g. ``tcp/127.0.0.1:40123``."""
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture()
def robots() -> Path:
    return ROOT / "robots"
