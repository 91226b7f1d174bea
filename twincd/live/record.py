"""``watch -o SESSION.mcap``: what arrived, plus twincd's channels, written as it goes.

Unlike every other output, the session file is written in place (no temporary file and
rename): chunks are written and flushed to disk at least every ``FLUSH_S`` seconds, so a
session that is killed leaves a file that reads up to its last flush (twincd reads a truncated
MCAP up to the damage, with one warning). A session that ends normally writes the summary and
footer, and the file is a complete MCAP.

What a live source does not carry is synthesised and said in the ``twincd.session`` metadata
record: the QoS profile of each channel (the default profile), and the publish time (set to
the log time, which is the source's log time, e.g. the bridge's receive time).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import IO

import numpy as np
from mcap.records import Metadata

from twincd.defaults import DEFAULT_SIM_TOPIC
from twincd.detection.channels import EVENT_TOPIC, SAMPLE_CHANNELS, event_payloads
from twincd.detection.events import Event
from twincd.errors import OutputError
from twincd.io.atomic import check_target, output_error
from twincd.io.cdr import JOINT_STATE, STRING, joint_state_block
from twincd.prepare.frames import Frame
from twincd.version import __version__

__all__ = ["FLUSH_S", "SessionRecorder"]

FLUSH_S = 0.5
SIM_TOPIC = DEFAULT_SIM_TOPIC
OUTPUT_KIND = "watch"


class SessionRecorder:
    """The session file at ``path`` (see the module's docstring)."""

    def __init__(self, path: Path, source: str, joint_names: Sequence[str], force: bool) -> None:
        from twincd.io.mcap.output import McapOutput
        from twincd.io.mcap.writer import mark

        self.path = Path(path)
        if self.path.suffix.lower() != ".mcap":
            raise OutputError(
                "a session is recorded as MCAP", str(path), "give a path ending in .mcap"
            )
        check_target(self.path, OUTPUT_KIND, force=force)
        self.joint_names = list(joint_names)
        try:
            self._stream: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        except OSError as exc:
            raise output_error(exc, self.path) from exc
        self._out = McapOutput(self._stream, str(self.path))
        mark(self._out, OUTPUT_KIND)
        self._out.metadata(
            Metadata(
                name="twincd.session",
                metadata={
                    "source": source,
                    "twincd_version": __version__,
                    "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                    "synthesised": "offered_qos_profiles (the default profile) on every "
                    "channel; publish_time = log_time (the source carries neither)",
                    "log_time": "the source's log time of each message (a Foxglove bridge's "
                    "receive time, or the time rclpy handed the message over); twincd's "
                    "channels carry the log time and header stamp of their joint-state sample",
                    "written": "as it goes: a killed session reads up to its last flush",
                },
            )
        )
        self._channels: dict[str, int] = {}
        self._last_flush = time.monotonic()
        self._closed = False
        self.flush()

    def _channel(self, topic: str, msgtype: str) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            cid = self._channels[topic] = self._out.ros2_channel(topic, msgtype)
        return cid

    def message(self, topic: str, msgtype: str, log_time_ns: int, data: bytes) -> None:
        """A message as it arrived from the source."""
        t = np.array([log_time_ns], dtype=np.int64)
        self._out.append(self._channel(topic, msgtype), t, [data])

    def scored(self, frame: Frame) -> None:
        """twincd's channels (``SAMPLE_CHANNELS``, as ``detect -o`` writes them) for a scored
        frame (``SCORED_COLUMNS``), each message at its joint-state sample's log time."""
        if not frame.n:
            return
        t = frame["log_time_ns"]
        for channel in SAMPLE_CHANNELS:
            cid = self._channel(channel.topic, channel.msgtype)
            self._out.append(cid, t, channel.encode(frame, self.joint_names))

    def twin(self, frame: Frame) -> None:
        """``/twincd/sim_effort``: the twin's effort computed live (``stamp_ns``,
        ``log_time_ns``, ``position``, ``velocity``, ``sim_effort``), each at its joint-state
        sample's log time."""
        sim = joint_state_block(
            frame["stamp_ns"],
            self.joint_names,
            frame["position"],
            frame["velocity"],
            frame["sim_effort"],
        )
        self._out.append(self._channel(SIM_TOPIC, JOINT_STATE), frame["log_time_ns"], sim)

    def events(self, events: Sequence[Event], log_time_ns: Sequence[int]) -> None:
        """Closed events, one JSON String each, at the log time of their last sample."""
        if not events:
            return
        times = np.asarray(log_time_ns, dtype=np.int64)
        self._out.append(self._channel(EVENT_TOPIC, STRING), times, event_payloads(events))

    def tick(self) -> None:
        """Flush when the last flush is ``FLUSH_S`` old."""
        if time.monotonic() - self._last_flush >= FLUSH_S:
            self.flush()

    def flush(self) -> None:
        """Every message so far into chunks, and the chunks to disk."""
        self._out.flush()
        try:
            self._stream.flush()
        except OSError as exc:
            raise output_error(exc, self.path) from exc
        self._last_flush = time.monotonic()

    def close(self) -> None:
        """The summary and footer: a complete MCAP."""
        if self._closed:
            return
        self._closed = True
        try:
            self._out.finish()
        finally:
            self._out.close()
            self._stream.close()

    def abandon(self) -> None:
        """An error: keep what was flushed, write no summary."""
        if self._closed:
            return
        self._closed = True
        self._out.close()
        self._stream.close()
