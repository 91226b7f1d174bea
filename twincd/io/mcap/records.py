"""The MCAP format as twincd packs and checks it by hand: magic, record layouts, and the few
records written or parsed outside mcap's own classes (Message, MessageIndex, Chunk headers).

Shared by the reader (``twincd.io.mcap.reader``, ``twincd.io.mcap.chunks``) and the writer
(``twincd.io.mcap.output``), so both sides agree on every offset.
"""

from __future__ import annotations

import functools
import io
import struct
from collections.abc import Sequence
from typing import Any

import numpy as np
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import McapRecord, Message
from numpy.typing import NDArray

__all__ = [
    "CHUNK_HEAD",
    "HEAD_DTYPE",
    "MAGIC",
    "MESSAGE_FIELDS",
    "MESSAGE_HEAD",
    "PREFIX",
    "U64",
    "Buffer",
    "McapDamage",
    "Payloads",
    "Times",
    "as_times",
    "message_dtype",
    "message_index",
    "parse_message",
    "parse_record",
    "record_bytes",
]

MAGIC = b"\x89MCAP0\r\n"
PREFIX = struct.Struct("<BQ")  # opcode, record length
MESSAGE_HEAD = 31  # prefix + channel id, sequence, log time, publish time
# prefix, start and end time, uncompressed size and CRC, compression name, compressed size
CHUNK_HEAD = struct.Struct("<BQQQQII4sQ")
MESSAGE_FIELDS = [
    ("opcode", "u1"),
    ("length", "<u8"),
    ("channel", "<u2"),
    ("sequence", "<u4"),
    ("log_time", "<u8"),
    ("publish_time", "<u8"),
]
HEAD_DTYPE = np.dtype(MESSAGE_FIELDS)
_INDEX_DTYPE = np.dtype([("log_time", "<u8"), ("offset", "<u8")])
U64 = NDArray[np.uint64]
Times = NDArray[np.integer[Any]]  # integer nanoseconds, (n,)
Payloads = NDArray[np.uint8] | Sequence[bytes]
Buffer = bytes | memoryview


class McapDamage(Exception):
    """A truncated or corrupt part of an MCAP file, at ``position`` (bytes)."""

    def __init__(self, what: str, position: int) -> None:
        super().__init__(what)
        self.what = what
        self.position = position


def record_bytes(record: McapRecord) -> bytes:
    """One record as mcap's own serialisation writes it."""
    builder = RecordBuilder()
    record.write(builder)
    data: bytes = builder.end()  # type: ignore[no-untyped-call]
    return data


def parse_record(record_type: Any, body: bytes) -> Any:
    """A record's body parsed by mcap's own class ``record_type`` (Schema, Channel, ...)."""
    return record_type.read(ReadDataStream(io.BytesIO(body)))


def parse_message(body: bytes) -> Message:
    """A Message record's body parsed by mcap (its length is the body's)."""
    stream = ReadDataStream(io.BytesIO(body))
    message: Message = Message.read(stream, len(body))
    return message


@functools.lru_cache(maxsize=64)
def message_dtype(size: int) -> np.dtype[Any]:
    """A packed Message record with a fixed-size payload: one array row per record."""
    return np.dtype([*MESSAGE_FIELDS, ("data", "u1", (size,))])


def message_index(channel_id: int, log_time: U64, offset: U64) -> bytes:
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


def as_times(values: Any, name: str) -> U64:
    """Integer nanoseconds (n,) as uint64, refused when not 1-D integers or negative."""
    array = np.asarray(values)
    if array.ndim != 1 or array.dtype.kind not in "iu":
        raise ValueError(f"{name} must be a 1-D array of integer nanoseconds")
    if array.dtype.kind == "i" and len(array) and int(array.min()) < 0:
        raise ValueError(f"{name} must not be negative")
    return array.astype(np.uint64, copy=False)
