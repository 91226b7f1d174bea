"""MCAP output: copy a log losslessly and add twincd's channels, or write a new log (contract:
Topics twincd writes).

Output is always a bare ros2-profile MCAP with ``ros2msg`` schemas, ``cdr`` messages and an
``offered_qos_profiles`` entry on every channel, written to a temporary file beside the target
and renamed into place (``twincd.io.atomic``), so an interrupted run leaves nothing behind.

Sources:
- MCAP (bare, or the storage files of a rosbag2 folder): Schema, Channel, Chunk and
  MessageIndex records pass through as they are, without decompression, so schema, channel
  metadata, log time, publish time, sequence and bytes stay unchanged. Only chunks that hold a
  replaced topic (a log simulated before), or whose channel ids must change (split rosbag2
  files numbering their channels differently, a channel without QoS metadata), are
  decompressed and rebuilt record by record.
- rosbag2 sqlite3 (and rosbag2 MCAP whose files or messages rosbag2 compressed): raw CDR bytes
  pass through rosbags; publish time is the log time (sqlite3 keeps one).
- ROS 1 bag: messages are converted to CDR (the container format forces it); times kept.

New channels are written in blocks: Message records are assembled with numpy, one structured
array per block, and each channel gets its own chunks (~1 MB uncompressed, zstd), which may
overlap the copied chunks in time; readers find them through the chunk index.

Records go through ``mcap.records`` wherever the library's serialisation does the job; only
the hot paths are hand-written: bulk Message and MessageIndex records, the headers of new
chunks, raw chunk pass-through.
"""

from __future__ import annotations

import contextlib
import functools
import io
import os
import re
import struct
import threading
import zlib
from collections import deque
from collections.abc import Callable, Collection, Iterable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path, PurePath
from types import TracebackType
from typing import IO, Any

import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Message,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from numpy.typing import NDArray

from twincd import __version__
from twincd.errors import LogReadError, OutputError, TwincdError
from twincd.io.atomic import MARKER, atomic_output, check_writable, output_error
from twincd.io.cdr import typestore
from twincd.io.mcap_read import McapDamage, chunk_records, records_before_cut

__all__ = [
    "DEFAULT_QOS",
    "QOS_KEY",
    "AugmentedMcap",
    "McapLogWriter",
    "NewTopic",
    "atomic_output",
    "check_writable",
    "write_augmented",
]

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

MAGIC = b"\x89MCAP0\r\n"
CHUNK_SIZE = 1 << 20  # uncompressed bytes per new chunk, as mcap's and rosbag2's writers do
ZSTD_LEVEL = 1  # float payloads: 2× as fast as zstd's default level 3 for 5-15 % larger chunks
_PREFIX = struct.Struct("<BQ")  # opcode, record length
_MESSAGE_HEAD = 31  # prefix + channel id, sequence, log time, publish time
# prefix, start and end time, uncompressed size and CRC, compression name, compressed size
_CHUNK_HEAD = struct.Struct("<BQQQQII4sQ")
_MESSAGE_FIELDS = [
    ("opcode", "u1"),
    ("length", "<u8"),
    ("channel", "<u2"),
    ("sequence", "<u4"),
    ("log_time", "<u8"),
    ("publish_time", "<u8"),
]
_HEAD_DTYPE = np.dtype(_MESSAGE_FIELDS)
_INDEX_DTYPE = np.dtype([("log_time", "<u8"), ("offset", "<u8")])
_BATCH = 8192  # messages buffered per channel by the per-message entry points
U64 = NDArray[np.uint64]
Times = NDArray[np.integer[Any]]  # integer nanoseconds, (n,)
Payloads = NDArray[np.uint8] | Sequence[bytes]
Buffer = bytes | memoryview

_WORKERS = max(1, min(2, (os.cpu_count() or 2) - 1))  # leave a core to the caller
_IN_FLIGHT = 2 * _WORKERS + 2  # chunks compressing or done but not yet written
_local = threading.local()


def _compress(data: Buffer) -> tuple[bytes, int]:
    """(zstd frame, CRC-32) of a chunk's records; runs on a worker thread."""
    compressor = getattr(_local, "zstd", None)
    if compressor is None:  # a compressor is not thread-safe: one per thread
        compressor = _local.zstd = zstandard.ZstdCompressor(level=ZSTD_LEVEL)
    return compressor.compress(data), zlib.crc32(data)


@dataclass
class NewTopic:
    """A channel to add: (log_time_ns, publish_time_ns, cdr_bytes) triples."""

    topic: str
    msgtype: str
    messages: Iterable[tuple[int, int, bytes]]


def _record_bytes(record: McapRecord) -> bytes:
    builder = RecordBuilder()
    record.write(builder)
    data: bytes = builder.end()  # type: ignore[no-untyped-call]
    return data


@functools.lru_cache(maxsize=64)
def _message_dtype(size: int) -> np.dtype[Any]:
    """A packed Message record with a fixed-size payload: one array row per record."""
    return np.dtype([*_MESSAGE_FIELDS, ("data", "u1", (size,))])


def _message_index(channel_id: int, log_time: U64, offset: U64) -> bytes:
    """A MessageIndex record (hand-written: mcap's packs each entry in Python)."""
    if len(log_time) > 1 and np.any(log_time[1:] < log_time[:-1]):
        order = np.argsort(log_time, kind="stable")  # readers expect entries in log-time order
        log_time, offset = log_time[order], offset[order]
    entries = np.empty(len(log_time), dtype=_INDEX_DTYPE)
    entries["log_time"] = log_time
    entries["offset"] = offset
    size = entries.nbytes
    head = struct.pack("<BQHI", Opcode.MESSAGE_INDEX, 6 + size, channel_id, size)
    return head + entries.tobytes()


class _Lane:
    """The pending chunk of one new channel: record bytes and their index entries."""

    __slots__ = ("count", "log_times", "offsets", "parts", "size")

    def __init__(self) -> None:
        self.clear()

    def clear(self) -> None:
        self.parts: list[NDArray[np.uint8]] = []
        self.log_times: list[U64] = []
        self.offsets: list[U64] = []
        self.size = 0
        self.count = 0

    def add(self, records: NDArray[np.uint8], log_time: U64, starts: U64) -> None:
        self.parts.append(records)
        self.log_times.append(log_time)
        self.offsets.append(starts + np.uint64(self.size))
        self.size += len(records)
        self.count += len(log_time)


class _Output:
    """The output file: data section written as it comes, summary kept for the end."""

    def __init__(self, stream: IO[bytes], where: str) -> None:
        self._stream = stream
        self._where = where
        self.offset = 0
        self._crc = 0
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self._schema_ids: dict[tuple[str, str, bytes], int] = {}
        self._channel_ids: dict[tuple[str, int, str, tuple[tuple[str, str], ...]], int] = {}
        self._reserved: set[int] = set()  # channel ids of dropped input channels: never reused
        self._declared: set[tuple[int, int]] = set()  # (opcode, id) written at top level
        self.chunk_indexes: list[ChunkIndex] = []
        self.metadata_indexes: list[MetadataIndex] = []
        self.attachment_indexes: list[AttachmentIndex] = []
        self.message_counts: dict[int, int] = {}
        self.start_time = 2**64 - 1
        self.end_time = 0
        self._lanes: dict[int, _Lane] = {}
        self._sequence: dict[int, int] = {}
        # chunks compress on worker threads (zstd releases the GIL) while the caller computes
        # the next block; they are written in submission order, at most _IN_FLIGHT pending
        self._pool = ThreadPoolExecutor(max_workers=_WORKERS, thread_name_prefix="twincd-zstd")
        self._pending: deque[tuple[Future[tuple[bytes, int]], int, dict[int, tuple[U64, U64]]]]
        self._pending = deque()
        self.raw(MAGIC)
        self.record(Header(profile="ros2", library=f"twincd {__version__}"))

    # ------------------------------------------------------------ bytes out

    def raw(self, data: bytes | memoryview) -> None:
        """Write ``data`` after every pending chunk, so that file order is call order."""
        self._drain()
        self._put(data)

    def _put(self, data: bytes | memoryview) -> None:
        try:
            self._stream.write(data)
        except OSError as exc:
            raise output_error(exc, Path(self._where)) from exc
        self._crc = zlib.crc32(data, self._crc)
        self.offset += len(data)

    def record(self, record: McapRecord) -> tuple[int, int]:
        """Write one record; its (offset, length)."""
        data = _record_bytes(record)
        self._drain()
        offset = self.offset
        self._put(data)
        return offset, len(data)

    def close(self) -> None:
        """Stop the compression threads (after ``finish``, or on an error)."""
        for future, _, _ in self._pending:
            future.cancel()
        self._pending.clear()
        self._pool.shutdown(wait=True)

    # ------------------------------------------------------------ schemas and channels

    def _free_id(self, wanted: int | None, used: Collection[int]) -> int:
        if wanted is not None and wanted != 0 and wanted not in used:
            return wanted
        new = max([0, *used]) + 1
        if new > 0xFFFF:
            raise OutputError("too many channels for one MCAP file", self._where, "split the log")
        return new

    def schema(self, name: str, encoding: str, data: bytes, wanted: int | None = None) -> int:
        key = (name, encoding, bytes(data))
        if key not in self._schema_ids:
            schema_id = self._free_id(wanted, self.schemas.keys())
            self.schemas[schema_id] = Schema(
                id=schema_id, data=key[2], encoding=encoding, name=name
            )
            self._schema_ids[key] = schema_id
        return self._schema_ids[key]

    def channel(
        self,
        topic: str,
        schema_id: int,
        encoding: str,
        metadata: dict[str, str],
        wanted: int | None = None,
    ) -> int:
        meta = dict(metadata)
        meta.setdefault(QOS_KEY, DEFAULT_QOS)
        key = (topic, schema_id, encoding, tuple(meta.items()))
        if key not in self._channel_ids:
            channel_id = self._free_id(wanted, self.channels.keys() | self._reserved)
            self.channels[channel_id] = Channel(
                id=channel_id,
                topic=topic,
                message_encoding=encoding,
                metadata=meta,
                schema_id=schema_id,
            )
            self._channel_ids[key] = channel_id
        return self._channel_ids[key]

    def ros2_channel(self, topic: str, msgtype: str) -> int:
        msgdef, _ = typestore().generate_msgdef(msgtype, ros_version=2)
        schema_id = self.schema(msgtype, "ros2msg", msgdef.encode())
        channel_id = self.channel(topic, schema_id, "cdr", {QOS_KEY: DEFAULT_QOS})
        self.declare(channel_id)
        return channel_id

    def reserve(self, channel_id: int) -> None:
        self._reserved.add(channel_id)

    def declare_schema(self, schema_id: int) -> None:
        if schema_id != 0 and (Opcode.SCHEMA, schema_id) not in self._declared:
            self.record(self.schemas[schema_id])
            self._declared.add((Opcode.SCHEMA, schema_id))

    def declare(self, channel_id: int) -> None:
        """Write the channel's records at top level, once, before any of its messages."""
        if (Opcode.CHANNEL, channel_id) not in self._declared:
            channel = self.channels[channel_id]
            self.declare_schema(channel.schema_id)
            self.record(channel)
            self._declared.add((Opcode.CHANNEL, channel_id))

    # ------------------------------------------------------------ other records

    def metadata(self, record: Metadata) -> None:
        offset, length = self.record(record)
        self.metadata_indexes.append(MetadataIndex(offset=offset, length=length, name=record.name))

    def attachment(self, raw: bytes, record: Attachment) -> None:
        self._drain()
        offset = self.offset
        self.raw(raw)  # as it is, CRC included
        self.attachment_indexes.append(
            AttachmentIndex(
                offset=offset,
                length=len(raw),
                log_time=record.log_time,
                create_time=record.create_time,
                data_size=len(record.data),
                name=record.name,
                media_type=record.media_type,
            )
        )

    def _count(self, channel_id: int, count: int, start: int, end: int) -> None:
        self.message_counts[channel_id] = self.message_counts.get(channel_id, 0) + count
        if count:
            self.start_time = min(self.start_time, start)
            self.end_time = max(self.end_time, end)

    # ------------------------------------------------------------ chunks

    def copy_chunk(self, body: bytes, indexes: Sequence[tuple[int, int, bytes]]) -> None:
        """Pass a chunk and its MessageIndex records (channel id, count, body) through raw."""
        start, end, usize, _crc, name_len = struct.unpack_from("<QQQII", body)
        compression = body[32 : 32 + name_len].decode()
        (csize,) = struct.unpack_from("<Q", body, 32 + name_len)
        self._drain()  # offsets below are final only after every pending chunk
        offset = self.offset
        self.raw(_PREFIX.pack(Opcode.CHUNK, len(body)))
        self.raw(body)
        index_start = self.offset
        offsets: dict[int, int] = {}
        for channel_id, count, index_body in indexes:
            offsets[channel_id] = self.offset
            self.raw(_PREFIX.pack(Opcode.MESSAGE_INDEX, len(index_body)))
            self.raw(index_body)
            self._count(channel_id, count, start, end)
        self.chunk_indexes.append(
            ChunkIndex(
                message_start_time=start,
                message_end_time=end,
                chunk_start_offset=offset,
                chunk_length=index_start - offset,
                message_index_offsets=offsets,
                message_index_length=self.offset - index_start,
                compression=compression,
                compressed_size=csize,
                uncompressed_size=usize,
            )
        )

    def write_chunk(self, data: Buffer, index: dict[int, tuple[U64, U64]]) -> None:
        """A new zstd chunk of ``data`` (records) with its index: channel → (log times, offsets)."""
        self._pending.append((self._pool.submit(_compress, data), memoryview(data).nbytes, index))
        while len(self._pending) > _IN_FLIGHT:
            self._write_next()

    def _drain(self) -> None:
        while self._pending:
            self._write_next()

    def _write_next(self) -> None:
        future, size, index = self._pending.popleft()
        compressed, crc = future.result()
        start = min(int(t.min()) for t, _ in index.values())
        end = max(int(t.max()) for t, _ in index.values())
        # the Chunk record by hand, header then data: mcap's Chunk.write would copy every
        # compressed chunk twice more (the fields as in mcap.records.Chunk.write)
        head = _CHUNK_HEAD.pack(
            Opcode.CHUNK, 44 + len(compressed), start, end, size, crc, 4, b"zstd", len(compressed)
        )
        offset = self.offset
        self._put(head)
        self._put(compressed)
        index_start = self.offset
        offsets: dict[int, int] = {}
        for channel_id, (log_time, starts) in sorted(index.items()):
            offsets[channel_id] = self.offset
            self._put(_message_index(channel_id, log_time, starts))
            self._count(channel_id, len(log_time), int(log_time.min()), int(log_time.max()))
        self.chunk_indexes.append(
            ChunkIndex(
                message_start_time=start,
                message_end_time=end,
                chunk_start_offset=offset,
                chunk_length=index_start - offset,
                message_index_offsets=offsets,
                message_index_length=self.offset - index_start,
                compression="zstd",
                compressed_size=len(compressed),
                uncompressed_size=size,
            )
        )

    # ------------------------------------------------------------ new messages (the hot path)

    def append(
        self,
        channel_id: int,
        log_time: Times,
        payloads: Payloads,
        publish_time: Times | None = None,
        sequence: NDArray[np.uint32] | None = None,
    ) -> None:
        """Messages of one channel, in blocks: no Python work per message for fixed sizes."""
        if isinstance(payloads, np.ndarray) and (payloads.ndim != 2 or payloads.dtype != np.uint8):
            raise ValueError("fixed-size payloads are a uint8 array (messages, bytes)")
        times = _times(log_time, "log_time_ns")
        n = len(times)
        publish = times if publish_time is None else _times(publish_time, "publish_time_ns")
        if len(publish) != n or len(payloads) != n:
            raise ValueError(
                f"{n} log times, {len(publish)} publish times and {len(payloads)} payloads"
            )
        if n == 0:
            return
        if sequence is None:
            first = self._sequence.get(channel_id, 0)
            sequence = ((first + np.arange(n, dtype=np.int64)) % 2**32).astype(np.uint32)
            self._sequence[channel_id] = (first + n) % 2**32
        lane = self._lanes.setdefault(channel_id, _Lane())
        if isinstance(payloads, np.ndarray):
            self._append_fixed(channel_id, lane, times, publish, sequence, payloads)
        else:
            self._append_variable(channel_id, lane, times, publish, sequence, payloads)

    def _append_fixed(
        self,
        channel_id: int,
        lane: _Lane,
        times: U64,
        publish: U64,
        sequence: NDArray[np.uint32],
        payloads: NDArray[np.uint8],
    ) -> None:
        size = payloads.shape[1]
        record = _MESSAGE_HEAD + size
        dtype = _message_dtype(size)
        i, n = 0, len(times)
        while i < n:
            j = min(n, i + max(1, (CHUNK_SIZE - lane.size) // record))
            block = np.empty(j - i, dtype=dtype)
            block["opcode"] = Opcode.MESSAGE
            block["length"] = 22 + size
            block["channel"] = channel_id
            block["sequence"] = sequence[i:j]
            block["log_time"] = times[i:j]
            block["publish_time"] = publish[i:j]
            block["data"] = payloads[i:j]
            starts = np.arange(j - i, dtype=np.uint64) * np.uint64(record)
            lane.add(block.view(np.uint8), times[i:j].copy(), starts)
            if lane.size >= CHUNK_SIZE:
                self._flush(channel_id)
            i = j

    def _append_variable(
        self,
        channel_id: int,
        lane: _Lane,
        times: U64,
        publish: U64,
        sequence: NDArray[np.uint32],
        payloads: Sequence[bytes],
    ) -> None:
        items = payloads if isinstance(payloads, (list, tuple)) else list(payloads)
        n = len(times)
        sizes = np.fromiter(map(len, items), dtype=np.int64, count=n)
        if sizes[0] > 0 and np.all(sizes == sizes[0]):  # one publisher's messages often are
            rows = np.frombuffer(b"".join(items), dtype=np.uint8).reshape(n, int(sizes[0]))
            self._append_fixed(channel_id, lane, times, publish, sequence, rows)
            return
        ends = np.cumsum(sizes + _MESSAGE_HEAD)
        bounds = np.concatenate(([0], ends))
        i = 0
        while i < n:
            limit = bounds[i] + max(0, CHUNK_SIZE - lane.size)
            j = max(i + 1, int(np.searchsorted(bounds, limit, side="right")) - 1)
            j = min(j, n)
            head = np.empty(j - i, dtype=_HEAD_DTYPE)
            head["opcode"] = Opcode.MESSAGE
            head["length"] = sizes[i:j] + 22
            head["channel"] = channel_id
            head["sequence"] = sequence[i:j]
            head["log_time"] = times[i:j]
            head["publish_time"] = publish[i:j]
            starts = bounds[i:j] - bounds[i]
            total = int(bounds[j] - bounds[i])
            # headers and payloads interleaved: mark the header bytes, the rest is payload
            mark = np.zeros(total + 1, dtype=np.int8)
            mark[starts] = 1
            mark[starts + _MESSAGE_HEAD] -= 1
            is_head = np.cumsum(mark[:total], dtype=np.int8).astype(bool)
            out = np.empty(total, dtype=np.uint8)
            out[is_head] = head.view(np.uint8)
            out[~is_head] = np.frombuffer(b"".join(items[i:j]), dtype=np.uint8)
            lane.add(out, times[i:j].copy(), starts.astype(np.uint64))
            if lane.size >= CHUNK_SIZE:
                self._flush(channel_id)
            i = j

    def _flush(self, channel_id: int) -> None:
        lane = self._lanes.get(channel_id)
        if lane is None or lane.count == 0:
            return
        data = (lane.parts[0] if len(lane.parts) == 1 else np.concatenate(lane.parts)).data
        log_time = np.concatenate(lane.log_times)
        offsets = np.concatenate(lane.offsets)
        lane.clear()
        self.write_chunk(data, {channel_id: (log_time, offsets)})

    # ------------------------------------------------------------ the end

    def finish(self) -> None:
        """Flush every channel, then DataEnd (with the data CRC), summary and footer."""
        for channel_id in sorted(self._lanes):
            self._flush(channel_id)
        self._drain()  # the data CRC covers every chunk
        self.record(DataEnd(data_section_crc=self._crc))
        summary_start = self.offset
        builder = RecordBuilder()
        groups: list[SummaryOffset] = []

        def group(opcode: Opcode, records: Iterable[McapRecord]) -> None:
            start = builder.count
            for record in records:
                record.write(builder)
            if builder.count > start:
                groups.append(
                    SummaryOffset(
                        group_opcode=opcode,
                        group_start=summary_start + start,
                        group_length=builder.count - start,
                    )
                )

        used = sorted({c.schema_id for c in self.channels.values()} - {0})
        counts = {cid: self.message_counts.get(cid, 0) for cid in sorted(self.channels)}
        total = sum(counts.values())
        stats = Statistics(
            message_count=total,
            schema_count=len(used),
            channel_count=len(self.channels),
            attachment_count=len(self.attachment_indexes),
            metadata_count=len(self.metadata_indexes),
            chunk_count=len(self.chunk_indexes),
            message_start_time=self.start_time if total else 0,
            message_end_time=self.end_time if total else 0,
            channel_message_counts=counts,
        )
        group(Opcode.SCHEMA, (self.schemas[s] for s in used))
        group(Opcode.CHANNEL, (self.channels[c] for c in sorted(self.channels)))
        group(Opcode.STATISTICS, [stats])
        group(Opcode.CHUNK_INDEX, self.chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, self.attachment_indexes)
        group(Opcode.METADATA_INDEX, self.metadata_indexes)
        offsets_start = summary_start + builder.count
        for summary_offset in groups:
            summary_offset.write(builder)
        summary: bytes = builder.end()  # type: ignore[no-untyped-call]
        footer_head = struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offsets_start)
        self.raw(summary)
        self.record(
            Footer(
                summary_start=summary_start,
                summary_offset_start=offsets_start,
                summary_crc=zlib.crc32(footer_head, zlib.crc32(summary)),
            )
        )
        self.raw(MAGIC)


def _times(values: Any, name: str) -> U64:
    array = np.asarray(values)
    if array.ndim != 1 or array.dtype.kind not in "iu":
        raise ValueError(f"{name} must be a 1-D array of integer nanoseconds")
    if array.dtype.kind == "i" and len(array) and int(array.min()) < 0:
        raise ValueError(f"{name} must not be negative")
    return array.astype(np.uint64, copy=False)


# ---------------------------------------------------------------- copying an MCAP source


class _Truncated(Exception):
    """The input ends inside a record or before its DataEnd record."""


def _records(stream: IO[bytes], size: int, copy: _McapCopy) -> Iterator[tuple[int, bytes]]:
    """(opcode, body) of each top-level record after the header, up to DataEnd; a cut-short
    file ends the records when ``copy.partial`` (and sets ``copy.truncated``), else raises.
    A chunk that the end of the file cuts short comes last with the bytes it has."""
    while True:
        prefix = stream.read(9)
        if len(prefix) < 9:
            opcode, length = -1, size
        else:
            opcode, length = _PREFIX.unpack(prefix)
        left = size - stream.tell()
        if length > left:
            if not copy.partial:
                raise _Truncated
            copy.truncated = True
            if opcode == Opcode.CHUNK:
                yield opcode, stream.read(left)
            return
        yield opcode, stream.read(length)
        if opcode in (Opcode.DATA_END, Opcode.FOOTER):
            return


def _parse(record_type: Any, body: bytes) -> Any:
    return record_type.read(ReadDataStream(io.BytesIO(body)))


_UNKNOWN = -1


class _McapCopy:
    """Copies one input MCAP file into the output, mapping its schema and channel ids."""

    def __init__(self, out: _Output, replaced: frozenset[str], partial: bool = False) -> None:
        self.out = out
        self.replaced = replaced
        # partial: a truncated input is copied up to the damage (as far as the reader reads)
        self.partial = partial
        self.truncated = False
        self.schema_ids: dict[int, int] = {}
        self.channel_ids: dict[int, int | None] = {}  # None: a replaced topic, dropped
        # messages outside chunks (an unchunked file), gathered into blocks per channel
        self.loose: dict[int, tuple[list[int], list[int], list[bytes], list[int]]] = {}
        # every id and definition unchanged: chunks may pass through without decompression
        self.exact = True

    def learn_schema(self, schema: Schema) -> int:
        if schema.id not in self.schema_ids:
            new = self.out.schema(schema.name, schema.encoding, schema.data, wanted=schema.id)
            self.schema_ids[schema.id] = new
            self.exact &= new == schema.id
        return self.schema_ids[schema.id]

    def learn_channel(self, channel: Channel) -> int | None:
        if channel.id not in self.channel_ids:
            if channel.topic in self.replaced:
                self.channel_ids[channel.id] = None
                self.out.reserve(channel.id)
                return None
            schema_id = 0
            if channel.schema_id != 0:
                if channel.schema_id not in self.schema_ids:
                    raise McapError(f"channel {channel.id} refers to an unknown schema")
                schema_id = self.schema_ids[channel.schema_id]
            new = self.out.channel(
                channel.topic,
                schema_id,
                channel.message_encoding,
                dict(channel.metadata),
                wanted=channel.id,
            )
            self.channel_ids[channel.id] = new
            self.exact &= new == channel.id and QOS_KEY in channel.metadata
        return self.channel_ids[channel.id]

    def run(self, stream: IO[bytes]) -> None:
        size = stream.seek(0, io.SEEK_END)
        stream.seek(0)
        if stream.read(8) != MAGIC:
            raise McapError("not an MCAP file (bad magic)")
        summary = None
        with contextlib.suppress(Exception):  # no usable summary: learn from the records
            stream.seek(0)
            summary = SeekingReader(stream).get_summary()
        if summary is not None:
            for schema in summary.schemas.values():
                self.learn_schema(schema)
            for channel in summary.channels.values():
                self.learn_channel(channel)
        stream.seek(8)
        records = _records(stream, size, self)
        opcode, _ = next(records, (None, b""))
        if opcode != Opcode.HEADER:
            raise McapError("the file does not start with a header record")
        pending = next(records, None)
        while pending is not None:
            opcode, body = pending
            pending = next(records, None)
            if opcode == Opcode.CHUNK:
                indexes = []
                while pending is not None and pending[0] == Opcode.MESSAGE_INDEX:
                    channel_id, length = struct.unpack_from("<HI", pending[1])
                    indexes.append((channel_id, length // 16, pending[1]))
                    pending = next(records, None)
                if pending is None and self.truncated:
                    self.rebuild(body, cut=True)  # it or its message indexes may be cut short
                else:
                    self.chunk(body, indexes)
            elif opcode == Opcode.SCHEMA:
                self.out.declare_schema(self.learn_schema(_parse(Schema, body)))
            elif opcode == Opcode.CHANNEL:
                channel_id = self.learn_channel(_parse(Channel, body))
                if channel_id is not None:
                    self.out.declare(channel_id)
            elif opcode == Opcode.MESSAGE:
                self.loose_message(_parse_message(body))
            elif opcode == Opcode.METADATA:
                metadata = _parse(Metadata, body)
                # rosbag2's would no longer list the new topics; the marker is written anew
                if metadata.name not in ("rosbag2", MARKER):
                    self.out.metadata(metadata)
            elif opcode == Opcode.ATTACHMENT:
                raw = _PREFIX.pack(opcode, len(body)) + body
                self.out.attachment(raw, _parse(Attachment, body))
            elif opcode in (Opcode.DATA_END, Opcode.FOOTER):
                break
            # anything else (indexes, summary records, unknown opcodes) is rebuilt or skipped
        self.flush_loose()

    def _target(self, channel_id: int) -> int | None:
        target = self.channel_ids.get(channel_id, _UNKNOWN)
        if target == _UNKNOWN:
            raise McapError(f"a message refers to channel {channel_id}, never defined before it")
        return target

    def loose_message(self, message: Message) -> None:
        target = self._target(message.channel_id)
        if target is not None:
            times, publish, payloads, sequence = self.loose.setdefault(target, ([], [], [], []))
            times.append(message.log_time)
            publish.append(message.publish_time)
            payloads.append(message.data)
            sequence.append(message.sequence)
            if len(times) >= _BATCH:
                self.flush_loose()

    def flush_loose(self) -> None:
        for target, (times, publish, payloads, sequence) in sorted(self.loose.items()):
            self.out.declare(target)
            self.out.append(
                target,
                np.array(times, dtype=np.uint64),
                payloads,
                np.array(publish, dtype=np.uint64),
                np.array(sequence, dtype=np.uint32),
            )
        self.loose.clear()

    def chunk(self, body: bytes, indexes: list[tuple[int, int, bytes]]) -> None:
        passes = (
            self.exact
            and bool(indexes)
            and all(self.channel_ids.get(cid, _UNKNOWN) == cid for cid, _, _ in indexes)
        )
        if passes:
            self.out.copy_chunk(body, indexes)
        else:
            self.rebuild(body)

    def rebuild(self, body: bytes, cut: bool = False) -> None:
        """Decompress a chunk and write it again without dropped messages, ids mapped.
        ``cut``: a chunk cut short keeps the whole records it holds, as reading does."""
        data = records_before_cut(body) if cut else chunk_records(body, 0)
        usize = len(data)
        view = memoryview(data)
        parts: list[bytes | memoryview] = []
        index: dict[int, tuple[list[int], list[int]]] = {}
        seen: list[int] = []
        written = pos = 0
        while pos < usize:
            opcode, length = _PREFIX.unpack_from(data, pos)
            end = pos + 9 + length
            if end > usize:
                raise McapError("a record overruns its chunk")
            record: bytes | memoryview = view[pos:end]
            if opcode == Opcode.MESSAGE:
                channel_id, _seq, log_time = struct.unpack_from("<HIQ", data, pos + 9)
                target = self._target(channel_id)
                if target is None:
                    record = b""
                else:
                    if target != channel_id:
                        record = bytes(view[pos : pos + 9]) + struct.pack("<H", target)
                        record += view[pos + 11 : end]
                    times, offsets = index.setdefault(target, ([], []))
                    times.append(log_time)
                    offsets.append(written)
            elif opcode == Opcode.SCHEMA:
                schema_id = self.learn_schema(_parse(Schema, data[pos + 9 : end]))
                record = _record_bytes(self.out.schemas[schema_id])
            elif opcode == Opcode.CHANNEL:
                target = self.learn_channel(_parse(Channel, data[pos + 9 : end]))
                record = b"" if target is None else _record_bytes(self.out.channels[target])
                if target is not None:
                    seen.append(target)
            if record:
                parts.append(record)
                written += len(record)
            pos = end
        if not index:  # no message left: keep only what the chunk defined, at top level
            for channel_id in seen:
                self.out.declare(channel_id)
            return
        self.out.write_chunk(
            b"".join(parts),
            {
                cid: (np.array(t, dtype=np.uint64), np.array(o, dtype=np.uint64))
                for cid, (t, o) in index.items()
            },
        )


def _parse_message(body: bytes) -> Message:
    stream = ReadDataStream(io.BytesIO(body))
    message: Message = Message.read(stream, len(body))
    return message


def _natural_key(path: Path) -> list[Any]:
    """``bag_2.mcap`` before ``bag_10.mcap``."""
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name)]


def _mcap_storage_files(source: Path) -> list[Path] | None:
    """The MCAP files behind a source, in recording order, or None when it is not MCAP-backed
    (or compressed by rosbag2: rosbags then decompresses it while converting)."""
    if source.is_file():
        return [source] if source.suffix == ".mcap" else None
    metadata = source / "metadata.yaml"
    if metadata.is_file():
        from ruamel.yaml import YAML

        try:
            info = YAML(typ="safe").load(metadata.read_text())["rosbag2_bagfile_information"]
            mode = str(info.get("compression_mode") or "none").lower()
            if info["storage_identifier"] != "mcap" or mode != "none":
                return None
            files = [source / PurePath(p).name for p in info["relative_file_paths"]]
        except Exception:  # rosbags' reader says what is wrong with it
            return None
        return files if files and all(f.is_file() for f in files) else None
    files = sorted(source.glob("*.mcap"), key=_natural_key)
    return files or None


def _copy_mcap(path: Path, out: _Output, replaced: frozenset[str], partial: bool) -> bool:
    """Copy one MCAP file into ``out``; whether it was truncated (copied up to the damage)."""
    try:
        with open(path, "rb") as stream:
            copy = _McapCopy(out, replaced, partial)
            copy.run(stream)
            return copy.truncated
    except TwincdError:
        raise
    except _Truncated as exc:
        raise LogReadError(
            "cannot copy MCAP: a record runs past the end of the file (truncated or damaged)",
            str(path),
            "check that the file is complete",
        ) from exc
    except (
        McapError,
        McapDamage,
        struct.error,
        ValueError,
        KeyError,
        IndexError,
        EOFError,
        OSError,
        zstandard.ZstdError,
    ) as exc:
        known = isinstance(exc, McapError | McapDamage)
        what = str(exc) if known else f"{type(exc).__name__}: {exc}"
        raise LogReadError(
            f"cannot copy MCAP: {what}".splitlines()[0],
            str(path),
            "check that the file is complete",
        ) from exc


# ---------------------------------------------------------------- converting other sources


def _copy_via_rosbags(source: Path, out: _Output, replaced: frozenset[str]) -> None:
    from rosbags.convert.converter import migrate_bytes
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
            if not reader.is2 and conn.msgtype in typestore().fielddefs:
                store = typestore()
            to_ros2[conn.msgtype] = (store, conn.msgtype)
            try:
                msgdef, _ = store.generate_msgdef(conn.msgtype, ros_version=2)
            except Exception:  # a custom type an old bag did not describe: bytes still copy
                msgdef = ""
            schema_id = out.schema(conn.msgtype, "ros2msg", msgdef.encode())
            qos = getattr(conn.ext, QOS_KEY, None)
            meta = {QOS_KEY: dump_qos_v8(list(qos)) if qos else DEFAULT_QOS}
            channels[conn.id] = out.channel(conn.topic, schema_id, "cdr", meta)
            out.declare(channels[conn.id])
        wanted = [c for c in reader.connections if c.id in channels]
        cache: dict[str, object] = {}

        def convert(conn: Any, raw: Any) -> bytes:
            store, msgtype = to_ros2[conn.msgtype]
            return bytes(
                migrate_bytes(
                    reader.typestore,
                    store,
                    conn.msgtype,
                    msgtype,
                    cache,
                    raw,
                    src_is2=False,
                    dst_is2=True,
                )
            )

        pending: dict[int, tuple[list[int], list[Any]]] = {cid: ([], []) for cid in channels}

        def flush(conn_id: int) -> None:
            times, payloads = pending[conn_id]
            if times:
                pending[conn_id] = ([], [])
                # sequence 0: neither sqlite3 nor ROS 1 bags keep the publisher's
                zero = np.zeros(len(times), dtype=np.uint32)
                out.append(channels[conn_id], np.array(times, dtype=np.int64), payloads, None, zero)

        is2 = reader.is2
        for conn, log_time, raw in reader.messages(connections=wanted):
            times, payloads = pending[conn.id]
            times.append(log_time)
            payloads.append(raw if is2 else convert(conn, raw))
            if len(times) >= _BATCH:
                flush(conn.id)
        for conn_id in pending:
            flush(conn_id)
    except TwincdError:
        raise
    except Exception as exc:  # the I/O edge
        raise LogReadError(
            f"cannot copy log: {exc}".splitlines()[0], str(source), "check that it is complete"
        ) from exc
    finally:
        reader.close()


class _Batches:
    """Per-message writes gathered into blocks per channel for ``_Output.append``."""

    def __init__(self, out: _Output) -> None:
        self.out = out
        self.pending: dict[int, tuple[list[int], list[int], list[bytes]]] = {}

    def add(self, channel_id: int, log_time: int, publish_time: int, data: bytes) -> None:
        times, publish, payloads = self.pending.setdefault(channel_id, ([], [], []))
        times.append(log_time)
        publish.append(publish_time)
        payloads.append(data)
        if len(times) >= _BATCH:
            self.flush(channel_id)

    def flush(self, channel_id: int | None = None) -> None:
        for cid in [channel_id] if channel_id is not None else sorted(self.pending):
            times, publish, payloads = self.pending.pop(cid, ([], [], []))
            if times:
                self.out.append(
                    cid,
                    np.array(times, dtype=np.int64),
                    payloads,
                    np.array(publish, dtype=np.int64),
                )


# ---------------------------------------------------------------- public writers


def mark(out: _Output, output: str) -> None:
    """The metadata record by which a later run knows this file as twincd's own ``output``
    (``twincd.io.atomic.output_kind``): it may replace it without being forced."""
    out.metadata(Metadata(name=MARKER, metadata={"output": output, "version": __version__}))


def _finish(
    stack: contextlib.ExitStack,
    finish: Callable[[], None],
    exc_type: type[BaseException] | None,
    exc: BaseException | None,
    tb: TracebackType | None,
) -> None:
    """End a writer: ``finish`` then rename into place; on any error remove the temporary."""
    if exc_type is not None:
        stack.__exit__(exc_type, exc, tb)  # the caller's error goes on, unchanged
        return
    try:
        finish()
    except BaseException as error:
        stack.__exit__(type(error), error, error.__traceback__)
        raise
    stack.close()


class AugmentedMcap:
    """``source`` copied losslessly into ``target``, plus new channels written in blocks.

    >>> with AugmentedMcap(source, target, {"/twincd/sim_effort"}) as out:  # doctest: +SKIP
    ...     ch = out.add_channel("/twincd/sim_effort", "sensor_msgs/msg/JointState")
    ...     out.write(ch, log_time_ns, payloads)  # (n,) int64 and (n, L) uint8, or n bytes

    Topics in ``replace_topics`` that the source already has (a log simulated before) are left
    out of the copy, so that writing them again replaces rather than duplicates them. The copy
    happens on entering; ``target`` appears only when the block ends without error, and may be
    the source itself (a bare ``.mcap``): the rename comes after the copy.
    """

    def __init__(
        self,
        source: Path,
        target: Path,
        replace_topics: Collection[str] = (),
        output: str = "detect",
        partial: bool = False,
    ) -> None:
        self.source = Path(source)
        self.target = Path(target)
        self.output = output
        self.partial = partial  # a truncated source is copied up to the damage
        self.replace_topics = frozenset(replace_topics)
        self._stack: contextlib.ExitStack | None = None
        self._out: _Output | None = None
        self._new: set[int] = set()
        self._copied_topics: set[str] = set()

    def __enter__(self) -> AugmentedMcap:
        with contextlib.ExitStack() as stack:
            stream = stack.enter_context(atomic_output(self.target))
            out = _Output(stream, str(self.target))
            stack.callback(out.close)
            mcap_files = _mcap_storage_files(self.source)
            if mcap_files is not None:
                for path in mcap_files:  # reading stops at a damaged file: so does the copy
                    if _copy_mcap(path, out, self.replace_topics, self.partial):
                        break
            else:
                _copy_via_rosbags(self.source, out, self.replace_topics)
            self._copied_topics = {c.topic for c in out.channels.values()}
            mark(out, self.output)
            self._out = out
            self._stack = stack.pop_all()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        stack, out = self._stack, self._out
        self._stack = self._out = None
        if stack is None or out is None:
            return
        _finish(stack, out.finish, exc_type, exc, tb)

    def _output(self) -> _Output:
        if self._out is None:
            raise RuntimeError("use AugmentedMcap as a context manager")
        return self._out

    def add_channel(self, topic: str, msgtype: str) -> int:
        """A new ros2 channel (``ros2msg`` schema, ``cdr``, default QoS); its id for ``write``."""
        out = self._output()
        if topic in self._copied_topics:
            raise ValueError(f"{topic} is already in the source: list it in replace_topics")
        channel_id = out.ros2_channel(topic, msgtype)
        self._new.add(channel_id)
        return channel_id

    def write(
        self,
        channel_id: int,
        log_time_ns: Times,
        payloads: Payloads,
        publish_time_ns: Times | None = None,
    ) -> None:
        """Messages of one new channel: log times (n,), CDR payloads as a uint8 array (n, L)
        of equal-size messages or n ``bytes``; publish times default to the log times.
        Sequence numbers continue from the channel's previous ``write``."""
        if channel_id not in self._new:
            raise ValueError(f"channel {channel_id} was not added with add_channel")
        self._output().append(channel_id, log_time_ns, payloads, publish_time_ns)


class McapLogWriter:
    """Write a new ros2 MCAP log (e.g. synthetic recordings) atomically.

    >>> with McapLogWriter(Path("run.mcap")) as out:          # doctest: +SKIP
    ...     ch = out.add_topic("/joint_states", "sensor_msgs/msg/JointState")
    ...     out.write(ch, log_time_ns, cdr_bytes)
    """

    def __init__(self, path: Path, output: str = "synth") -> None:
        self.path = Path(path)
        self.output = output
        self._stack: contextlib.ExitStack | None = None
        self._out: _Output | None = None
        self._batches: _Batches | None = None

    def __enter__(self) -> McapLogWriter:
        with contextlib.ExitStack() as stack:
            stream = stack.enter_context(atomic_output(self.path))
            self._out = _Output(stream, str(self.path))
            stack.callback(self._out.close)
            mark(self._out, self.output)
            self._batches = _Batches(self._out)
            self._stack = stack.pop_all()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        stack, out, batches = self._stack, self._out, self._batches
        self._stack = self._out = self._batches = None
        if stack is None or out is None or batches is None:
            return

        def finish() -> None:
            batches.flush()
            out.finish()

        _finish(stack, finish, exc_type, exc, tb)

    def _parts(self) -> tuple[_Output, _Batches]:
        if self._out is None or self._batches is None:
            raise RuntimeError("use McapLogWriter as a context manager")
        return self._out, self._batches

    def add_topic(self, topic: str, msgtype: str) -> int:
        return self._parts()[0].ros2_channel(topic, msgtype)

    def write(
        self, channel_id: int, log_time_ns: int, data: bytes, publish_time_ns: int | None = None
    ) -> None:
        """One message (buffered per channel and written in blocks)."""
        _, batches = self._parts()
        publish = log_time_ns if publish_time_ns is None else publish_time_ns
        batches.add(channel_id, int(log_time_ns), int(publish), bytes(data))

    def write_many(
        self,
        channel_id: int,
        log_time_ns: Times,
        payloads: Payloads,
        publish_time_ns: Times | None = None,
    ) -> None:
        """Many messages of one channel at once, as ``AugmentedMcap.write``."""
        out, batches = self._parts()
        batches.flush(channel_id)  # keep this channel's sequence numbers in write order
        out.append(channel_id, log_time_ns, payloads, publish_time_ns)


def write_augmented(source: Path, target: Path, new_topics: Iterable[NewTopic]) -> None:
    """Write ``target``: every message of ``source`` unchanged, plus ``new_topics``.

    A topic of ``new_topics`` that the source already has (a log simulated before) is replaced,
    not duplicated; every other input message is copied unchanged.

    ``target`` may equal a bare MCAP ``source`` (in-place rewrite): the copy is complete before
    the rename replaces it.
    """
    new_topics = list(new_topics)
    with AugmentedMcap(source, target, {t.topic for t in new_topics}) as out:
        for topic in new_topics:
            channel_id = out.add_channel(topic.topic, topic.msgtype)
            batch: list[tuple[int, int, bytes]] = []
            for message in topic.messages:
                batch.append(message)
                if len(batch) >= _BATCH:
                    _write_batch(out, channel_id, batch)
                    batch = []
            _write_batch(out, channel_id, batch)


def _write_batch(out: AugmentedMcap, channel_id: int, batch: list[tuple[int, int, bytes]]) -> None:
    if batch:
        log_time, publish_time, payloads = zip(*batch)
        out.write(
            channel_id,
            np.array(log_time, dtype=np.int64),
            list(payloads),
            np.array(publish_time, dtype=np.int64),
        )
