"""``climbd top``: the frame shows what the robots publish; live against running daemons."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

from conftest import free_port

from climbd.daemon.cli.top import CLEAR, RobotView, render
from climbd.daemon.contract import messages as m

ROOT = Path(__file__).resolve().parent.parent


def test_frame_shows_mode_rates_joints_features_and_session() -> None:
    view = RobotView("widowx", roles=["control", "perception"])
    joints = [
        m.JointHealth(name="rf_coxa", temperature=41.5, voltage=11.9),
        m.JointHealth(name="rf_femur", temperature=66.0, voltage=11.8, derated=True),
        m.JointHealth(name="rf_tibia", lost=True, errors=["overload"]),
    ]
    for k, stamp in enumerate((10.0, 10.5)):
        view.on_message(
            m.Health(
                stamp=stamp,
                mode=m.Mode.ACTIVE,
                joints=joints,
                loop=m.LoopStats(rate_hz=100.0, ticks=1000 + 49 * k, lateness_p99=250e-6),
                session="alice@laptop",
            ),
            now=stamp,
        )
    view.on_message(m.ModeState(mode=m.Mode.ACTIVE, reason="requested by s1"), now=10.5)
    view.on_message(
        m.JointState(names=["rf_coxa", "rf_femur", "rf_tibia"], position=[0.1, -0.25, 1.5]), 10.5
    )
    joist = m.Joist(distance=0.97, yaw=0.2618, height=0.1, endpoints=[[0, 0, 0], [0, 1, 0]])
    for k in range(5):
        view.on_message(m.Joists(joists=[joist, joist]), now=10.0 + 0.1 * k)
    view.on_message(
        m.Health(
            role="perception",
            plugins={"joists": "failed: ValueError: x"},
            dropped_frames=3,
            refused_frames={"too_new": 4, "no_pose": 1},
        ),
        now=10.5,
    )
    text = "\n".join(render({"widowx": view}, now=10.6))
    assert "── widowx ── roles: control, perception" in text
    assert "mode ACTIVE: requested by s1" in text
    assert "loop 98.0 Hz of 100 Hz" in text and "p99 250 µs" in text
    assert "session alice@laptop" in text
    lines = {line.split()[0]: line for line in text.splitlines() if line.startswith("  rf_")}
    assert lines["rf_coxa"].split()[1:4] == ["+0.100", "41.5", "11.9"]
    assert "derated" in lines["rf_femur"] and lines["rf_femur"].split()[1] == "-0.250"
    assert "overload,LOST" in lines["rf_tibia"]
    joist_line = next(line for line in text.splitlines() if line.startswith("features/joists"))
    assert "10.0 Hz" in joist_line and "2 joists; nearest 0.970 m, yaw +15.0°" in joist_line
    assert "plugin joists (perception): failed: ValueError: x" in text
    assert "perception: 3 frames dropped" in text
    assert "perception: frames without a body pose: 1 no_pose, 4 too_new" in text
    assert "SILENT" in "\n".join(render({"widowx": view}, now=20.0))


def _start(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "climbd.daemon.cli", "run", *args, "--quiet"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def _wait(proc: subprocess.Popen, text: str, timeout: float = 60.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if text in line:
            return
        assert line or proc.poll() is None, f"exited before {text!r}"
    raise AssertionError(f"{text!r} not printed")


def test_top_once_and_live_against_running_robots() -> None:
    widowx_ep = f"tcp/127.0.0.1:{free_port()}"
    hubrobo_ep = f"tcp/127.0.0.1:{free_port()}"
    perception_ep = f"tcp/127.0.0.1:{free_port()}"
    procs = [
        _start("--profile", "robots/widowx.toml", "--driver", "fake", "--listen", widowx_ep),
        _start("--profile", "robots/hubrobo.toml", "--driver", "fake", "--listen", hubrobo_ep),
    ]
    perception = [
        "--profile", "robots/widowx.toml", "--role", "perception", "--source", "floor",
        "--plugin", "elevation", "--connect", widowx_ep, "--listen", perception_ep,
    ]  # fmt: skip
    procs.append(_start(*perception))
    try:
        _wait(procs[0], "control role")
        _wait(procs[1], "control role")
        _wait(procs[2], "perception role")
        time.sleep(4.0)  # both stand (2 s profile stand time) and the grid flows
        res = subprocess.run(
            [sys.executable, "-m", "climbd.daemon.cli", "top", "--all", "--once", "--window", "3"]
            + ["--connect", widowx_ep, "--connect", hubrobo_ep, "--connect", perception_ep],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
        )
        live = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "climbd.daemon.cli",
                "top",
                "--robot",
                "hubrobo",
                "--interval",
                "0.2",
            ]
            + ["--connect", hubrobo_ep],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        time.sleep(4.0)
        live.send_signal(signal.SIGINT)
        live_out, live_err = live.communicate(timeout=30)
    finally:
        for p in procs:
            p.send_signal(signal.SIGTERM)
        for p in procs:
            p.communicate(timeout=30)
    assert res.returncode == 0, res.stderr
    out = res.stdout
    assert CLEAR not in out
    hubrobo, widowx = out.split("── widowx ──")  # robots by name
    assert "roles: control, perception" in widowx and "mode HOLD: stand complete" in widowx
    assert "lf_tibia" in widowx and "35.0" in widowx
    grid = next(line for line in widowx.splitlines() if line.startswith("features/grid"))
    rate = float(grid.split()[1])
    assert rate > 0 and "cells of 1 cm" in grid
    assert "roles: control" in hubrobo and "mode HOLD" in hubrobo and "features/" not in hubrobo
    assert live.returncode == 0, live_err
    frames = live_out.split(CLEAR)
    assert len(frames) >= 3 and "── hubrobo ──" in frames[-1] and "Traceback" not in live_err
    assert all(p.returncode == 0 for p in procs)
