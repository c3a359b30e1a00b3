"""``climbd record``: every topic of a robot (or a filtered set) to an MCAP file.

Encoding: each payload is stored as JSON (``message_encoding = "json"``) with the message's
JSON Schema from its msgspec Struct embedded (``schema encoding = "jsonschema"``, schema name
``climbd.<Type>``), so Foxglove and the ``mcap`` tools decode it without climbd. JSON has no
NaN: a NaN float is stored as ``null`` and ``climbd replay`` turns it back into NaN.

Zenoh callbacks only decode and enqueue; the main thread writes. Log times are the wall clock
at start plus monotonic time since, so a wall-clock jump never reorders a recording. A write
that fails (disk full, file size limit) stops the recording cleanly: the file is cut back to
its last whole record and sealed so it stays readable, the reason is printed, and nothing on
the bus notices (the recorder only subscribes).
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import fnmatch
import logging
import os
import queue
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from climbd.daemon.cli.client import add_credential_arguments, client_config
from climbd.daemon.contract.messages import ALL_MESSAGES, SchemaMismatch, decode, key
from climbd.daemon.runtime.access import AccessError

log = logging.getLogger("climbd.record")

FLUSH_PERIOD = 0.5
"""Seconds between flushes to disk: how much a power cut or a full disk can lose."""

QUEUE_LIMIT = 100_000
"""Messages waiting for the writer beyond which new ones are dropped (and counted)."""

SCHEMA_PREFIX = "climbd."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", required=True, help="robot name, or '*' for every robot")
    parser.add_argument(
        "--connect", action="append", default=[], help="Zenoh endpoint of the robot (repeatable)"
    )
    parser.add_argument("-o", "--output", help="MCAP file (default: climbd-<robot>-<time>.mcap)")
    parser.add_argument(
        "--topics",
        nargs="+",
        default=["*"],
        help="topics or patterns to record, e.g. state/joints 'features/*' (default: all)",
    )
    parser.add_argument("--duration", type=float, help="stop by itself after S seconds")
    add_credential_arguments(parser)


def select_topics(patterns: list[str]) -> list:
    """Message types whose topic matches one of ``patterns`` (fnmatch); an unknown one is named."""

    chosen = [m for m in ALL_MESSAGES if any(fnmatch.fnmatchcase(m.TOPIC, p) for p in patterns)]
    for p in patterns:
        if not any(fnmatch.fnmatchcase(m.TOPIC, p) for m in ALL_MESSAGES):
            known = ", ".join(m.TOPIC for m in ALL_MESSAGES)
            raise ValueError(f"--topics: {p!r} matches no topic (topics: {known})")
    return chosen


def json_schema(message: type) -> bytes:
    """The JSON Schema of one message type, self-contained (its ``$defs`` included).

    Encoded by msgspec, so a NaN default is written as null: strict JSON, as MCAP readers expect.
    """
    import msgspec

    return msgspec.json.encode(msgspec.json.schema(message))


@dataclass
class Sample:
    """One received message: its key, its type and the log time (ns since the epoch)."""

    key: str
    message: object
    log_time: int


class WriteFailed(OSError):
    """Writing the recording failed (disk full, size limit); the message names file and reason."""


class McapSink:
    """Writes Samples to an MCAP file, flushing every FLUSH_PERIOD; seals it on a write failure.

    Records are written unchunked, so every message ends at a known offset; on a failed write
    the file is cut back to the last whole record that fits together with a closing footer.
    """

    def __init__(self, path: Path, messages: list[type]) -> None:
        from mcap.writer import CompressionType, Writer

        self.path = path
        try:
            self.file: BinaryIO = open(path, "wb")  # noqa: SIM115 - closed by close()/fail()
        except OSError as e:
            raise WriteFailed(f"{path}: cannot create the recording: {e.strerror or e}") from None
        self.writer = Writer(self.file, compression=CompressionType.NONE, use_chunking=False)
        self.count = 0
        self.topics: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.schemas: dict[type, int] = {}
        self._marks: collections.deque[tuple[int, int]] = collections.deque(maxlen=4096)
        self._last_flush = time.monotonic()
        self._encoder = None
        try:
            self.writer.start(profile="climbd", library="climbd record")
            for m in messages:
                self.schemas[m] = self.writer.register_schema(
                    SCHEMA_PREFIX + m.__name__, "jsonschema", json_schema(m)
                )
            self.file.flush()
        except OSError as e:
            self.file.close()
            raise WriteFailed(f"{path}: cannot start the recording: {e.strerror or e}") from None
        self._first = self.file.tell()

    def write(self, sample: Sample) -> None:
        """Add one message (and its channel on first sight); raises WriteFailed once sealed."""
        import msgspec

        try:
            channel = self.channel(sample.key, type(sample.message))
            data = msgspec.json.encode(sample.message)
            self.writer.add_message(channel, sample.log_time, data, sample.log_time, self.count)
            self.count += 1
            self._marks.append((self.file.tell(), self.count))
            self.topics[sample.key] = self.topics.get(sample.key, 0) + 1
            if time.monotonic() - self._last_flush >= FLUSH_PERIOD:
                self.flush()
        except OSError as e:
            self.fail(e)

    def channel(self, key: str, message: type) -> int:
        """The channel id of ``key``, registered (with its schema) on first use."""
        channel = self.channels.get(key)
        if channel is None:
            meta = {"type": message.__name__, "topic": message.TOPIC}
            channel = self.channels[key] = self.writer.register_channel(
                key, "json", self.schemas[message], meta
            )
        return channel

    def flush(self) -> None:
        self.file.flush()
        self._last_flush = time.monotonic()

    def close(self) -> None:
        """Write the summary (schemas, channels, statistics, index) and close the file."""
        try:
            self.writer.finish()
            self.file.close()
        except OSError as e:
            self.fail(e)

    def fail(self, error: OSError) -> None:
        """Cut the file back to the last whole record that fits with a footer, seal, raise."""
        from mcap.data_stream import RecordBuilder
        from mcap.records import DataEnd, Footer
        from mcap.writer import MCAP0_MAGIC

        builder = RecordBuilder()
        DataEnd(data_section_crc=0).write(builder)
        Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(builder)
        trailer = builder.end() + MCAP0_MAGIC
        fd = self.file.fileno()
        on_disk = os.fstat(fd).st_size
        kept, sealed = 0, False
        for mark, count in reversed([(self._first, 0), *self._marks]):
            if mark > on_disk:
                continue
            try:
                os.ftruncate(fd, mark)
                sealed = os.pwrite(fd, trailer, mark) == len(trailer)
            except OSError:
                continue
            if sealed:
                kept = count
                break
        self.count = kept
        # The buffered writer still holds bytes it could not write: they go with the fd.
        os.close(fd)
        with contextlib.suppress(OSError):
            self.file.close()
        reason = error.strerror or str(error)
        state = "file sealed and readable" if sealed else "file could not be sealed"
        raise WriteFailed(f"{self.path}: {reason}; {kept} messages kept, {state}") from None


class Recorder:
    """Subscribes to the chosen topics of ``robot`` on a Zenoh session and feeds an McapSink."""

    def __init__(self, session, robot: str, messages: list[type]) -> None:
        self.session = session
        self.robot = robot
        self.messages = messages
        self.queue: queue.SimpleQueue[Sample] = queue.SimpleQueue()
        self.dropped = 0
        self.decode_errors = 0
        self._lock = threading.Lock()
        self._wall0 = time.time_ns()
        self._mono0 = time.monotonic_ns()
        self._subscribers = []

    def log_time(self) -> int:
        """Nanoseconds since the epoch, advancing monotonically from the start of the recording."""
        return self._wall0 + time.monotonic_ns() - self._mono0

    def start(self) -> None:
        for m in self.messages:
            self._subscribers.append(
                self.session.declare_subscriber(key(self.robot, m), self._handler(m))
            )

    def _handler(self, message: type):
        import msgspec

        def on_sample(sample) -> None:
            try:
                msg = decode(sample.payload.to_bytes(), message)
            except (msgspec.DecodeError, msgspec.ValidationError, SchemaMismatch):
                with self._lock:
                    self.decode_errors += 1
                return
            if self.queue.qsize() >= QUEUE_LIMIT:
                with self._lock:
                    self.dropped += 1
                return
            self.queue.put(Sample(str(sample.key_expr), msg, self.log_time()))

        return on_sample

    def stop(self) -> None:
        for s in self._subscribers:
            s.undeclare()
        self._subscribers.clear()

    def drain(self, sink: McapSink, stop: threading.Event, until: float | None) -> None:
        """Write queued samples until ``stop`` or ``until`` (monotonic); then what is queued."""
        while not stop.is_set() and (until is None or time.monotonic() < until):
            try:
                sample = self.queue.get(timeout=0.1)
            except queue.Empty:
                sink.flush()
                continue
            sink.write(sample)
        self.stop()
        while True:
            try:
                sink.write(self.queue.get_nowait())
            except queue.Empty:
                return


def default_output(robot: str) -> Path:
    name = "all" if robot == "*" else robot
    return Path(f"climbd-{name}-{time.strftime('%Y%m%d-%H%M%S')}.mcap")


def main(args: argparse.Namespace) -> int:
    import zenoh

    try:
        messages = select_topics(args.topics)
        config = client_config(args, "record")
    except (ValueError, AccessError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    path = Path(args.output) if args.output else default_output(args.robot)
    try:
        sink = McapSink(path, messages)
    except (WriteFailed, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    if args.robot != "*":
        try:
            for m in messages:
                sink.channel(key(args.robot, m), m)
        except OSError as e:
            print(f"error: {path}: {e.strerror or e}", file=sys.stderr)
            return 1
    session = zenoh.open(config)
    recorder = Recorder(session, args.robot, messages)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    # A file size limit then fails the write (EFBIG), handled like a full disk, not a kill.
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    recorder.start()
    print(f"climbd: recording {len(messages)} topics of {args.robot} to {path}", flush=True)
    until = time.monotonic() + args.duration if args.duration else None
    code = 0
    try:
        recorder.drain(sink, stop, until)
        sink.close()
    except WriteFailed as e:
        print(f"climbd: recording stopped: {e}", file=sys.stderr, flush=True)
        code = 1
    finally:
        recorder.stop()
        session.close()
    topics = "" if code else ", ".join(f"{k} {n}" for k, n in sorted(sink.topics.items()))
    print(
        f"climbd: recorded {sink.count} messages on {len(sink.topics)} topics to {path}"
        f"{'; ' + topics if topics else ''}; dropped {recorder.dropped}, "
        f"undecodable {recorder.decode_errors}",
        flush=True,
    )
    return code
