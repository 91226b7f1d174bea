"""MCAP output: copy a log losslessly and add twincd's channels, or write a new log (DESIGN §3).

Output is always a bare ros2-profile MCAP with ``ros2msg`` schemas, ``cdr`` messages and an
``offered_qos_profiles`` entry on every channel. It is written to a temporary file beside the
target and renamed into place, so an interrupted run leaves nothing partial behind.

Sources:
- MCAP (bare, or the storage files of a rosbag2 folder): every record passes through raw —
  schema, channel metadata, log time, publish time, sequence and bytes unchanged.
- rosbag2 sqlite3: raw CDR bytes pass through; publish time is the log time (sqlite3 keeps one).
- ROS 1 bag: messages are converted to CDR (the container format forces it); times kept.
"""

from __future__ import annotations

import contextlib
import os
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from rosbags.convert.converter import migrate_bytes

from twincd import __version__
from twincd.errors import LogReadError, OutputError, TwincdError
from twincd.io.cdr import TYPESTORE

# What `ros2 bag record` offers for a default publisher (reliable, volatile, keep-last).
DEFAULT_QOS = (
    "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n"
    "  deadline:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  liveliness: 1\n"
    "  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  avoid_ros_namespace_conventions: false"
)
QOS_KEY = "offered_qos_profiles"


@dataclass
class NewTopic:
    """A channel to add: (log_time_ns, publish_time_ns, cdr_bytes) triples."""

    topic: str
    msgtype: str
    messages: Iterable[tuple[int, int, bytes]]


def check_writable(target: Path) -> None:
    """Fail early, before any work, when ``target`` cannot be written."""
    target = Path(target)
    if target.is_dir():
        raise OutputError("output is a folder", str(target), "give a file name")
    folder = target.parent
    if not folder.is_dir():
        raise OutputError(
            "cannot write output: its folder does not exist", str(target), "create the folder first"
        )
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(
            "cannot write output: its folder is not writable", str(target), "pick another path"
        )


@contextlib.contextmanager
def atomic_output(target: Path) -> Iterator[IO[bytes]]:
    """A binary stream that becomes ``target`` only if the block finishes without error."""
    target = Path(target)
    if target.is_dir():
        raise OutputError("output is a folder", str(target), "give a file name")
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        stream = open(tmp, "wb")  # noqa: SIM115 - closed below, before the rename
    except OSError as exc:
        raise OutputError(
            f"cannot write output: {exc.strerror}", str(target), "pick a writable output path"
        ) from exc
    try:
        with stream:
            yield stream
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


class _McapOut:
    """A ros2-profile MCAP writer that registers each schema and channel once."""

    def __init__(self, stream: IO[bytes]) -> None:
        self.writer = Writer(stream, compression=CompressionType.ZSTD)
        self.writer.start(profile="ros2", library=f"twincd {__version__}")
        self._schemas: dict[tuple[str, str, bytes], int] = {}
        self._channels: dict[tuple[str, int, str], int] = {}
        self._sequence: dict[int, int] = {}

    def schema(self, name: str, encoding: str, data: bytes) -> int:
        key = (name, encoding, data)
        if key not in self._schemas:
            self._schemas[key] = self.writer.register_schema(name, encoding, data)
        return self._schemas[key]

    def channel(self, topic: str, schema_id: int, encoding: str, metadata: dict[str, str]) -> int:
        key = (topic, schema_id, encoding)
        if key not in self._channels:
            meta = dict(metadata)
            meta.setdefault(QOS_KEY, DEFAULT_QOS)
            self._channels[key] = self.writer.register_channel(topic, encoding, schema_id, meta)
        return self._channels[key]

    def ros2_channel(self, topic: str, msgtype: str, qos: str = DEFAULT_QOS) -> int:
        msgdef, _ = TYPESTORE.generate_msgdef(msgtype, ros_version=2)
        schema_id = self.schema(msgtype, "ros2msg", msgdef.encode())
        return self.channel(topic, schema_id, "cdr", {QOS_KEY: qos})

    def message(self, channel_id: int, log_time: int, data: bytes, publish_time: int) -> None:
        seq = self._sequence.get(channel_id, 0)
        self._sequence[channel_id] = seq + 1
        self.writer.add_message(channel_id, log_time, data, publish_time, sequence=seq)

    def finish(self) -> None:
        self.writer.finish()  # type: ignore[no-untyped-call]


class McapLogWriter:
    """Write a new ros2 MCAP log (e.g. synthetic recordings) atomically.

    >>> with McapLogWriter(Path("run.mcap")) as out:          # doctest: +SKIP
    ...     ch = out.add_topic("/joint_states", "sensor_msgs/msg/JointState")
    ...     out.write(ch, log_time_ns, cdr_bytes)
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._ctx: contextlib.AbstractContextManager[IO[bytes]] | None = None
        self._out: _McapOut | None = None

    def __enter__(self) -> McapLogWriter:
        self._ctx = atomic_output(self.path)
        self._out = _McapOut(self._ctx.__enter__())
        return self

    def __exit__(self, *exc: Any) -> None:
        assert self._ctx is not None and self._out is not None
        if exc[0] is None:
            self._out.finish()
        self._ctx.__exit__(*exc)

    def add_topic(self, topic: str, msgtype: str) -> int:
        assert self._out is not None, "use McapLogWriter as a context manager"
        return self._out.ros2_channel(topic, msgtype)

    def write(
        self, channel_id: int, log_time_ns: int, data: bytes, publish_time_ns: int | None = None
    ) -> None:
        assert self._out is not None, "use McapLogWriter as a context manager"
        self._out.message(
            channel_id,
            log_time_ns,
            data,
            log_time_ns if publish_time_ns is None else publish_time_ns,
        )


def _mcap_storage_files(source: Path) -> list[Path] | None:
    """The MCAP files behind a source, or None when it is not MCAP-backed."""
    if source.is_file():
        return [source] if source.suffix == ".mcap" else None
    files = sorted(source.glob("*.mcap"))
    return files or None


def _copy_mcap(path: Path, out: _McapOut, replaced: frozenset[str]) -> None:
    try:
        with open(path, "rb") as stream:
            reader = make_reader(stream)
            # file order, not log-time order: log-time order queues whole chunks in memory
            for schema, channel, message in reader.iter_messages(log_time_order=False):
                if channel.topic in replaced:
                    continue
                if schema is None:
                    schema_id = 0
                else:
                    schema_id = out.schema(schema.name, schema.encoding, schema.data)
                channel_id = out.channel(
                    channel.topic, schema_id, channel.message_encoding, dict(channel.metadata)
                )
                out.writer.add_message(
                    channel_id,
                    message.log_time,
                    message.data,
                    message.publish_time,
                    sequence=message.sequence,
                )
            for record in reader.iter_metadata():
                if record.name != "rosbag2":  # it would no longer list the new topics
                    out.writer.add_metadata(record.name, dict(record.metadata))
            for att in reader.iter_attachments():
                out.writer.add_attachment(
                    att.create_time, att.log_time, att.name, att.media_type, att.data
                )
    except (McapError, struct.error, ValueError, EOFError) as exc:
        raise LogReadError(
            f"cannot copy MCAP: {type(exc).__name__}: {exc}".splitlines()[0],
            str(path),
            "check that the file is complete",
        ) from exc


def _copy_via_rosbags(source: Path, out: _McapOut, replaced: frozenset[str]) -> None:
    from rosbags.rosbag2.metadata import dump_qos_v8

    from twincd.io.logs import open_reader

    reader = open_reader(source)
    try:
        channels: dict[int, int] = {}
        # ROS 1 messages become ROS 2 ones (Header loses `seq`) with rosbags' own converter,
        # for every type the ROS 2 store knows; others keep the bag's own definition
        to_ros2: dict[str, tuple[Any, str]] = {}
        for conn in reader.connections:
            if conn.topic in replaced:
                continue
            store = reader.typestore
            if not reader.is2 and conn.msgtype in TYPESTORE.fielddefs:
                store = TYPESTORE
            to_ros2[conn.msgtype] = (store, conn.msgtype)
            try:
                msgdef, _ = store.generate_msgdef(conn.msgtype, ros_version=2)
            except Exception:  # a custom type an old bag did not describe: bytes still copy
                msgdef = ""
            schema_id = out.schema(conn.msgtype, "ros2msg", msgdef.encode())
            qos = getattr(conn.ext, QOS_KEY, None)
            meta = {QOS_KEY: dump_qos_v8(list(qos)) if qos else DEFAULT_QOS}
            channels[conn.id] = out.channel(conn.topic, schema_id, "cdr", meta)
        wanted = [c for c in reader.connections if c.id in channels]
        cache: dict[str, object] = {}
        for conn, log_time, raw in reader.messages(connections=wanted):
            data = raw
            if not reader.is2:
                store, msgtype = to_ros2[conn.msgtype]
                data = migrate_bytes(
                    reader.typestore,
                    store,
                    conn.msgtype,
                    msgtype,
                    cache,
                    raw,
                    src_is2=False,
                    dst_is2=True,
                )
            out.writer.add_message(channels[conn.id], log_time, bytes(data), log_time)
    except TwincdError:
        raise
    except Exception as exc:  # the I/O edge
        raise LogReadError(
            f"cannot copy log: {exc}".splitlines()[0], str(source), "check that it is complete"
        ) from exc
    finally:
        reader.close()


def write_augmented(source: Path, target: Path, new_topics: Iterable[NewTopic]) -> None:
    """Write ``target``: every message of ``source`` unchanged, plus ``new_topics``.

    A topic of ``new_topics`` that the source already has (a log simulated before) is replaced,
    not duplicated; every other input message is copied unchanged.

    ``target`` may equal a bare MCAP ``source`` (in-place rewrite): the copy is complete before
    the rename replaces it.
    """
    source, target = Path(source), Path(target)
    new_topics = list(new_topics)
    replaced = frozenset(t.topic for t in new_topics)
    with atomic_output(target) as stream:
        out = _McapOut(stream)
        mcap_files = _mcap_storage_files(source)
        if mcap_files is not None:
            for path in mcap_files:
                _copy_mcap(path, out, replaced)
        else:
            _copy_via_rosbags(source, out, replaced)
        for topic in new_topics:
            channel_id = out.ros2_channel(topic.topic, topic.msgtype)
            for log_time, publish_time, data in topic.messages:
                out.message(channel_id, log_time, data, publish_time)
        out.finish()
