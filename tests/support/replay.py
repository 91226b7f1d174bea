"""A real Foxglove WebSocket server in the test process (``foxglove_sdk``) that replays a log.

``Replay(log, speed=…)`` starts a server on a free port (its own ``foxglove.Context``, so that
servers of different tests never share channels), advertises every topic of the MCAP ``log``
(or ``channels``: topic → (schema name, schema text)), and, once a client subscribes to the
first topic (and to each of ``WATCHED`` the log has, up to 5 s), publishes the log's messages
``speed`` times faster than they were recorded, with the log time of *now* (as foxglove_bridge
stamps what it receives). ``loop=True`` starts again at the end until stopped.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import foxglove
from mcap.reader import make_reader

# what watch subscribes to when a log carries it: publishing waits for each of them, so that
# no twin effort is sent before its subscription arrived (samples without it are skipped)
WATCHED = ("/joint_states", "/twincd/sim_effort", "/collision_flag", "/collision_link")


class _Listener:
    def __init__(self) -> None:
        self.subscribed = threading.Event()
        self.topics: set[str] = set()

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self.topics.add(str(getattr(channel, "topic", "")))
        self.subscribed.set()

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        pass


def read_messages(log: Path) -> tuple[dict[str, tuple[str, bytes]], list[tuple[str, int, bytes]]]:
    """(topic → (schema name, schema data), [(topic, log time, payload)]) of an MCAP log."""
    channels: dict[str, tuple[str, bytes]] = {}
    messages: list[tuple[str, int, bytes]] = []
    with open(log, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.topic not in channels:
                assert schema is not None
                channels[channel.topic] = (schema.name, schema.data)
            messages.append((channel.topic, message.log_time, message.data))
    return channels, messages


class Replay:
    def __init__(
        self,
        log: Path | None = None,
        speed: float = 10.0,
        port: int = 0,
        loop: bool = False,
        channels: dict[str, tuple[str, bytes]] | None = None,
        messages: list[tuple[str, int, bytes]] | None = None,
    ) -> None:
        if log is not None:
            channels, messages = read_messages(log)
        self.channels_spec = channels or {}
        self.messages = messages or []
        self.speed = speed
        self.loop = loop
        self.context = foxglove.Context()
        self.listener = _Listener()
        self.server = foxglove.start_server(
            port=port,
            context=self.context,
            server_listener=self.listener,
            message_backlog_size=1_000_000,
        )
        self.port = self.server.port
        self.url = f"ws://127.0.0.1:{self.port}"
        self.channels = {
            topic: foxglove.Channel(
                topic,
                schema=foxglove.Schema(name=name, encoding="ros2msg", data=data),
                message_encoding="cdr",
                context=self.context,
            )
            for topic, (name, data) in self.channels_spec.items()
        }
        self._stop = threading.Event()
        self.done = threading.Event()
        self._thread = threading.Thread(target=self._play, daemon=True)
        self._thread.start()

    def _play(self) -> None:
        while not self.listener.subscribed.wait(0.05):
            if self._stop.is_set():
                return
        # the client's other subscriptions (labels, twin effort) may come in messages of their own
        wanted = set(WATCHED) & set(self.channels_spec)
        deadline = time.monotonic() + 5.0
        while not wanted <= self.listener.topics and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(0.1)
        while not self._stop.is_set():
            if not self.messages:
                break
            t0_log = self.messages[0][1]
            t0 = time.monotonic()
            for topic, log_time, data in self.messages:
                if self._stop.is_set():
                    return
                due = t0 + (log_time - t0_log) * 1e-9 / self.speed
                wait = due - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
                self.channels[topic].log(data, log_time=time.time_ns())
            if not self.loop:
                break
        self.done.set()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        for channel in self.channels.values():
            channel.close()
        self.server.stop()

    def __enter__(self) -> Replay:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()


# ---------------------------------------------------------------- a source on a fake clock


class FakeClock:
    """A monotonic clock that moves only when told (``advance``): what ``watch`` reads its time
    from in tests that must not depend on the machine's speed (patch the watch module's
    ``time`` with it)."""

    def __init__(self) -> None:
        self.now_ns = 1_000_000_000

    def monotonic(self) -> float:
        return self.now_ns * 1e-9

    def monotonic_ns(self) -> int:
        return self.now_ns

    def advance(self, seconds: float) -> None:
        self.now_ns += max(0, round(seconds * 1e9))


class Scripted:
    """A ``twincd.live.Source`` without a transport: ``messages`` ((topic, log time, payload), as
    ``read_messages`` gives them) arrive on ``clock`` as they were logged (the first at once,
    ``speed`` times faster than logged), and the connection goes away and comes back at the
    times of ``drops`` ((away at s, back at s) from the first message; nothing arrives in
    between). ``receive`` waits on the fake clock: it moves to the next arrival or by the
    timeout."""

    def __init__(
        self,
        messages: list[tuple[str, int, bytes]],
        clock: FakeClock,
        speed: float = 1.0,
        drops: tuple[tuple[float, float], ...] = (),
    ) -> None:
        self.name = "scripted"
        self.clock = clock
        first = messages[0][1]
        start = clock.now_ns
        self._due = [
            (start + round((t - first) / speed), topic, t, data) for topic, t, data in messages
        ]
        self._drops = [(start + round(a * 1e9), start + round(b * 1e9)) for a, b in drops]
        self._changes: list[Any] = []
        self._next = 0
        self._said = 0  # connection changes said (2 per drop)

    def start(self, wanted: Any, timeout_s: float) -> None:
        pass

    def _away(self, at_ns: int) -> bool:
        return any(a <= at_ns < b for a, b in self._drops)

    def receive(self, timeout_s: float) -> list[Any]:
        from twincd.live.source import Arrival

        limit = self.clock.now_ns + round(timeout_s * 1e9)
        if self._next < len(self._due) and self._due[self._next][0] > self.clock.now_ns:
            self.clock.now_ns = min(limit, self._due[self._next][0])
        elif self._next >= len(self._due):
            self.clock.now_ns = limit
        self._say_changes()
        out = []
        while self._next < len(self._due) and self._due[self._next][0] <= self.clock.now_ns:
            due, topic, log_time, data = self._due[self._next]
            self._next += 1
            if not self._away(due):
                out.append(Arrival(topic, log_time, due, data))
        return out

    def _say_changes(self) -> None:
        times = [(t, up) for a, b in self._drops for t, up in ((a, False), (b, True))]
        while self._said < len(times) and times[self._said][0] <= self.clock.now_ns:
            from twincd.live.source import Connection

            at, up = times[self._said]
            reason = "" if up else "connection closed"
            self._changes.append(Connection(up, at * 1e-9, reason))
            self._said += 1

    def notices(self) -> list[Any]:
        changes, self._changes = self._changes, []
        return changes

    def close(self) -> None:
        pass
