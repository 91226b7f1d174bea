"""The ``ros2`` source: DDS through rclpy (the user's ROS 2, or the extra ``twincd[ros]``).

Subscriptions take raw CDR (``raw=True``), so twincd decodes them with its own numpy decoders
as for a log; the QoS is best effort with a deep history (it matches reliable and best-effort
publishers). The log time of a message is the time rclpy handed it over. The node spins on its
own thread (its own rclpy context) and hands messages over through a queue.
"""

from __future__ import annotations

import importlib
import queue
import threading
import time
from collections.abc import Sequence
from typing import Any

from twincd.live.source import Arrival, Connection, SourceError, Wanted, take_queued

__all__ = ["Ros2Source"]

_DEPTH = 1000


def _rclpy() -> Any:
    try:
        return importlib.import_module("rclpy")
    except ImportError as exc:
        raise SourceError(
            "rclpy is not installed",
            "ros2",
            "source your ROS 2 installation (setup.bash) first, or install twincd[ros] "
            "(Linux x86_64, Python 3.10–3.13)",
        ) from exc


def _message_class(msgtype: str) -> Any:
    package, _, name = msgtype.split("/")
    try:
        return getattr(importlib.import_module(f"{package}.msg"), name)
    except (ImportError, AttributeError) as exc:
        raise SourceError(
            f"the ROS 2 message type {msgtype} is not installed",
            "ros2",
            f"install the {package} messages (ros-{package.replace('_', '-')})",
        ) from exc


class Ros2Source:
    """A ``Source`` on ROS 2 topics through rclpy."""

    def __init__(self, connect_timeout_s: float = 10.0) -> None:
        self.name = "ros2"
        self.connect_timeout_s = connect_timeout_s
        self._queue: queue.Queue[Arrival] = queue.Queue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._context: Any = None
        self._node: Any = None

    def start(self, wanted: Sequence[Wanted], timeout_s: float) -> None:
        rclpy = _rclpy()
        executors = importlib.import_module("rclpy.executors")
        qos_module = importlib.import_module("rclpy.qos")

        self._context = rclpy.Context()
        rclpy.init(context=self._context)
        self._node = rclpy.create_node("twincd_watch", context=self._context)
        node = self._node
        deadline = time.monotonic() + timeout_s
        required = {w.topic: w for w in wanted if w.required}
        while True:
            types = dict(node.get_topic_names_and_types())
            for topic, want in required.items():
                offered = types.get(topic)
                if offered and want.msgtype not in offered:
                    self.close()
                    raise SourceError(
                        f"topic {topic} carries {', '.join(offered)}, not {want.msgtype}",
                        "ros2",
                        "pick the JointState topic",
                        option="topic",
                    )
            if all(t in types for t in required) or time.monotonic() >= deadline:
                break
            time.sleep(0.05)
        missing = [t for t in required if t not in types]
        if missing:
            seen = ", ".join(sorted(types)) or "none"
            self.close()
            raise SourceError(
                f"waited {timeout_s:g} s for topic(s) {', '.join(missing)} on ROS 2 "
                f"(domain {self._domain()}); the graph has: {seen}",
                "ros2",
                "name the JointState topic, check ROS_DOMAIN_ID, or start the robot's driver",
                option="topic",
            )
        qos = qos_module.QoSProfile(
            depth=_DEPTH,
            history=qos_module.HistoryPolicy.KEEP_LAST,
            reliability=qos_module.ReliabilityPolicy.BEST_EFFORT,
        )
        for want in wanted:
            node.create_subscription(
                _message_class(want.msgtype), want.topic, self._callback(want.topic), qos, raw=True
            )
        executor = executors.SingleThreadedExecutor(context=self._context)
        executor.add_node(node)

        def spin() -> None:
            while not self._stop.is_set() and self._context.ok():
                executor.spin_once(timeout_sec=0.05)

        self._thread = threading.Thread(target=spin, name="twincd-ros2", daemon=True)
        self._thread.start()

    def _domain(self) -> str:
        import os

        return os.environ.get("ROS_DOMAIN_ID", "0")

    def _callback(self, topic: str) -> Any:
        def take(data: bytes) -> None:
            self._queue.put(Arrival(topic, time.time_ns(), time.monotonic_ns(), bytes(data)))

        return take

    def notices(self) -> list[Connection]:
        """None: DDS has no connection that goes away (publishers simply stop)."""
        return []

    def receive(self, timeout_s: float) -> list[Arrival]:
        return take_queued(self._queue, timeout_s)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        if self._node is not None:
            self._node.destroy_node()
            self._node = None
        if self._context is not None:
            rclpy = _rclpy()
            if self._context.ok():
                rclpy.shutdown(context=self._context)
            self._context = None
