"""Soak, fuzz and reliability campaign: the figures of issue 12 for BENCHMARKS.md.

- Soak: two ``climbd run`` daemons of the WidowX on the fake joint bus, side by side for
  ``--minutes``: one walking (tripod at 0.05 m/s, driven by a teleop client with heartbeats that
  claims the session again and re-requests ACTIVE whenever the robot holds, counting each
  HOLD and its reason), the baseline idle in HOLD. Every ``--sample`` seconds: resident memory
  (/proc) and the loop's lateness from Health over Zenoh; ratios walking / idle.
  The physics twin does not walk under the daemon yet, so the soak walks on the fake bus.
- Fuzz: ``--fuzz N`` inputs per message decoder and for the profile parser (tests/fuzzing.py),
  with our decode beside msgspec's untyped decode of the same inputs as the baseline.
- Campaign: runs tests/test_campaign.py and tabulates fault × robot → outcome.

``--write`` replaces the ``## bench/soak.py`` section of BENCHMARKS.md with this run's tables.
Usage: ``python bench/soak.py [--minutes 5] [--sample 30] [--fuzz 10000] [--campaign] [--write]``
"""

from __future__ import annotations

import argparse
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
        [sys.executable, "-m", "daemon.cli", "run", "--profile", "robots/widowx.toml"]
        + ["--driver", "fake", "--listen", endpoint, "--quiet", *extra],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def soak(minutes: float, sample: float) -> tuple[list[str], dict]:
    """Run the walking and idle daemons; a markdown table and a summary of the run."""
    from daemon.bus import Bus, Endpoints, zenoh_config
    from daemon.messages import Health, Mode
    from daemon.teleop import TeleopClient

    seconds = minutes * 60
    eps = {k: f"tcp/127.0.0.1:{free_port()}" for k in ("walk", "idle")}
    procs = {"walk": daemon(eps["walk"], "--gait", "tripod"), "idle": daemon(eps["idle"])}
    health: dict[str, Health] = {}
    lock = threading.Lock()
    buses = []
    for name, ep in eps.items():
        bus = Bus("widowx", zenoh_config(None, "bench", Endpoints([], [ep])))

        def keep(h: Health, name: str = name) -> None:
            with lock:
                health[name] = h

        bus.subscribe(Health, keep)
        buses.append(bus)
    time.sleep(4.0)  # both stood up (2 s stand)
    operator = TeleopClient(buses[0], "soak", heartbeat_hz=20.0, rate_hz=10.0)
    operator.start()
    rows, holds, active, polls = [], {}, 0, 0
    start = next_sample = time.monotonic()
    try:
        while time.monotonic() - start < seconds:
            state = operator.mode
            if state is None or state.mode != Mode.ACTIVE:
                if state is not None and state.mode == Mode.HOLD and polls:
                    holds[state.reason] = holds.get(state.reason, 0) + 1
                operator.claim()  # a session lost with a late heartbeat is claimed again
                time.sleep(0.1)
                operator.request(Mode.ACTIVE)
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
        "span": last[0] - first[0],
        "active": 100 * active / max(1, polls),
        "holds": holds,
        "codes": codes,
    }
    return table, summary


def fuzz(n: int) -> list[str]:
    """``n`` inputs per decoder and for the profile parser; throughput beside msgspec's own."""
    import msgspec
    from fuzzing import check_profile, check_profile_text, edited_profile, profile_edits
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from daemon.messages import ALL_MESSAGES, decode

    cfg = settings(
        max_examples=n, deadline=None, database=None, suppress_health_check=list(HealthCheck)
    )
    rows = [
        "| target | inputs | failures | ours µs/input | msgspec untyped µs/input | ratio |",
        "|---|---|---|---|---|---|",
    ]
    for message in ALL_MESSAGES:
        seen = _fuzz_decoder(message, cfg)
        ours = _per_input(seen, lambda p, message=message: decode(p, message))
        base = _per_input(seen, msgspec.msgpack.decode)
        rows.append(
            f"| {message.__name__} decoder | {len(seen)} | 0 | {ours:.2f} | {base:.2f} | "
            f"{ours / base:.2f} |"
        )
    count = [0]

    @cfg
    @given(profile_edits)
    def profiles(edits) -> None:
        count[0] += 1
        check_profile(edited_profile(edits))

    profiles()
    rows.append(f"| profile parser (edited stock profile) | {count[0]} | 0 | | | |")
    count[0] = 0
    with tempfile.TemporaryDirectory() as d:

        @cfg
        @given(st.text(max_size=400))
        def texts(text: str) -> None:
            count[0] += 1
            check_profile_text(Path(d) / "fuzz.toml", text)

        texts()
    rows.append(f"| profile parser (any file text) | {count[0]} | 0 | | | |")
    return rows


def _fuzz_decoder(message, cfg) -> list[bytes]:
    """Run the decoder property on ``message``; the inputs hypothesis generated."""
    from fuzzing import check_decoder, payloads
    from hypothesis import given

    seen: list[bytes] = []

    @cfg
    @given(payloads(message))
    def run(payload: bytes) -> None:
        seen.append(payload)
        check_decoder(message, payload)

    run()
    return seen


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
    order = ["Reliability campaign", "Fuzzing", "Soak", "Interpretation"]
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
    parser.add_argument("--fuzz", type=int, default=10_000, help="inputs per target (0: none)")
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
        rows = fuzz(args.fuzz)
        parts[title] = "\n".join(
            [
                f"### {title}",
                "",
                f"Command: {run}. Baseline: msgspec's untyped decode of the same inputs. "
                "A failure is any exception other than the ones the bus catches "
                "(decoders) or ProfileError (profiles).",
                "",
                *rows,
            ]
        )
        print(parts[title], flush=True)
    if args.minutes:
        title = f"Soak ({args.minutes:g} min, WidowX, fake joint bus, tripod at 0.05 m/s)"
        table, s = soak(args.minutes, args.sample)
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
            ]
        )
        print(parts[title], flush=True)
    if args.write:
        write_section(parts)
    return 0


if __name__ == "__main__":
    sys.exit(main())
