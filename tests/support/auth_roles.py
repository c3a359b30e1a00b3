"""Helpers of the access-control tests: a stock profile with ``[network.auth]`` added, and
the control role's Health as a read-only observer sees it."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from climbd.daemon.contract.messages import Health
from support.zenoh_roles import Observer


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
        f'include = "{robots / "widowx.toml"}"\n[network.auth]\n{auth}\n'
        f'telemetry_listen = ["{telemetry}"]\n{commanders}\n'
    )
    return str(path)


def control_health(obs: Observer, pred: Callable[[Health], bool], timeout: float = 30.0) -> Health:
    """The first Health of the control role satisfying ``pred``."""
    return obs.wait(Health, lambda h: h.role == "control" and pred(h), timeout)
