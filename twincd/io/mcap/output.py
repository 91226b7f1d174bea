"""An MCAP file being written: the data section as it comes, the summary at the end.

Records are written in call order; new chunks compress on worker threads (zstd releases the GIL)
while the caller computes the next block, and are written in submission order. Records go
through ``mcap.records`` wherever the library's serialisation does the job; only the hot paths
are hand-written (``twincd.io.mcap.records``): bulk Message and MessageIndex records, the headers
of new chunks, raw chunk pass-through. Output is a ros2-profile file with every channel's QoS.
"""

from __future__ import annotations

import functools
import os
import struct
import threading
import zlib
from collections import deque
from collections.abc import Iterable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import IO

import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Metadata,
    MetadataIndex,
    Statistics,
    SummaryOffset,
)
from numpy.typing import NDArray

from twincd.io.atomic import output_error
from twincd.io.cdr import typestore
from twincd.io.mcap.channels import DEFAULT_QOS, QOS_KEY, ChannelTable
from twincd.io.mcap.messages import Lane
from twincd.io.mcap.records import (
    CHUNK_HEAD,
    MAGIC,
    PREFIX,
    U64,
    Buffer,
    Payloads,
    Times,
    as_times,
    message_index,
    record_bytes,
)
from twincd.version import __version__

__all__ = ["McapOutput"]

ZSTD_LEVEL = 1  # float payloads: 2× as fast as zstd's default level 3 for 5-15 % larger chunks
_WORKERS = max(1, min(2, (os.cpu_count() or 2) - 1))  # leave a core to the caller
_IN_FLIGHT = 2 * _WORKERS + 2  # chunks compressing or done but not yet written
_local = threading.local()


def _compress(data: Buffer) -> tuple[bytes, int]:
    """(zstd frame, CRC-32) of a chunk's records; runs on a worker thread."""
    compressor = getattr(_local, "zstd", None)
    if compressor is None:  # a compressor is not thread-safe: one per thread
        compressor = _local.zstd = zstandard.ZstdCompressor(level=ZSTD_LEVEL)
    return compressor.compress(data), zlib.crc32(data)


class McapOutput(ChannelTable):
    """The output file: data section written as it comes, summary kept for the end."""

    def __init__(self, stream: IO[bytes], where: str) -> None:
        super().__init__(where)
        self._stream = stream
        self.offset = 0
        self._crc = 0
        self._declared: set[tuple[int, int]] = set()  # (opcode, id) written at top level
        self.chunk_indexes: list[ChunkIndex] = []
        self.metadata_indexes: list[MetadataIndex] = []
        self.attachment_indexes: list[AttachmentIndex] = []
        self.message_counts: dict[int, int] = {}
        self.start_time = 2**64 - 1
        self.end_time = 0
        self._lanes: dict[int, Lane] = {}
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
        data = record_bytes(record)
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

    def ros2_channel(self, topic: str, msgtype: str) -> int:
        """A new ros2 channel (``ros2msg`` schema, ``cdr``, default QoS), declared at once."""
        msgdef, _ = typestore().generate_msgdef(msgtype, ros_version=2)
        schema_id = self.schema(msgtype, "ros2msg", msgdef.encode())
        channel_id = self.channel(topic, schema_id, "cdr", {QOS_KEY: DEFAULT_QOS})
        self.declare(channel_id)
        return channel_id

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
        self.raw(PREFIX.pack(Opcode.CHUNK, len(body)))
        self.raw(body)
        index_start = self.offset
        offsets: dict[int, int] = {}
        for channel_id, count, index_body in indexes:
            offsets[channel_id] = self.offset
            self.raw(PREFIX.pack(Opcode.MESSAGE_INDEX, len(index_body)))
            self.raw(index_body)
            self._count(channel_id, count, start, end)
        self._index_chunk(start, end, offset, index_start, offsets, compression, csize, usize)

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
        head = CHUNK_HEAD.pack(
            Opcode.CHUNK, 44 + len(compressed), start, end, size, crc, 4, b"zstd", len(compressed)
        )
        offset = self.offset
        self._put(head)
        self._put(compressed)
        index_start = self.offset
        offsets: dict[int, int] = {}
        for channel_id, (log_time, starts) in sorted(index.items()):
            offsets[channel_id] = self.offset
            self._put(message_index(channel_id, log_time, starts))
            self._count(channel_id, len(log_time), int(log_time.min()), int(log_time.max()))
        self._index_chunk(start, end, offset, index_start, offsets, "zstd", len(compressed), size)

    def _index_chunk(
        self,
        start: int,
        end: int,
        offset: int,
        index_start: int,
        offsets: dict[int, int],
        compression: str,
        compressed_size: int,
        uncompressed_size: int,
    ) -> None:
        """The ChunkIndex of the chunk written at ``offset``, its MessageIndex records from
        ``index_start`` up to here (the summary's index of every chunk)."""
        self.chunk_indexes.append(
            ChunkIndex(
                message_start_time=start,
                message_end_time=end,
                chunk_start_offset=offset,
                chunk_length=index_start - offset,
                message_index_offsets=offsets,
                message_index_length=self.offset - index_start,
                compression=compression,
                compressed_size=compressed_size,
                uncompressed_size=uncompressed_size,
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
        times = as_times(log_time, "log_time_ns")
        n = len(times)
        publish = times if publish_time is None else as_times(publish_time, "publish_time_ns")
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
        lane = self._lanes.setdefault(channel_id, Lane())
        flush = functools.partial(self._flush, channel_id)  # when the lane is full
        if isinstance(payloads, np.ndarray):
            lane.add_fixed(channel_id, times, publish, sequence, payloads, flush)
        else:
            lane.add_variable(channel_id, times, publish, sequence, payloads, flush)

    def flush(self) -> None:
        """Every message appended so far into chunks, and every chunk written to the stream
        (not flushed to disk: the stream's own flush does that)."""
        for channel_id in sorted(self._lanes):
            self._flush(channel_id)
        self._drain()

    def _flush(self, channel_id: int) -> None:
        lane = self._lanes.get(channel_id)
        taken = None if lane is None else lane.take()
        if taken is not None:
            data, log_time, offsets = taken
            self.write_chunk(data, {channel_id: (log_time, offsets)})

    def finish(self) -> None:
        """Flush every channel, then DataEnd (with the data CRC), summary and footer."""
        self.flush()  # the data CRC covers every chunk
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
