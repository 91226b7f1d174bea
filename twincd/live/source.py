"""Live sources: one small interface, one module per transport.

A source delivers raw CDR messages of the topics ``watch`` asks for.
``twincd.live.connect.open_source(spec)`` picks the transport by the form of ``spec``:

- ``ws://HOST:PORT`` (or ``wss://``): a Foxglove WebSocket server such as foxglove_bridge
  (``twincd.live.foxglove``);
- ``ros2``: DDS through rclpy (``twincd.live.ros2``; the user's ROS 2 or the extra ``twincd[ros]``);
- ``zenoh`` or ``zenoh/ENDPOINT`` (``zenoh/tcp/HOST:7447``): a robot on rmw_zenoh, through its
  Zenoh router (``twincd.live.zenoh``; the extra ``twincd[zenoh]``).

A fourth transport is one module that implements ``Source`` and one line in ``open_source``
(the transports import this module; it imports none of them).
Transport libraries are imported when a source opens, never on ``import twincd``.
"""

from __future__ import annotations

import queue
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from twincd.errors import TwincdError

__all__ = [
    "Arrival",
    "Connection",
    "Source",
    "SourceError",
    "SourceLost",
    "Wanted",
    "ros_type",
    "take_queued",
]


class SourceError(TwincdError):
    """A live source that cannot be reached, or that does not carry what is asked of it."""


class SourceLost(SourceError):
    """A source that went away during a session and did not come back in time."""


@dataclass(frozen=True)
class Wanted:
    """A topic to subscribe to: its ROS 2 type; ``required``: the session cannot start
    without it (the joint states), else it is taken when it is published (labels)."""

    topic: str
    msgtype: str
    required: bool = True


@dataclass(frozen=True)
class Arrival:
    """One message as it arrived: its topic, the time the source gives it (the bridge's log
    time, or the time rclpy handed it over), the local monotonic time it was taken (ns, for
    latency) and its CDR payload."""

    topic: str
    log_time_ns: int
    received_ns: int
    data: bytes


@dataclass(frozen=True)
class Connection:
    """The source's connection changed: it went away (``up`` False; ``reason``), or it came
    back (``up`` True). ``at`` is the local monotonic time (s) it was seen."""

    up: bool
    at: float
    reason: str = ""


class Source(Protocol):
    """A live transport: ``start`` connects and subscribes (``SourceError`` when it cannot
    within ``timeout_s``), ``receive`` returns what arrived (empty after ``timeout_s`` without
    a message; ``SourceLost`` when the source went away and did not come back), ``notices``
    the changes of the connection since it was last called (a transport without connections,
    DDS, has none), ``close`` ends it. ``name`` names it in messages."""

    name: str

    def start(self, wanted: Sequence[Wanted], timeout_s: float) -> None: ...

    def receive(self, timeout_s: float) -> list[Arrival]: ...

    def notices(self) -> list[Connection]: ...

    def close(self) -> None: ...


def take_queued(
    arrivals: queue.Queue[Arrival], timeout_s: float, limit: int = 4096
) -> list[Arrival]:
    """What a transport's own thread queued: the first within ``timeout_s`` and every one
    already there (up to ``limit``); empty when none came."""
    out: list[Arrival] = []
    try:
        out.append(arrivals.get(timeout=max(timeout_s, 0.0)))
    except queue.Empty:
        return out
    while len(out) < limit:
        try:
            out.append(arrivals.get_nowait())
        except queue.Empty:
            break
    return out


def ros_type(name: str) -> str:
    """The ROS 2 type name: ``sensor_msgs/JointState`` → ``sensor_msgs/msg/JointState``."""
    parts = name.strip().split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return name.strip()
