"""Topic batches: every log form read as decoded arrays, a bounded batch at a time.

``TopicReader(path).batches(topics)`` yields ``(topic, batch)`` pairs in (approximately) log-time
order, each batch a few tens of thousands of messages at most, never the whole log:

- bare MCAP files and the MCAP storage files of rosbag2 folders: whole chunks, decoded with
  numpy (``twincd.io.mcap_read`` and the decoders of ``twincd.io.cdr``);
- rosbag2 sqlite3: bulk SQL in timestamp order, decoded the same way;
- ROS 1 bags, compressed rosbag2 bags and anything else: rosbags' AnyReader, per message.

``watermark_ns`` says how far the log has been read: every wanted message with a log time
below it has been yielded. Joining topics by log time (labels) waits for it.
"""

from __future__ import annotations

import struct
from abc import ABC, abstractmethod
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import Any

import numpy as np

from twincd.errors import LogReadError, TopicError, TwincdError
from twincd.io.cdr import (
    BOOL,
    JOINT_STATE,
    CdrStats,
    decode_bools,
    decode_joint_states,
    typestore,
)
from twincd.io.mcap_read import MAGIC, McapDamage, McapFile
from twincd.io.sqlite_read import FETCH, Sqlite3Storage, SqliteDamage
from twincd.types import BoolArray, ByteArray, FloatArray, IntArray

STRING = "std_msgs/msg/String"
SUPPORTED = (JOINT_STATE, BOOL, STRING)
DEFAULT_BATCH = 16384  # messages decoded at once: 4× smaller peak memory than 65 536, as fast
_NS = 1_000_000_000
_END = 2**63 - 1  # the watermark once everything has been read


@dataclass(frozen=True)
class JointStateBatch:
    """JointState messages that share one name list (and array widths).

    ``stamp_ns`` is the raw header stamp (0 where the publisher left it empty). A ragged
    message (a filled array whose length differs from ``names``) keeps its own widths.
    """

    names: tuple[str, ...]
    log_time_ns: IntArray
    stamp_ns: IntArray
    position: FloatArray  # (n, k)
    velocity: FloatArray  # (n, k), or (n, 0) for messages without velocity
    effort: FloatArray  # (n, k), or (n, 0)

    def __len__(self) -> int:
        return len(self.log_time_ns)


@dataclass(frozen=True)
class BoolBatch:
    """std_msgs/msg/Bool messages."""

    log_time_ns: IntArray
    value: BoolArray

    def __len__(self) -> int:
        return len(self.log_time_ns)


@dataclass(frozen=True)
class StringBatch:
    """std_msgs/msg/String messages (rare: decoded by rosbags)."""

    log_time_ns: IntArray
    values: list[str]

    def __len__(self) -> int:
        return len(self.log_time_ns)


Batch = JointStateBatch | BoolBatch | StringBatch


@dataclass(frozen=True)
class _Raw:
    """Undecoded CDR messages of one topic, all of one payload length."""

    topic: str
    log_time_ns: IntArray
    payloads: ByteArray


class _Damage(Exception):
    """Reading stopped at a damaged part of the log (``where`` says what and where)."""


def first_line(exc: BaseException) -> str:
    """An exception's first line of text (its type name when it has none)."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def open_reader(path: Path) -> Any:
    """An opened rosbags AnyReader, or one clear LogReadError."""
    from rosbags.highlevel import AnyReader

    _refuse_non_logs(path)
    try:
        # Humble-era rosbag2 bags store no message definitions: bring the standard ones
        reader = AnyReader([path], default_typestore=typestore())
        reader.open()
    except Exception as exc:  # the I/O edge: every reader failure becomes one line
        raise LogReadError(
            f"cannot read log: {first_line(exc)}",
            str(path),
            "check that it is a rosbag2 folder, an MCAP file or a ROS 1 bag and not truncated",
        ) from exc
    return reader


def _refuse_non_logs(path: Path) -> None:
    if not path.exists():
        raise LogReadError("no such file or folder", str(path), "check the path")
    if path.is_file() and path.stat().st_size == 0:
        raise LogReadError("empty file", str(path), "record the log again or remove it")
    if path.is_file() and path.suffix == ".db3":
        raise LogReadError(
            "a bare .db3 file is not a log", str(path), "give the rosbag2 folder that holds it"
        )


# ---------------------------------------------------------------- backends


class _Backend(ABC):
    """One way of reading a log: its topics, and a stream of raw messages or batches."""

    topics: dict[str, str]
    hint = "re-record it or cut the damaged part"
    damage: str | None = None  # found while opening

    @abstractmethod
    def items(self, topics: Sequence[str], batch_size: int) -> Iterator[Any]:
        """``_Raw`` messages, ready ``(topic, Batch)`` pairs, and watermarks (``int``).

        A watermark is yielded once every wanted message with an earlier log time has been;
        ``_Damage`` is raised where reading cannot go on.
        """

    def close(self) -> None:  # noqa: B027 - most backends hold nothing to release
        """Release files and connections."""


class _McapBackend(_Backend):
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
                raise _Damage(_where(f, exc, len(self.files) > 1)) from exc
            for raw in raws:
                yield _Raw(names[i][raw.channel_id], raw.log_time_ns, raw.payloads)
            # chunks are visited by start time: later ones hold nothing older than the next
            yield refs[k + 1][0] if k + 1 < len(refs) else _END

    def close(self) -> None:
        for f in self.files:
            f.close()


def _where(f: McapFile, exc: McapDamage, name: bool) -> str:
    at = f"{exc.what} at byte {exc.position:,} of {f.size:,}"
    return f"{f.path.name}: {at}" if name else at


class _SqliteBackend(_Backend):
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
                yield item if isinstance(item, int) else _Raw(*item)
        except SqliteDamage as exc:
            raise _Damage(first_line(exc)) from exc
        yield _END

    def close(self) -> None:
        self.storage.close()


class _RosbagsBackend(_Backend):
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
            raise _Damage(first_line(exc)) from exc
        self.stats.add(fallback=pending.count)
        yield from pending.flush()
        yield _END

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
            if msgtype == BOOL:
                out.append((topic, BoolBatch(times, np.array([bool(m.data) for _, m in items]))))
            else:
                out.append((topic, StringBatch(times, [str(m.data) for _, m in items])))
        self.joint, self.other, self.count = {}, {}, 0
        out.sort(key=lambda tb: int(tb[1].log_time_ns[0]))
        return iter(out)


def _stack(rows: list[Any], k: int) -> FloatArray:
    out = np.zeros((len(rows), k))
    for i, r in enumerate(rows):
        out[i] = r
    return out


def _rosbag2_storage(path: Path) -> tuple[str, list[Path]] | None:
    """(storage id, storage files) of an uncompressed rosbag2 folder whose files all exist;
    None sends the folder to rosbags (compressed bags, odd metadata: its errors are clear)."""
    from ruamel.yaml import YAML

    try:
        meta = YAML(typ="safe").load((path / "metadata.yaml").read_text())
        info = meta["rosbag2_bagfile_information"]
        mode = str(info.get("compression_mode") or "").lower()
        if mode not in ("", "none") or info.get("compression_format"):
            return None
        files = [path / PurePath(str(x)).name for x in info["relative_file_paths"]]
        storage = str(info["storage_identifier"])
    except Exception:  # rosbags reports bad metadata in its own words
        return None
    if not files or not all(f.is_file() for f in files):
        return None
    return storage, files


def _open_backend(path: Path, source: str, stats: CdrStats) -> _Backend:
    _refuse_non_logs(path)
    if path.is_file():
        with open(path, "rb") as f:
            head = f.read(len(MAGIC))
        if head == MAGIC:
            return _McapBackend([path], source)
        if path.suffix == ".mcap":
            raise LogReadError(
                "cannot read log: not an MCAP file (bad magic)",
                source,
                "check that it is an MCAP file and not damaged",
            )
        return _RosbagsBackend(path, stats)
    if (path / "metadata.yaml").is_file():
        storage = _rosbag2_storage(path)
        if storage is not None and storage[0] == "mcap":
            return _McapBackend(storage[1], source)
        if storage is not None and storage[0] == "sqlite3":
            return _SqliteBackend(storage[1], source)
    return _RosbagsBackend(path, stats)


# ---------------------------------------------------------------- the reader


class TopicReader:
    """Decoded batches of the topics of one log (a context manager).

    ``strict``: a truncated or corrupt log raises ``LogReadError``; otherwise reading stops at
    the damage and ``damage`` says what was read.
    """

    def __init__(self, path: str | Path, strict: bool = True, batch_size: int = DEFAULT_BATCH):
        self.path = Path(path)
        self.source = str(self.path)
        self.strict = strict
        self.batch_size = batch_size
        self.stats = CdrStats()
        self.watermark_ns = -(2**63)
        self.messages = 0  # yielded so far
        self.last_log_time_ns: int | None = None
        self._damage: str | None = None
        self._backend = _open_backend(self.path, self.source, self.stats)
        self.topics: dict[str, str] = dict(self._backend.topics)
        if self._backend.damage is not None:
            if not self.topics:  # nothing intact to read: an error, strict or not
                damage, self.strict = self._backend.damage, True
                self._damaged(damage)
            self._damaged(self._backend.damage)

    def __enter__(self) -> TopicReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._backend.close()

    @property
    def damage(self) -> str | None:
        """With strict=False: what is damaged and how much was read before it; else None."""
        if self._damage is None:
            return None
        upto = (
            f" up to log time {self.last_log_time_ns}" if self.last_log_time_ns is not None else ""
        )
        read = f"read {self.messages} message(s) of the wanted topics{upto}"
        fix = "; `mcap recover` can repair it" if isinstance(self._backend, _McapBackend) else ""
        return f"log is damaged: {self._damage}; {read}{fix}"

    def _damaged(self, where: str) -> None:
        if self.strict:
            self.close()
            raise LogReadError(f"cannot read damaged log: {where}", self.source, self._backend.hint)
        self._damage = self._damage or where

    def batches(self, topics: Sequence[str]) -> Iterator[tuple[str, Batch]]:
        """``(topic, batch)`` of the given topics in about log-time order; topics the log
        lacks are skipped. Each batch holds messages of one topic (and one JointState layout).
        """
        wanted = [t for t in dict.fromkeys(topics) if t in self.topics]
        for t in wanted:
            if self.topics[t] not in SUPPORTED:
                raise TopicError(
                    f"topic {t} is {self.topics[t]}, which twincd does not read",
                    self.source,
                    f"give a topic of type {', '.join(SUPPORTED)}",
                )
        pending: dict[tuple[str, int], list[_Raw]] = {}
        count = 0
        try:
            for item in self._backend.items(wanted, self.batch_size):
                if isinstance(item, int):
                    if count >= self.batch_size:
                        yield from self._flush(pending)
                        count = 0
                    if count == 0:  # everything before the mark has been yielded
                        self.watermark_ns = item
                elif isinstance(item, _Raw):
                    pending.setdefault((item.topic, item.payloads.shape[1]), []).append(item)
                    count += len(item.log_time_ns)
                    if count >= 4 * self.batch_size:  # a huge chunk: bound memory anyway
                        yield from self._flush(pending)
                        count = 0
                else:
                    yield self._note(*item)
        except _Damage as exc:
            yield from self._flush(pending)
            self._damaged(str(exc))
            self.watermark_ns = _END
            return
        yield from self._flush(pending)
        self.watermark_ns = _END

    def _note(self, topic: str, batch: Batch) -> tuple[str, Batch]:
        self.messages += len(batch)
        if len(batch):
            last = int(batch.log_time_ns.max())
            self.last_log_time_ns = max(last, self.last_log_time_ns or last)
        return topic, batch

    def _flush(self, pending: dict[tuple[str, int], list[_Raw]]) -> Iterator[tuple[str, Batch]]:
        out: list[tuple[str, Batch]] = []
        for key in list(pending):
            raws = pending.pop(key)  # let the pieces go before decoding: a lower peak
            log_time = np.concatenate([r.log_time_ns for r in raws])
            payloads = np.concatenate([r.payloads for r in raws])
            del raws
            out.extend((key[0], b) for b in self._decode(key[0], log_time, payloads))
        out.sort(key=lambda tb: int(tb[1].log_time_ns[0]))
        for topic, batch in out:
            yield self._note(topic, batch)

    def _decode(self, topic: str, log_time: IntArray, payloads: ByteArray) -> list[Batch]:
        msgtype = self.topics[topic]
        try:
            if msgtype == JOINT_STATE:
                return [
                    JointStateBatch(
                        g.names, log_time[g.rows], g.stamp_ns, g.position, g.velocity, g.effort
                    )
                    for g in decode_joint_states(payloads, self.stats)
                ]
            if msgtype == BOOL:
                return [BoolBatch(log_time, decode_bools(payloads, self.stats))]
            values = []
            for row in payloads:
                msg: Any = typestore().deserialize_cdr(row.tobytes(), STRING)
                values.append(str(msg.data))
            self.stats.add(fallback=len(values))
            return [StringBatch(log_time, values)]
        except TwincdError:
            raise
        except Exception as exc:  # a payload even rosbags cannot decode
            raise LogReadError(
                f"cannot decode a {msgtype} message: {first_line(exc)}",
                f"{self.source}, {topic} near log time {int(log_time[0])}",
                "the log is corrupt; re-record it",
            ) from exc
