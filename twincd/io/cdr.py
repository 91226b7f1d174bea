"""ROS 2 CDR: message construction, bulk encoders and bulk decoders for the types twincd uses.

rosbags is the reference for every byte. The hot paths (JointState, Bool, Float64 by the
million) are hand-written with numpy over blocks of equal-length payloads: the layout is taken
from one message, every other row is checked against it byte for byte, and rows that do not fit
go through rosbags. ``STATS`` counts how many messages took the fast path and how many the
fallback, so that a silently broken fast path shows up in tests.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from twincd.types import BoolArray, ByteArray, FloatArray, IntArray

JOINT_STATE = "sensor_msgs/msg/JointState"
# ros2_control's joint_state_broadcaster: every state interface of every joint
DYNAMIC_JOINT_STATE = "control_msgs/msg/DynamicJointState"
BOOL = "std_msgs/msg/Bool"
STRING = "std_msgs/msg/String"
FLOAT64 = "std_msgs/msg/Float64"


# control_msgs is not in rosbags' stores: its two messages twincd reads, as control_msgs defines
# them (a bag's own definitions take precedence where it stores them)
CONTROL_MSGS = {
    "control_msgs/msg/InterfaceValue": "string[] interface_names\nfloat64[] values\n",
    DYNAMIC_JOINT_STATE: (
        "std_msgs/Header header\nstring[] joint_names\n"
        "control_msgs/InterfaceValue[] interface_values\n"
    ),
}


@lru_cache(maxsize=1)
def typestore() -> Any:
    """rosbags' store of the latest ROS 2 message types, the reference for every byte, with
    control_msgs' ``DynamicJointState`` (built on first use: the fast paths never need it, and
    it costs 70 ms of start-up)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.LATEST)
    types: dict[str, Any] = {}
    for name, text in CONTROL_MSGS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def _type(name: str) -> Any:
    return typestore().types[name]


_NS = 1_000_000_000
_BLOCK = 65536  # rows per block when joint_state_cdr encodes a long series
_MAX_LAYOUTS = 64  # distinct JointState layouts tried in one decode call before giving up


@dataclass
class CdrStats:
    """How many messages each path encoded or decoded."""

    fast: int = 0
    fallback: int = 0

    def add(self, fast: int = 0, fallback: int = 0) -> None:
        self.fast += fast
        self.fallback += fallback

    def reset(self) -> None:
        self.fast = self.fallback = 0


STATS = CdrStats()  # process-wide totals; readers also keep their own


def _count(stats: CdrStats | None, fast: int = 0, fallback: int = 0) -> None:
    STATS.add(fast, fallback)
    if stats is not None and stats is not STATS:
        stats.add(fast, fallback)


def header(stamp_ns: int, frame_id: str = "") -> Any:
    sec, nanosec = divmod(int(stamp_ns), _NS)
    return _type("std_msgs/msg/Header")(
        stamp=_type("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec), frame_id=frame_id
    )


def _align(offset: int, size: int) -> int:
    return (offset + size - 1) // size * size


# ---------------------------------------------------------------- encoders


def _joint_state_rosbags(
    stamp_ns: int,
    names: list[str],
    position: NDArray[np.float64],
    velocity: NDArray[np.float64],
    effort: NDArray[np.float64],
) -> bytes:
    msg = _type(JOINT_STATE)(
        header=header(stamp_ns),
        name=names,
        position=np.ascontiguousarray(position, dtype=np.float64),
        velocity=np.ascontiguousarray(velocity, dtype=np.float64),
        effort=np.ascontiguousarray(effort, dtype=np.float64),
    )
    return bytes(typestore().serialize_cdr(msg, JOINT_STATE))


def _joint_state_layout(names: Sequence[str], counts: Sequence[int]) -> tuple[int, list[int]]:
    """(message length, byte offsets of the position/velocity/effort doubles) of a
    little-endian CDR JointState with an empty frame_id and ``counts`` values per array."""
    body = 8 + 4 + 1  # stamp (sec, nanosec), frame_id: length and its NUL
    body = _align(body, 4) + 4  # name count
    for name in names:
        body = _align(body, 4) + 4 + len(name.encode()) + 1
    starts = []
    for count in counts:
        body = _align(body, 4) + 4  # value count
        if count:  # an empty sequence has no element to align
            body = _align(body, 8)
        starts.append(4 + body)  # +4: the encapsulation header before the body
        body += 8 * count
    return 4 + body, starts


def _rows(values: Any, n: int) -> FloatArray:
    """(n, k) little-endian float64 rows; an empty or None array gives (n, 0)."""
    if values is None:
        return np.zeros((n, 0), dtype="<f8")
    array = np.asarray(values, dtype="<f8")
    if array.size == 0:
        return np.zeros((n, 0), dtype="<f8")
    return array.reshape(n, -1)


def joint_state_block(
    stamp_ns: NDArray[np.int64] | Sequence[int],
    names: Sequence[str],
    position: Any,
    velocity: Any,
    effort: Any,
    stats: CdrStats | None = None,
) -> ByteArray:
    """CDR JointState messages as one (n, L) uint8 array, one message per row.

    ``position``, ``velocity`` and ``effort`` are (n, k) arrays; velocity or effort may be
    empty (or None) for messages without them. Every row has the same layout, so the bytes are
    filled into a template for all rows at once (rosbags per message was most of ``simulate``'s
    time). The template is checked against rosbags on the first row; if they differ, rosbags
    serialises every row. Call it per block of rows: the result holds all of them.
    """
    stamps = np.asarray(stamp_ns, dtype=np.int64).reshape(-1)
    n = len(stamps)
    name_list = [str(x) for x in names]
    arrays = [_rows(a, n) for a in (position, velocity, effort)]
    length, starts = _joint_state_layout(name_list, [a.shape[1] for a in arrays])
    if n == 0:
        return np.zeros((0, length), dtype=np.uint8)
    first = _joint_state_rosbags(int(stamps[0]), name_list, *(a[0] for a in arrays))
    if len(first) == length:
        block = np.tile(np.frombuffer(first, dtype=np.uint8), (n, 1))
        sec, nanosec = np.divmod(stamps, _NS)
        block[:, 4:8] = sec.astype("<i4").reshape(n, 1).view(np.uint8)
        block[:, 8:12] = nanosec.astype("<u4").reshape(n, 1).view(np.uint8)
        for start, values in zip(starts, arrays):
            width = 8 * values.shape[1]
            block[:, start : start + width] = np.ascontiguousarray(values).view(np.uint8)
        if block[0].tobytes() == first:
            _count(stats, fast=n)
            return block
    # an unexpected layout: stay with the library for every row
    rows = [
        np.frombuffer(
            _joint_state_rosbags(int(stamps[i]), name_list, *(a[i] for a in arrays)), np.uint8
        )
        for i in range(n)
    ]
    _count(stats, fallback=n)
    return np.stack(rows)


def joint_state_cdr(
    stamp_ns: NDArray[np.int64],
    names: Sequence[str],
    position: NDArray[np.float64],
    velocity: NDArray[np.float64],
    effort: NDArray[np.float64],
) -> Iterator[bytes]:
    """CDR-serialised JointState messages, one ``bytes`` per row (see ``joint_state_block``)."""
    n = len(stamp_ns)
    arrays = [_rows(a, n) for a in (position, velocity, effort)]
    for b0 in range(0, n, _BLOCK):
        rows = slice(b0, min(b0 + _BLOCK, n))
        pos, vel, eff = (a[rows] for a in arrays)
        block = joint_state_block(stamp_ns[rows], names, pos, vel, eff)
        for row in block:
            yield row.tobytes()


def _scalar_block(
    values: Any, dtype: str, msgtype: str, make: Any, stats: CdrStats | None
) -> ByteArray:
    data = np.asarray(values).reshape(-1).astype(dtype)
    n = len(data)
    width = data.dtype.itemsize
    body = _align(0, width)  # the value sits at the start of the (aligned) body
    length = 4 + body + width
    if n == 0:
        return np.zeros((0, length), dtype=np.uint8)
    first = bytes(typestore().serialize_cdr(make(data[0].item()), msgtype))
    if len(first) == length:
        block = np.tile(np.frombuffer(first, dtype=np.uint8), (n, 1))
        block[:, 4 + body :] = data.reshape(n, 1).view(np.uint8)
        if block[0].tobytes() == first:
            _count(stats, fast=n)
            return block
    rows = [
        np.frombuffer(typestore().serialize_cdr(make(v.item()), msgtype), np.uint8) for v in data
    ]
    _count(stats, fallback=n)
    return np.stack(rows)


def float64_block(values: Any, stats: CdrStats | None = None) -> ByteArray:
    """CDR std_msgs/msg/Float64 messages as one (n, 12) uint8 array."""
    return _scalar_block(values, "<f8", FLOAT64, lambda v: _type(FLOAT64)(data=float(v)), stats)


def bool_block(values: Any, stats: CdrStats | None = None) -> ByteArray:
    """CDR std_msgs/msg/Bool messages as one (n, 5) uint8 array."""
    return _scalar_block(values, "u1", BOOL, lambda v: _type(BOOL)(data=bool(v)), stats)


def bool_cdr(value: bool) -> bytes:
    return bytes(typestore().serialize_cdr(_type(BOOL)(data=bool(value)), BOOL))


def serialize(msg: object, msgtype: str) -> bytes:
    """Any typestore message to CDR bytes."""
    return bytes(typestore().serialize_cdr(msg, msgtype))


# ---------------------------------------------------------------- decoders


@dataclass(frozen=True)
class JointStateGroup:
    """Decoded JointState rows that share one name list and array widths.

    ``rows`` index the payloads given to ``decode_joint_states``; ``stamp_ns`` is the raw
    header stamp (sec · 1e9 + nanosec, 0 where the publisher left it empty). Widths are the
    messages' own: a ragged message (filled arrays of another length than ``names``) keeps
    its shape, so the caller decides what to do with it.
    """

    rows: NDArray[np.intp]
    names: tuple[str, ...]
    stamp_ns: IntArray
    position: FloatArray
    velocity: FloatArray
    effort: FloatArray
    fast: bool

    def __len__(self) -> int:
        return len(self.rows)


@dataclass(frozen=True)
class _Layout:
    """Where things are in one JointState payload (absolute byte offsets)."""

    little: bool
    names: tuple[str, ...]
    arrays: tuple[tuple[int, int], ...]  # (start, count) of position, velocity, effort
    static: NDArray[np.intp]  # bytes that must equal the first row's (all but stamp, doubles)


def _parse_layout(row: bytes) -> _Layout | None:
    """The layout of one CDR JointState, or None when it is not one this parser handles."""
    size = len(row)
    if size < 4 + 8 + 4 + 4 or row[0] != 0 or row[1] not in (0, 1):
        return None
    little = row[1] == 1
    order: Any = "little" if little else "big"
    spans: list[tuple[int, int]] = [(0, 4)]  # encapsulation header

    def aligned(pos: int, width: int) -> int:
        return 4 + _align(pos - 4, width)  # CDR aligns relative to the body

    def count(pos: int) -> int | None:
        if pos + 4 > size:
            return None
        value = int.from_bytes(row[pos : pos + 4], order)
        spans.append((pos, pos + 4))
        return value

    def string(pos: int, content: bool = True) -> tuple[str, int] | None:
        n = count(pos)
        if n is None or n < 1 or pos + 4 + n > size or row[pos + 4 + n - 1] != 0:
            return None
        spans.append((pos + 4 if content else pos + 3 + n, pos + 4 + n))
        try:
            return row[pos + 4 : pos + 3 + n].decode(), pos + 4 + n
        except UnicodeDecodeError:
            return None

    # frame_id: its length shapes the layout, its text is not decoded (a counter in it must
    # not push every row off the fast path), its NUL must be there; bytes 4-12 are the stamp
    got = string(12, content=False)
    if got is None:
        return None
    pos = aligned(got[1], 4)
    n_names = count(pos)
    if n_names is None or n_names > size:
        return None
    pos += 4
    names = []
    for _ in range(n_names):
        got = string(aligned(pos, 4))
        if got is None:
            return None
        names.append(got[0])
        pos = got[1]
    arrays = []
    for _ in range(3):
        pos = aligned(pos, 4)
        k = count(pos)
        if k is None:
            return None
        pos += 4
        if k:
            pos = aligned(pos, 8)
        if pos + 8 * k > size:
            return None
        arrays.append((pos, k))
        pos += 8 * k
    if size - pos > 3:  # more than trailing padding (rosbags allows 3 bytes): unknown layout
        return None
    static = np.concatenate([np.arange(a, b, dtype=np.intp) for a, b in spans])
    return _Layout(little, tuple(names), tuple(arrays), static)


def _matching_rows(payloads: ByteArray, rows: NDArray[np.intp], static: NDArray[np.intp]) -> Any:
    """Which ``rows`` have the same ``static`` bytes as the first of them."""
    block = payloads if len(rows) == len(payloads) else payloads[rows]
    width = block.shape[1]
    if width % 4 == 0 and block.flags.c_contiguous:
        # compare 4-byte words under a byte mask: half the time of a byte gather
        mask = np.zeros(width, dtype=np.uint8)
        mask[static] = 0xFF
        mask32 = mask.view(np.uint32)
        words = np.flatnonzero(mask32)
        w = block.view(np.uint32)[:, words]
        return ((w ^ w[0]) & mask32[words] == 0).all(axis=1)
    sub = block[:, static]
    return (sub == sub[0]).all(axis=1)


def _doubles(block: ByteArray, start: int, k: int, little: bool) -> FloatArray:
    raw = np.ascontiguousarray(block[:, start : start + 8 * k]).view("<f8" if little else ">f8")
    return raw.astype(np.float64, copy=False).reshape(len(block), k)


def _decode_layout(payloads: ByteArray, rows: NDArray[np.intp], layout: _Layout) -> JointStateGroup:
    block = payloads if len(rows) == len(payloads) else payloads[rows]
    i32, u32 = ("<i4", "<u4") if layout.little else (">i4", ">u4")
    sec = np.ascontiguousarray(block[:, 4:8]).view(i32).reshape(-1).astype(np.int64)
    nanosec = np.ascontiguousarray(block[:, 8:12]).view(u32).reshape(-1).astype(np.int64)
    pos, vel, eff = (_doubles(block, s, k, layout.little) for s, k in layout.arrays)
    return JointStateGroup(rows, layout.names, sec * _NS + nanosec, pos, vel, eff, fast=True)


def _decode_with_rosbags(payloads: ByteArray, rows: NDArray[np.intp]) -> list[JointStateGroup]:
    by_key: dict[tuple[Any, ...], list[tuple[int, Any]]] = {}
    for r in rows.tolist():
        msg: Any = typestore().deserialize_cdr(payloads[r].tobytes(), JOINT_STATE)
        key = (tuple(msg.name), len(msg.position), len(msg.velocity), len(msg.effort))
        by_key.setdefault(key, []).append((r, msg))
    groups = []
    for (names, kp, kv, ke), items in by_key.items():
        msgs = [m for _, m in items]

        def stack(field: str, k: int, msgs: list[Any] = msgs) -> FloatArray:
            out = np.zeros((len(msgs), k))
            for i, m in enumerate(msgs):
                out[i] = getattr(m, field)
            return out

        stamps = [m.header.stamp.sec * _NS + m.header.stamp.nanosec for m in msgs]
        groups.append(
            JointStateGroup(
                np.array([r for r, _ in items], dtype=np.intp),
                names,
                np.array(stamps, dtype=np.int64),
                stack("position", kp),
                stack("velocity", kv),
                stack("effort", ke),
                fast=False,
            )
        )
    return groups


def decode_joint_states(
    payloads: ByteArray, stats: CdrStats | None = None
) -> list[JointStateGroup]:
    """Decode (n, L) equal-length CDR JointState payloads into groups of one layout each.

    The layout of the first undecoded row is parsed, every remaining row whose layout bytes
    (everything but the stamp, the doubles and padding) equal it is decoded with numpy, and
    the rest starts the next group. Rows no layout fits, and any left after ``_MAX_LAYOUTS``
    layouts, are deserialised by rosbags (``fast=False``): never silently wrong.
    """
    payloads = np.asarray(payloads, dtype=np.uint8)
    if payloads.ndim != 2:
        raise ValueError("payloads must be a 2-D (messages, bytes) array")
    remaining = np.arange(len(payloads), dtype=np.intp)
    groups: list[JointStateGroup] = []
    slow: list[NDArray[np.intp]] = []
    tries = 0
    while len(remaining) and tries < _MAX_LAYOUTS:
        tries += 1
        layout = _parse_layout(payloads[remaining[0]].tobytes())
        if layout is None:
            slow.append(remaining[:1])
            remaining = remaining[1:]
            continue
        match = _matching_rows(payloads, remaining, layout.static)
        groups.append(_decode_layout(payloads, remaining[match], layout))
        remaining = remaining[~match]
    slow.append(remaining)
    slow_rows = np.concatenate(slow)
    if len(slow_rows):
        groups.extend(_decode_with_rosbags(payloads, np.sort(slow_rows)))
    _count(
        stats,
        fast=sum(len(g) for g in groups if g.fast),
        fallback=sum(len(g) for g in groups if not g.fast),
    )
    groups.sort(key=lambda g: int(g.rows[0]))
    return groups


def decode_bools(payloads: ByteArray, stats: CdrStats | None = None) -> BoolArray:
    """Decode (n, L) equal-length CDR std_msgs/msg/Bool payloads (L = 5, or 8 when padded)."""
    payloads = np.asarray(payloads, dtype=np.uint8)
    n = len(payloads)
    values = np.zeros(n, dtype=bool)
    if n == 0:
        return values
    width = payloads.shape[1]
    head = payloads[0, :4]
    fast = np.zeros(n, dtype=bool)
    if 5 <= width <= 8 and head[0] == 0 and head[1] in (0, 1):
        fast = (payloads[:, :4] == head).all(axis=1) & (payloads[:, 4] <= 1)
        values[fast] = payloads[fast, 4] == 1
    slow = np.flatnonzero(~fast)
    for r in slow.tolist():
        msg: Any = typestore().deserialize_cdr(payloads[r].tobytes(), BOOL)
        values[r] = bool(msg.data)
    _count(stats, fast=n - len(slow), fallback=len(slow))
    return values
