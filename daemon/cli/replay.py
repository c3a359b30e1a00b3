"""``climbd replay``: republish an MCAP recording on the network at real or chosen speed.

Messages go out in log-time order, each at ``(log_time - first) / speed`` after the start,
on the key it was recorded under (or under ``--robot NEW``), as the same msgpack payload a
live robot sends, so perception, behaviours and ``climbd top`` run on recorded data unchanged.
Command topics (``cmd/**``) are left out unless ``--commands`` is given: replaying an
operator's motion or mode requests onto a live robot would move it.
"""

from __future__ import annotations

import argparse
import fnmatch
import logging
import math
import signal
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from climbd.daemon.cli.client import add_credential_arguments, client_config
from climbd.daemon.cli.record import RecordingError, RecordingFile
from climbd.daemon.runtime.access import AccessError
from climbd.daemon.runtime.network import Network

log = logging.getLogger("climbd.replay")


@dataclass
class Recorded:
    """One recorded message: key, decoded Struct and log time (ns)."""

    key: str
    message: object
    log_time: int


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="MCAP recording (climbd record)")
    parser.add_argument(
        "--speed", type=float, default=1.0, help="playback speed factor (default: 1, real time)"
    )
    parser.add_argument(
        "--connect", action="append", default=[], help="Zenoh endpoint to connect to (repeatable)"
    )
    parser.add_argument(
        "--listen", action="append", default=[], help="Zenoh endpoint to listen on (repeatable)"
    )
    parser.add_argument("--robot", help="republish under this robot name instead of the recorded")
    parser.add_argument("--topics", nargs="+", default=["*"], help="topics or patterns to replay")
    parser.add_argument(
        "--commands", action="store_true", help="also replay cmd/** topics (moves a live robot)"
    )
    parser.add_argument(
        "--wait", type=float, default=0.5, help="seconds to let subscribers connect first"
    )
    add_credential_arguments(parser)


def read(path: str | Path, topics: list[str] | None = None) -> Iterator[Recorded]:
    """The messages of a recording in log-time order, decoded to their Structs.

    A recording that was not closed cleanly (recorder killed, power cut) gives every complete
    message, with one warning saying so and how many were recovered.
    """
    patterns = topics or ["*"]
    recording = RecordingFile(path)
    items = [
        Recorded(e.channel.topic, e.value, e.message.log_time)
        for e in recording
        if any(fnmatch.fnmatchcase(type(e.value).TOPIC, p) for p in patterns)
    ]
    if not recording.sealed:
        log.warning(recording.describe())
    items.sort(key=lambda r: r.log_time)
    yield from items


def pace(log_times: list[int], speed: float) -> list[float]:
    """Seconds after the start at which each message is sent: recorded gaps divided by ``speed``."""
    if speed <= 0 or not math.isfinite(speed):
        raise ValueError(f"--speed: expected a finite factor > 0, found {speed}")
    if not log_times:
        return []
    first = log_times[0]
    return [(t - first) * 1e-9 / speed for t in log_times]


def rename(key: str, robot: str | None) -> str:
    """``climbd/<old>/<topic>`` under ``robot`` (unchanged when ``robot`` is None)."""
    if robot is None:
        return key
    _, _, rest = key.split("/", 2)
    return f"climbd/{robot}/{rest}"


class Replayer:
    """Publishes recorded messages on a Network, each with the QoS its topic has on a live robot."""

    def __init__(self, net) -> None:
        self.net = net
        self.publishers: dict[str, object] = {}
        self.sent = 0

    def publish(self, key: str, message) -> None:
        pub = self.publishers.get(key)
        if pub is None:
            robot = key.split("/")[1]
            pub = self.publishers[key] = self.net.publisher(type(message), robot)
        pub.put(message)
        self.sent += 1

    def run(
        self, items: list[Recorded], speed: float, robot: str | None, stop: threading.Event
    ) -> None:
        """Send ``items`` at their paced times until done or ``stop``."""
        offsets = pace([r.log_time for r in items], speed)
        start = time.monotonic()
        for item, offset in zip(items, offsets, strict=True):
            delay = start + offset - time.monotonic()
            if delay > 0 and stop.wait(delay):
                return
            if stop.is_set():
                return
            self.publish(rename(item.key, robot), item.message)


def main(args: argparse.Namespace) -> int:
    import json

    try:
        pace([], args.speed)
        items = [
            r
            for r in read(args.file, args.topics)
            if args.commands or not r.key.split("/", 2)[-1].startswith("cmd/")
        ]
        config = client_config(args, "replay")
        config.insert_json5("listen/endpoints", json.dumps(list(args.listen)))
    except (RecordingError, ValueError, AccessError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    try:
        net = Network(args.robot or "replay", config)
    except Exception as e:  # zenoh raises ZError for a bad endpoint or a port in use
        print(f"error: zenoh: {e}", file=sys.stderr)
        return 1
    replayer = Replayer(net)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    span = (items[-1].log_time - items[0].log_time) * 1e-9 if items else 0.0
    print(
        f"climbd: replaying {len(items)} messages ({span:.1f} s recorded) from {args.file} "
        f"at {args.speed:g}x",
        flush=True,
    )
    try:
        stop.wait(args.wait)
        replayer.run(items, args.speed, args.robot, stop)
        stop.wait(0.2)  # let the last puts leave before the session closes
    finally:
        net.close()
    print(f"climbd: replayed {replayer.sent} of {len(items)} messages", flush=True)
    return 0
