"""Soak, fuzz and reliability campaign: the figures of issue 12 for BENCHMARKS.md.

- Soak: two ``climbd run`` daemons of the WidowX on the fake joint bus, side by side for
  ``--minutes``: one walking (tripod at 0.05 m/s, driven by a teleop client with heartbeats that
  claims the session again and re-requests ACTIVE whenever the robot holds, counting each
  HOLD and its reason), the baseline idle in HOLD. Every ``--sample`` seconds: resident memory
  (/proc) and the loop's lateness from Health over Zenoh; ratios walking / idle.
- Twin soak (``--twin [--perception]``): ``climbd run --sim`` in real time on a flat floor,
  walked in a circle by a teleop client; per ``--window``: RSS of each process, loop lateness,
  ticks missed, modes, odometry path, perception output; ratios to the first window.
- Fuzz: ``--fuzz N`` inputs per message decoder and for the profile parser
  (tests/support/fuzzing.py), with our decode beside msgspec's untyped decode of the same inputs as
the baseline. - Campaign: runs tests/test_campaign.py and tabulates fault × robot → outcome.

``--write`` replaces the ``## bench/soak.py`` section of BENCHMARKS.md with this run's tables.
- E-stop drills (both soaks, ``--estop-every`` s): ``climbd estop`` engages the walking
  daemon's e-stop as a separate process; counted (engaged, confirmed, seen, lost) and timed
  (launch → the soak's ModeState ESTOP); then reset by the session holder and walked on.
Usage: ``python bench/soak.py [--minutes 5] [--sample 30] [--twin [--perception] [--window 300]]
[--estop-every 60] [--fuzz 10000] [--campaign] [--write]``
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rss_mib(pid: int) -> float:
    """Resident set size of ``pid`` (MiB) from /proc."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for pid {pid}")


def daemon(endpoint: str, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "climbd.daemon.cli", "run", "--profile", "robots/widowx.toml"]
        + ["--driver", "fake", "--listen", endpoint, "--quiet", *extra],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


ESTOP_LOST_AFTER = 2.0
"""Seconds within which the soak must see ModeState ESTOP once ``climbd estop`` has exited 0
(it waits that long for its own confirmation, so a drill it confirmed is lost only when the
soak's subscriber does not hear what the CLI heard); a drill's launch → seen latency includes
the CLI's start-up (~1 s of imports and a Zenoh session), so is reported, and its share
within ESTOP_LOST_AFTER of the launch beside it."""


class EstopDrills:
    """E-stop drills on a walking daemon, as an operator does them: every ``every`` seconds
    ``climbd estop --robot widowx --connect <endpoint>`` engages the e-stop as a separate
    process (confirmed by the robot's ModeState, exit 0); the soak's own subscriber times
    launch → ModeState ESTOP; then the e-stop is reset by the session holder, the soak's teleop
    client (``TeleopClient.reset``), or, when it holds no session (the twin's --activate
    autonomy), by ``climbd estop --reset``, which claims, resets and releases. A drill is lost
    when the CLI exits non-zero or the soak does not see ESTOP within ESTOP_LOST_AFTER of the
    CLI's exit. A drill waits for the robot to be ACTIVE (at most ``every`` more seconds)."""

    def __init__(self, bus, endpoint: str, every: float) -> None:
        from climbd.daemon.contract.messages import ModeState

        self.endpoint = endpoint
        self.every = every
        self.next_at = time.monotonic() + every
        self.engaged = self.confirmed = self.seen = self.lost = 0
        self.resets: dict[str, int] = {}
        self.latencies: list[float] = []
        self.failures: list[str] = []
        self.cli_seconds: list[float] = []
        self.cli_confirmed: list[float] = []
        self.skipped = 0
        self._launched: float | None = None
        self._seen_at: float | None = None
        self._event = threading.Event()
        bus.subscribe(ModeState, self._on_mode)

    def _on_mode(self, state) -> None:
        """The first ModeState ESTOP after a launch (on Zenoh's thread)."""
        if state.mode.value == "ESTOP" and self._launched is not None and self._seen_at is None:
            self._seen_at = time.monotonic()
            self._event.set()

    def _cli(self, *extra: str, timeout: float = 30.0) -> subprocess.CompletedProcess:
        argv = [sys.executable, "-m", "climbd.daemon.cli", "estop", "--robot", "widowx"]
        argv += ["--connect", self.endpoint, *extra]
        try:
            return subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired as e:
            return subprocess.CompletedProcess(argv, -9, e.stdout or "", f"timed out: {e}")

    def due(self, state) -> bool:
        """Whether a drill is due, ``state`` the latest ModeState: one waits for ACTIVE up to
        ``every`` seconds; a robot still latched (a failed reset) is not drilled (skipped)."""
        now = time.monotonic()
        if now < self.next_at:
            return False
        mode = state.mode.value if state is not None else ""
        if mode in ("ESTOP", "FAULT"):
            self.skipped += 1
            self.next_at = now + 5.0
            return False
        return mode == "ACTIVE" or now >= self.next_at + self.every

    def drill(self, client, at: float) -> None:
        """Engage, time it, count it, reset it (``client``: the soak's TeleopClient)."""
        from climbd.daemon.cli.confirm import Unconfirmed

        self.engaged += 1
        n = self.engaged
        self._seen_at, self._event = None, threading.Event()
        self._launched = launched = time.monotonic()
        done = self._cli("--reason", f"soak drill {n}")
        exited = time.monotonic()
        self.cli_seconds.append(exited - launched)
        ok = done.returncode == 0
        self.confirmed += ok
        if ok and "confirmed in " in done.stdout:
            with contextlib.suppress(ValueError):
                self.cli_confirmed.append(float(done.stdout.split("confirmed in ")[1].split()[0]))
        self._event.wait(max(0.0, exited + ESTOP_LOST_AFTER - time.monotonic()))
        seen_at, self._launched = self._seen_at, None
        if seen_at is not None:
            self.seen += 1
            self.latencies.append(seen_at - launched)
        in_time = seen_at is not None and seen_at <= exited + ESTOP_LOST_AFTER
        if not (ok and in_time):
            self.lost += 1
            why = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no output"]
            seen = f"seen after {seen_at - launched:.2f} s" if seen_at else "never seen"
            self.failures.append(
                f"drill {n} at {at:.0f} s: CLI exit {done.returncode} ({why[0]}), ESTOP {seen}"
            )
        if client.claimed:  # the session holder resets, as the operator at the keyboard does
            client.claim()  # again: a session lost to late heartbeats would refuse the reset
            try:
                client.reset()
                self.resets["session holder"] = self.resets.get("session holder", 0) + 1
            except Unconfirmed as e:
                key = f"failed: {failure_key(e)}"
                self.resets[key] = self.resets.get(key, 0) + 1
        else:
            out = self._cli("--reset", "--reason", f"soak drill {n}")
            key = "estop --reset" if out.returncode == 0 else f"failed: {out.stderr.strip()}"
            self.resets[key] = self.resets.get(key, 0) + 1
        self.next_at = time.monotonic() + self.every

    def notes(self) -> list[str]:
        """The drill's lines below a table."""
        import numpy as np

        if not self.engaged:
            return ["E-stop drills: none (the run was shorter than --estop-every)."]
        lat = np.array(self.latencies) * 1e3
        stats = (
            f"p50 {np.percentile(lat, 50):.0f} ms, p99 {np.percentile(lat, 99):.0f} ms, "
            f"max {lat.max():.0f} ms"
            if len(lat)
            else "n/a"
        )
        fast = sum(t <= ESTOP_LOST_AFTER for t in self.latencies)
        own = (
            f"{np.median(self.cli_confirmed) * 1e3:.0f} ms / {max(self.cli_confirmed) * 1e3:.0f} ms"
            if self.cli_confirmed
            else "n/a"
        )
        return [
            f"E-stop drills (`climbd estop --robot widowx --connect <endpoint>` as a separate "
            f"process every {self.every:g} s, once ACTIVE): {self.engaged} engaged, "
            f"{self.confirmed} confirmed by the CLI (exit 0), {self.seen} seen by the soak's "
            f"subscriber, **{self.lost} lost** (goal 0: {'met' if self.lost == 0 else 'NOT met'}; "
            f"lost: CLI exit ≠ 0 or ESTOP not seen within {ESTOP_LOST_AFTER:g} s of its exit). "
            f"Launch → ModeState ESTOP seen by the soak: {stats}, {fast} of {len(lat)} within "
            f"{ESTOP_LOST_AFTER:g} s of the launch (the launch includes the CLI's start-up: "
            f"its run time median {np.median(self.cli_seconds):.2f} s; its own send → confirm "
            f"median / max {own}). Resets: {self.resets}"
            + (f"; drills skipped, robot still latched: {self.skipped}" if self.skipped else "")
            + "."
            + (f" Lost: {'; '.join(self.failures[:5])}." if self.failures else "")
        ]


MEMORY_GOAL = 1.05
"""Issue #33: resident memory at the end of a soak over that at its start, per process."""


def memory_note(ratios: dict[str, float]) -> str:
    """The memory line: end/start RSS per process against MEMORY_GOAL."""
    cells = ", ".join(
        f"{k} {v:.3f} ({'met' if v <= MEMORY_GOAL else 'NOT met'})" for k, v in ratios.items()
    )
    return f"Memory end/start (RSS, per process; goal ≤ {MEMORY_GOAL:g}): {cells or 'n/a'}."


def failure_key(e: Exception) -> str:
    """An Unconfirmed reset as counted: its kind and message, numbers and ids blanked."""
    import re

    text = re.sub(r"[0-9a-f]{32}", "<session>", str(e))
    return f"{type(e).__name__}: {re.sub(r'[0-9.]+ ms', 'N ms', text)[:100]}"


def reason_key(reason: str) -> str:
    """A mode's reason as counted: a drill's e-stop and a reset by one session or another are
    one key each, not one per CLI process or session id."""
    if reason.startswith("e-stop by ") and "soak drill" in reason:
        return "e-stop drill"
    if reason.startswith("reset by "):
        return "reset by <session>"
    if reason.startswith("joint state older than "):
        return reason.split(":")[0]  # the joints and their ages differ every time
    return reason


def soak(minutes: float, sample: float, estop_every: float = 0.0) -> tuple[list[str], dict]:
    """Run the walking and idle daemons; a markdown table and a summary of the run."""
    from climbd.daemon.cli.confirm import Unconfirmed
    from climbd.daemon.cli.teleop import TeleopClient
    from climbd.daemon.contract.messages import Health, Mode
    from climbd.daemon.runtime.network import Endpoints, Network, zenoh_config

    seconds = minutes * 60
    eps = {k: f"tcp/127.0.0.1:{free_port()}" for k in ("walk", "idle")}
    procs = {"walk": daemon(eps["walk"], "--gait", "tripod"), "idle": daemon(eps["idle"])}
    health: dict[str, Health] = {}
    lock = threading.Lock()
    buses = []
    for name, ep in eps.items():
        bus = Network("widowx", zenoh_config(None, "bench", Endpoints([], [ep])))

        def keep(h: Health, name: str = name) -> None:
            with lock:
                health[name] = h

        bus.subscribe(Health, keep)
        buses.append(bus)
    time.sleep(4.0)  # both stood up (2 s stand)
    operator = TeleopClient(buses[0], "soak", heartbeat_hz=20.0, rate_hz=10.0)
    operator.start()
    drills = EstopDrills(buses[0], eps["walk"], estop_every) if estop_every > 0 else None
    rows, holds, active, polls = [], {}, 0, 0
    start = next_sample = time.monotonic()
    try:
        while time.monotonic() - start < seconds:
            state = operator.mode
            if drills is not None and operator.claimed and drills.due(state):
                drills.drill(operator, time.monotonic() - start)
                state = operator.mode
            if state is not None and state.mode in (Mode.ESTOP, Mode.FAULT):
                key = f"{state.mode.value}: {reason_key(state.reason)}"
                holds[key] = holds.get(key, 0) + 1
                operator.claim()  # again: a session lost to late heartbeats refuses the reset
                try:
                    operator.reset()
                except Unconfirmed as e:  # refused or late: retried at the next poll
                    key = f"reset failed: {failure_key(e)}"
                    holds[key] = holds.get(key, 0) + 1
            elif state is not None and state.mode == Mode.STAND:
                pass  # standing up (after an e-stop reset to OFF): HOLD follows, then ACTIVE
            elif state is None or state.mode != Mode.ACTIVE:
                if state is not None and state.mode in (Mode.HOLD, Mode.OFF) and polls:
                    key = reason_key(state.reason)
                    key = key if state.mode == Mode.HOLD else f"OFF: {key}"
                    holds[key] = holds.get(key, 0) + 1
                operator.claim()  # a session lost with a late heartbeat is claimed again
                time.sleep(0.1)
                off = state is not None and state.mode == Mode.OFF  # reset with torque off
                operator.request(Mode.STAND if off else Mode.ACTIVE)
                operator.set_motion(vx=0.05)
            else:
                active += 1
            polls += 1
            time.sleep(0.5)
            if time.monotonic() >= next_sample + sample:
                next_sample += sample
                with lock:
                    h = dict(health)
                rows.append(
                    (
                        time.monotonic() - start,
                        f"{100 * active / polls:.0f} %",
                        rss_mib(procs["walk"].pid),
                        rss_mib(procs["idle"].pid),
                        h["walk"].loop,
                        h["idle"].loop,
                    )
                )
    finally:
        operator.close()
        for p in procs.values():
            p.send_signal(signal.SIGTERM)
        codes = {k: p.wait(30) for k, p in procs.items()}
        for bus in buses:
            bus.close()
    table = [
        "| t (s) | time ACTIVE so far | RSS walking (MiB) | RSS idle (MiB) "
        "| p99 lateness walking (µs) | p99 idle (µs) | ratio | max walking (µs) "
        "| overruns walking / idle |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for t, mode, rw, ri, lw, li in rows:
        ratio = lw.lateness_p99 / li.lateness_p99 if li.lateness_p99 > 0 else float("nan")
        table.append(
            f"| {t:.0f} | {mode} | {rw:.1f} | {ri:.1f} | {lw.lateness_p99 * 1e6:.0f} | "
            f"{li.lateness_p99 * 1e6:.0f} | {ratio:.2f} | {lw.lateness_max * 1e6:.0f} | "
            f"{lw.overruns} / {li.overruns} |"
        )
    first, last = rows[0], rows[-1]
    summary = {
        "growth_walk": last[2] - first[2],
        "growth_idle": last[3] - first[3],
        "memory": {"walking": last[2] / first[2], "idle": last[3] / first[3]},
        "span": last[0] - first[0],
        "active": 100 * active / max(1, polls),
        "holds": holds,
        "codes": codes,
        "drills": drills.notes() if drills is not None else [],
    }
    return table, summary


FLAT_WORLD = 'name = "flat"\n[floor]\nsize = 10.0  # half-size: a 20 m square\n'
"""The soak's world: a bare floor; the walk circles (radius vx / yaw_rate) in its middle."""


def role_pids(top: int) -> dict[str, int]:
    """The processes of a ``climbd run``: itself, and a supervisor's children by their role."""
    argv = Path(f"/proc/{top}/cmdline").read_bytes().split(b"\0")
    pids = {"supervisor" if b"all" in argv else "control": top}
    for pid in map(int, Path(f"/proc/{top}/task/{top}/children").read_text().split()):
        with contextlib.suppress(OSError, ValueError, IndexError):
            child = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
            pids[child[child.index(b"--role") + 1].decode()] = pid
    return pids


def rss_sample(top: int) -> dict[str, float]:
    """RSS (MiB) of each process of the run; one that just exited (a restart) is left out."""
    out = {}
    for role, pid in role_pids(top).items():
        with contextlib.suppress(OSError):
            out[role] = rss_mib(pid)
    return out


def open_client(endpoint: str, proc: subprocess.Popen, timeout: float = 60.0):
    """A Zenoh client session on the daemon's endpoint, once it listens (the roles start slowly).

    A client, not a peer: the control role routes the perception role's topics to its clients.
    """
    import zenoh

    from climbd.daemon.runtime.network import Endpoints, Network, zenoh_config

    deadline = time.monotonic() + timeout
    while True:
        try:
            return Network(
                "widowx", zenoh_config(None, "bench", Endpoints([], [endpoint]), "client")
            )
        except zenoh.ZError:
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"climbd run never listened on {endpoint}") from None
            time.sleep(0.5)


class TwinRecorder:
    """What the twin soak hears over Zenoh: Health reports, mode changes, odometry, features."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.health: list[tuple[float, object]] = []
        self.modes: list[tuple[float, str, str]] = []
        self.body: list[tuple[float, float, float]] = []
        self.features: list[tuple[float, int]] = []
        self.perception: list[tuple[float, object]] = []
        self._last_body = -1.0

    def attach(self, bus) -> TwinRecorder:
        """Subscribe to the topics the soak tabulates on ``bus``."""
        from climbd.daemon.contract.messages import BodyState, Health, Joists, ModeState

        bus.subscribe(Health, self._on_health)
        bus.subscribe(ModeState, self._on_mode)
        bus.subscribe(BodyState, self._on_body, latest_only=True)
        bus.subscribe(Joists, lambda j: self._add(self.features, (time.monotonic(), len(j.joists))))
        return self

    def _add(self, items: list, item) -> None:
        with self.lock:
            items.append(item)

    def _on_health(self, h) -> None:
        self._add(self.health if h.role == "control" else self.perception, (time.monotonic(), h))

    def _on_mode(self, s) -> None:
        with self.lock:
            if not self.modes or self.modes[-1][1:] != (s.mode.value, s.reason):
                self.modes.append((time.monotonic(), s.mode.value, s.reason))

    def _on_body(self, b) -> None:
        now = time.monotonic()
        if now - self._last_body >= 0.2:  # 5 Hz is plenty for a 0.05 m/s walk's path length
            self._last_body = now
            self._add(self.body, (now, b.position[0], b.position[1]))


class SoakOperator:
    """The teleop client that keeps the robot walking: STAND → ACTIVE once stood, HOLD → ACTIVE
    (e.g. after a late heartbeat), FAULT/ESTOP → reset; each state it had to leave is counted."""

    def __init__(self, client, motion: dict[str, float]) -> None:
        self.client = client
        self.motion = motion
        self.recoveries: dict[str, int] = {}
        self.reset_failures: dict[str, int] = {}
        self._seen = -1.0

    def poll(self, recorder: TwinRecorder) -> None:
        """Act on the latest mode (every call retries until the robot walks again)."""
        from climbd.daemon.cli.confirm import Unconfirmed
        from climbd.daemon.contract.messages import Mode

        with recorder.lock:
            since, mode, reason = recorder.modes[-1] if recorder.modes else (0.0, "", "")
        if mode in ("", Mode.ACTIVE.value) or (mode == "STAND" and time.monotonic() - since < 4.0):
            return
        if since != self._seen:
            self._seen = since
            key = f"{mode} ({reason_key(reason)})"
            self.recoveries[key] = self.recoveries.get(key, 0) + 1
        if mode in (Mode.FAULT.value, Mode.ESTOP.value):
            # claimed (again) first, as `climbd estop --reset` does: a session lost meanwhile
            # (late heartbeats expire it, silently in FAULT) would have every reset refused
            self.client.claim()
            try:
                self.client.reset()
            except Unconfirmed as e:  # refused or late: the next poll retries
                key = failure_key(e)
                self.reset_failures[key] = self.reset_failures.get(key, 0) + 1
            return
        self.client.claim()  # a session lost to a late heartbeat is claimed again
        time.sleep(0.1)
        self.client.request(Mode.STAND if mode == Mode.OFF.value else Mode.ACTIVE)
        self.client.set_motion(**self.motion)


def twin_soak(
    minutes: float, window: float, perception: bool, estop_every: float = 0.0
) -> tuple[list[str], dict]:
    """Walk the WidowX in the real-time twin for ``minutes``; a table per ``window`` seconds."""
    from climbd.daemon.cli.teleop import TeleopClient

    motion = {"vx": 0.05, "yaw_rate": 0.05}
    tmp = Path(tempfile.mkdtemp(prefix="climbd-soak-"))
    (tmp / "flat.toml").write_text(FLAT_WORLD)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    argv = [sys.executable, "-m", "climbd.daemon.cli", "run", "--profile", "robots/widowx.toml"]
    argv += ["--sim", str(tmp / "flat.toml"), "--activate", "--gait", "tripod", "--quiet"]
    argv += ["--listen", endpoint, "--snapshot", str(tmp / "top.png")]
    argv += ["--role", "all"] if perception else []
    out = (tmp / "climbd.log").open("w")
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT)
    rss: list[tuple[float, dict[str, float]]] = []
    pids: dict[str, set[int]] = {}
    with contextlib.ExitStack() as stack:
        stack.callback(out.close)
        stack.callback(proc.wait, 60)
        stack.callback(proc.send_signal, signal.SIGTERM)
        bus = open_client(endpoint, proc)
        stack.callback(bus.close)
        recorder = TwinRecorder().attach(bus)
        client = TeleopClient(bus, "soak", heartbeat_hz=20.0, rate_hz=10.0)
        client.start()
        stack.callback(client.close)
        operator = SoakOperator(client, motion)
        drills = EstopDrills(bus, endpoint, estop_every) if estop_every > 0 else None
        time.sleep(3.0)  # the twin drops the robot onto the floor
        start = next_rss = time.monotonic()
        while time.monotonic() - start < minutes * 60 and proc.poll() is None:
            if drills is not None and drills.due(client.mode):
                drills.drill(client, time.monotonic() - start)
            operator.poll(recorder)
            if time.monotonic() >= next_rss:
                next_rss += 5.0
                for role, pid in role_pids(proc.pid).items():
                    pids.setdefault(role, set()).add(pid)
                rss.append((time.monotonic(), rss_sample(proc.pid)))
            time.sleep(0.5)
    code = proc.returncode
    log = (tmp / "climbd.log").read_text()
    sim_line = next((ln for ln in log.splitlines() if ln.startswith("sim: ")), "no sim summary")
    rows = _twin_windows(recorder, rss, start, window)
    warm = [m for t, m in rss if t < start + window] or [m for _, m in rss[:1]]
    summary = {
        "memory": {r: rss[-1][1][r] / warm[-1][r] for r in warm[-1] if r in rss[-1][1]}
        if rss
        else {},
        "drills": drills.notes() if drills is not None else [],
        "code": code,
        "recoveries": operator.recoveries or "none",
        "reset_failures": operator.reset_failures or "none",
        "restarts": {r: len(p) - 1 for r, p in pids.items()},
        "modes": [(round(t - start), m, r) for t, m, r in recorder.modes],
        "sim": sim_line,
        "tracebacks": [
            next((ln for ln in block.splitlines()[1:] if ln[:1] not in ("", " ")), "?")
            for block in log.split("Traceback (most recent call last):")[1:]
        ],
        "log": str(tmp / "climbd.log"),
    }
    return rows, summary


def _twin_windows(recorder: TwinRecorder, rss, start: float, window: float) -> list[str]:
    """The per-window table; ratios against the first window (the run's own baseline)."""
    import numpy as np

    roles = list(rss[0][1]) if rss else []
    head = ["window (min)", *(f"RSS {r} (MiB)" for r in roles), "lateness p50 (µs)"]
    head += ["p99 (µs)", "ticks (missed)", "overruns", "ACTIVE", "mode changes", "walked (m)"]
    head += ["Joists msgs /s", "with a joist", "frames dropped", "RSS ratio", "p99 ratio"]
    rows = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    end = max([t for t, _ in rss] + [t for t, _ in recorder.health] + [start])
    base = None
    k = 0
    while start + k * window < end - 1.0:
        lo, hi = start + k * window, start + (k + 1) * window
        k += 1
        mem = [m for t, m in rss if lo <= t < hi]
        hs = [h for t, h in recorder.health if lo <= t < hi]
        if not mem or len(hs) < 2:
            continue
        p50 = float(np.median([h.loop.lateness_p50 for h in hs]))
        p99 = max(h.loop.lateness_p99 for h in hs)
        ticks, overruns, expected = _loop_counts(hs)
        missed = max(0.0, expected - ticks)
        active = sum(h.mode.value == "ACTIVE" for h in hs) / len(hs)
        changes = sum(lo <= t < hi for t, _, _ in recorder.modes)
        path = np.array([(x, y) for t, x, y in recorder.body if lo <= t < hi]).reshape(-1, 2)
        walked = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()) if len(path) else 0.0
        total = sum(mem[-1].values())
        base = base or (total, p99)
        cells = [f"{(lo - start) / 60:g}-{(hi - start) / 60:g}"]
        cells += [f"{mem[-1].get(r, float('nan')):.1f}" for r in roles]
        cells += [f"{p50 * 1e6:.0f}", f"{p99 * 1e6:.0f}"]
        cells += [f"{ticks} ({100 * missed / max(expected, 1):.0f} %)"]
        cells += [str(overruns), f"{100 * active:.0f} %"]
        found = [n for t, n in recorder.features if lo <= t < hi]
        seen = [h.dropped_frames for t, h in recorder.perception if lo <= t < hi]
        dropped = sum(max(0, b - a) for a, b in itertools.pairwise(seen)) if seen else "n/a"
        cells += [str(changes), f"{walked:.2f}", f"{len(found) / (min(hi, end) - lo):.1f}"]
        cells += [str(sum(n > 0 for n in found)), str(dropped)]
        cells += [f"{total / base[0]:.3f}"]
        cells += [f"{p99 / base[1]:.2f}" if base[1] > 0 else "n/a"]
        rows.append("| " + " | ".join(cells) + " |")
    return rows


def _loop_counts(reports: list) -> tuple[int, int, float]:
    """Ticks and overruns between consecutive Health reports, and the ticks due meanwhile
    (rate × time); a pair across a restart of the control role (counters reset) is skipped."""
    ticks = overruns = 0
    expected = 0.0
    for a, b in itertools.pairwise(reports):
        if b.loop.ticks >= a.loop.ticks:
            ticks += b.loop.ticks - a.loop.ticks
            overruns += b.loop.overruns - a.loop.overruns
            expected += (b.stamp - a.stamp) * b.loop.rate_hz
    return ticks, overruns, expected


def twin_title(args: argparse.Namespace) -> str:
    roles = "control + perception roles" if args.perception else "control role"
    return f"Twin soak ({args.minutes:g} min, WidowX, real-time twin, {roles})"


def twin_intro(run: str, args: argparse.Namespace) -> str:
    return (
        f"Command: {run}. `climbd run --profile robots/widowx.toml --sim <flat 20 m floor> "
        f"--activate --gait tripod{' --role all' if args.perception else ''}` in real time "
        "(not --stepped), walked by a teleop client over Zenoh (vx 0.05 m/s, yaw_rate 0.05 "
        "rad/s: a 1 m circle) with 20 Hz heartbeats. Per window: RSS (/proc VmRSS) of each "
        "process at the window's end; the loop's lateness p50 (median of the window's Health "
        "reports of the loop's own 4096-tick p50) and p99 (worst such report); ticks done and "
        "missed against rate × time; ACTIVE as a share of Health reports; path length of the "
        "odometry (BodyState, the estimate); perception's Joists messages per second and how "
        "many report a joist (the floor has none: each is a false positive). Baseline: the "
        "first window of the same run (ratios)."
    )


def twin_notes(s: dict) -> list[str]:
    """The run's events below the table: mode changes, recoveries, restarts, twin summary."""
    changes = ", ".join(f"{t} s {m} ({r})" for t, m, r in s["modes"][:12])
    more = len(s["modes"]) - 12
    return [
        f"Mode changes (s from the start): {changes}{f', … {more} more' if more > 0 else ''}.",
        f"Operator recoveries (state left → count): {s['recoveries']}; role restarts: "
        f"{s['restarts']}; exit code {s['code']}; tracebacks in the daemon's log: "
        f"{len(s['tracebacks'])} {sorted(set(s['tracebacks']))}; resets not confirmed: "
        f"{s['reset_failures']}.",
        f"Twin: {s['sim']}",
        memory_note(s["memory"]) + " Start: the end of the first window (after warm-up).",
        *s["drills"],
    ]


def fuzz(n: int, only: list[str] | None = None) -> list[str]:
    """``n`` inputs per decoder (msgpack on the bus, JSON in recordings), for the profile parser
    and for the point cloud reader; throughput beside msgspec's own untyped decode. ``only``
    (message names) fuzzes those messages' decoders alone, e.g. to re-check one after a fix."""
    import msgspec
    from hypothesis import strategies as st
    from support.fuzzing import (
        check_cloud,
        check_decoder,
        check_json_decoder,
        check_profile,
        check_profile_bytes,
        check_profile_text,
        cloud_files,
        edited_profile,
        json_payloads,
        payloads,
        profile_bytes,
        profile_edits,
    )

    from climbd.daemon.cli.record import from_json
    from climbd.daemon.contract.messages import ALL_MESSAGES, decode

    rows = [
        "| target | inputs | failures | ours µs/input | msgspec untyped µs/input | ratio |",
        "|---|---|---|---|---|---|",
    ]
    for message in ALL_MESSAGES:
        if only and message.__name__ not in only:
            continue
        for what, strategy, check, ours_fn, base_fn in (
            ("decoder", payloads(message), check_decoder, decode, None),
            ("JSON decoder (recordings)", json_payloads(message), check_json_decoder, from_json, 1),
        ):
            seen, failed = _fuzz_target(n, strategy, lambda p, m=message, c=check: c(m, p))
            ours = _per_input(seen, lambda p, m=message, f=ours_fn: f(p, m))
            base = _per_input(seen, msgspec.json.decode if base_fn else msgspec.msgpack.decode)
            rows.append(
                f"| {message.__name__} {what} | {len(seen)} | {failed} | {ours:.2f} | "
                f"{base:.2f} | {ours / base:.2f} |"
            )
    if only:
        return rows
    seen, failed = _fuzz_target(n, profile_edits, lambda e: check_profile(edited_profile(e)))
    rows.append(f"| profile parser (edited stock profile) | {len(seen)} | {failed} | | | |")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for what, strategy, check in (
            ("any file text", st.text(max_size=400), check_profile_text),
            ("file bytes: non-UTF-8, cut, BOMs", profile_bytes, check_profile_bytes),
        ):
            seen, failed = _fuzz_target(n, strategy, lambda x, c=check: c(tmp / "fuzz.toml", x))
            rows.append(f"| profile parser ({what}) | {len(seen)} | {failed} | | | |")
        seen, failed = _fuzz_target(n, cloud_files, lambda f: check_cloud(tmp, *f))
        rows.append(
            f"| point cloud reader (.pcd/.ply/.npy cut, mutated, lying headers, non-UTF-8) "
            f"| {len(seen)} | {failed} | | | |"
        )
    return rows


def _fuzz_target(n: int, strategy, check) -> tuple[list, str]:
    """Run ``check`` on ``n`` inputs of ``strategy``: the inputs generated, and the failures
    ("0", or how many, with the first one's exception and where in climbd it was raised).
    A failure is counted, not raised, so every target gets its ``n`` inputs."""
    from hypothesis import HealthCheck, given, settings

    cfg = settings(
        max_examples=n, deadline=None, database=None, suppress_health_check=list(HealthCheck)
    )
    seen: list = []
    failures: list[BaseException] = []

    @cfg
    @given(strategy)
    def run(value) -> None:
        seen.append(value)
        try:
            check(value)
        except Exception as e:  # noqa: BLE001 - a failure is tabulated, not raised
            failures.append(e)

    run()
    if not failures:
        return seen, "0"
    kinds: dict[str, int] = {}
    for e in failures:
        kinds[type(e).__name__] = kinds.get(type(e).__name__, 0) + 1
    e = failures[0]
    where = next((f" in {f.name} ({Path(f.filename).name}:{f.lineno})" for f in _frames(e)), "")
    counts = ", ".join(f"{k} ×{v}" for k, v in kinds.items())
    return seen, f"**{len(failures)}** ({counts}; first{where}: {str(e)[:80]})"


def _frames(e: BaseException) -> list:
    """The traceback's frames of climbd's own code, innermost first."""
    import traceback

    frames = traceback.extract_tb(e.__traceback__)
    return [f for f in reversed(frames) if "/daemon/" in f.filename]


def _per_input(inputs: list[bytes], fn) -> float:
    """Mean µs per call of ``fn`` over ``inputs``, errors included."""
    start = time.perf_counter()
    for p in inputs:
        try:
            fn(p)
        except Exception:  # noqa: S112 - garbage is expected to be refused
            continue
    return (time.perf_counter() - start) / max(1, len(inputs)) * 1e6


def campaign() -> list[str]:
    """Run tests/test_campaign.py; the fault × robot table from its junit report."""
    from test_campaign import FAULTS, ROBOTS

    with tempfile.TemporaryDirectory() as d:
        report = Path(d) / "campaign.xml"
        subprocess.run(
            [
                sys.executable,
                "-m",
                "pytest",
                "-q",
                "tests/test_campaign.py",
                f"--junitxml={report}",
            ],
            cwd=ROOT,
            check=False,
        )
        cases = ET.parse(report).getroot().iter("testcase")
        results = {}
        for case in cases:
            cell = case.get("name").split("[", 1)[1].rstrip("]")
            props = {p.get("name"): p.get("value") for p in case.iter("property")}
            skipped = case.find("skipped")
            if skipped is not None:
                results[cell] = f"xfail: {skipped.get('message', '').removeprefix('xfail: ')}"
            elif case.find("failure") is not None or case.find("error") is not None:
                results[cell] = "**FAIL**"
            else:
                results[cell] = f"pass: {props.get('outcome', '')}"
    passed = sum(v.startswith("pass") for v in results.values())
    gaps = sum(v.startswith("xfail") for v in results.values())
    rows = [
        f"{passed} of {len(results)} applicable cells pass; {gaps} are known gaps (strict "
        f"xfail, reason given); {len(results) - passed - gaps} fail.",
        "",
        "| fault | " + " | ".join(ROBOTS) + " |",
        "|---" * (len(ROBOTS) + 1) + "|",
    ]
    for fault, (robots, why) in FAULTS.items():
        cells = [
            results.get(f"{fault}-{r}", "**missing**") if r in robots else f"n/a ({why})"
            for r in ROBOTS
        ]
        rows.append(f"| {fault} | " + " | ".join(cells) + " |")
    return rows


INTRO = (
    "Generated by bench/soak.py; each part gives the command that produced it. The campaign "
    "runs the real drivers on their emulators (tests/test_campaign.py); every cell must pass "
    "or say plainly why not."
)


def write_section(parts: dict[str, str]) -> None:
    """Replace the ``### <title>`` parts of this run in BENCHMARKS.md's ``## bench/soak.py``.

    Parts this run did not produce (e.g. the soak, when only the campaign ran) are kept, and
    so is a hand-written ``### Interpretation`` of the figures.
    """
    path = ROOT / "BENCHMARKS.md"
    doc = path.read_text()
    head = "## bench/soak.py"
    before, _, rest = doc.partition(head)
    body, sep, tail = rest.partition("\n## ")
    old = {}
    for chunk in body.split("\n### ")[1:]:
        title = chunk.split("\n", 1)[0].split(" (")[0]
        old[title] = "### " + chunk.rstrip()
    new = {title.split(" (")[0]: text.rstrip() for title, text in parts.items()}
    merged = {**old, **new}
    order = ["Reliability campaign", "Fuzzing", "Soak", "Twin soak", "Interpretation"]
    chunks = [merged[k] for k in order if k in merged]
    section = "\n\n".join([head, INTRO, *chunks]) + "\n"
    if not rest:
        path.write_text(doc.rstrip() + "\n\n" + section)
        return
    path.write_text(before + section + (sep and "\n## " + tail))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=5.0, help="soak length (0: no soak)")
    parser.add_argument("--sample", type=float, default=30.0, help="seconds between samples")
    parser.add_argument("--twin", action="store_true", help="soak: walk in the real-time twin")
    parser.add_argument(
        "--perception", action="store_true", help="twin soak: the perception role too"
    )
    parser.add_argument("--window", type=float, default=300.0, help="twin soak: table window (s)")
    parser.add_argument(
        "--estop-every",
        type=float,
        default=60.0,
        help="soaks: seconds between e-stop drills with `climbd estop` (0: none)",
    )
    parser.add_argument("--fuzz", type=int, default=10_000, help="inputs per target (0: none)")
    parser.add_argument(
        "--fuzz-only", action="append", metavar="MESSAGE", help="fuzz only these decoders"
    )
    parser.add_argument("--campaign", action="store_true", help="run the fault campaign")
    parser.add_argument("--write", action="store_true", help="update BENCHMARKS.md")
    args = parser.parse_args()
    load = os.getloadavg()[0]
    run = f"`.venv/bin/python bench/soak.py {' '.join(sys.argv[1:])}` (load average {load:.1f})"
    parts: dict[str, str] = {}
    if args.campaign:
        title = "Reliability campaign (tests/test_campaign.py)"
        parts[title] = "\n".join([f"### {title}", "", f"Command: {run}.", "", *campaign()])
        print(parts[title], flush=True)
    if args.fuzz:
        title = f"Fuzzing ({args.fuzz} inputs per target)"
        rows = fuzz(args.fuzz, args.fuzz_only)
        parts[title] = "\n".join(
            [
                f"### {title}",
                "",
                f"Command: {run}. Baseline: msgspec's untyped decode of the same inputs. "
                "A failure is any exception other than the ones the bus catches "
                "(msgpack decoders), the recording reader catches (JSON decoders: "
                "msgspec.DecodeError/ValidationError), ProfileError (profiles) or "
                "CloudFileError (point clouds). Inputs are bytes as well as text: "
                "invalid UTF-8, truncated payloads, huge declared lengths, deep nesting "
                "(tests/support/fuzzing.py).",
                "",
                *rows,
            ]
        )
        print(parts[title], flush=True)
    if args.minutes and args.twin:
        title = twin_title(args)
        table, s = twin_soak(args.minutes, args.window, args.perception, args.estop_every)
        parts[title] = "\n".join(
            [f"### {title}", "", twin_intro(run, args), "", *table, "", *twin_notes(s)]
        )
        print(parts[title], flush=True)
    elif args.minutes:
        title = f"Soak ({args.minutes:g} min, WidowX, fake joint bus, tripod at 0.05 m/s)"
        table, s = soak(args.minutes, args.sample, args.estop_every)
        parts[title] = "\n".join(
            [
                f"### {title}",
                "",
                f"Command: {run}. The walking daemon runs beside an idle one (HOLD) as the "
                "baseline; lateness is the loop's own p99 over its last 4096 ticks (Health).",
                "",
                *table,
                "",
                f"Memory growth over {s['span']:.0f} s after warm-up: walking "
                f"{s['growth_walk']:+.1f} MiB, idle baseline {s['growth_idle']:+.1f} MiB; "
                f"ACTIVE {s['active']:.1f} % of the time; HOLDs re-activated by the operator: "
                f"{s['holds'] or 'none'}; exit codes {s['codes']}.",
                memory_note(s["memory"]) + " Start: the first sample (after warm-up).",
                *s["drills"],
            ]
        )
        print(parts[title], flush=True)
    if args.write:
        write_section(parts)
    return 0


if __name__ == "__main__":
    sys.exit(main())
