"""Dynamixel bus cycle time vs the physical bus limit and a naive per-servo SDK baseline.

The emulator runs in its own process (as servos would be their own hardware) and delivers
each reply when its last byte would arrive: bytes × 10 / baud plus return delay. The bus
limit of a cycle is computed here from the packet sizes of the published protocols, averaged
over one health period (every ``rate_hz / health_rate_hz`` cycles the read block is longer).
Baseline, same run, same emulator: what the SDK examples do — read present position and
write goal position one servo at a time. Cycle times are medians (this machine is shared;
the mean is printed beside them).

    .venv/bin/python bench/dynamixel.py [--cycles 300]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import dynamixel_sdk as sdk
import numpy as np

from daemon.messages import JointCommand
from daemon.profile import load
from drivers.dynamixel.bus import DynamixelBus

ROOT = Path(__file__).resolve().parent.parent


def bus_limit_s(protocol: int, n: int, baud: int, health_every: int, delay_s: float = 0.0):
    """Seconds a cycle needs on the wire (average over a health period), and its bytes."""
    if protocol == 1:
        # READ: FF FF ID LEN INST ADDR N CHK = 8; status: 6 + data. SYNC WRITE: 8 + 3 per servo.
        ordinary = n * (8 + 6 + 6) + (8 + 3 * n)
        health = n * (8 + 6 + 8) + (8 + 3 * n)
        replies_ordinary = replies_health = n
    else:
        # (FAST) SYNC READ: 14 + n; one chained status of 8 + n × (data + 4).
        # SYNC WRITE: 14 + 5 per servo. Health adds a fast sync read of Hardware Error Status.
        ordinary = (14 + n) + (8 + n * 14) + (14 + 5 * n)
        health = (14 + n) + (8 + n * 25) + (14 + n) + (8 + n * 5) + (14 + 5 * n)
        replies_ordinary, replies_health = 1, 2
    total = (health_every - 1) * ordinary + health
    replies = (health_every - 1) * replies_ordinary + replies_health
    seconds = (total * 10.0 / baud + replies * delay_s) / health_every
    return seconds, total / health_every


class Emulator:
    """``python -m drivers.sim.dynamixel`` in a child process; ``.port`` is its pty."""

    def __init__(self, profile_path: Path, baud: int) -> None:
        cmd = [sys.executable, "-m", "drivers.sim.dynamixel", "--profile", str(profile_path)]
        cmd += ["--baud", str(baud), "--return-delay-us", "0", "--spin-us", "150"]
        self.proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, text=True)
        self.port = self.proc.stdout.readline().strip()

    def close(self) -> None:
        self.proc.terminate()
        self.proc.wait(timeout=5)


def profile_file(tmp: Path, base: str, protocol: int, model: str, baud: int) -> Path:
    path = tmp / f"{base}-{model}-{baud}.toml"
    path.write_text(
        f'include = "{ROOT / "robots" / base}.toml"\n'
        f'[bus]\nprotocol = {protocol}\nmodel = "{model}"\nbaud = {baud}\nreturn_delay_us = 0\n'
    )
    return path


def run_driver(profile, port: str, cycles: int) -> float:
    bus = DynamixelBus.from_profile(profile, port=port)
    bus.open()
    q = np.zeros(len(bus.ids))
    command = JointCommand(position=q.tolist())
    for _ in range(bus.health_every):
        bus.read()
    times = np.empty(cycles)
    for k in range(cycles):
        t0 = time.perf_counter()
        bus.read()
        bus.write(command)
        times[k] = time.perf_counter() - t0
    lost = [h.name for h in bus.health() if h.lost]
    bus.close()
    if lost:
        raise SystemExit(f"servos lost during the benchmark: {lost}")
    return times


def run_naive(profile, port: str, cycles: int) -> float:
    """The SDK examples' pattern: readNByteTxRx then writeNByteTxRx, servo by servo."""
    handler = sdk.PortHandler(port)
    handler.openPort()
    handler.setBaudRate(profile.bus.baud)
    ph = sdk.PacketHandler(float(profile.bus.protocol))
    ids = [j.id for j in profile.joints]
    if profile.bus.protocol == 1:
        read, write, present, goal, value = ph.read2ByteTxRx, ph.write2ByteTxRx, 36, 30, 512
    else:
        read, write, present, goal, value = ph.read4ByteTxRx, ph.write4ByteTxRx, 132, 116, 2048
    times = np.empty(cycles)
    for k in range(cycles):
        t0 = time.perf_counter()
        for i in ids:
            read(handler, i, present)
        for i in ids:
            write(handler, i, goal, value)
        times[k] = time.perf_counter() - t0
    handler.closePort()
    return times


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=300)
    args = parser.parse_args()
    cases = [("widowx", 1, "AX-18A", 1_000_000)]
    for base in ("hubrobo", "widowx"):  # 12 and 18 X-series servos
        cases += [(base, 2, "XL430-W250", b) for b in (1_000_000, 2_000_000, 3_000_000, 4_000_000)]
    header = (
        "| model | servos | baud | bytes/cycle | bus limit µs (Hz) | driver median µs (Hz) "
        "| driver mean µs | % of limit (median) | naive SDK median µs | speed-up |"
    )
    print(header)
    print("|" + "---|" * 10)
    with tempfile.TemporaryDirectory() as tmp:
        for base, protocol, model, baud in cases:
            path = profile_file(Path(tmp), base, protocol, model, baud)
            profile = load(path)
            n = len(profile.joints)
            every = max(1, round(profile.rate_hz / profile.bus.health_rate_hz))
            limit, nbytes = bus_limit_s(protocol, n, baud, every)
            emu = Emulator(path, baud)
            try:
                driver = run_driver(profile, emu.port, args.cycles)
                naive = run_naive(profile, emu.port, max(20, args.cycles // 5))
            finally:
                emu.close()
            d, d_mean, b = np.median(driver), driver.mean(), np.median(naive)
            print(
                f"| {model} P{protocol}.0 | {n} | {baud / 1e6:g} M | {nbytes:.0f} "
                f"| {limit * 1e6:.0f} ({1 / limit:.0f}) | {d * 1e6:.0f} ({1 / d:.0f}) "
                f"| {d_mean * 1e6:.0f} | {100 * limit / d:.0f} % | {b * 1e6:.0f} | {b / d:.1f}× |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
