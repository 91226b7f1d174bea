"""The ways of reading a log's topics, one per storage form, behind one interface: bare MCAP files
and rosbag2 MCAP folders (``twincd.io.mcap``, whole chunks), rosbag2 sqlite3 (``twincd.io.sqlite3``,
bulk SQL), and everything else (ROS 1 bags, compressed bags) through rosbags, per message.

``open_backend`` picks one from what the path holds.
"""

from __future__ import annotations

import struct
from abc import ABC, abstractmethod
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from twincd.errors import LogReadError
from twincd.io.cdr import JOINT_STATE, CdrStats
from twincd.io.mcap import MAGIC, McapDamage, McapFile
from twincd.io.sources import first_line, open_reader, refuse_non_logs, storage_of, unreadable
from twincd.io.sqlite3 import FETCH, Sqlite3Storage, SqliteDamage
from twincd.io.stream.batch import (
    END,
    Batch,
    Damage,
    JointStateBatch,
    RawTopic,
    message_batches,
)
from twincd.types import FloatArray

__all__ = ["Backend", "McapBackend", "open_backend"]

_NS = 1_000_000_000


class Backend(ABC):
    """One way of reading a log: its topics, and a stream of raw messages or batches."""

    topics: dict[str, str]
    hint = "re-record it or cut the damaged part"
    damage: str | None = None  # found while opening

    @abstractmethod
    def items(self, topics: Sequence[str], batch_size: int) -> Iterator[Any]:
        """``RawTopic`` messages, ready ``(topic, Batch)`` pairs, and watermarks (``int``).

        A watermark is yielded once every wanted message with an earlier log time has been;
        ``Damage`` is raised where reading cannot go on.
        """

    def close(self) -> None:  # noqa: B027 - most backends hold nothing to release
        """Release files and connections."""


class McapBackend(Backend):
    """Whole chunks of MCAP files, decoded with numpy; stops at the first damaged file."""

    hint = "read what is intact without strict reading, or repair it with `mcap recover`"

    def __init__(self, paths: Sequence[Path], source: str) -> None:
        self.files: list[McapFile] = []
        try:
            for p in paths:
                self.files.append(McapFile(p))
        except McapDamage as exc:
            self.close()
            raise LogReadError(
                f"cannot read log: {exc.what}",
                str(p),
                "check that it is an MCAP file (ros2 profile, cdr) and not truncated",
            ) from exc
        except OSError as exc:
            self.close()
            raise LogReadError(
                f"cannot read log: {exc.strerror}", str(p), "check the path"
            ) from exc
        self.topics = {}
        self.usable = len(self.files)
        for i, f in enumerate(self.files):
            for ch in f.channels.values():
                if ch.encoding == "cdr" and ch.msgtype:
                    self.topics.setdefault(ch.topic, ch.msgtype)
            if f.damage is not None:
                self.damage = _where(f, f.damage, len(self.files) > 1)
                self.usable = i + 1  # stop at the damage: later files are not read
                break

    def items(self, topics: Sequence[str], batch_size: int) -> Iterator[Any]:
        refs = []
        names: list[dict[int, str]] = []
        for i, f in enumerate(self.files[: self.usable]):
            ids = {
                c.id: c.topic
                for c in f.channels.values()
                if c.topic in topics and c.encoding == "cdr" and c.msgtype == self.topics[c.topic]
            }
            names.append(ids)
            wanted = frozenset(ids)
            for ref in f.chunks:
                if wanted and (ref.channels is None or ref.channels & wanted):
                    refs.append((ref.start_time, i, ref.offset, ref, wanted))
        refs.sort(key=lambda r: r[:3])
        for k, (_, i, _, ref, wanted) in enumerate(refs):
            f = self.files[i]
            try:
                raws = f.read_chunk(ref, wanted)
            except McapDamage as exc:
                raise Damage(_where(f, exc, len(self.files) > 1)) from exc
            for raw in raws:
                yield RawTopic(names[i][raw.channel_id], raw.log_time_ns, raw.payloads)
            # chunks are visited by start time: later ones hold nothing older than the next
            yield refs[k + 1][0] if k + 1 < len(refs) else END

    def close(self) -> None:
        for f in self.files:
            f.close()


def _where(f: McapFile, exc: McapDamage, name: bool) -> str:
    at = f"{exc.what} at byte {exc.position:,} of {f.size:,}"
    return f"{f.path.name}: {at}" if name else at


class SqliteBackend(Backend):
    """Bulk SQL over the .db3 files of a rosbag2 folder."""

    def __init__(self, paths: Sequence[Path], source: str) -> None:
        try:
            self.storage = Sqlite3Storage(paths)
        except SqliteDamage as exc:
            raise LogReadError(
                f"cannot read log: {first_line(exc)}",
                source,
                "check that the rosbag2 folder is complete",
            ) from exc
        self.topics = self.storage.topics

    def items(self, topics: Sequence[str], batch_size: int) -> Iterator[Any]:
        try:
            for item in self.storage.read(topics, min(FETCH, batch_size)):
                yield item if isinstance(item, int) else RawTopic(*item)
        except SqliteDamage as exc:
            raise Damage(first_line(exc)) from exc
        yield END

    def close(self) -> None:
        self.storage.close()


class RosbagsBackend(Backend):
    """Per-message reading through rosbags (ROS 1 bags, compressed bags): the slow path."""

    def __init__(self, path: Path, stats: CdrStats) -> None:
        self.reader = open_reader(path)
        self.stats = stats
        self.topics = {}
        for c in self.reader.connections:
            self.topics.setdefault(c.topic, c.msgtype)

    def items(self, topics: Sequence[str], batch_size: int) -> Iterator[Any]:
        reader = self.reader
        conns = [
            c for c in reader.connections if c.topic in topics and c.msgtype == self.topics[c.topic]
        ]
        pending = _Pending()
        last = -1
        try:
            for conn, log_time, raw in reader.messages(connections=conns):
                pending.add(
                    conn.topic, conn.msgtype, log_time, reader.deserialize(raw, conn.msgtype)
                )
                last = log_time
                if pending.count >= batch_size:
                    self.stats.add(fallback=pending.count)
                    yield from pending.flush()
                    yield last  # rosbags yields in log-time order
        except (Exception, struct.error) as exc:  # damaged storage surfaces mid-iteration
            if pending.count:
                self.stats.add(fallback=pending.count)
                yield from pending.flush()
            raise Damage(first_line(exc)) from exc
        self.stats.add(fallback=pending.count)
        yield from pending.flush()
        yield END

    def close(self) -> None:
        self.reader.close()


class _Pending:
    """Deserialised messages waiting to become batches (rosbags path)."""

    def __init__(self) -> None:
        self.joint: dict[tuple[Any, ...], list[tuple[int, Any]]] = {}
        self.other: dict[tuple[str, str], list[tuple[int, Any]]] = {}
        self.count = 0

    def add(self, topic: str, msgtype: str, log_time: int, msg: Any) -> None:
        self.count += 1
        if msgtype == JOINT_STATE:
            key = (topic, tuple(msg.name), len(msg.position), len(msg.velocity), len(msg.effort))
            self.joint.setdefault(key, []).append((log_time, msg))
        else:
            self.other.setdefault((topic, msgtype), []).append((log_time, msg))

    def flush(self) -> Iterator[tuple[str, Batch]]:
        out: list[tuple[str, Batch]] = []
        for (topic, names, kp, kv, ke), items in self.joint.items():
            msgs = [m for _, m in items]
            out.append(
                (
                    topic,
                    JointStateBatch(
                        names,
                        np.array([t for t, _ in items], dtype=np.int64),
                        np.array(
                            [m.header.stamp.sec * _NS + m.header.stamp.nanosec for m in msgs],
                            dtype=np.int64,
                        ),
                        _stack([m.position for m in msgs], kp),
                        _stack([m.velocity for m in msgs], kv),
                        _stack([m.effort for m in msgs], ke),
                    ),
                )
            )
        for (topic, msgtype), items in self.other.items():
            times = np.array([t for t, _ in items], dtype=np.int64)
            out.extend((topic, b) for b in message_batches(msgtype, times, [m for _, m in items]))
        self.joint, self.other, self.count = {}, {}, 0
        out.sort(key=lambda tb: int(tb[1].log_time_ns[0]))
        return iter(out)


def _stack(rows: list[Any], k: int) -> FloatArray:
    out = np.zeros((len(rows), k))
    for i, r in enumerate(rows):
        out[i] = r
    return out


def open_backend(path: Path, source: str, stats: CdrStats) -> Backend:
    """The fastest backend that reads ``path``: MCAP, sqlite3, else rosbags. The storage files
    come from ``storage_of``, the one place that says what a log path stands for. A path this
    user may not read is one ``LogReadError`` that names it."""
    try:
        return _open_backend(path, source, stats)
    except PermissionError as exc:
        raise unreadable(exc, path) from exc


def _open_backend(path: Path, source: str, stats: CdrStats) -> Backend:
    refuse_non_logs(path)
    if path.is_file():
        with open(path, "rb") as f:
            head = f.read(len(MAGIC))
        if head == MAGIC:
            return McapBackend([path], source)
        if path.suffix == ".mcap":
            raise LogReadError(
                "cannot read log: not an MCAP file (bad magic)",
                source,
                "check that it is an MCAP file and not damaged",
            )
    storage = storage_of(path)
    if storage is None:
        return RosbagsBackend(path, stats)
    storage.warn(source)
    if storage.storage == "mcap":
        return McapBackend(storage.files, source)
    if storage.storage == "sqlite3":
        return SqliteBackend(storage.files, source)
    return RosbagsBackend(path, stats)


# ---------------------------------------------------------------- the reader
