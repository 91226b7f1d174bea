"""A log copied losslessly into an MCAP output, minus the topics about to be written anew.

MCAP sources (bare, or the storage files of a rosbag2 folder): Schema, Channel, Chunk and
MessageIndex records pass through as they are, without decompression, so schema, channel
metadata, log time, publish time, sequence and bytes stay unchanged. Only chunks that hold a
replaced topic (a log simulated before), or whose channel ids must change (split rosbag2 files
numbering their channels differently, a channel without QoS metadata), are decompressed and
rebuilt record by record. A truncated source may be copied up to its damage, as reading does.
Every other source goes through ``twincd.io.mcap.convert`` (sqlite3 in bulk, the rest through
rosbags). Which files a source stands for is ``twincd.io.sources.storage_of``'s to say.
"""

from __future__ import annotations

import contextlib
import io
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import numpy as np
import zstandard
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Attachment, Channel, Message, Metadata, Schema

from twincd.errors import LogReadError, TwincdError
from twincd.io.atomic import MARKER
from twincd.io.mcap.channels import QOS_KEY
from twincd.io.mcap.chunks import chunk_records, records_before_cut
from twincd.io.mcap.convert import copy_sqlite3, copy_via_rosbags
from twincd.io.mcap.messages import BATCH
from twincd.io.mcap.output import McapOutput
from twincd.io.mcap.records import (
    MAGIC,
    PREFIX,
    McapDamage,
    parse_message,
    parse_record,
    record_bytes,
)
from twincd.io.sources import storage_of

__all__ = ["copy_log"]


def copy_log(source: Path, out: McapOutput, replaced: frozenset[str], partial: bool) -> None:
    """Every message of ``source`` but those of ``replaced`` topics into ``out``; ``partial``:
    a truncated MCAP source is copied up to the damage (reading stops there too)."""
    storage = storage_of(source)
    if storage is not None and storage.storage == "sqlite3":
        copy_sqlite3(storage.files, source, out, replaced)
        return
    if storage is None or storage.storage != "mcap":
        copy_via_rosbags(source, out, replaced)
        return
    for path in storage.files:  # reading stops at a damaged file: so does the copy
        if _copy_mcap(path, out, replaced, partial):
            break


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
            opcode, length = PREFIX.unpack(prefix)
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


_UNKNOWN = -1


class _McapCopy:
    """Copies one input MCAP file into the output, mapping its schema and channel ids."""

    def __init__(self, out: McapOutput, replaced: frozenset[str], partial: bool = False) -> None:
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
                self.out.declare_schema(self.learn_schema(parse_record(Schema, body)))
            elif opcode == Opcode.CHANNEL:
                channel_id = self.learn_channel(parse_record(Channel, body))
                if channel_id is not None:
                    self.out.declare(channel_id)
            elif opcode == Opcode.MESSAGE:
                self.loose_message(parse_message(body))
            elif opcode == Opcode.METADATA:
                metadata = parse_record(Metadata, body)
                # rosbag2's would no longer list the new topics; the marker is written anew
                if metadata.name not in ("rosbag2", MARKER):
                    self.out.metadata(metadata)
            elif opcode == Opcode.ATTACHMENT:
                raw = PREFIX.pack(opcode, len(body)) + body
                self.out.attachment(raw, parse_record(Attachment, body))
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
            if len(times) >= BATCH:
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
            opcode, length = PREFIX.unpack_from(data, pos)
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
                schema_id = self.learn_schema(parse_record(Schema, data[pos + 9 : end]))
                record = record_bytes(self.out.schemas[schema_id])
            elif opcode == Opcode.CHANNEL:
                target = self.learn_channel(parse_record(Channel, data[pos + 9 : end]))
                record = b"" if target is None else record_bytes(self.out.channels[target])
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


def _copy_mcap(path: Path, out: McapOutput, replaced: frozenset[str], partial: bool) -> bool:
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
