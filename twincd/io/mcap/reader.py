"""MCAP files opened for bulk reading: channels, the chunk list, and a chunk's wanted messages.

Below mcap's per-message iterator (per-message Python objects are the cost to avoid on long
logs): mcap's own reader finds the summary (channels, schemas, chunk indexes) and parses the rare
records (Channel, Schema); chunks are read whole and their messages gathered with numpy
(``twincd.io.mcap.chunks``). Files without a summary or chunk index (a recorder killed before
the end) are scanned record by record once to rebuild the chunk list, up to the first damage.
"""

from __future__ import annotations

import contextlib
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from mcap.opcode import Opcode
from mcap.records import Channel, Schema

from twincd.io.mcap.chunks import (
    RawMessages,
    chunk_records,
    gather,
    message_offsets,
    records_before_cut,
    u64,
)
from twincd.io.mcap.records import MAGIC, McapDamage, parse_record
from twincd.types import IntArray

__all__ = ["ChunkRef", "McapChannel", "McapFile"]

_FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _MESSAGE_INDEX, _DATA_END = (
    int(o)
    for o in (
        Opcode.FOOTER,
        Opcode.SCHEMA,
        Opcode.CHANNEL,
        Opcode.MESSAGE,
        Opcode.CHUNK,
        Opcode.MESSAGE_INDEX,
        Opcode.DATA_END,
    )
)
_RAW_REGION = 1 << 20  # bytes of unchunked top-level records read as one pseudo-chunk


@dataclass(frozen=True)
class McapChannel:
    """One channel: its topic, its schema's name (the ROS type) and message encoding."""

    id: int
    topic: str
    msgtype: str
    encoding: str


@dataclass(frozen=True)
class ChunkRef:
    """Where a chunk's messages are: a Chunk record, or a run of top-level records (``raw``)."""

    start_time: int
    offset: int  # of the record's opcode (or the first raw record)
    length: int  # the whole record (or the run of raw records)
    index_offset: int  # the MessageIndex records that follow the chunk
    index_length: int
    channels: frozenset[int] | None  # channels with a MessageIndex; None: walk the records
    raw: bool = False
    cut: bool = False  # a chunk cut short by the end of the file: its whole records are read


@dataclass
class _PendingChunk:
    """A chunk ``McapFile._scan`` found, waiting for the MessageIndex records that follow it."""

    ref: ChunkRef  # its start time, offset and length
    records: bytes  # its records, decompressed
    index_end: int  # where the MessageIndex records read so far end
    indexed: set[int] = field(default_factory=set)  # the channels they index


def _channel_from(record: Any, schemas: dict[int, Any]) -> McapChannel:
    schema = schemas.get(record.schema_id)
    name = schema.name if schema is not None else ""
    return McapChannel(record.id, record.topic, name, record.message_encoding)


class McapFile:
    """One MCAP file opened for bulk reading: channels, chunk list, and chunk reading."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._f: BinaryIO = open(self.path, "rb")  # noqa: SIM115 - closed by close()
        self.size = self.path.stat().st_size
        self.channels: dict[int, McapChannel] = {}
        self.chunks: list[ChunkRef] = []
        self.damage: McapDamage | None = None  # found while scanning an unindexed file
        self.indexed = False
        self._schemas: dict[int, Any] = {}
        try:
            if self._f.read(len(MAGIC)) != MAGIC:
                raise McapDamage("not an MCAP file (bad magic)", 0)
            if not self._read_summary():
                self._scan()
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        self._f.close()

    # ------------------------------------------------------------ discovery

    def _read_summary(self) -> bool:
        """Channels and chunks from the summary section; False when there is none to use."""
        from mcap.reader import make_reader

        self._f.seek(0)
        try:
            summary = make_reader(self._f).get_summary()
        except Exception:  # no footer or a damaged summary: scan the data section instead
            return False
        if summary is None or not summary.chunk_indexes or not summary.channels:
            return False
        self._schemas = dict(summary.schemas)
        for cid, ch in summary.channels.items():
            self.channels[cid] = _channel_from(ch, self._schemas)
        for ci in summary.chunk_indexes:
            self.chunks.append(
                ChunkRef(
                    start_time=ci.message_start_time,
                    offset=ci.chunk_start_offset,
                    length=ci.chunk_length,
                    index_offset=ci.chunk_start_offset + ci.chunk_length,
                    index_length=ci.message_index_length,
                    channels=frozenset(ci.message_index_offsets) or None,
                )
            )
        self.indexed = True
        return True

    def _scan(self) -> None:
        """Walk the data section once: channels, and a chunk list rebuilt from the records.

        Stops at the first damage (``self.damage``); every chunk before it stays readable.
        """
        pos = len(MAGIC)
        chunk: _PendingChunk | None = None  # the last chunk, waiting for its MessageIndex records
        raw_start = raw_time = -1

        def close_chunk(trust_index: bool) -> None:
            nonlocal chunk
            if chunk is not None:
                self._close_chunk(chunk, trust_index)
                chunk = None

        def close_raw(end: int) -> None:
            nonlocal raw_start, raw_time
            if raw_start >= 0:
                self.chunks.append(
                    ChunkRef(raw_time, raw_start, end - raw_start, end, 0, None, raw=True)
                )
            raw_start = raw_time = -1

        try:
            while True:
                if pos == self.size:
                    raise McapDamage("the file ends without a footer", pos)
                if pos + 9 > self.size:
                    raise McapDamage("the file ends inside a record header", pos)
                opcode, length = struct.unpack("<BQ", self._read_at(pos, 9))
                end = pos + 9 + length
                if end > self.size:
                    if opcode == _CHUNK:
                        close_chunk(trust_index=True)
                        close_raw(pos)
                        self._cut_chunk(pos)
                        raise McapDamage("the file ends inside the chunk", pos)
                    raise McapDamage(f"a record (opcode 0x{opcode:02x}) runs past the end", pos)
                if opcode != _MESSAGE_INDEX:
                    close_chunk(trust_index=True)
                if opcode not in (_MESSAGE, _SCHEMA, _CHANNEL):
                    close_raw(pos)
                if opcode in (_DATA_END, _FOOTER):
                    break
                if opcode == _CHUNK:
                    body = self._read_at(pos + 9, length)
                    start_time = struct.unpack_from("<Q", body)[0]
                    ref = ChunkRef(start_time, pos, 9 + length, 0, 0, None)
                    chunk = _PendingChunk(ref, chunk_records(body, pos), end)
                elif opcode == _MESSAGE_INDEX and chunk is not None:
                    chunk.indexed.add(struct.unpack("<H", self._read_at(pos + 9, 2))[0])
                    chunk.index_end = end
                elif opcode == _MESSAGE:
                    log_time = struct.unpack("<Q", self._read_at(pos + 9 + 6, 8))[0]
                    if raw_start < 0:
                        raw_start, raw_time = pos, log_time
                    raw_time = min(raw_time, log_time)
                elif opcode in (_SCHEMA, _CHANNEL):
                    self._note(opcode, self._read_at(pos + 9, length), pos)
                if raw_start >= 0 and end - raw_start >= _RAW_REGION:
                    close_raw(end)
                pos = end
        except McapDamage as exc:
            self.damage = exc
        except (struct.error, ValueError, EOFError) as exc:
            self.damage = McapDamage(f"a corrupt record ({exc})", pos)
        if self.damage is not None:
            # the last chunk's MessageIndex records may be cut short: walk it; if the chunk
            # itself is unusable, the damage already says where reading stops
            with contextlib.suppress(McapDamage, struct.error, ValueError):
                close_chunk(trust_index=False)
            close_raw(pos)

    def _close_chunk(self, chunk: _PendingChunk, trust_index: bool) -> None:
        """Add a chunk found by ``_scan`` to ``chunks``: read by the channels its MessageIndex
        records name when they are to be trusted and cover every message in it, else walked now
        (its Channel and Schema records noted) and walked again when read."""
        ref = chunk.ref
        index_at = ref.offset + ref.length
        channels = frozenset(chunk.indexed) if trust_index and chunk.indexed else None
        if channels is not None and not self._index_covers(
            chunk.records, index_at, chunk.index_end
        ):
            channels = None  # the index misses messages: walk this chunk when reading
        if channels is None:
            self._walk(chunk.records, ref.offset)
        index_length = chunk.index_end - index_at
        self.chunks.append(
            ChunkRef(ref.start_time, ref.offset, ref.length, index_at, index_length, channels)
        )

    def _cut_chunk(self, pos: int) -> None:
        """Keep the whole records of a chunk that the end of the file cuts short, if any."""
        body = self._read_at(pos + 9, self.size - pos - 9)
        buf = records_before_cut(body)
        if not buf:
            return
        with contextlib.suppress(McapDamage):  # a corrupt definition: the damage says enough
            self._walk(buf, pos)
            start_time = struct.unpack_from("<Q", body)[0]  # the header is whole: buf is not empty
            self.chunks.append(
                ChunkRef(start_time, pos, self.size - pos, self.size, 0, None, cut=True)
            )

    def _note(self, opcode: int, body: bytes, where: int) -> None:
        from mcap.exceptions import McapError

        try:
            record = parse_record(Schema if opcode == _SCHEMA else Channel, body)
        except (McapError, struct.error, ValueError) as exc:
            raise McapDamage(f"a corrupt schema or channel record ({exc})", where) from exc
        if opcode == _SCHEMA:
            self._schemas[record.id] = record
        else:
            self.channels[record.id] = _channel_from(record, self._schemas)

    def _index_covers(self, buf: bytes, index_at: int, index_end: int) -> bool:
        """Whether the MessageIndex records at ``index_at`` cover every message of ``buf``;
        the records between the indexed messages (schemas, channels) are noted on the way."""
        try:
            index = self._read_index(index_at, index_end - index_at)
            offsets = [o for _, o in index.values()]
            starts = np.sort(np.concatenate(offsets)) if offsets else np.zeros(0, np.int64)
            arr = np.frombuffer(buf, dtype=np.uint8)
            if len(starts) and (starts[0] < 0 or starts[-1] + 9 > len(arr)):
                return False
            ends = starts + 9 + u64(arr, starts + 1).astype(np.int64)
            if len(starts) > 1 and (starts[1:] < ends[:-1]).any():
                return False
            bounds = [0, *np.stack([starts, ends], 1).reshape(-1).tolist(), len(buf)]
            for a, b in zip(bounds[::2], bounds[1::2]):
                if b < a or self._walk(buf[a:b], index_at, messages_allowed=False) < 0:
                    return False
        except McapDamage:
            return False
        return True

    def _walk(self, buf: bytes, where: int, messages_allowed: bool = True) -> int:
        """Walk the records of ``buf``, noting channels and schemas; -1 when a Message record
        turns up where none may be (an incomplete index)."""
        pos = 0
        while pos < len(buf):
            if pos + 9 > len(buf):
                raise McapDamage("a chunk ends inside a record", where)
            opcode, length = struct.unpack_from("<BQ", buf, pos)
            end = pos + 9 + length
            if end > len(buf):
                raise McapDamage("a record runs past the end of its chunk", where)
            if opcode in (_SCHEMA, _CHANNEL):
                self._note(opcode, buf[pos + 9 : end], where)
            elif opcode == _MESSAGE and not messages_allowed:
                return -1
            pos = end
        return pos

    # ------------------------------------------------------------ reading

    def _read_at(self, offset: int, length: int) -> bytes:
        if offset < 0 or length < 0 or offset + length > self.size:
            raise McapDamage("a record or index points past the end of the file", offset)
        self._f.seek(offset)
        data = self._f.read(length)
        if len(data) != length:
            raise McapDamage("the file ends inside a record", offset)
        return data

    def _read_index(self, offset: int, length: int) -> dict[int, tuple[IntArray, IntArray]]:
        """channel -> (log times, offsets) from the MessageIndex records at ``offset``."""
        data = self._read_at(offset, length) if length else b""
        index: dict[int, tuple[IntArray, IntArray]] = {}
        pos = 0
        while pos + 9 <= len(data):
            opcode, rec_len = struct.unpack_from("<BQ", data, pos)
            if opcode == _MESSAGE_INDEX:
                channel, n_bytes = struct.unpack_from("<HI", data, pos + 9)
                pairs = np.frombuffer(data, "<u8", n_bytes // 8, pos + 15).reshape(-1, 2)
                index[channel] = (pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64))
            pos += 9 + rec_len
        return index

    def read_chunk(self, ref: ChunkRef, wanted: frozenset[int]) -> list[RawMessages]:
        """The messages of the ``wanted`` channels in one chunk, in log-time order per channel."""
        try:
            return self._read_chunk(ref, wanted)
        except (struct.error, ValueError) as exc:  # a record whose fields contradict each other
            raise McapDamage(f"a corrupt chunk or message index ({exc})", ref.offset) from exc

    def _read_chunk(self, ref: ChunkRef, wanted: frozenset[int]) -> list[RawMessages]:
        if ref.raw:
            buf = self._read_at(ref.offset, ref.length)
        else:
            record = self._read_at(ref.offset, ref.length)
            if record[0] != _CHUNK:
                raise McapDamage("the chunk index points at no chunk", ref.offset)
            buf = chunk_records(memoryview(record)[9:], ref.offset, ref.cut)
        if ref.channels is not None:
            index = self._read_index(ref.index_offset, ref.index_length)
            offsets = {c: index[c][1] for c in wanted if c in index}
        else:
            offsets = message_offsets(buf, wanted, ref.offset)
        arr = np.frombuffer(buf, dtype=np.uint8)
        out: list[RawMessages] = []
        for channel, offs in offsets.items():
            out.extend(gather(arr, channel, offs, ref.offset))
        return out
