"""Blocks of samples flowing through stateful stages: the one code path for whole logs, chunked
logs and live samples.

A ``Frame`` is a block of consecutive samples as named columns (arrays whose first axis is the
sample). A stage takes frames in and gives frames out; a stage may hold samples back (a centred
derivative needs a few samples after each one, a zero-phase filter a few seconds), but it always
emits the oldest samples first, in order, and ``finish()`` flushes the rest. ``Derived`` wraps
such a signal stage so that the columns of a sample stay with the sample whatever the stage's
delay, and ``Chain`` runs stages one after the other. Fed the same samples, a chain gives the
same output whether they come in one frame, in blocks, or one at a time.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from typing import Any, Protocol, TypeVar

import numpy as np

from twincd.types import Array

T = TypeVar("T")


class Frame(Mapping[str, Array]):
    """Consecutive samples as named columns of equal length (first axis = sample)."""

    __slots__ = ("_columns", "_n")

    def __init__(self, columns: Mapping[str, Array | None] | None = None, n: int | None = None):
        cols = {k: v for k, v in (columns or {}).items() if v is not None}
        lengths = {len(v) for v in cols.values()}
        if n is None:
            n = lengths.pop() if lengths else 0
        if lengths - {n}:
            sizes = {k: len(v) for k, v in cols.items()}
            raise ValueError(f"columns of different lengths: {sizes}")
        self._columns: dict[str, Array] = cols
        self._n = n

    def __getitem__(self, key: str) -> Array:
        return self._columns[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._columns)

    def __len__(self) -> int:  # the number of columns, as for any mapping
        return len(self._columns)

    @property
    def n(self) -> int:
        """Number of samples."""
        return self._n

    def with_columns(self, **columns: Array | None) -> Frame:
        return Frame({**self._columns, **columns}, self._n)

    def head(self, k: int) -> Frame:
        return Frame({c: v[:k] for c, v in self._columns.items()}, min(k, self._n))

    def tail(self, k: int) -> Frame:
        """Everything after the first ``k`` samples."""
        return Frame({c: v[k:] for c, v in self._columns.items()}, max(self._n - k, 0))

    @staticmethod
    def concat(frames: Sequence[Frame]) -> Frame:
        frames = [f for f in frames if f.n]
        if not frames:
            return Frame()
        if len(frames) == 1:
            return frames[0]
        keys = list(frames[0])
        return Frame({k: np.concatenate([f[k] for f in frames]) for k in keys})


class Stage(Protocol):
    """A stateful block transformer: outputs are the oldest not-yet-emitted samples, in order."""

    def push(self, frame: Frame) -> Frame: ...

    def finish(self) -> Frame: ...


class FrameSink(Protocol):
    """Where per-sample results go while a log streams (an output file, a figure's envelope):
    each frame of results and the events that closed in it."""

    def write(self, frame: Frame, events: list[Any]) -> None: ...


class SignalStage(Protocol):
    """What twincd.signal's streaming classes offer: values in, values out, possibly delayed."""

    def push(self, stamp_ns: Array, values: Array) -> Array: ...

    def finish(self) -> Array: ...


class _Fifo:
    """Frames waiting for a delayed stage's output, popped sample-exact."""

    def __init__(self) -> None:
        self._frames: deque[Frame] = deque()
        self.n = 0

    def put(self, frame: Frame) -> None:
        if frame.n:
            self._frames.append(frame)
            self.n += frame.n

    def take(self, k: int) -> Frame:
        parts: list[Frame] = []
        while k > 0:
            first = self._frames[0]
            if first.n <= k:
                parts.append(self._frames.popleft())
                k -= first.n
                self.n -= first.n
            else:
                parts.append(first.head(k))
                self._frames[0] = first.tail(k)
                self.n -= k
                k = 0
        return Frame.concat(parts)


class Derived:
    """Adds column ``out`` = ``signal`` applied to column ``source`` (with the frame's
    ``stamp_ns``), holding each frame's other columns until the signal stage emits its samples.
    ``keep=False`` drops ``source`` from the output: a wide input is then not held twice (in
    the signal stage and here) while it waits.
    """

    def __init__(self, signal: SignalStage, source: str, out: str, keep: bool = True) -> None:
        self.signal = signal
        self.source = source
        self.out = out
        self.keep = keep
        self._waiting = _Fifo()

    def _emit(self, values: Array) -> Frame:
        frame = self._waiting.take(len(values))
        return frame.with_columns(**{self.out: values})

    def push(self, frame: Frame) -> Frame:
        if not frame.n:
            return frame
        values = frame[self.source]
        if not self.keep:
            frame = Frame({k: v for k, v in frame.items() if k != self.source}, frame.n)
        self._waiting.put(frame)
        return self._emit(self.signal.push(frame["stamp_ns"], values))

    def finish(self) -> Frame:
        values = self.signal.finish()
        out = self._emit(values)
        if self._waiting.n:  # a signal stage must give back every sample it took
            raise RuntimeError(f"stage for {self.out!r} lost {self._waiting.n} sample(s)")
        return out

    @property
    def pending(self) -> int:
        """Samples held back right now (bounded by the stage's lookahead)."""
        return self._waiting.n


class Mapped:
    """A stage without delay or state: ``func(frame) -> frame``."""

    def __init__(self, func: Callable[[Frame], Frame]) -> None:
        self.func = func

    def push(self, frame: Frame) -> Frame:
        return self.func(frame) if frame.n else frame

    def finish(self) -> Frame:
        return Frame()


class Chain:
    """Stages run in order; ``finish`` flushes each stage into the ones after it."""

    def __init__(self, stages: Iterable[Stage]) -> None:
        self.stages = list(stages)

    def push(self, frame: Frame) -> Frame:
        for stage in self.stages:
            frame = stage.push(frame)
        return frame

    def finish(self) -> Frame:
        out: list[Frame] = []
        for i, stage in enumerate(self.stages):
            flushed = stage.finish()
            for later in self.stages[i + 1 :]:
                flushed = later.push(flushed)
            out.append(flushed)
        return Frame.concat(out)

    def run(self, frames: Iterable[Frame]) -> Iterator[Frame]:
        """Every output frame (non-empty) for ``frames``, then the flush."""
        for frame in frames:
            out = self.push(frame)
            if out.n:
                yield out
        out = self.finish()
        if out.n:
            yield out


_DONE = object()


def prefetched(items: Iterable[T], depth: int = 2) -> Iterator[T]:
    """``items`` produced by a background thread, at most ``depth`` ahead of the consumer.

    Reading a log (zstd decompression, numpy decoding) releases the GIL for most of its time,
    so it runs on the second core while the twin and the filters work on the previous block.
    An error in the producer is raised in the consumer; leaving early stops the producer.
    """
    import queue
    import threading

    box: queue.Queue[Any] = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def offer(item: Any) -> bool:
        # never a blocking put: a consumer that has left (an error, SIGTERM) drains nothing, and
        # its join must not wait for ever on a full queue
        while not stop.is_set():
            try:
                box.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            for item in items:
                if not offer(item):
                    return
            offer(_DONE)
        except BaseException as exc:  # handed over to the consumer
            offer(exc)

    worker = threading.Thread(target=produce, name="twincd-reader", daemon=True)
    worker.start()
    try:
        while True:
            item = box.get()
            if item is _DONE:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        worker.join()
