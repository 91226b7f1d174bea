"""The public MCAP writers: a log copied with new channels added, or a new log, written atomically.

Output is always a bare ros2-profile MCAP with ``ros2msg`` schemas, ``cdr`` messages and an
``offered_qos_profiles`` entry on every channel, written to a temporary file beside the target
and renamed into place (``twincd.io.atomic``), so an interrupted run leaves nothing behind.
``AugmentedMcap`` copies its source losslessly (``twincd.io.mcap.copy``) and then takes new
channels in blocks; ``McapLogWriter`` writes a new log (synthetic recordings, tests). New
channels get chunks of their own (``twincd.io.mcap.messages``), which may overlap the copied
chunks in time; readers find them through the chunk index.
"""

from __future__ import annotations

import abc
import contextlib
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TypeVar

import numpy as np
from mcap.records import Metadata

from twincd.io.atomic import MARKER, atomic_output
from twincd.io.mcap.copy import copy_log
from twincd.io.mcap.messages import BATCH
from twincd.io.mcap.output import McapOutput
from twincd.io.mcap.records import Payloads, Times
from twincd.version import __version__

__all__ = ["AugmentedMcap", "McapLogWriter", "NewTopic", "write_augmented"]


@dataclass
class NewTopic:
    """A channel to add: (log_time_ns, publish_time_ns, cdr_bytes) triples."""

    topic: str
    msgtype: str
    messages: Iterable[tuple[int, int, bytes]]


class _Batches:
    """Per-message writes gathered into blocks per channel for ``McapOutput.append``."""

    def __init__(self, out: McapOutput) -> None:
        self.out = out
        self.pending: dict[int, tuple[list[int], list[int], list[bytes]]] = {}

    def add(self, channel_id: int, log_time: int, publish_time: int, data: bytes) -> None:
        times, publish, payloads = self.pending.setdefault(channel_id, ([], [], []))
        times.append(log_time)
        publish.append(publish_time)
        payloads.append(data)
        if len(times) >= BATCH:
            self.flush(channel_id)

    def flush(self, channel_id: int | None = None) -> None:
        for cid in [channel_id] if channel_id is not None else sorted(self.pending):
            times, publish, payloads = self.pending.pop(cid, ([], [], []))
            if times:
                self.out.append(
                    cid,
                    np.array(times, dtype=np.int64),
                    payloads,
                    np.array(publish, dtype=np.int64),
                )


# ---------------------------------------------------------------- public writers


def mark(out: McapOutput, output: str) -> None:
    """The metadata record by which a later run knows this file as twincd's own ``output``
    (``twincd.io.atomic.output_kind``): it may replace it without being forced."""
    out.metadata(Metadata(name=MARKER, metadata={"output": output, "version": __version__}))


def _finish(
    stack: contextlib.ExitStack,
    finish: Callable[[], None],
    exc_type: type[BaseException] | None,
    exc: BaseException | None,
    tb: TracebackType | None,
) -> None:
    """End a writer: ``finish`` then rename into place; on any error remove the temporary."""
    if exc_type is not None:
        stack.__exit__(exc_type, exc, tb)  # the caller's error goes on, unchanged
        return
    try:
        finish()
    except BaseException as error:
        stack.__exit__(type(error), error, error.__traceback__)
        raise
    stack.close()


class _AtomicMcap(abc.ABC):
    """An MCAP written to ``path`` atomically and marked as twincd's ``output``: opened on
    entering, finished and renamed into place when the block ends without error."""

    def __init__(self, path: Path, output: str) -> None:
        self._path = path
        self.output = output
        self._stack: contextlib.ExitStack | None = None
        self._out: McapOutput | None = None

    def _begin(self, out: McapOutput) -> None:  # noqa: B027 (a hook: nothing, unless overridden)
        """What goes into ``out`` before the mark (nothing here)."""

    def _end(self, out: McapOutput) -> None:
        """What ends ``out`` before the rename."""
        out.finish()

    @abc.abstractmethod
    def _ready(self, channel_id: int) -> McapOutput:
        """The output, ready for a block of ``channel_id``'s messages (each writer's checks)."""

    def write_many(
        self,
        channel_id: int,
        log_time_ns: Times,
        payloads: Payloads,
        publish_time_ns: Times | None = None,
    ) -> None:
        """Messages of one channel: log times (n,), CDR payloads as a uint8 array (n, L) of
        equal-size messages or n ``bytes``; publish times default to the log times. Sequence
        numbers continue from the channel's previous messages."""
        self._ready(channel_id).append(channel_id, log_time_ns, payloads, publish_time_ns)

    def __enter__(self: _Writer) -> _Writer:
        with contextlib.ExitStack() as stack:
            stream = stack.enter_context(atomic_output(self._path))
            out = McapOutput(stream, str(self._path))
            stack.callback(out.close)
            self._begin(out)
            mark(out, self.output)
            self._out = out
            self._stack = stack.pop_all()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        stack, out = self._stack, self._out
        self._stack = self._out = None
        if stack is None or out is None:
            return
        _finish(stack, lambda: self._end(out), exc_type, exc, tb)


_Writer = TypeVar("_Writer", bound=_AtomicMcap)


class AugmentedMcap(_AtomicMcap):
    """``source`` copied losslessly into ``target``, plus new channels written in blocks.

    >>> with AugmentedMcap(source, target, {"/twincd/sim_effort"}) as out:  # doctest: +SKIP
    ...     ch = out.add_channel("/twincd/sim_effort", "sensor_msgs/msg/JointState")
    ...     out.write(ch, log_time_ns, payloads)  # (n,) int64 and (n, L) uint8, or n bytes

    Topics in ``replace_topics`` that the source already has (a log simulated before) are left
    out of the copy, so that writing them again replaces rather than duplicates them. The copy
    happens on entering; ``target`` appears only when the block ends without error, and may be
    the source itself (a bare ``.mcap``): the rename comes after the copy.
    """

    def __init__(
        self,
        source: Path,
        target: Path,
        replace_topics: Collection[str] = (),
        output: str = "detect",
        partial: bool = False,
    ) -> None:
        self.source = Path(source)
        self.target = Path(target)
        super().__init__(self.target, output)
        self.partial = partial  # a truncated source is copied up to the damage
        self.replace_topics = frozenset(replace_topics)
        self._new: set[int] = set()
        self._copied_topics: set[str] = set()

    def _begin(self, out: McapOutput) -> None:
        copy_log(self.source, out, self.replace_topics, self.partial)
        self._copied_topics = {c.topic for c in out.channels.values()}

    def _output(self) -> McapOutput:
        if self._out is None:
            raise RuntimeError("use AugmentedMcap as a context manager")
        return self._out

    def add_channel(self, topic: str, msgtype: str) -> int:
        """A new ros2 channel (``ros2msg`` schema, ``cdr``, default QoS); its id for ``write``."""
        out = self._output()
        if topic in self._copied_topics:
            raise ValueError(f"{topic} is already in the source: list it in replace_topics")
        channel_id = out.ros2_channel(topic, msgtype)
        self._new.add(channel_id)
        return channel_id

    def _ready(self, channel_id: int) -> McapOutput:
        if channel_id not in self._new:
            raise ValueError(f"channel {channel_id} was not added with add_channel")
        return self._output()

    # a new channel's messages, many at once (``write_many``)
    write = _AtomicMcap.write_many


class McapLogWriter(_AtomicMcap):
    """Write a new ros2 MCAP log (e.g. synthetic recordings) atomically.

    >>> with McapLogWriter(Path("run.mcap")) as out:          # doctest: +SKIP
    ...     ch = out.add_topic("/joint_states", "sensor_msgs/msg/JointState")
    ...     out.write(ch, log_time_ns, cdr_bytes)
    """

    def __init__(self, path: Path, output: str = "synth") -> None:
        self.path = Path(path)
        super().__init__(self.path, output)
        self._batches: _Batches | None = None

    def _begin(self, out: McapOutput) -> None:
        self._batches = _Batches(out)

    def _end(self, out: McapOutput) -> None:
        batches, self._batches = self._batches, None
        if batches is not None:
            batches.flush()
        out.finish()

    def _parts(self) -> tuple[McapOutput, _Batches]:
        if self._out is None or self._batches is None:
            raise RuntimeError("use McapLogWriter as a context manager")
        return self._out, self._batches

    def add_topic(self, topic: str, msgtype: str) -> int:
        return self._parts()[0].ros2_channel(topic, msgtype)

    def write(
        self, channel_id: int, log_time_ns: int, data: bytes, publish_time_ns: int | None = None
    ) -> None:
        """One message (buffered per channel and written in blocks)."""
        _, batches = self._parts()
        publish = log_time_ns if publish_time_ns is None else publish_time_ns
        batches.add(channel_id, int(log_time_ns), int(publish), bytes(data))

    def _ready(self, channel_id: int) -> McapOutput:
        out, batches = self._parts()
        batches.flush(channel_id)  # keep this channel's sequence numbers in write order
        return out


def write_augmented(source: Path, target: Path, new_topics: Iterable[NewTopic]) -> None:
    """Write ``target``: every message of ``source`` unchanged, plus ``new_topics``.

    A topic of ``new_topics`` that the source already has (a log simulated before) is replaced,
    not duplicated; every other input message is copied unchanged.

    ``target`` may equal a bare MCAP ``source`` (in-place rewrite): the copy is complete before
    the rename replaces it.
    """
    new_topics = list(new_topics)
    with AugmentedMcap(source, target, {t.topic for t in new_topics}) as out:
        for topic in new_topics:
            channel_id = out.add_channel(topic.topic, topic.msgtype)
            batch: list[tuple[int, int, bytes]] = []
            for message in topic.messages:
                batch.append(message)
                if len(batch) >= BATCH:
                    _write_batch(out, channel_id, batch)
                    batch = []
            _write_batch(out, channel_id, batch)


def _write_batch(out: AugmentedMcap, channel_id: int, batch: list[tuple[int, int, bytes]]) -> None:
    if batch:
        log_time, publish_time, payloads = zip(*batch)
        out.write(
            channel_id,
            np.array(log_time, dtype=np.int64),
            list(payloads),
            np.array(publish_time, dtype=np.int64),
        )
