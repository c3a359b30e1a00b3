"""One-hop latency and throughput of climbd's Network vs raw zenoh put/subscribe of the same bytes.

Two Zenoh sessions in this process, linked by TCP on loopback, multicast scouting off. For a
joint-state message (18 joints) and a 200 × 200 float32 elevation grid, three paths, in the
same run and interleaved round by round so the shared machine's noise hits all alike:

- raw: a declared zenoh publisher puts pre-encoded bytes, a subscriber callback takes them
  (``payload.to_bytes()``) — the baseline, with the same QoS climbd gives the topic;
- climbd: ``Network.publisher(T).put(message)`` (encodes) → ``Network.subscribe`` on Zenoh's thread
  (decodes and validates the Struct);
- climbd+asyncio: the same, delivered to an asyncio loop as the daemon receives it.

Latency: one message in flight at a time, send → callback (perf_counter, one process).
Throughput: a burst sent back to back; messages delivered per second at the subscriber, and
the share of the burst delivered (congestion control DROP may shed some, as in the daemon).
Zenoh's defaults apply to both paths (on one machine that includes its shared-memory transport).

    .venv/bin/python bench/bus.py [--rounds 5] [--samples 400]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import socket
import threading
import time

import numpy as np
import zenoh

from climbd.daemon.contract.messages import ElevationGrid, JointState, Message, encode, key
from climbd.daemon.runtime.network import Endpoints, Network, zenoh_config

ROBOT = "bench"
AIO_ROBOT = "bench-aio"
"""Each path has its own key, so every put has exactly one subscriber."""
PATHS = ("raw", "climbd", "climbd+asyncio")


def free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def joint_state() -> JointState:
    n = 18
    return JointState(
        stamp=time.monotonic(),
        names=[f"leg{i // 3}_{('coxa', 'femur', 'tibia')[i % 3]}" for i in range(n)],
        position=np.linspace(-1, 1, n).tolist(),
        velocity=np.zeros(n).tolist(),
        effort=np.zeros(n).tolist(),
    )


def elevation_grid() -> ElevationGrid:
    heights = np.random.default_rng(0).normal(0.0, 0.05, (200, 200)).astype("<f4")
    return ElevationGrid(stamp=time.monotonic(), rows=200, cols=200, heights=heights.tobytes())


class Receiver:
    """Counts arrivals and stamps the last one; ``wait`` blocks for the next."""

    def __init__(self) -> None:
        self.count = 0
        self.at = 0.0
        self.event = threading.Event()

    def __call__(self, _item) -> None:
        self.at = time.perf_counter()
        self.count += 1
        self.event.set()


class Rig:
    """Publisher and subscriber sessions (raw and climbd) plus an asyncio delivery loop."""

    def __init__(self) -> None:
        ep = free_endpoint()
        self.aio = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.aio.run_forever, daemon=True)
        self.thread.start()
        self.pub_bus = Network(ROBOT, zenoh_config(None, "pub", Endpoints([ep], [])))
        self.sub_bus = Network(ROBOT, zenoh_config(None, "sub", Endpoints([], [ep])))
        self.sub_aio = Network(
            AIO_ROBOT, zenoh_config(None, "sub-aio", Endpoints([], [ep])), self.aio
        )
        time.sleep(1.0)

    def paths(self, message: Message):
        """(path name, send function, receiver) for each path of ``message``'s type."""
        t = type(message)
        payload = encode(message)
        out = {}
        climbd_pub = self.pub_bus.publisher(t)
        control = t is JointState  # climbd's QoS: REAL_TIME + express for control streams
        raw_pub = self.pub_bus.session.declare_publisher(
            key(ROBOT, f"raw/{t.TOPIC}"),
            priority=zenoh.Priority.REAL_TIME if control else zenoh.Priority.DEFAULT,
            congestion_control=zenoh.CongestionControl.DROP,
            express=control,
        )
        raw_rx = Receiver()
        self.sub_bus.session.declare_subscriber(
            key(ROBOT, f"raw/{t.TOPIC}"), lambda s: raw_rx(s.payload.to_bytes())
        )
        out["raw"] = (lambda: raw_pub.put(payload), raw_rx)
        rx = Receiver()
        self.sub_bus.subscribe(t, rx)
        aio_rx = Receiver()
        self.sub_aio.subscribe(t, aio_rx)
        aio_pub = self.pub_bus.publisher(t, robot=AIO_ROBOT)
        out["climbd"] = (lambda: climbd_pub.put(message), rx)
        out["climbd+asyncio"] = (lambda: aio_pub.put(message), aio_rx)
        time.sleep(0.5)
        return out

    def close(self) -> None:
        for b in (self.pub_bus, self.sub_bus, self.sub_aio):
            b.close()
        self.aio.call_soon_threadsafe(self.aio.stop)
        self.thread.join(2)


def latency(send, rx: Receiver, samples: int) -> list[float]:
    """One-way latencies (s), one message in flight at a time."""
    out = []
    for _ in range(samples):
        rx.event.clear()
        t0 = time.perf_counter()
        send()
        if rx.event.wait(0.5):
            out.append(rx.at - t0)
    return out


def throughput(send, rx: Receiver, burst: int) -> tuple[float, float]:
    """Messages per second delivered of a burst sent back to back, and the fraction delivered."""
    start_count = rx.count
    t0 = time.perf_counter()
    for _ in range(burst):
        send()
    deadline = time.perf_counter() + 5.0
    last, last_change = rx.count, time.perf_counter()
    while rx.count - start_count < burst and time.perf_counter() < deadline:
        time.sleep(0.001)
        if rx.count != last:
            last, last_change = rx.count, time.perf_counter()
        elif time.perf_counter() - last_change > 0.2:
            break  # the rest was dropped (congestion control DROP)
    got = rx.count - start_count
    return (got / (rx.at - t0) if got else 0.0), got / burst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--samples", type=int, default=400, help="latency samples per round")
    parser.add_argument("--json", help="also write the results here")
    args = parser.parse_args()
    rig = Rig()
    results = {}
    try:
        for name, message, burst, scale in (
            ("JointState (18 joints)", joint_state(), 5000, 1),
            ("ElevationGrid 200×200 f32", elevation_grid(), 200, 4),
        ):
            paths = rig.paths(message)
            lat = {p: [] for p in PATHS}
            rate = {p: [] for p in PATHS}
            delivered = {p: [] for p in PATHS}
            for _ in PATHS:  # warm-up: connections, caches, allocator
                for p in PATHS:
                    latency(*paths[p], 20)
            for _ in range(args.rounds):
                for p in PATHS:
                    send, rx = paths[p]
                    lat[p] += latency(send, rx, max(20, args.samples // scale))
                    r, fraction = throughput(send, rx, burst)
                    rate[p].append(r)
                    delivered[p].append(fraction)
            size = len(encode(message))
            results[name] = {
                p: {
                    "p50_us": float(np.percentile(lat[p], 50) * 1e6),
                    "p99_us": float(np.percentile(lat[p], 99) * 1e6),
                    "msgs_per_s": float(np.median(rate[p])),
                    "mb_per_s": float(np.median(rate[p]) * size / 1e6),
                    "delivered": float(np.mean(delivered[p])),
                    "samples": len(lat[p]),
                }
                for p in PATHS
            }
            results[name]["bytes"] = size
    finally:
        rig.close()
    print(
        f"{'message':<27} {'path':<15} {'p50 µs':>8} {'p99 µs':>8} {'p50/raw':>8} "
        f"{'msg/s':>9} {'MB/s':>8} {'raw/rate':>8} {'deliv.':>6}"
    )
    for name, r in results.items():
        raw = r["raw"]
        for p in PATHS:
            x = r[p]
            print(
                f"{name:<27} {p:<15} {x['p50_us']:8.0f} {x['p99_us']:8.0f} "
                f"{x['p50_us'] / raw['p50_us']:8.2f} {x['msgs_per_s']:9.0f} "
                f"{x['mb_per_s']:8.1f} {raw['msgs_per_s'] / max(x['msgs_per_s'], 1e-9):8.2f} "
                f"{x['delivered']:6.0%}"
            )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2)


if __name__ == "__main__":
    main()
