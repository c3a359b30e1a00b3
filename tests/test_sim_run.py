"""``climbd run --sim``: the daemon's own paths in the twin — driver on the pty, perception role
on ray-cast depth through a software device, the default behaviour walking."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def climbd(tmp_path: Path, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "climbd.daemon.cli",
            "run",
            *args,
            "--snapshot",
            str(tmp_path / "top.png"),
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_all_roles_stand_and_walk_toward_a_joist_they_perceive_then_sit(
    tmp_path: Path, endpoint: str
):
    res = climbd(
        tmp_path,
        "--profile",
        str(ROOT / "robots" / "widowx-attic-sim.toml"),
        "--role",
        "all",
        "--sim",
        "attic_paper",
        "--stepped",
        "--activate",
        "--duration",
        "8",
        "--listen",
        endpoint,
        "--quiet",
    )
    assert res.returncode == 0, res.stderr
    assert "mode HOLD → ACTIVE" in res.stderr
    moved = re.search(r"body moved [0-9.]+ m \(x ([-+0-9.]+) m", res.stdout)
    assert moved and float(moved.group(1)) > 0.2, res.stdout
    published = re.search(r"perception stopped; (\d+) features published", res.stdout)
    assert published and int(published.group(1)) > 20, res.stdout
    assert "stand complete" in res.stderr and "Traceback" not in res.stderr
    summary = re.search(r"body height ([0-9.]+) m, fallen: (\w+)", res.stdout)
    assert summary, res.stdout
    assert abs(float(summary.group(1)) - 0.10) < 0.015 and summary.group(2) == "no"
    assert "sat down, then torque off" in res.stdout
    assert (tmp_path / "top.png").stat().st_size > 10_000
