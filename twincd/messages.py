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


def joint_state_cdr(
    stamp_ns: NDArray[np.int64],
    names: Sequence[str],
    position: NDArray[np.float64],
    velocity: NDArray[np.float64],
    effort: NDArray[np.float64],
) -> Iterator[bytes]:
    """CDR-serialised JointState messages, one per row."""
    name_list = list(names)
    for i in range(len(stamp_ns)):
        msg = _JointState(
            header=header(int(stamp_ns[i])),
            name=name_list,
            position=np.ascontiguousarray(position[i], dtype=np.float64),
            velocity=np.ascontiguousarray(velocity[i], dtype=np.float64),
            effort=np.ascontiguousarray(effort[i], dtype=np.float64),
        )
        yield bytes(TYPESTORE.serialize_cdr(msg, "sensor_msgs/msg/JointState"))


def bool_cdr(value: bool) -> bytes:
    return bytes(TYPESTORE.serialize_cdr(_Bool(data=bool(value)), "std_msgs/msg/Bool"))


def float64_cdr(value: float) -> bytes:
    return bytes(TYPESTORE.serialize_cdr(_Float64(data=float(value)), "std_msgs/msg/Float64"))


def serialize(msg: object, msgtype: str) -> bytes:
    """Any typestore message to CDR bytes."""
    return bytes(TYPESTORE.serialize_cdr(msg, msgtype))
