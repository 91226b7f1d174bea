"""New Message records assembled in blocks with numpy: the hot path of writing.

A ``Lane`` holds the pending chunk of one new channel. Fixed-size payloads become one structured
array row per record (no Python work per message); variable-size ones are interleaved with their
headers by a byte mask. Whenever a lane reaches ``CHUNK_SIZE`` it is handed to ``flush`` (the
output compresses and writes it as a chunk of its own).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from mcap.opcode import Opcode
from numpy.typing import NDArray

from twincd.io.mcap.records import HEAD_DTYPE, MESSAGE_HEAD, U64, Buffer, message_dtype

__all__ = ["BATCH", "CHUNK_SIZE", "Lane"]

CHUNK_SIZE = 1 << 20  # uncompressed bytes per new chunk, as mcap's and rosbag2's writers do
BATCH = 8192  # messages gathered per channel by the per-message entry points before a block


class Lane:
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

    def take(self) -> tuple[Buffer, U64, U64] | None:
        """The pending records, their log times and offsets (None when empty); then empty."""
        if self.count == 0:
            return None
        data = (self.parts[0] if len(self.parts) == 1 else np.concatenate(self.parts)).data
        log_time = np.concatenate(self.log_times)
        offsets = np.concatenate(self.offsets)
        self.clear()
        return data, log_time, offsets

    def add_fixed(
        self,
        channel_id: int,
        times: U64,
        publish: U64,
        sequence: NDArray[np.uint32],
        payloads: NDArray[np.uint8],
        flush: Callable[[], None],
    ) -> None:
        """Records with equal-size payloads (messages, bytes), one array row each."""
        size = payloads.shape[1]
        record = MESSAGE_HEAD + size
        dtype = message_dtype(size)
        i, n = 0, len(times)
        while i < n:
            j = min(n, i + max(1, (CHUNK_SIZE - self.size) // record))
            block = np.empty(j - i, dtype=dtype)
            block["opcode"] = Opcode.MESSAGE
            block["length"] = 22 + size
            block["channel"] = channel_id
            block["sequence"] = sequence[i:j]
            block["log_time"] = times[i:j]
            block["publish_time"] = publish[i:j]
            block["data"] = payloads[i:j]
            starts = np.arange(j - i, dtype=np.uint64) * np.uint64(record)
            self.add(block.view(np.uint8), times[i:j].copy(), starts)
            if self.size >= CHUNK_SIZE:
                flush()
            i = j

    def add_variable(
        self,
        channel_id: int,
        times: U64,
        publish: U64,
        sequence: NDArray[np.uint32],
        payloads: Sequence[bytes],
        flush: Callable[[], None],
    ) -> None:
        """Records with payloads of any sizes (equal sizes take ``add_fixed``)."""
        items = payloads if isinstance(payloads, (list, tuple)) else list(payloads)
        n = len(times)
        sizes = np.fromiter(map(len, items), dtype=np.int64, count=n)
        if sizes[0] > 0 and np.all(sizes == sizes[0]):  # one publisher's messages often are
            rows = np.frombuffer(b"".join(items), dtype=np.uint8).reshape(n, int(sizes[0]))
            self.add_fixed(channel_id, times, publish, sequence, rows, flush)
            return
        ends = np.cumsum(sizes + MESSAGE_HEAD)
        bounds = np.concatenate(([0], ends))
        i = 0
        while i < n:
            limit = bounds[i] + max(0, CHUNK_SIZE - self.size)
            j = max(i + 1, int(np.searchsorted(bounds, limit, side="right")) - 1)
            j = min(j, n)
            head = np.empty(j - i, dtype=HEAD_DTYPE)
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
            mark[starts + MESSAGE_HEAD] -= 1
            is_head = np.cumsum(mark[:total], dtype=np.int8).astype(bool)
            out = np.empty(total, dtype=np.uint8)
            out[is_head] = head.view(np.uint8)
            out[~is_head] = np.frombuffer(b"".join(items[i:j]), dtype=np.uint8)
            self.add(out, times[i:j].copy(), starts.astype(np.uint64))
            if self.size >= CHUNK_SIZE:
                flush()
            i = j
