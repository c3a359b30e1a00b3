"""``climbd run`` as users start it: stands, answers status and e-stop, SIGTERM exits 0 safely."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


class Daemon:
    """``climbd run`` in a subprocess, its stderr collected line by line."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "climbd.daemon.cli", "run", *args],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.log: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stderr:
            self.log.append(line)

    def wait_for(self, text: str, timeout: float = 60.0) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if any(text in line for line in self.log):
                return
            if self.proc.poll() is not None:
                break
            time.sleep(0.05)
        raise AssertionError(f"{text!r} not logged; log:\n{''.join(self.log)}")

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 30.0) -> tuple[int, str]:
        self.proc.send_signal(sig)
        self.proc.wait(timeout=timeout)
        self._reader.join(5)  # the reader owns stderr until its end
        return self.proc.returncode, self.proc.stdout.read()

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def climbd(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "climbd.daemon.cli", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.mark.parametrize(
    "robot,sig,pose",
    [
        ("widowx", signal.SIGTERM, "sat down, then torque off"),
        ("qingzhui", signal.SIGINT, "torque on, holding the commanded pose"),
    ],
)
def test_signal_exits_zero_in_the_safe_pose(endpoint: str, robot: str, sig, pose: str) -> None:
    d = Daemon("--profile", f"robots/{robot}.toml", "--driver", "fake", "--listen", endpoint)
    try:
        d.wait_for("stand complete")
        code, out = d.stop(sig)
    finally:
        d.kill()
    assert code == 0, "".join(d.log)
    assert pose in out
    assert "Traceback" not in "".join(d.log)


def test_duration_ends_by_itself_with_a_report(endpoint: str) -> None:
    res = climbd(
        "run",
        "--profile",
        "robots/hubrobo.toml",
        "--driver",
        "fake",
        "--duration",
        "2",
        "--listen",
        endpoint,
    )
    assert res.returncode == 0, res.stderr
    assert "stand complete" in res.stderr
    assert "climbd: stopped in HOLD" in res.stdout and "ticks at 100 Hz" in res.stdout
    assert "leaked" not in res.stderr, "every object is freed at exit (no nanobind leak report)"


def test_status_and_estop_from_other_processes(endpoint: str) -> None:
    d = Daemon("--profile", "robots/widowx.toml", "--driver", "fake", "--listen", endpoint)
    try:
        d.wait_for("stand complete")
        status = climbd("status", "--robot", "widowx", "--connect", endpoint)
        assert status.returncode == 0, status.stderr
        assert "control: mode HOLD" in status.stdout and "rf_coxa" in status.stdout
        estop = climbd("estop", "--robot", "widowx", "--connect", endpoint, "--reason", "test")
        assert estop.returncode == 0, estop.stderr
        d.wait_for("e-stop by")
        status = climbd("status", "--robot", "widowx", "--connect", endpoint)
        assert "mode ESTOP" in status.stdout
        code, out = d.stop()
    finally:
        d.kill()
    assert code == 0 and "stopped in ESTOP" in out and "torque off" in out


def test_bad_profile_and_missing_driver_are_clear_errors(tmp_path: Path, endpoint: str) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text((ROOT / "robots" / "widowx.toml").read_text().replace("rate_hz = 100.0", ""))
    res = climbd("run", "--profile", str(bad), "--driver", "fake")
    assert res.returncode == 2 and "rate_hz" in res.stderr and "Traceback" not in res.stderr
    res = climbd("run", "--profile", "robots/widowx.toml", "--driver", "warp", "--listen", endpoint)
    assert res.returncode == 1
    assert "no plugin named 'warp'" in res.stderr and "fake" in res.stderr
    assert "Traceback" not in res.stderr


def test_status_without_a_robot_times_out_cleanly(endpoint: str) -> None:
    res = climbd("status", "--robot", "ghost", "--connect", endpoint, "--timeout", "1")
    assert res.returncode == 1 and "no health from robot 'ghost'" in res.stderr


def test_notify_socket_gets_ready(tmp_path: Path, endpoint: str) -> None:
    import socket

    path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(30)
    env = {**os.environ, "NOTIFY_SOCKET": str(path), "WATCHDOG_USEC": "400000"}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "climbd.daemon.cli",
            "run",
            "--profile",
            "robots/widowx.toml",
            "--driver",
            "fake",
            "--listen",
            endpoint,
            "--duration",
            "2",
            "--quiet",
        ],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        got = []
        while "STOPPING=1" not in got:
            got.append(sock.recv(256).decode())
        assert proc.wait(30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        sock.close()
    assert got[0] == "READY=1"
    assert got.count("WATCHDOG=1") >= 5, got
