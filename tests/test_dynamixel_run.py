"""Acceptance: ``climbd run --driver dynamixel --port <pty>`` stands each robot up through
dynamixel_sdk against the emulated servo chain; the servos end at the stand pose."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import msgspec
import numpy as np
import pytest

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.messages import Health
from climbd.daemon.contract.profile import load
from climbd.drivers.dynamixel.config import DynamixelConfig
from climbd.drivers.sim.dynamixel import DynamixelEmulator, ServoChain

ROOT = Path(__file__).resolve().parent.parent
RESOLUTION = {1: np.radians(300) / 1023, 2: 2 * np.pi / 4096}


@pytest.mark.parametrize(
    "robot,latency_ms",
    [("widowx", None), ("widowx", 1), ("widowx", 16), ("hubrobo", 16)],
)
def test_climbd_run_stands_up_on_the_emulated_bus(
    robot: str, latency_ms: int | None, endpoint: str, tmp_path
) -> None:
    """The bare chain carries no load, so sag compensation is off here (the goals would reach
    past the stand pose by the sag a load would cause); tests/test_sim_hil.py tests it loaded.
    Behind an emulated USB adapter (1 or 16 ms latency timer): holding, every servo receives
    every goal at the loop's rate and ``climbd status`` shows every joint's state within the
    profile's bound."""
    stiff = tmp_path / f"{robot}.toml"
    stiff.write_text(f'include = "{ROOT / "robots" / f"{robot}.toml"}"\n[bus]\nstiffness = 0.0\n')
    profile = load(stiff)
    chain = ServoChain.from_profile(profile)
    with DynamixelEmulator(chain, latency_ms=latency_ms) as emu:
        proc = subprocess.Popen(
            [sys.executable, "-m", "climbd.daemon.cli", "run", "--profile", str(profile.source)]
            + ["--driver", "dynamixel", "--port", emu.port, "--listen", endpoint, "--quiet"],
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        log: list[str] = []
        reader = threading.Thread(target=lambda: log.extend(proc.stderr), daemon=True)
        reader.start()
        try:
            end = time.monotonic() + 60
            while not any("stand complete" in line for line in log):
                assert proc.poll() is None and time.monotonic() < end, "".join(log)
                time.sleep(0.05)
            time.sleep(0.5)  # HOLD: the servos settle on the last goal
            with chain.lock:  # a snapshot between two sync writes, not across one
                before = [s.goals for s in chain.servos.values()]
            status = subprocess.run(
                [sys.executable, "-m", "climbd.daemon.cli", "status", "--robot", profile.name]
                + ["--connect", endpoint, "--json"],
                cwd=ROOT,
                capture_output=True,
                text=True,
                timeout=30,
            )
            with chain.lock:
                after = [s.goals for s in chain.servos.values()]
            received = [a - b for a, b in zip(after, before, strict=True)]
            goals = chain.joint_goals()
            present = chain.joint_positions()
            torque = [s.torque_enabled for s in chain.servos.values()]
        finally:
            proc.terminate()
            proc.wait(timeout=30)
            reader.join(5)
    stand = Kinematics(profile).stand_joints()
    resolution = RESOLUTION[DynamixelConfig.from_profile(profile).protocol]
    assert all(torque)
    assert np.max(np.abs(present - goals)) <= resolution
    assert np.max(np.abs(goals - stand)) < 0.01 + resolution
    assert proc.returncode == 0, "".join(log)
    assert status.returncode == 0, status.stderr
    bus = msgspec.json.decode(status.stdout, type=Health).bus
    assert bus is not None and bus.oldest_age_max <= profile.bus.max_state_age, bus
    assert bus.writes_per_s >= 0.9 * profile.rate_hz, bus
    assert len(set(received)) == 1 and received[0] > 0, received  # one sync write reaches all
    assert ("adapter holds" in bus.plan) == (latency_ms is not None), bus.plan
    assert "Traceback" not in "".join(log)
