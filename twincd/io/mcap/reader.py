"""MCAP reading below mcap's per-message iterator: whole chunks, message payloads as arrays.

Hand-written hot path (per-message Python objects are the cost to avoid on long logs). mcap's own
reader finds the summary (channels, schemas, chunk indexes) and parses the rare records
(Channel, Schema); chunks are read and decompressed whole, the MessageIndex records give the
offsets of the wanted channels' messages, and their log times and payloads are gathered with
numpy. Files without a summary or chunk index (a recorder killed before the end) are scanned
record by record once to rebuild the chunk list, up to the first damage; a chunk that the end
of the file cuts short gives the whole records its bytes hold (``records_before_cut``).
"""

from __future__ import annotations

import contextlib
import io
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import NDArray

from twincd.types import ByteArray, IntArray

MAGIC = b"\x89MCAP0\r\n"
_FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _MESSAGE_INDEX = 0x02, 0x03, 0x04, 0x05, 0x06, 0x07
_DATA_END = 0x0F
_MESSAGE_HEAD = 1 + 8 + 2 + 4 + 8 + 8  # opcode, length, channel, sequence, log and publish time
_RAW_REGION = 1 << 20  # bytes of unchunked top-level records read as one pseudo-chunk
_MAX_TIME = 2**63 - 1  # nanoseconds: later log times do not fit the int64 time line
_MAX_CHUNK = 4 << 30  # mcap's own record size limit: larger means a corrupt length field


class McapDamage(Exception):
    """A truncated or corrupt part of an MCAP file, at ``position`` (bytes)."""

    def __init__(self, what: str, position: int) -> None:
        super().__init__(what)
        self.what = what
        self.position = position


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


@dataclass(frozen=True)
class RawMessages:
    """Messages of one channel from one chunk, all with payloads of the same length."""

    channel_id: int
    log_time_ns: IntArray
    payloads: ByteArray  # (n, L)


def _channel_from(record: Any, schemas: dict[int, Any]) -> McapChannel:
    schema = schemas.get(record.schema_id)
    name = schema.name if schema is not None else ""
    return McapChannel(record.id, record.topic, name, record.message_encoding)


def _parse_record(opcode: int, body: bytes) -> Any:
    """A Schema or Channel record parsed by mcap's own reader."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Channel, Schema

    stream = ReadDataStream(io.BytesIO(body))
    return Schema.read(stream) if opcode == _SCHEMA else Channel.read(stream)


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
        chunk: ChunkRef | None = None  # the last chunk, waiting for its MessageIndex records
        chunk_buf = b""
        indexed: set[int] = set()
        index_end = 0
        raw_start = raw_time = -1

        def close_chunk(trust_index: bool) -> None:
            nonlocal chunk
            if chunk is None:
                return
            index_at = chunk.offset + chunk.length
            channels = frozenset(indexed) if trust_index and indexed else None
            if channels is not None and not self._index_covers(chunk_buf, index_at, index_end):
                channels = None  # the index misses messages: walk this chunk when reading
            if channels is None:
                self._walk(chunk_buf, chunk.offset)
            self.chunks.append(
                ChunkRef(
                    chunk.start_time,
                    chunk.offset,
                    chunk.length,
                    index_at,
                    index_end - index_at,
                    channels,
                )
            )
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
                    chunk = ChunkRef(start_time, pos, 9 + length, 0, 0, None)
                    chunk_buf = chunk_records(body, pos)
                    indexed = set()
                    index_end = end
                elif opcode == _MESSAGE_INDEX and chunk is not None:
                    indexed.add(struct.unpack("<H", self._read_at(pos + 9, 2))[0])
                    index_end = end
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
            record = _parse_record(opcode, body)
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
            ends = starts + 9 + _u64(arr, starts + 1).astype(np.int64)
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
            offsets = _message_offsets(buf, wanted, ref.offset)
        arr = np.frombuffer(buf, dtype=np.uint8)
        out: list[RawMessages] = []
        for channel, offs in offsets.items():
            out.extend(_gather(arr, channel, offs, ref.offset))
        return out


def chunk_records(body: bytes | memoryview, where: int, cut: bool = False) -> bytes:
    """The records of a Chunk record's body, decompressed and checked.

    ``cut``: the body may end early (a chunk that a killed recorder never closed, at the end of
    a truncated file); its data is then decompressed as a stream up to the cut and the whole
    records it holds are returned (no size or CRC can be checked on a part).
    """
    view = memoryview(body)
    usize = struct.unpack_from("<Q", view, 16)[0]
    crc, clen = struct.unpack_from("<II", view, 24)
    compression = bytes(view[32 : 32 + clen]).decode()
    p = 32 + clen
    dlen = struct.unpack_from("<Q", view, p)[0]
    data = view[p + 8 : p + 8 + dlen]
    if usize > _MAX_CHUNK:
        raise McapDamage(f"a chunk claims {usize:,} bytes uncompressed", where)
    if compression not in ("", "zstd", "lz4"):
        raise McapDamage(f"unsupported chunk compression {compression!r}", where)
    whole = len(data) == dlen
    if not whole and not cut:
        raise McapDamage("a chunk is cut short", where)
    try:
        out = _decompress(compression, data, usize, whole)
    except Exception as exc:  # the decompressors' own error types
        raise McapDamage(f"a chunk does not decompress ({exc})", where) from exc
    if not whole:
        return out[: _whole_records(out)]
    if len(out) != usize:
        raise McapDamage("a chunk decompresses to the wrong size", where)
    if crc and zlib.crc32(out) != crc:
        raise McapDamage("a chunk fails its CRC check", where)
    return out


def records_before_cut(body: bytes | memoryview) -> bytes:
    """The whole records that the last chunk of a truncated file still gives (``b""`` when
    its header is cut or its data is corrupt): what reading keeps of it, and copying too."""
    try:
        return chunk_records(body, 0, cut=True)
    except (McapDamage, struct.error, ValueError):
        return b""


def _decompress(compression: str, data: memoryview, usize: int, whole: bool) -> bytes:
    """``data`` decompressed; when not ``whole``, as much as its bytes give, as a stream."""
    if compression == "":
        return bytes(data[:usize])
    if compression == "zstd":
        import zstandard

        if whole:
            return zstandard.ZstdDecompressor().decompress(data, max_output_size=usize)
        reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data))
        return reader.read(usize)
    import lz4.frame  # type: ignore[import-untyped]

    if whole:
        return bytes(lz4.frame.decompress(data))
    return bytes(lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=usize))


def _whole_records(buf: bytes) -> int:
    """The length of the run of whole records at the start of ``buf``."""
    pos, size = 0, len(buf)
    while pos + 9 <= size:
        end = pos + 9 + struct.unpack_from("<Q", buf, pos + 1)[0]
        if end > size:
            break
        pos = end
    return pos


def _message_offsets(buf: bytes, wanted: frozenset[int], where: int) -> dict[int, IntArray]:
    """Offsets of the wanted channels' Message records, by walking every record."""
    found: dict[int, list[int]] = {c: [] for c in wanted}
    pos, size = 0, len(buf)
    unpack = struct.unpack_from
    while pos < size:
        if pos + 9 > size:
            raise McapDamage("a chunk ends inside a record", where)
        opcode, length = unpack("<BQ", buf, pos)
        if opcode == _MESSAGE:
            hits = found.get(unpack("<H", buf, pos + 9)[0])
            if hits is not None:
                hits.append(pos)
        pos += 9 + length
    if pos > size:
        raise McapDamage("a record runs past the end of its chunk", where)
    return {c: np.array(v, dtype=np.int64) for c, v in found.items() if v}


def _u64(arr: ByteArray, at: IntArray) -> NDArray[np.uint64]:
    window = np.lib.stride_tricks.sliding_window_view(arr, 8)
    result: NDArray[np.uint64] = np.ascontiguousarray(window[at]).view("<u8").reshape(-1)
    return result


def _gather(arr: ByteArray, channel: int, offs: IntArray, where: int) -> list[RawMessages]:
    """Log times and payloads of the Message records at ``offs``, grouped by payload length."""
    if len(offs) == 0:
        return []
    if offs.min() < 0 or offs.max() + _MESSAGE_HEAD > len(arr):
        raise McapDamage("a message index points outside its chunk", where)
    head = np.lib.stride_tricks.sliding_window_view(arr, _MESSAGE_HEAD)[offs]
    length = np.ascontiguousarray(head[:, 1:9]).view("<u8").reshape(-1).astype(np.int64)
    chan = np.ascontiguousarray(head[:, 9:11]).view("<u2").reshape(-1)
    raw_time = np.ascontiguousarray(head[:, 15:23]).view("<u8").reshape(-1)
    if (raw_time > np.uint64(_MAX_TIME)).any():
        raise McapDamage("a log time above 2^63 ns (after the year 2262)", where)
    log_time = raw_time.astype(np.int64)
    size = length - (_MESSAGE_HEAD - 9)
    if (
        (head[:, 0] != _MESSAGE).any()
        or (chan != channel).any()
        or (size < 0).any()
        or (offs + 9 + length > len(arr)).any()
    ):
        raise McapDamage("a message index does not match its chunk's records", where)
    order = np.lexsort((offs, log_time))
    start = offs + _MESSAGE_HEAD
    out = []
    for width in np.unique(size).tolist():
        sel = order[size[order] == width]
        if width == 0:
            payloads = np.zeros((len(sel), 0), dtype=np.uint8)
        else:
            payloads = np.lib.stride_tricks.sliding_window_view(arr, width)[start[sel]]
        out.append(RawMessages(channel, log_time[sel], payloads))
    return out
