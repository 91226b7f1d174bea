"""Progress within a log: whoever listens (the CLI, drawing on a terminal) is told of the
samples each block of a log brings as it streams through the chain (``PreparedStream``); the
library itself draws nothing. The listener is per context (a ``ContextVar``): work that runs in
other processes, or on a cluster, reports per log instead (``twincd.executors.run.run_logs``)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from contextvars import ContextVar

SampleListener = Callable[[int], None]

_listener: ContextVar[SampleListener | None] = ContextVar("twincd_samples", default=None)


@contextlib.contextmanager
def listening(callback: SampleListener) -> Iterator[None]:
    """``callback(samples)`` is told of each block's samples while the block runs."""
    token = _listener.set(callback)
    try:
        yield
    finally:
        _listener.reset(token)


def samples_done(samples: int) -> None:
    """Tell the listener, if any, that ``samples`` more samples went through."""
    callback = _listener.get()
    if callback is not None and samples:
        callback(samples)
