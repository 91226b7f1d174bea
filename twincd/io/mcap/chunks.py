"""MCAP chunks read in bulk: a Chunk record's body decompressed and checked, and the Message
records of wanted channels gathered with numpy into log times and (n, L) payload arrays.

The hot path of reading (no Python object per message); a chunk that the end of a truncated
file cuts short gives the whole records its bytes hold (``records_before_cut``), for reading and
for copying alike.
"""

from __future__ import annotations

import io
import struct
import zlib
from dataclasses import dataclass

import numpy as np
from mcap.opcode import Opcode
from numpy.typing import NDArray

from twincd.io.mcap.records import MESSAGE_HEAD, McapDamage
from twincd.types import ByteArray, IntArray

__all__ = ["RawMessages", "chunk_records", "gather", "message_offsets", "records_before_cut", "u64"]

_MESSAGE = int(Opcode.MESSAGE)
_MAX_TIME = 2**63 - 1  # nanoseconds: later log times do not fit the int64 time line
_MAX_CHUNK = 4 << 30  # mcap's own record size limit: larger means a corrupt length field


@dataclass(frozen=True)
class RawMessages:
    """Messages of one channel from one chunk, all with payloads of the same length."""

    channel_id: int
    log_time_ns: IntArray
    payloads: ByteArray  # (n, L)


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


def message_offsets(buf: bytes, wanted: frozenset[int], where: int) -> dict[int, IntArray]:
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


def u64(arr: ByteArray, at: IntArray) -> NDArray[np.uint64]:
    window = np.lib.stride_tricks.sliding_window_view(arr, 8)
    result: NDArray[np.uint64] = np.ascontiguousarray(window[at]).view("<u8").reshape(-1)
    return result


def gather(arr: ByteArray, channel: int, offs: IntArray, where: int) -> list[RawMessages]:
    """Log times and payloads of the Message records at ``offs``, grouped by payload length."""
    if len(offs) == 0:
        return []
    if offs.min() < 0 or offs.max() + MESSAGE_HEAD > len(arr):
        raise McapDamage("a message index points outside its chunk", where)
    head = np.lib.stride_tricks.sliding_window_view(arr, MESSAGE_HEAD)[offs]
    length = np.ascontiguousarray(head[:, 1:9]).view("<u8").reshape(-1).astype(np.int64)
    chan = np.ascontiguousarray(head[:, 9:11]).view("<u2").reshape(-1)
    raw_time = np.ascontiguousarray(head[:, 15:23]).view("<u8").reshape(-1)
    if (raw_time > np.uint64(_MAX_TIME)).any():
        raise McapDamage("a log time above 2^63 ns (after the year 2262)", where)
    log_time = raw_time.astype(np.int64)
    size = length - (MESSAGE_HEAD - 9)
    if (
        (head[:, 0] != _MESSAGE).any()
        or (chan != channel).any()
        or (size < 0).any()
        or (offs + 9 + length > len(arr)).any()
    ):
        raise McapDamage("a message index does not match its chunk's records", where)
    order = np.lexsort((offs, log_time))
    start = offs + MESSAGE_HEAD
    out = []
    for width in np.unique(size).tolist():
        sel = order[size[order] == width]
        if width == 0:
            payloads = np.zeros((len(sel), 0), dtype=np.uint8)
        else:
            payloads = np.lib.stride_tricks.sliding_window_view(arr, width)[start[sel]]
        out.append(RawMessages(channel, log_time[sel], payloads))
    return out
