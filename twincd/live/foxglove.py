"""The ``ws://`` source: a Foxglove WebSocket client (foxglove_bridge, or any such server).

The protocol, as far as ``watch`` needs it: the server sends JSON ``advertise`` messages that
list its channels (id, topic, encoding, schemaName); the client answers with ``subscribe``
(a subscription id per channel); messages then come as binary frames: opcode 1, the
subscription id (u32), the log time (u64, ns), both little-endian, then the payload (CDR for
ROS 2 channels). Both subprotocols are offered: foxglove_bridge 3.x accepts only
``foxglove.sdk.v1``, 0.8.x only ``foxglove.websocket.v1``.

The client runs on its own thread (an asyncio loop) and hands messages over through a queue.
A connection that drops is re-opened (a restarted bridge) for up to the connect timeout, and
the channels are subscribed again.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import queue
import struct
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from twincd.live.source import Arrival, Connection, SourceError, SourceLost, Wanted, ros_type

__all__ = ["SUBPROTOCOLS", "FoxgloveSource"]

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
_MESSAGE_DATA = 1
_HEAD = struct.Struct("<BIQ")
_RETRY_S = 0.1


@dataclass(frozen=True)
class _Note:
    """What the client thread tells the caller besides messages."""

    # "subscribed", "dropped" (the connection closed), "error" (fatal), "gone" (no
    # connection within the timeout)
    kind: str
    text: str = ""


class FoxgloveSource:
    """A ``Source`` on a Foxglove WebSocket server at ``url``."""

    def __init__(self, url: str, connect_timeout_s: float = 10.0) -> None:
        self.name = url
        self.url = url
        self.connect_timeout_s = connect_timeout_s
        self._queue: queue.Queue[Arrival | _Note] = queue.Queue()
        self._wanted: dict[str, Wanted] = {}
        self._advertised: dict[str, str] = {}  # topic → schema name, as last advertised
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._task: asyncio.Task[None] | None = None
        self.connections = 0
        self._reason = "no answer"  # why the last connection attempt failed
        self._changes: list[Connection] = []  # for ``notices``
        self._down = False  # the connection closed and is not back yet

    # ------------------------------------------------------------ the caller's side

    def start(self, wanted: Sequence[Wanted], timeout_s: float) -> None:
        try:
            import websockets  # noqa: F401
        except ImportError as exc:  # pragma: no cover - a dependency of twincd
            raise SourceError(
                "the WebSocket client library is not installed",
                self.name,
                "install twincd with its dependencies (pip install twincd)",
            ) from exc
        self._wanted = {w.topic: w for w in wanted}
        self.connect_timeout_s = timeout_s
        self._thread = threading.Thread(target=self._run, name="twincd-foxglove", daemon=True)
        self._thread.start()
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            try:
                item = self._queue.get(timeout=max(0.0, min(left, 0.2)))
            except queue.Empty:
                if left <= 0:
                    self.close()
                    if not self.connections:
                        raise self._unreachable(timeout_s, self._reason) from None
                    raise self._not_advertised(timeout_s) from None
                continue
            if isinstance(item, Arrival):  # cannot come before "subscribed"; keep it anyway
                self._queue.put(item)
                continue
            if item.kind == "subscribed":
                return
            self.close()
            if item.kind == "gone":
                raise self._unreachable(timeout_s, item.text)
            raise SourceError(item.text, self.name, "pick the JointState topic", option="topic")

    def _unreachable(self, timeout_s: float, reason: str) -> SourceError:
        return SourceError(
            f"cannot reach the Foxglove WebSocket server within {timeout_s:g} s ({reason})",
            self.name,
            "start foxglove_bridge there, or check the host and port",
            option="connect_timeout",
        )

    def _not_advertised(self, timeout_s: float) -> SourceError:
        required = [w.topic for w in self._wanted.values() if w.required]
        missing = [t for t in required if t not in self._advertised]
        seen = ", ".join(f"{t} ({s})" for t, s in sorted(self._advertised.items())) or "none"
        return SourceError(
            f"waited {timeout_s:g} s for channel(s) {', '.join(missing or required)} to be "
            f"advertised; the server advertises: {seen}",
            self.name,
            "name the JointState topic, or start the robot's driver",
            option="topic",
        )

    def receive(self, timeout_s: float) -> list[Arrival]:
        out: list[Arrival] = []
        try:
            item = self._queue.get(timeout=max(timeout_s, 0.0))
        except queue.Empty:
            return out
        while True:
            if isinstance(item, Arrival):
                out.append(item)
            elif item.kind == "gone":
                raise SourceLost(
                    f"the source went away and did not come back within "
                    f"{self.connect_timeout_s:g} s ({item.text})",
                    self.name,
                    "restart it, or watch again",
                )
            elif item.kind == "error":
                raise SourceError(item.text, self.name, "pick the JointState topic", option="topic")
            elif item.kind == "dropped" and not self._down:
                self._down = True
                self._changes.append(Connection(False, time.monotonic(), item.text))
            elif item.kind == "subscribed" and self._down:  # back, its topics subscribed again
                self._down = False
                self._changes.append(Connection(True, time.monotonic()))
            if len(out) >= 4096:
                return out
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return out

    def notices(self) -> list[Connection]:
        """The connection closing, and coming back with the topics subscribed again."""
        changes, self._changes = self._changes, []
        return changes

    def close(self) -> None:
        loop, task, thread = self._loop, self._task, self._thread
        if loop is not None and task is not None:
            with contextlib.suppress(RuntimeError):  # the loop already ended
                loop.call_soon_threadsafe(task.cancel)
        if thread is not None:
            thread.join(timeout=5.0)
        self._thread = None

    # ------------------------------------------------------------ the client thread

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            self._task = loop.create_task(self._main())
            with contextlib.suppress(asyncio.CancelledError):
                loop.run_until_complete(self._task)
        finally:
            loop.close()

    async def _main(self) -> None:
        from websockets.asyncio.client import connect
        from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI
        from websockets.typing import Subprotocol

        protocols = [Subprotocol(p) for p in SUBPROTOCOLS]
        since = time.monotonic()  # without a connection since
        reason = "no answer"
        while True:
            try:
                ws = await connect(
                    self.url,
                    subprotocols=protocols,
                    open_timeout=max(0.5, self.connect_timeout_s),
                    max_size=None,
                    compression=None,
                )
            except InvalidURI as exc:
                self._queue.put(_Note("gone", str(exc)))
                return
            except (OSError, InvalidHandshake, TimeoutError, asyncio.TimeoutError) as exc:
                reason = self._reason = str(exc) or type(exc).__name__
                if time.monotonic() - since > self.connect_timeout_s:
                    self._queue.put(_Note("gone", reason))
                    return
                await asyncio.sleep(_RETRY_S)
                continue
            self.connections += 1
            try:
                if not await self._session(ws):
                    return
            except ConnectionClosed as exc:
                reason = f"connection closed: {exc}"
            finally:
                await ws.close()
            reason = "connection closed"
            self._queue.put(_Note("dropped", reason))
            since = time.monotonic()

    async def _session(self, ws: Any) -> bool:
        """Subscribe and forward messages until the connection closes (True) or a fatal
        mismatch (False)."""
        subscriptions: dict[int, str] = {}  # subscription id → topic
        by_channel: dict[int, int] = {}  # channel id → subscription id
        told = False
        next_id = 0
        async for frame in ws:
            if isinstance(frame, bytes | bytearray | memoryview):
                data = bytes(frame)
                if len(data) < _HEAD.size or data[0] != _MESSAGE_DATA:
                    continue
                _, sub, log_time = _HEAD.unpack_from(data)
                topic = subscriptions.get(sub)
                if topic is not None:
                    arrival = Arrival(topic, log_time, time.monotonic_ns(), data[_HEAD.size :])
                    self._queue.put(arrival)
                continue
            try:
                message = json.loads(frame)
            except ValueError:
                continue
            op = message.get("op") if isinstance(message, dict) else None
            if op == "advertise":
                subscribe = []
                for channel in message.get("channels", []):
                    topic = str(channel.get("topic", ""))
                    schema = ros_type(str(channel.get("schemaName", "")))
                    self._advertised[topic] = schema
                    want = self._wanted.get(topic)
                    cid = int(channel.get("id", -1))
                    if want is None or cid in by_channel:
                        continue
                    encoding = str(channel.get("encoding", ""))
                    if schema != want.msgtype or encoding != "cdr":
                        what = f"{schema} in {encoding or 'no encoding'}"
                        if want.required:
                            self._queue.put(
                                _Note(
                                    "error",
                                    f"channel {topic} carries {what}, not {want.msgtype} in cdr",
                                )
                            )
                            return False
                        continue
                    next_id += 1
                    sub = next_id
                    by_channel[cid] = sub
                    subscriptions[sub] = topic
                    subscribe.append({"id": sub, "channelId": cid})
                if subscribe:
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subscribe}))
                required = {w.topic for w in self._wanted.values() if w.required}
                if not told and required <= set(subscriptions.values()):
                    told = True
                    self._queue.put(_Note("subscribed"))
            elif op == "unadvertise":
                for cid in message.get("channelIds", []):
                    sub = by_channel.pop(int(cid), None)
                    if sub is not None:
                        subscriptions.pop(sub, None)
        return True
