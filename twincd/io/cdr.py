"""ROS 2 message construction and CDR serialisation for the channels twincd writes."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rosbags.typesys import Stores, get_typestore

TYPESTORE = get_typestore(Stores.LATEST)

_Time = TYPESTORE.types["builtin_interfaces/msg/Time"]
_Header = TYPESTORE.types["std_msgs/msg/Header"]
_JointState = TYPESTORE.types["sensor_msgs/msg/JointState"]
_Bool = TYPESTORE.types["std_msgs/msg/Bool"]
_Float64 = TYPESTORE.types["std_msgs/msg/Float64"]


def header(stamp_ns: int, frame_id: str = "") -> Any:
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return _Header(stamp=_Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def _joint_state_rosbags(
    stamp_ns: int,
    names: list[str],
    position: NDArray[np.float64],
    velocity: NDArray[np.float64],
    effort: NDArray[np.float64],
) -> bytes:
    msg = _JointState(
        header=header(stamp_ns),
        name=names,
        position=np.ascontiguousarray(position, dtype=np.float64),
        velocity=np.ascontiguousarray(velocity, dtype=np.float64),
        effort=np.ascontiguousarray(effort, dtype=np.float64),
    )
    return bytes(TYPESTORE.serialize_cdr(msg, "sensor_msgs/msg/JointState"))


def _align(offset: int, size: int) -> int:
    return (offset + size - 1) // size * size


def _joint_state_layout(names: Sequence[str]) -> tuple[int, list[int]]:
    """(message length, byte offsets of the position/velocity/effort doubles) of a
    little-endian CDR JointState with an empty frame_id and len(names) values per array."""
    body = 8 + 4 + 1  # stamp (sec, nanosec), frame_id: length and its NUL
    body = _align(body, 4) + 4  # name count
    for name in names:
        body = _align(body, 4) + 4 + len(name.encode()) + 1
    starts = []
    for _ in range(3):
        body = _align(body, 4) + 4  # value count
        body = _align(body, 8)
        starts.append(4 + body)  # +4: the encapsulation header before the body
        body += 8 * len(names)
    return 4 + body, starts


_BLOCK = 65536


def joint_state_cdr(
    stamp_ns: NDArray[np.int64],
    names: Sequence[str],
    position: NDArray[np.float64],
    velocity: NDArray[np.float64],
    effort: NDArray[np.float64],
) -> Iterator[bytes]:
    """CDR-serialised JointState messages, one per row.

    Every row has the same layout, so the bytes are filled into a template for a block of rows
    at once: rosbags' per-message serialisation was most of ``simulate``'s time after reading
    (benchmarks/bench_io.py). The template is checked against rosbags on the first row, and
    rosbags serialises every row where they would differ.
    """
    name_list = list(names)
    d = len(name_list)
    n = len(stamp_ns)
    if n == 0:
        return
    arrays = [np.asarray(a, dtype="<f8").reshape(n, d) for a in (position, velocity, effort)]
    length, starts = _joint_state_layout(name_list)
    first = _joint_state_rosbags(int(stamp_ns[0]), name_list, *(a[0] for a in arrays))
    template = np.frombuffer(first, dtype=np.uint8)
    if len(first) != length:  # an unexpected layout: stay with the library
        for i in range(n):
            yield _joint_state_rosbags(int(stamp_ns[i]), name_list, *(a[i] for a in arrays))
        return
    sec, nanosec = np.divmod(np.asarray(stamp_ns, dtype=np.int64), 1_000_000_000)
    for b0 in range(0, n, _BLOCK):
        rows = slice(b0, min(b0 + _BLOCK, n))
        block = np.tile(template, (rows.stop - rows.start, 1))
        block[:, 4:8] = sec[rows].astype("<i4")[:, None].view(np.uint8)
        block[:, 8:12] = nanosec[rows].astype("<u4")[:, None].view(np.uint8)
        for start, values in zip(starts, arrays):
            block[:, start : start + 8 * d] = np.ascontiguousarray(values[rows]).view(np.uint8)
        if b0 == 0 and bytes(block[0]) != first:  # the template disagrees: use the library
            for i in range(n):
                yield _joint_state_rosbags(int(stamp_ns[i]), name_list, *(a[i] for a in arrays))
            return
        for row in block:
            yield row.tobytes()


def bool_cdr(value: bool) -> bytes:
    return bytes(TYPESTORE.serialize_cdr(_Bool(data=bool(value)), "std_msgs/msg/Bool"))


def float64_cdr(value: float) -> bytes:
    return bytes(TYPESTORE.serialize_cdr(_Float64(data=float(value)), "std_msgs/msg/Float64"))


def serialize(msg: object, msgtype: str) -> bytes:
    """Any typestore message to CDR bytes."""
    return bytes(TYPESTORE.serialize_cdr(msg, msgtype))
