"""``climbd install``: units and udev rules rendered for the user's paths, verified by systemd."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from climbd.daemon.cli.main import build_parser

ROOT = Path(__file__).resolve().parent.parent


def install(tmp_path: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "climbd.daemon.cli",
            "install",
            "--profile",
            "robots/widowx.toml",
            "--unit-dir",
            str(tmp_path / "units"),
            "--udev-dir",
            str(tmp_path / "udev"),
            "--user",
            "root",
            "--workdir",
            str(tmp_path),
            *extra,
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_units_are_rendered_for_this_machine(tmp_path: Path) -> None:
    res = install(tmp_path, "--climbd", "/opt/climbd/bin/climbd")
    assert res.returncode == 0, res.stderr
    control = (tmp_path / "units" / "climbd-control.service").read_text()
    profile = (ROOT / "robots" / "widowx.toml").resolve()
    assert f"ExecStart=/opt/climbd/bin/climbd run --profile {profile} --role control" in control
    assert (
        "Type=notify" in control and "WatchdogSec=" in control and "Restart=on-failure" in control
    )
    assert "CPUSchedulingPolicy=fifo" in control and "LimitMEMLOCK=infinity" in control
    assert "{" not in control, "every placeholder is filled"
    perception = (tmp_path / "units" / "climbd-perception.service").read_text()
    assert "--role perception" in perception
    rules = (tmp_path / "udev" / "99-climbd.rules").read_text()
    assert 'ATTR{latency_timer}="1"' in rules and 'SYMLINK+="dynamixel"' in rules
    assert "first start creates them" in res.stdout and f"~ being {tmp_path}" in res.stdout


def execstart(unit: str) -> list[str]:
    """The last ``ExecStart`` command line of a unit or drop-in, split."""
    lines = [line for line in unit.splitlines() if line.startswith("ExecStart=")]
    return lines[-1].removeprefix("ExecStart=").split()


def test_torque_legs_get_the_bridge_unit_and_the_control_role_is_pointed_at_it(
    tmp_path: Path,
) -> None:
    qingzhui = ("--profile", "robots/qingzhui.toml", "--python", "/opt/climbd/bin/python")
    res = install(tmp_path, *qingzhui, "--climbd", "/opt/climbd/bin/climbd", "--torque-bridge")
    assert res.returncode == 0, res.stderr
    units = tmp_path / "units"
    bridge = execstart((units / "climbd-torque-bridge.service").read_text())
    profile = str((ROOT / "robots" / "qingzhui.toml").resolve())
    assert bridge[:5] == [
        "/opt/climbd/bin/python",
        "-m",
        "climbd.drivers.torque.bridge",
        "--profile",
        profile,
    ]
    drop_in = (units / "climbd-control.service.d" / "torque-bridge.conf").read_text()
    assert "Requires=climbd-torque-bridge.service" in drop_in
    assert "After=climbd-torque-bridge.service" in drop_in
    control = execstart(drop_in)
    assert control[0] == "/opt/climbd/bin/climbd"
    run = build_parser().parse_args(control[1:])
    assert (run.command, run.profile, run.role, run.driver) == (
        "run",
        profile,
        "control",
        "torque-bridge",
    )
    listen = bridge[bridge.index("--listen") + 1].split("/")
    assert run.port.split("/") == listen[::-1], "each the other's peer"
    assert "climbd-torque-bridge" in res.stdout.splitlines()[-1], "enabled with the others"

    res = install(tmp_path, *qingzhui)
    assert (
        res.returncode == 0
        and not (units / "climbd-control.service.d" / "torque-bridge.conf").exists()
    )
    assert "removed" in res.stdout


@pytest.mark.parametrize(
    ("role", "profile", "field"),
    [
        ("all", "robots/widowx.toml", "bus.kind is 'dynamixel'"),
        ("perception", "robots/qingzhui.toml", "--role perception"),
    ],
)
def test_the_bridge_is_refused_without_torque_legs_or_a_control_role(
    tmp_path: Path, role: str, profile: str, field: str
) -> None:
    res = install(tmp_path, "--profile", profile, "--role", role, "--torque-bridge")
    assert res.returncode == 2 and field in res.stderr
    assert not (tmp_path / "units").exists()


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
@pytest.mark.parametrize("bridge", [(), ("--profile", "robots/qingzhui.toml", "--torque-bridge")])
def test_systemd_analyze_verifies_the_units(tmp_path: Path, bridge: tuple[str, ...]) -> None:
    climbd = shutil.which("climbd") or str(Path(sys.executable).with_name("climbd"))
    assert install(tmp_path, "--climbd", climbd, *bridge).returncode == 0
    units = sorted((tmp_path / "units").glob("*.service"))
    res = subprocess.run(
        ["systemd-analyze", "verify", *map(str, units)], capture_output=True, text=True, timeout=60
    )
    problems = [
        line
        for line in (res.stdout + res.stderr).splitlines()
        if "climbd-" in line and "network-online.target" not in line
    ]
    assert res.returncode == 0 and not problems, res.stdout + res.stderr


def test_bad_profile_is_refused(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 1\n")
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "climbd.daemon.cli",
            "install",
            "--profile",
            str(bad),
            "--unit-dir",
            str(tmp_path / "u"),
            "--udev-dir",
            str(tmp_path / "d"),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 2 and "$.name" in res.stderr
    assert not (tmp_path / "u").exists()
