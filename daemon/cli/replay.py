"""``climbd replay``: republish an MCAP recording on the network at real or chosen speed.

Messages go out in log-time order, each at ``(log_time - first) / speed`` after the start,
on the key it was recorded under (or under ``--robot NEW``), as the same msgpack payload a
live robot sends, so perception, behaviours and ``climbd top`` run on recorded data unchanged.
Command topics (``cmd/**``) are left out unless ``--commands`` is given: replaying an
operator's motion or mode requests onto a live robot would move it.
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import msgspec

from climbd.daemon.cli.client import add_credential_arguments, client_config
from climbd.daemon.cli.record import SCHEMA_PREFIX
from climbd.daemon.contract.messages import ALL_MESSAGES
from climbd.daemon.runtime.access import AccessError
from climbd.daemon.runtime.network import Network


class RecordingError(ValueError):
    """A file that cannot be replayed; the message names file and channel."""


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


def restore_nan(value, info):
    """``value`` decoded from JSON with ``null`` back to NaN wherever ``info`` expects a float.

    JSON has no NaN, so ``climbd record`` stores NaN floats as null; fields that may be None
    (``float | None``) keep their null.
    """
    from msgspec import inspect as mi

    if isinstance(info, mi.FloatType):
        return math.nan if value is None else value
    if isinstance(info, mi.StructType) and isinstance(value, dict):
        fields = {f.encode_name: f.type for f in info.fields}
        return {k: restore_nan(v, fields[k]) if k in fields else v for k, v in value.items()}
    if isinstance(info, (mi.ListType, mi.VarTupleType)) and isinstance(value, list):
        return [restore_nan(v, info.item_type) for v in value]
    if isinstance(info, mi.DictType) and isinstance(value, dict):
        return {k: restore_nan(v, info.value_type) for k, v in value.items()}
    return value


def from_json(data: bytes, message: type):
    """Decode one recorded JSON payload as ``message`` (NaN restored, schema checked)."""
    obj = msgspec.json.decode(data)
    return msgspec.convert(restore_nan(obj, msgspec.inspect.type_info(message)), message)


def read(path: str | Path, topics: list[str] | None = None) -> Iterator[Recorded]:
    """The messages of a recording in log-time order, decoded to their Structs."""
    import fnmatch

    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    types = {SCHEMA_PREFIX + m.__name__: m for m in ALL_MESSAGES}
    patterns = topics or ["*"]
    path = Path(path)
    try:
        f = open(path, "rb")  # noqa: SIM115 - closed below, also when the generator is dropped
    except OSError as e:
        raise RecordingError(f"{path}: {e.strerror or e}") from None
    with f:
        try:
            for schema, channel, msg in make_reader(f).iter_messages(log_time_order=True):
                if schema is None or schema.name not in types:
                    name = schema.name if schema is not None else "none"
                    raise RecordingError(
                        f"{path}: channel {channel.topic}: schema {name!r} is not a climbd message"
                    )
                m = types[schema.name]
                if not any(fnmatch.fnmatchcase(m.TOPIC, p) for p in patterns):
                    continue
                try:
                    value = from_json(msg.data, m)
                except (msgspec.DecodeError, msgspec.ValidationError) as e:
                    raise RecordingError(
                        f"{path}: channel {channel.topic}, message {msg.sequence}: {e}"
                    ) from None
                yield Recorded(channel.topic, value, msg.log_time)
        except (McapError, ValueError, EOFError) as e:
            if isinstance(e, RecordingError):
                raise
            raise RecordingError(f"{path}: not a readable MCAP file: {e}") from None


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
