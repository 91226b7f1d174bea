"""The ``zenoh`` source: a robot on rmw_zenoh, through ``eclipse-zenoh`` (the extra
``twincd[zenoh]``), without ROS installed.

rmw_zenoh publishes each message under the key ``<domain>/<topic without its leading
slash>/<DDS type>/<type hash>`` (``0/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_…``;
Humble writes ``TypeHashNotSupported`` for the hash), its payload the message's CDR. ``watch``
subscribes to ``<domain>/<topic>/*/*`` for each topic it wants (the domain: ``ROS_DOMAIN_ID``, 0
when unset) and checks the type in the key. It opens a Zenoh session in client mode on the
endpoint given (``zenoh/tcp/HOST:PORT``; plain ``zenoh``: ``tcp/localhost:7447``, where
rmw_zenoh's router listens by default), retrying until the connect timeout. Zenoh reconnects
by itself; a session that has had no router or peer for the connect timeout is lost. The log
time of a message is the time it was taken. Zenoh 1.x only talks to rmw_zenoh built on Zenoh
1.x (Jazzy's rmw_zenoh, Kilted and later).
"""

from __future__ import annotations

import importlib
import json
import os
import queue
import threading
import time
from collections.abc import Sequence
from typing import Any

from twincd.live.source import Arrival, Connection, SourceError, SourceLost, Wanted, take_queued

__all__ = ["DEFAULT_ENDPOINT", "ZenohSource", "key_type"]

DEFAULT_ENDPOINT = "tcp/localhost:7447"
_RETRY_S = 0.1


def key_type(key: str) -> str:
    """The ROS 2 type of an rmw_zenoh key (``…/sensor_msgs::msg::dds_::JointState_/hash`` →
    ``sensor_msgs/msg/JointState``); empty when the key has no type part."""
    parts = key.split("/")
    if len(parts) < 4:
        return ""
    names = [p for p in parts[-2].split("::") if p != "dds_"]
    return "/".join(names).removesuffix("_")


def _reason(exc: Exception) -> str:
    """Zenoh's message without the Rust source location it ends with."""
    return str(exc).split(" at /")[0].strip().rstrip("!") or type(exc).__name__


class ZenohSource:
    """A ``Source`` on rmw_zenoh topics, through the Zenoh router at ``endpoint``."""

    def __init__(self, endpoint: str = "", connect_timeout_s: float = 10.0) -> None:
        self.endpoint = endpoint or DEFAULT_ENDPOINT
        self.name = f"zenoh/{self.endpoint}"
        self.connect_timeout_s = connect_timeout_s
        self.domain = os.environ.get("ROS_DOMAIN_ID", "0") or "0"
        self._queue: queue.Queue[Arrival] = queue.Queue()
        self._session: Any = None
        self._subscribers: list[Any] = []
        self._wrong: list[str] = []  # "topic carries type" for a required topic
        self._lock = threading.Lock()
        self._connected_at = time.monotonic()
        self._changes: list[Connection] = []  # for ``notices``
        self._down = False  # no router or peer since the last check that saw one

    def start(self, wanted: Sequence[Wanted], timeout_s: float) -> None:
        try:
            zenoh = importlib.import_module("zenoh")
        except ImportError as exc:
            raise SourceError(
                "eclipse-zenoh is not installed",
                self.name,
                "install twincd[zenoh]",
            ) from exc
        self.connect_timeout_s = timeout_s
        config = zenoh.Config()
        config.insert_json5("mode", '"client"')
        config.insert_json5("connect/endpoints", json.dumps([self.endpoint]))
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self._session = zenoh.open(config)
                break
            except zenoh.ZError as exc:
                if time.monotonic() >= deadline:
                    raise SourceError(
                        f"cannot reach the Zenoh router within {timeout_s:g} s ({_reason(exc)})",
                        self.name,
                        "start the robot's Zenoh router (ros2 run rmw_zenoh_cpp rmw_zenohd), "
                        "or check the endpoint",
                        option="connect_timeout",
                    ) from exc
                time.sleep(_RETRY_S)
        self._connected_at = time.monotonic()
        for want in wanted:
            key = f"{self.domain}/{want.topic.strip('/')}/*/*"
            self._subscribers.append(self._session.declare_subscriber(key, self._callback(want)))

    def _callback(self, want: Wanted) -> Any:
        def take(sample: Any) -> None:
            key = str(sample.key_expr)
            msgtype = key_type(key)
            if msgtype != want.msgtype:
                if want.required:
                    with self._lock:
                        self._wrong.append(
                            f"topic {want.topic} carries {msgtype or key}, not {want.msgtype}"
                        )
                return
            data = bytes(sample.payload.to_bytes())
            self._queue.put(Arrival(want.topic, time.time_ns(), time.monotonic_ns(), data))

        return take

    def receive(self, timeout_s: float) -> list[Arrival]:
        with self._lock:
            wrong = self._wrong[:1]
        if wrong:
            raise SourceError(
                wrong[0],
                self.name,
                "pick the JointState topic",
                option="topic",
            )
        out = take_queued(self._queue, timeout_s)
        if out and self._down:  # messages again: the router is back
            self._note(up=True)
        if not out and self._session is not None:
            info = self._session.info
            if list(info.routers_zid()) or list(info.peers_zid()):
                self._connected_at = time.monotonic()
                if self._down:
                    self._note(up=True)
            elif not self._down:
                self._note(up=False, reason="no Zenoh router or peer")
            elif time.monotonic() - self._connected_at > self.connect_timeout_s:
                raise SourceLost(
                    f"the Zenoh router went away and did not come back within "
                    f"{self.connect_timeout_s:g} s",
                    self.name,
                    "restart it, or watch again",
                )
        return out

    def _note(self, up: bool, reason: str = "") -> None:
        self._down = not up
        self._changes.append(Connection(up, time.monotonic(), reason))

    def notices(self) -> list[Connection]:
        """The router going away (no router or peer), and coming back."""
        changes, self._changes = self._changes, []
        return changes

    def close(self) -> None:
        for sub in self._subscribers:
            sub.undeclare()
        self._subscribers = []
        if self._session is not None:
            self._session.close()
            self._session = None
