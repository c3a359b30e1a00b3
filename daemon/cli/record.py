"""``climbd record``: every topic of a robot (or a filtered set) to an MCAP file.

Encoding: each payload is stored as JSON (``message_encoding = "json"``) with the message's
JSON Schema from its msgspec Struct embedded (``schema encoding = "jsonschema"``, schema name
``climbd.<Type>``), so Foxglove and the ``mcap`` tools decode it without climbd. JSON has no
NaN: a NaN float is stored as ``null`` and ``climbd replay`` turns it back into NaN.

Zenoh callbacks only decode and enqueue; the main thread writes, and flushes and fsyncs every
FLUSH_PERIOD. Log times are the wall clock at start plus monotonic time since, so a wall-clock
jump never reorders a recording. A write that fails (disk full, file size limit) stops the
recording cleanly: the file is cut back to its last whole record and sealed so it stays
readable, the reason is printed, and nothing on the bus notices (the recorder only subscribes).
A recording that cannot start (full disk, unwritable path) or keeps no message is removed.

With ``--scene`` the recording also holds the robot drawn in Foxglove's well-known schemas, on
the topics and with the schemas ``climbd view`` serves live (``/tf``, ``/robot``, ``/joists``,
``/holds``, ``/stairs``, ``/truss``, ``/elevation``, ``/mode``, ``/health``, ``/loop``,
``/estop``, and once drawn ``/plan``, ``/grasp`` and the twin's ``/truth/…``; see
daemon/runtime/scene.py): the file opened in Foxglove shows the 3-D scene. They are derived
from the raw topics as they are written (transforms at ``--scene-rate``, stamped with the log
time), need the robot's profile (``--profile``, default the stock one of ``--robot``), and
carry the channel metadata ``scene``; ``climbd replay`` leaves them out (it republishes the raw
topics, which ``climbd view`` then draws again).

A recorder killed outright (kill -9, power cut) leaves a file without its footer:
RecordingFile reads every complete message of it, and ``climbd record --recover FILE`` rewrites
those into a sealed, indexed MCAP.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import fnmatch
import logging
import math
import os
import queue
import signal
import struct
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, NamedTuple

import msgspec

from climbd.daemon.cli.client import add_credential_arguments, client_config, find_profile
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import ALL_MESSAGES, SchemaMismatch, decode, key
from climbd.daemon.runtime import scene
from climbd.daemon.runtime.access import AccessError

if TYPE_CHECKING:
    from mcap.records import Channel, Message, Schema

log = logging.getLogger("climbd.record")

FLUSH_PERIOD = 0.5
"""Seconds between flush + fsync to disk: how much a crash, power cut or full disk can lose."""

QUEUE_LIMIT = 100_000
"""Messages waiting for the writer beyond which new ones are dropped (and counted)."""

SCHEMA_PREFIX = "climbd."

MAGIC = b"\x89MCAP0\r\n"
"""The 8 bytes an MCAP file starts and ends with."""

FOOTER_SIZE = 1 + 8 + 20
"""Bytes of a Footer record: opcode, length, summary start, summary offset start, CRC."""

SCENE = "scene"
"""Channel metadata key of the scene's channels (``--scene``): derived, not climbd messages."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", help="robot name, or '*' for every robot (required to record)")
    parser.add_argument(
        "--connect", action="append", default=[], help="Zenoh endpoint of the robot (repeatable)"
    )
    parser.add_argument(
        "-o",
        "--output",
        help="MCAP file (default: climbd-<robot>-<time>.mcap; with --recover FILE.recovered.mcap)",
    )
    parser.add_argument(
        "--topics",
        nargs="+",
        default=["*"],
        help="topics or patterns to record, e.g. state/joints 'features/*' (default: all)",
    )
    parser.add_argument("--duration", type=float, help="stop by itself after S seconds")
    parser.add_argument(
        "--recover",
        metavar="FILE",
        help="rewrite the complete messages of a recording that was not closed cleanly "
        "(recorder killed, power cut) into a sealed, indexed MCAP, then exit",
    )
    parser.add_argument(
        "--scene",
        action="store_true",
        help="also write the robot as a Foxglove 3-D scene (the channels climbd view serves), "
        "drawn from the raw topics, which are then recorded too",
    )
    parser.add_argument(
        "--profile",
        help="with --scene: the robot's profile (default: the stock profile robots/<robot>.toml)",
    )
    parser.add_argument(
        "--scene-rate", type=float, default=30.0, help="with --scene: transforms per second"
    )
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
    return msgspec.json.encode(msgspec.json.schema(message))


def restore_nan(value, info):
    """``value`` decoded from JSON with ``null`` back to NaN wherever ``info`` expects a float.

    JSON has no NaN, so ``climbd record`` stores NaN floats as null; fields that may be None
    (``float | None``) keep their null.
    """
    from msgspec import inspect as mi

    if isinstance(info, mi.FloatType):
        return math.nan if value is None else value
    if isinstance(info, mi.UnionType) and isinstance(value, dict):  # a Struct or None
        structs = [t for t in info.types if isinstance(t, mi.StructType)]
        return restore_nan(value, structs[0]) if len(structs) == 1 else value
    if isinstance(info, mi.StructType) and isinstance(value, dict):
        fields = {f.encode_name: f.type for f in info.fields}
        return {k: restore_nan(v, fields[k]) if k in fields else v for k, v in value.items()}
    if isinstance(info, (mi.ListType, mi.VarTupleType)) and isinstance(value, list):
        return [restore_nan(v, info.item_type) for v in value]
    if isinstance(info, mi.DictType) and isinstance(value, dict):
        return {k: restore_nan(v, info.value_type) for k, v in value.items()}
    return value


def from_json(data: bytes, message: type):
    """Decode one recorded JSON payload as ``message`` (NaN restored, schema checked); JSON
    nested past Python's recursion limit is a DecodeError like any other malformed payload."""
    try:
        obj = msgspec.json.decode(data)
    except RecursionError:
        raise msgspec.DecodeError("JSON nested too deeply") from None
    return msgspec.convert(restore_nan(obj, msgspec.inspect.type_info(message)), message)


@dataclass
class Sample:
    """One received message: its key, its type and the log time (ns since the epoch)."""

    key: str
    message: object
    log_time: int


class WriteFailed(OSError):
    """Writing the recording failed (disk full, size limit); the message names file and reason."""


class RecordingError(ValueError):
    """A file that cannot be read as a recording; the message names file and channel."""


class McapSink:
    """Writes Samples to an MCAP file, flushing and fsyncing every FLUSH_PERIOD; seals it on a
    write failure.

    Records are written unchunked, so every message ends at a known offset; on a failed write
    the file is cut back to the last whole record that fits together with a closing footer.
    With ``robot`` the channels of its topics are declared up front, silent ones included.
    With ``scene_stream`` each message written also feeds it, and what it draws goes on the scene's
    channels (declared up front) with the message's log time.
    """

    def __init__(
        self,
        path: Path,
        messages: list[type],
        robot: str | None = None,
        scene_stream: scene.SceneStream | None = None,
    ) -> None:
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        try:
            self.file: BinaryIO = open(self.path, "wb")  # noqa: SIM115 - closed by close()/fail()
        except OSError as e:
            raise WriteFailed(f"{path}: cannot create the recording: {e.strerror or e}") from None
        self.writer = Writer(self.file, compression=CompressionType.NONE, use_chunking=False)
        self.count = 0
        self.topics: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.schemas: dict[type, int] = {}
        self.scene = scene_stream
        self.scene_channels: dict[str, int] = {}
        self.scene_topics: dict[str, int] = {}
        self._marks: collections.deque[tuple[int, int]] = collections.deque(maxlen=4096)
        self._last_flush = time.monotonic()
        try:
            self._start(messages, robot)
        except OSError as e:
            self._discard()
            raise WriteFailed(f"{path}: cannot start the recording: {e.strerror or e}") from None
        self._first = self.file.tell()

    def _start(self, messages: list[type], robot: str | None) -> None:
        """Write the header, the schemas (and ``robot``'s channels) and sync them to disk, so a
        full disk or size limit shows now rather than after the recording has begun.

        The writer holds schemas and channels back until the next record it writes itself: a
        metadata record naming robot and topics is that record.
        """
        self.writer.start(profile="climbd", library="climbd record")
        for m in messages:
            self.schemas[m] = self.writer.register_schema(
                SCHEMA_PREFIX + m.__name__, "jsonschema", json_schema(m)
            )
        if robot is not None:
            for m in messages:
                self.channel(key(robot, m), m)
        info = {"robot": robot or "*", "topics": " ".join(m.TOPIC for m in messages)}
        if self.scene is not None:
            self._start_scene(robot or "*")
            info[SCENE] = self.scene.robot.profile.name
        self.writer.add_metadata("climbd", info)
        self.file.flush()
        os.fsync(self.file.fileno())

    def _start_scene(self, robot: str) -> None:
        """Declare the scene's schemas and channels (``scene.TOPICS``), as the view does; an
        optional one (``scene.OPTIONAL_TOPICS``) is declared when first drawn."""
        self._scene_robot = robot
        self._scene_schemas: dict[tuple[str, str, bytes], int] = {}
        for topic in scene.TOPICS:
            self._scene_channel(topic)

    def _scene_channel(self, topic: str) -> int:
        declared = scene.channel_schema(topic)
        schema = declared[:3]
        if schema not in self._scene_schemas:
            self._scene_schemas[schema] = self.writer.register_schema(*schema)
        self.scene_channels[topic] = self.writer.register_channel(
            topic,
            declared.message_encoding,
            self._scene_schemas[schema],
            {SCENE: "foxglove", "robot": self._scene_robot},
        )
        self.scene_topics[topic] = 0
        return self.scene_channels[topic]

    def write(self, sample: Sample) -> None:
        """Add one message (and its channel on first sight), and what the scene draws of it;
        raises WriteFailed once sealed."""
        try:
            channel = self.channel(sample.key, type(sample.message))
            data = msgspec.json.encode(sample.message)
            self.writer.add_message(channel, sample.log_time, data, sample.log_time, self.count)
            if self.scene is not None:
                self._write_scene(sample)
        except OSError as e:
            self.fail(e)
        self.count += 1
        self._marks.append((self.file.tell(), self.count))
        self.topics[sample.key] = self.topics.get(sample.key, 0) + 1
        self.flush_due()

    def _write_scene(self, sample: Sample) -> None:
        t = sample.log_time
        for topic, out in self.scene.update((sample.message,), t, t * 1e-9):
            channel = self.scene_channels.get(topic)
            if channel is None:
                channel = self._scene_channel(topic)
            self.writer.add_message(channel, t, scene.payload(out), t, self.count)
            self.scene_topics[topic] += 1

    def channel(self, key: str, message: type) -> int:
        """The channel id of ``key``, registered (with its schema) on first use."""
        channel = self.channels.get(key)
        if channel is None:
            meta = {"type": message.__name__, "topic": message.TOPIC}
            channel = self.channels[key] = self.writer.register_channel(
                key, "json", self.schemas[message], meta
            )
        return channel

    def flush_due(self) -> None:
        """Flush and fsync if FLUSH_PERIOD has passed since the last time."""
        if time.monotonic() - self._last_flush >= FLUSH_PERIOD:
            self.flush()

    def flush(self) -> None:
        """Write what is buffered and fsync it: a crash or power cut then loses nothing of it."""
        try:
            self.file.flush()
            os.fsync(self.file.fileno())
        except OSError as e:
            self.fail(e)
        self._last_flush = time.monotonic()

    def close(self) -> None:
        """Write the summary (schemas, channels, statistics, index), sync and close the file."""
        try:
            self.writer.finish()
            self.file.flush()
            os.fsync(self.file.fileno())
            self.file.close()
        except OSError as e:
            self.fail(e)

    def fail(self, error: OSError) -> None:
        """Cut the file back to the last whole record that fits with a footer, seal, raise;
        a file left without any message is removed instead."""
        from mcap.data_stream import RecordBuilder
        from mcap.records import DataEnd, Footer

        builder = RecordBuilder()
        DataEnd(data_section_crc=0).write(builder)
        Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(builder)
        trailer = builder.end() + MAGIC
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
        with contextlib.suppress(OSError):
            os.fsync(fd)
        self.count = kept
        reason = error.strerror or str(error)
        if kept == 0:
            self._discard()
            raise WriteFailed(f"{self.path}: {reason}; no message kept, file removed") from None
        self._close_unflushed()
        state = "file sealed and readable" if sealed else "file could not be sealed"
        raise WriteFailed(f"{self.path}: {reason}; {kept} messages kept, {state}") from None

    def _close_unflushed(self) -> None:
        """Close the file dropping the bytes its buffer could not write.

        The descriptor is pointed at /dev/null first, so the buffer's last flush goes there and
        close() never writes to (or closes) a descriptor number another thread has reused.
        """
        null = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(null, self.file.fileno())
        finally:
            os.close(null)
        with contextlib.suppress(OSError):
            self.file.close()

    def _discard(self) -> None:
        """Close and remove a recording that could not start, so no empty file is left."""
        self._close_unflushed()
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()


class Entry(NamedTuple):
    """One complete message of a recording: its MCAP records and the decoded Struct (None for
    a message of the scene's channels)."""

    schema: Schema
    channel: Channel
    message: Message
    value: object


class RecordingFile:
    """The messages of a recording in file order, read to the end of its last complete record.

    A file that ends with its footer (sealed) is read strictly: any damage raises
    RecordingError. One that does not (recorder killed, power cut, still being written) is
    read up to the first record that is cut short or unreadable; ``reason`` then says where
    reading stopped and ``count`` how many messages were recovered. The scene's channels
    (``--scene``) are skipped, or with ``scene`` given as entries without a decoded value.
    """

    def __init__(self, path: str | Path, scene: bool = False) -> None:
        self.path = Path(path)
        self.scene = scene
        self.sealed = False
        self.reason = ""
        self.count = 0

    def describe(self) -> str:
        """One line: whether the file was closed cleanly, and how many messages were read."""
        if self.sealed:
            return f"{self.path}: {self.count} messages"
        return (
            f"{self.path}: not closed cleanly ({self.reason}); "
            f"recovered {self.count} complete messages"
        )

    def __iter__(self) -> Iterator[Entry]:
        try:
            f = open(self.path, "rb")  # noqa: SIM115 - closed below, also when the generator is dropped
        except OSError as e:
            raise RecordingError(f"{self.path}: {e.strerror or e}") from None
        with f:
            size = os.fstat(f.fileno()).st_size
            head = f.read(len(MAGIC))
            if not MAGIC.startswith(head):
                raise RecordingError(f"{self.path}: not an MCAP file")
            self.sealed = ends_sealed(f.fileno(), size)
            self.count = 0
            if len(head) < len(MAGIC):
                self._damaged("the file ends inside the MCAP header")
                return
            yield from self._entries(f, size)

    def _entries(self, f: BinaryIO, size: int) -> Iterator[Entry]:
        """The messages after the magic, one top-level record at a time (chunks broken up)."""
        from mcap.exceptions import McapError
        from mcap.records import Channel, Chunk, Footer, Message, Schema
        from mcap.stream_reader import StreamReader, breakup_chunk

        types = {SCHEMA_PREFIX + m.__name__: m for m in ALL_MESSAGES}
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        records = StreamReader(f, skip_magic=True, emit_chunks=True, record_size_limit=size).records
        while True:
            at = f.tell()
            cut = record_cut_short(f.fileno(), at, size)
            if cut:
                self._damaged(cut)
                return
            try:
                record = next(records)
                inner = breakup_chunk(record) if isinstance(record, Chunk) else [record]
            except (McapError, ValueError, struct.error, UnicodeDecodeError) as e:
                self._damaged(f"unreadable record at byte {at}: {e}")
                return
            for r in inner:
                if isinstance(r, Schema):
                    schemas[r.id] = r
                elif isinstance(r, Channel):
                    channels[r.id] = r
                elif isinstance(r, Message):
                    channel = channels.get(r.channel_id)
                    if channel is not None and SCENE in channel.metadata:
                        if self.scene and channel.schema_id in schemas:
                            self.count += 1
                            yield Entry(schemas[channel.schema_id], channel, r, None)
                        continue
                    entry = self._entry(r, at, schemas, channels, types)
                    if entry is None:
                        return
                    self.count += 1
                    yield entry
            if isinstance(record, Footer):
                if not self.sealed:
                    self._damaged(f"{size - f.tell()} bytes after the footer are not its magic")
                return

    def _entry(
        self,
        msg: Message,
        at: int,
        schemas: dict[int, Schema],
        channels: dict[int, Channel],
        types: dict[str, type],
    ) -> Entry | None:
        """``msg`` decoded as the climbd message its channel's schema names; None (reading
        stops) if it is damaged, RecordingError if it is not a climbd message at all."""
        channel = channels.get(msg.channel_id)
        if channel is None:
            self._damaged(f"message on unknown channel {msg.channel_id} at byte {at}")
            return None
        schema = schemas.get(channel.schema_id)
        if schema is None or schema.name not in types:
            name = schema.name if schema is not None else "none"
            raise RecordingError(
                f"{self.path}: channel {channel.topic}: schema {name!r} is not a climbd message"
            )
        try:
            value = from_json(msg.data, types[schema.name])
        except (msgspec.DecodeError, msgspec.ValidationError) as e:
            self._damaged(f"channel {channel.topic}, message {msg.sequence} at byte {at}: {e}")
            return None
        return Entry(schema, channel, msg, value)

    def _damaged(self, reason: str) -> None:
        """Stop reading at ``reason``: an error in a sealed file, the torn end of another."""
        if self.sealed:
            raise RecordingError(f"{self.path}: not a readable MCAP file: {reason}")
        self.reason = reason


def ends_sealed(fd: int, size: int) -> bool:
    """Whether the file ends with a Footer record and the closing magic, as a sealed MCAP does."""
    if size < 2 * len(MAGIC) + FOOTER_SIZE:
        return False
    tail = os.pread(fd, FOOTER_SIZE + len(MAGIC), size - FOOTER_SIZE - len(MAGIC))
    opcode, length = struct.unpack_from("<BQ", tail)
    return tail.endswith(MAGIC) and opcode == 0x02 and length == FOOTER_SIZE - 9


def record_cut_short(fd: int, at: int, size: int) -> str:
    """Why the file has no whole record at byte ``at`` ("" if it has one)."""
    if at >= size:
        return "the file ends without a footer"
    head = os.pread(fd, 9, at)
    if len(head) < 9:
        return f"the last record is cut short at byte {at}"
    _, length = struct.unpack("<BQ", head)
    if at + 9 + length > size:
        return f"the last record is cut short at byte {at}"
    return ""


def recovered_path(source: Path) -> Path:
    """Where ``--recover FILE`` writes by default: FILE with the suffix ``.recovered.mcap``."""
    return source.with_suffix(".recovered.mcap")


def recover(source: Path, target: Path) -> RecordingFile:
    """Rewrite the complete messages of ``source`` into a sealed, indexed MCAP at ``target``.

    Written under a temporary name and renamed once synced, so a failed recovery leaves no
    partial file; RecordingError if ``source`` holds no complete message.
    """
    if target.resolve() == source.resolve():
        raise RecordingError(f"{source}: the recovered recording needs another name (-o)")
    partial = target.with_name(target.name + ".partial")
    try:
        recording = _rewrite(source, partial)
        os.replace(partial, target)
    except OSError as e:
        partial.unlink(missing_ok=True)
        reason = e.strerror or str(e)
        raise WriteFailed(f"{target}: cannot write the recovered recording: {reason}") from None
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    return recording


def _rewrite(source: Path, target: Path) -> RecordingFile:
    """Copy the messages of ``source`` with their schemas and channels to a new, chunked MCAP."""
    from mcap.writer import CompressionType, Writer

    recording = RecordingFile(source, scene=True)
    with open(target, "wb") as f:
        writer = Writer(f, compression=CompressionType.NONE)
        writer.start(profile="climbd", library="climbd record --recover")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, msg, _ in recording:
            if channel.id not in channels:
                if schema.id not in schemas:
                    schemas[schema.id] = writer.register_schema(
                        schema.name, schema.encoding, schema.data
                    )
                channels[channel.id] = writer.register_channel(
                    channel.topic,
                    channel.message_encoding,
                    schemas[schema.id],
                    channel.metadata,
                )
            writer.add_message(
                channels[channel.id], msg.log_time, msg.data, msg.publish_time, msg.sequence
            )
        if recording.count == 0:
            raise RecordingError(f"{source}: no complete message to recover ({recording.reason})")
        writer.finish()
        f.flush()
        os.fsync(f.fileno())
    return recording


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
        """Write queued samples until ``stop`` or ``until`` (monotonic); then what is queued.

        Runs on the thread that owns the file, so the periodic flush + fsync happens here, also
        while no message arrives, never on a Zenoh callback thread.
        """
        while not stop.is_set() and (until is None or time.monotonic() < until):
            try:
                sample = self.queue.get(timeout=0.1)
            except queue.Empty:
                sink.flush_due()
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


def main_recover(args: argparse.Namespace) -> int:
    """``climbd record --recover FILE [-o OUT]``: print what was recovered; 1 if nothing was."""
    source = Path(args.recover)
    target = Path(args.output) if args.output else recovered_path(source)
    try:
        recording = recover(source, target)
    except (RecordingError, WriteFailed) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    state = "closed cleanly" if recording.sealed else f"not closed cleanly: {recording.reason}"
    print(
        f"climbd: recovered {recording.count} messages from {source} to {target}; "
        f"{source} was {state}",
        flush=True,
    )
    return 0


def main(args: argparse.Namespace) -> int:
    import zenoh

    # A file size limit fails a write (EFBIG), handled like a full disk, not a kill.
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    if args.recover:
        return main_recover(args)
    try:
        if not args.robot:
            raise ValueError("--robot is required to record (or --recover FILE)")
        messages = select_topics(args.topics)
        stream = scene_of(args) if args.scene else None
        if stream is not None:  # the scene is drawn from these: record them too
            messages = [m for m in ALL_MESSAGES if m in messages or m in scene.INPUTS]
        config = client_config(args, "record")
    except (ValueError, AccessError, profiles.ProfileError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    path = Path(args.output) if args.output else default_output(args.robot)
    try:
        sink = McapSink(path, messages, None if args.robot == "*" else args.robot, stream)
    except WriteFailed as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    session = zenoh.open(config)
    recorder = Recorder(session, args.robot, messages)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    recorder.start()
    drawn = f", with its scene on {len(scene.TOPICS)} channels" if stream is not None else ""
    print(f"climbd: recording {len(messages)} topics of {args.robot}{drawn} to {path}", flush=True)
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
    if stream is not None and not code:
        drawn = ", ".join(f"{k} {n}" for k, n in sink.scene_topics.items())
        topics += f"; scene: {sum(sink.scene_topics.values())} messages ({drawn})"
    print(
        f"climbd: recorded {sink.count} messages on {len(sink.topics)} topics to {path}"
        f"{'; ' + topics if topics else ''}; dropped {recorder.dropped}, "
        f"undecodable {recorder.decode_errors}",
        flush=True,
    )
    return code


def scene_of(args: argparse.Namespace) -> scene.SceneStream:
    """The scene of ``--scene``: the robot's profile, transforms at ``--scene-rate``; a drawing
    that fails is said once per topic on stderr."""
    if args.robot == "*":
        raise ValueError("--scene draws one robot: give its name with --robot")
    if not args.scene_rate > 0:
        raise ValueError(f"--scene-rate must be positive, found {args.scene_rate}")
    robot = scene.RobotScene(find_profile(args.robot, args.profile))

    def refused(text: str) -> None:
        print(f"climbd: {text}", file=sys.stderr, flush=True)

    return scene.SceneStream(robot, refused, tf_period=1.0 / args.scene_rate)
