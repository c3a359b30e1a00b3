"""Dynamixel bus cycle time vs the physical bus limit and a naive per-servo SDK baseline.

The emulator runs in its own process (as servos would be their own hardware) and delivers
each reply when its last byte would arrive: bytes × 10 / baud plus return delay, counted from
when it reads the instruction (never earlier than a real wire could).

Bus limit: the wire time of one cycle's packets at the baud rate (10 bits a byte) plus the
return delays (0 here), with zero host turnaround — a bound no host reaches. It is computed
from the published packet formats for ordinary cycles and for health cycles (every
``rate_hz / health_rate_hz`` cycles the read block is longer), and the driver is measured the
same way: median of its ordinary cycles and median of its health cycles, each weighted by how
often it runs. Per round trip, a real host also pays a turnaround the wire does not show; the
floor of that here is the round trip of a pty between two processes, measured in the same run
(``pty RTT``), and ``limit + floor`` adds it once per round trip of the cycle. ``host CPU``
is the driver's cycle against servos that answer at once (replies cached in memory): the CPU
a cycle spends in the driver and the SDK, which no wire or transport hides.

Baseline, same run, same emulator: what the SDK examples do — read present position and write
goal position one servo at a time. Both processes run SCHED_FIFO (emulator above the driver,
as servos have their own processors) unless ``--no-realtime``: on a shared machine the
scheduler's latency otherwise swamps the figures (a deployed control loop runs real-time too).

    .venv/bin/python bench/dynamixel.py [--cycles 300] [--no-realtime]
"""

from __future__ import annotations

import argparse
import os
import select
import subprocess
import sys
import tempfile
import time
import tty
from pathlib import Path
from typing import NamedTuple

import dynamixel_sdk as sdk
import numpy as np
from loop import realtime

from climbd.daemon.contract.messages import JointCommand
from climbd.daemon.contract.profile import load
from climbd.daemon.runtime.loop import ControlLoop, MonotonicClock
from climbd.drivers.dynamixel.bus import MISPARSE, DynamixelBus, LatencyPort
from climbd.drivers.dynamixel.config import DynamixelConfig
from climbd.drivers.sim.dynamixel import ServoChain
from climbd.drivers.sim.dynamixel.wire import Framer

ROOT = Path(__file__).resolve().parent.parent
DRIVER_PRIORITY, EMULATOR_PRIORITY = 40, 50


def cycle_bytes(protocol: int, n: int) -> tuple[int, int, int]:
    """Bytes on the wire of an ordinary and of a health cycle, and the round trips of each."""
    if protocol == 1:
        # READ: FF FF ID LEN INST ADDR N CHK = 8; status: 6 + data (6, health 8).
        # SYNC WRITE of goals: 8 + 3 per servo, no reply. One round trip per servo.
        write = 8 + 3 * n
        return n * (8 + 6 + 6) + write, n * (8 + 6 + 8) + write, n
    # (FAST) SYNC READ: 14 + n; one chained status of 8 + n × (data + 4), data 10 (health 21).
    # SYNC WRITE: 14 + 5 per servo. Health adds a fast sync read of Hardware Error Status.
    write = 14 + 5 * n
    ordinary = (14 + n) + (8 + n * 14) + write
    health = (14 + n) + (8 + n * 25) + (14 + n) + (8 + n * 5) + write
    return ordinary, health, 1


def bus_limit_s(protocol: int, n: int, baud: int, delay_s: float = 0.0) -> tuple[float, float]:
    """Seconds an ordinary and a health cycle need on the wire (plus the return delays)."""
    ordinary, health, _ = cycle_bytes(protocol, n)
    replies = (n, n) if protocol == 1 else (1, 2)
    return (
        ordinary * 10.0 / baud + replies[0] * delay_s,
        health * 10.0 / baud + replies[1] * delay_s,
    )


def weighted(ordinary: float, health: float, every: int) -> float:
    """Average cycle over a health period: ``every - 1`` ordinary cycles and one health cycle."""
    return ((every - 1) * ordinary + health) / every


def pty_round_trip_s(count: int = 2000) -> float:
    """Median round trip of 8 bytes through a pty to an echoing child process."""
    master, slave = os.openpty()
    tty.setraw(slave)
    pid = os.fork()
    if pid == 0:
        os.close(slave)
        if os.sched_getscheduler(0) == os.SCHED_FIFO:
            realtime(EMULATOR_PRIORITY)
        while (data := os.read(master, 64)) != b"q":
            os.write(master, data)
        os._exit(0)
    os.close(master)
    times = np.empty(count)
    for k in range(count):
        t0 = time.perf_counter()
        os.write(slave, b"\x55" * 8)
        got = 0
        while got < 8:
            select.select([slave], [], [])
            got += len(os.read(slave, 64))
        times[k] = time.perf_counter() - t0
    os.write(slave, b"q")
    os.waitpid(pid, 0)
    os.close(slave)
    return float(np.median(times))


class Emulator:
    """``python -m climbd.drivers.sim.dynamixel`` in a child process; ``.port`` is its pty."""

    def __init__(self, profile_path: Path, baud: int, rt: bool, latency_ms: float = 0.0) -> None:
        cmd = [sys.executable, "-m", "climbd.drivers.sim.dynamixel", "--profile", str(profile_path)]
        cmd += ["--baud", str(baud), "--return-delay-us", "0", "--spin-us", "150"]
        cmd += ["--latency-ms", str(latency_ms)]
        self.proc = subprocess.Popen(
            cmd,
            cwd=ROOT,
            stdout=subprocess.PIPE,
            text=True,
            preexec_fn=(lambda: realtime(EMULATOR_PRIORITY)) if rt else None,
        )
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


class InstantPort(LatencyPort):
    """A port whose servos answer at once, from a cache of the emulator's replies to each
    distinct instruction: what the host's CPU costs per transaction, with no transport or wire."""

    def __init__(self, chain: ServoChain) -> None:
        super().__init__("instant", latency_ms=1.0)
        self.chain = chain
        self.framer = Framer(chain.protocol)
        self.replies: dict[bytes, bytes] = {}
        self.inbox = b""

    def writePort(self, packet: list[int]) -> int:  # noqa: N802 - SDK override
        data = bytes(packet)
        reply = self.replies.get(data)
        if reply is None:
            answers = (r.data for i in self.framer.feed(data) for r in self.chain.handle(i))
            reply = self.replies[data] = b"".join(answers)
        self.inbox += reply
        return len(data)

    def readPort(self, length: int) -> bytes:  # noqa: N802 - SDK override
        data, self.inbox = self.inbox[:length], self.inbox[length:]
        return data

    def clearPort(self) -> None:  # noqa: N802 - SDK override
        self.inbox = b""


def host_cpu_s(profile, cycles: int = 200) -> tuple[float, float]:
    """Median host CPU of one driver cycle (read + write) and of one stock-SDK READ of the
    per-cycle block, both against instantly answering servos."""
    port = InstantPort(ServoChain.from_profile(profile))
    bus = DynamixelBus.from_profile(profile, port="instant", fast_sync_read=True)
    bus.port = port
    command = JointCommand(position=np.zeros(len(bus.ids)).tolist())
    cycle = np.empty(cycles)
    for k in range(cycles):
        t0 = time.perf_counter()
        bus.read()
        bus.write(command)
        cycle[k] = time.perf_counter() - t0
    if bus.lost.any():
        raise SystemExit("instant port: servos did not answer")
    ph, state = sdk.PacketHandler(float(bus.config.protocol)), bus.model.state
    one = np.empty(cycles)
    for k in range(cycles):
        t0 = time.perf_counter()
        ph.readTxRx(port, bus.ids[0], state.address, state.size)
        one[k] = time.perf_counter() - t0
    return float(np.median(cycle)), float(np.median(one))


def run_driver(profile, port: str, cycles: int) -> tuple[np.ndarray, np.ndarray]:
    """Seconds of each read() + write() cycle, and which cycles were health cycles."""
    bus = DynamixelBus.from_profile(profile, port=port)
    bus.open()
    command = JointCommand(position=np.zeros(len(bus.ids)).tolist())
    for _ in range(bus.health_every):
        bus.read()
    times = np.empty(cycles)
    health = np.zeros(cycles, bool)
    for k in range(cycles):
        health[k] = (bus.reads + 1) % bus.health_every == 0
        t0 = time.perf_counter()
        bus.read()
        bus.write(command)
        times[k] = time.perf_counter() - t0
    lost = [h.name for h in bus.health() if h.lost]
    bus.close()
    if lost:
        raise SystemExit(f"servos lost during the benchmark: {lost}")
    return times, health


def naive_sdk(profile, handler: sdk.PortHandler) -> tuple:
    """The SDK examples' calls on ``handler`` (opened, set to the profile's baud): servo ids,
    their read and write of 2 (1.0) or 4 (2.0) bytes, present and goal position addresses, a
    mid-range goal."""
    config = DynamixelConfig.from_profile(profile)
    handler.setBaudRate(config.baud)
    ph = sdk.PacketHandler(float(config.protocol))
    ids = [j.id for j in profile.joints]
    if config.protocol == 1:
        return ids, ph.read2ByteTxRx, ph.write2ByteTxRx, 36, 30, 512
    return ids, ph.read4ByteTxRx, ph.write4ByteTxRx, 132, 116, 2048


def run_naive(profile, port: str, cycles: int) -> np.ndarray:
    """The SDK examples' pattern: readNByteTxRx then writeNByteTxRx, servo by servo."""
    handler = sdk.PortHandler(port)
    handler.openPort()
    ids, read, write, present, goal, value = naive_sdk(profile, handler)
    times = np.empty(cycles)
    for k in range(cycles):
        t0 = time.perf_counter()
        for i in ids:
            try:
                read(handler, i, present)
            except MISPARSE:  # a reply later than the SDK's timeout, taken for the next one
                handler.clearPort()
        for i in ids:
            write(handler, i, goal, value)
        times[k] = time.perf_counter() - t0
    handler.closePort()
    return times


class Scheduled(NamedTuple):
    """One run of the driver under the control loop, reads between ticks."""

    on_time: float
    """Share of ticks after the first second that ended before the next was due."""
    writes_per_servo: float
    reads_per_servo: float
    oldest_p50: float
    oldest_p99: float
    updates: float
    """Joint updates per second: reads plus goals, every servo."""


def run_scheduled(profile, port: str, seconds: float) -> Scheduled:
    """The driver as the control role runs it: read, a goal sweeping every joint, write, and
    the idle time served; ages are what each tick's JointState says."""
    bus = DynamixelBus.from_profile(profile, port=port)
    bus.open()
    rest = np.asarray(bus.read().position)
    phase = np.arange(rest.size)
    oldest: list[float] = []

    def tick(t: float, dt: float) -> None:
        state = bus.read()
        if loop.ticks == warm:  # the first second (the first tick reads every servo) left out
            loop.timing.overruns = 0
        if state.age:
            oldest.append(float(np.nanmax(state.age)))
        goal = rest + 0.2 * np.sin(2 * np.pi * 0.5 * t + phase)
        bus.write(JointCommand(position=goal.tolist()))

    loop = ControlLoop(profile.rate_hz, MonotonicClock(), tick, bus.serve_until)
    ticks = int(seconds * profile.rate_hz)
    warm = int(profile.rate_hz)
    reads0 = bus.read_schedule.read_count
    start = time.monotonic()
    loop.run(max_ticks=ticks)
    took = time.monotonic() - start
    reads = bus.read_schedule.read_count - reads0
    lost = [h.name for h in bus.health() if h.lost]
    bus.close()
    if lost:
        raise SystemExit(f"servos lost during the benchmark: {lost}")
    n = len(profile.joints)
    ages = np.array(oldest[int(profile.rate_hz) :])  # after the first second
    return Scheduled(
        on_time=1.0 - loop.timing.overruns / (ticks - warm),
        writes_per_servo=ticks / took,
        reads_per_servo=reads / took / n,
        oldest_p50=float(np.percentile(ages, 50)),
        oldest_p99=float(np.percentile(ages, 99)),
        updates=(reads + ticks * n) / took,
    )


def run_naive_rate(profile, port: str, seconds: float, latency_ms: float) -> tuple[float, float]:
    """The SDK examples' loop (read then write, servo by servo, each waiting for its status)
    behind the same adapter: joint updates per second, and the share of 1/rate periods in
    which it completed a cycle of every servo."""
    handler = LatencyPort(port, max(latency_ms, 1.0))
    handler.openPort()
    ids, read, write, present, goal, value = naive_sdk(profile, handler)
    updates = cycles = 0
    start = time.monotonic()
    while time.monotonic() - start < seconds:
        for i in ids:
            try:
                updates += read(handler, i, present)[1] == sdk.COMM_SUCCESS
            except MISPARSE:
                handler.clearPort()
        for i in ids:
            try:
                updates += write(handler, i, goal, value)[0] == sdk.COMM_SUCCESS
            except MISPARSE:
                handler.clearPort()
        cycles += 1
    took = time.monotonic() - start
    handler.closePort()
    return updates / took, min(1.0, cycles / (took * profile.rate_hz))


def adapter_table(rt: bool, rounds: int, seconds: float) -> None:
    """Reads between ticks behind no adapter, a 1 ms and a 16 ms latency timer (#38)."""
    print(
        "| robot | adapter | ticks on time | goals /servo/s | reads /servo/s | oldest state p50 ms "
        "| oldest p99 ms | joint updates/s | naive SDK updates/s | naive cycles on time "
        "| ours / naive |"
    )
    print("|" + "---|" * 11)
    for robot in ("widowx", "hubrobo"):
        path = ROOT / "robots" / f"{robot}.toml"
        profile = load(path)
        baud = DynamixelConfig.from_profile(profile).baud
        for latency in (0.0, 1.0, 16.0):
            runs, naive = [], []
            for _ in range(rounds):
                emu = Emulator(path, baud, rt, latency)
                try:
                    runs.append(run_scheduled(profile, emu.port, seconds))
                    naive.append(run_naive_rate(profile, emu.port, min(seconds, 3.0), latency))
                finally:
                    emu.close()

            def spread(values, scale=1.0, fmt="{:.0f}"):
                v = np.array(values) * scale
                med = fmt.format(np.median(v))
                return f"{med} ({fmt.format(v.min())}–{fmt.format(v.max())})"

            ours = [r.updates for r in runs]
            theirs = [u for u, _ in naive]
            print(
                f"| {robot} | {f'{latency:g} ms' if latency else 'none (pty)'} "
                f"| {spread([r.on_time for r in runs], 100, '{:.1f}')} % "
                f"| {spread([r.writes_per_servo for r in runs])} "
                f"| {spread([r.reads_per_servo for r in runs])} "
                f"| {spread([r.oldest_p50 for r in runs], 1e3)} "
                f"| {spread([r.oldest_p99 for r in runs], 1e3)} "
                f"| {spread(ours)} | {spread(theirs)} "
                f"| {spread([c for _, c in naive], 100, '{:.0f}')} % "
                f"| {spread(np.array(ours) / np.array(theirs), 1.0, '{:.1f}')}× |",
                flush=True,
            )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=300)
    parser.add_argument("--no-realtime", action="store_true", help="normal scheduling")
    parser.add_argument(
        "--adapter",
        action="store_true",
        help="instead: reads between ticks of the control loop behind no, a 1 ms and a 16 ms "
        "USB adapter, against the SDK's one-servo-at-a-time loop (#38)",
    )
    parser.add_argument("--rounds", type=int, default=3, help="with --adapter: runs per row")
    parser.add_argument("--seconds", type=float, default=5.0, help="with --adapter: per run")
    args = parser.parse_args()
    rt = not args.no_realtime and realtime(DRIVER_PRIORITY)
    if args.adapter:
        print(f"scheduling: {'SCHED_FIFO' if rt else 'normal'}; load {os.getloadavg()[0]:.1f}\n")
        adapter_table(rt, args.rounds, args.seconds)
        return 0
    rtt = pty_round_trip_s()
    print(
        f"scheduling: {'SCHED_FIFO' if rt else 'normal'}; load average "
        f"{os.getloadavg()[0]:.1f}; pty RTT (median) {rtt * 1e6:.0f} µs\n"
    )
    cases = [("widowx", 1, "AX-18A", 1_000_000)]
    for base in ("hubrobo", "widowx"):  # 12 and 18 X-series servos
        cases += [(base, 2, "XL430-W250", b) for b in (1_000_000, 2_000_000, 3_000_000, 4_000_000)]
    print(
        "| model | servos | baud | bytes/cycle | round trips | bus limit µs (Hz) "
        "| limit + pty floor µs | driver µs (Hz) | % of bus limit | % of limit + floor "
        "| naive SDK µs | speed-up | host CPU µs |"
    )
    print("|" + "---|" * 13)
    notes = []
    with tempfile.TemporaryDirectory() as tmp:
        for base, protocol, model, baud in cases:
            path = profile_file(Path(tmp), base, protocol, model, baud)
            profile = load(path)
            n = len(profile.joints)
            every = max(1, round(profile.rate_hz / profile.bus.health_rate_hz))
            ordinary_b, health_b, trips = cycle_bytes(protocol, n)
            limit = weighted(*bus_limit_s(protocol, n, baud), every)
            floor = limit + weighted(trips, trips + (protocol == 2), every) * rtt
            emu = Emulator(path, baud, rt)
            try:
                times, health = run_driver(profile, emu.port, args.cycles)
                naive = run_naive(profile, emu.port, max(20, args.cycles // 5))
            finally:
                emu.close()
            d = weighted(np.median(times[~health]), np.median(times[health]), every)
            b = np.median(naive)
            cpu, sdk_read = host_cpu_s(profile)
            print(
                f"| {model} P{protocol}.0 | {n} | {baud / 1e6:g} M "
                f"| {weighted(ordinary_b, health_b, every):.0f} | {trips} "
                f"| {limit * 1e6:.0f} ({1 / limit:.0f}) | {floor * 1e6:.0f} "
                f"| {d * 1e6:.0f} ({1 / d:.0f}) | {100 * limit / d:.0f} % "
                f"| {100 * floor / d:.0f} % | {b * 1e6:.0f} | {b / d:.1f}× | {cpu * 1e6:.0f} |",
                flush=True,
            )
            if protocol == 1:
                allowed = (limit / 0.9 - limit) / trips
                notes.append(
                    f"P1.0, {n} servos: the 90 % goal allows {allowed * 1e6:.0f} µs of host and "
                    f"transport per transaction; the pty round trip alone is {rtt * 1e6:.0f} µs, "
                    f"the stock SDK's CPU for one READ {sdk_read * 1e6:.0f} µs, the driver's CPU "
                    f"per transaction (cycle CPU / round trips) {cpu / trips * 1e6:.0f} µs"
                )
    print("\n" + "\n".join(notes))
    return 0


if __name__ == "__main__":
    sys.exit(main())
