"""Helpers of the access-control tests: a stock profile with ``[network.auth]`` added, and
the control role's Health as a read-only observer sees it."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

from climbd.daemon.contract.messages import Health
from support.zenoh_roles import Observer


def unauthenticated_widowx(tmp_path: Path, robots: Path) -> Path:
    """The stock WidowX profile without its ``[network.auth]`` table and with plain ``tcp/``
    endpoints, as profiles were before they were secure by default (``include`` cannot remove
    a table, so this is a copy)."""
    text = (robots / "widowx.toml").read_text()
    text = re.sub(r"\n\[network\.auth\].*?\n\n", "\n\n", text, flags=re.S)
    text = text.replace('"tls/', '"tcp/')
    assert "auth" not in text and "tls/" not in text
    path = tmp_path / "widowx-unauthenticated.toml"
    path.write_text(text)
    return path


def auth_profile(
    tmp_path: Path,
    robots: Path,
    auth: str,
    telemetry: str,
    commanders: str = 'commanders = ["operator"]',
) -> str:
    """widowx with ``[network.auth]`` holding ``auth`` (TOML lines), the read-only
    ``telemetry`` endpoint and ``commanders`` (or any other TOML lines, e.g. a rights table)."""
    path = tmp_path / "widowx-auth.toml"
    path.write_text(
        f'include = "{unauthenticated_widowx(tmp_path, robots)}"\n[network.auth]\n{auth}\n'
        f'telemetry_listen = ["{telemetry}"]\n{commanders}\n'
    )
    return str(path)


def control_health(obs: Observer, pred: Callable[[Health], bool], timeout: float = 30.0) -> Health:
    """The first Health of the control role satisfying ``pred``."""
    return obs.wait(Health, lambda h: h.role == "control" and pred(h), timeout)
