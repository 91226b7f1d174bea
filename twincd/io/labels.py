"""The collision labels as their messages say them (contract: Inputs, ``--label-topic``):
std_msgs/Bool, each message holding until the next. Joint-state samples take the label held at
their log time (``twincd.io.stream``); a push whose messages all fall between two samples (in a
hole of the recording) marks none of them, so ``evaluate`` reads the spans from the messages
too, to count such pushes apart instead of losing them. A small topic, read by the topic reader
every command reads a log with."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from twincd.io.cdr import BOOL
from twincd.types import IntArray

__all__ = ["read_label_spans"]

OPEN_END = np.iinfo(np.int64).max  # a span still on at the log's last message


def read_label_spans(path: str | Path, topic: str, strict: bool = False) -> IntArray | None:
    """(k, 2) log times [on, off) of each span the label ``topic`` held True (``OPEN_END``: to
    the end); None: the log lacks ``topic``. ``strict`` as for every reader."""
    from twincd.io.links import read_small_topic
    from twincd.io.stream import BoolBatch

    batches = read_small_topic(path, topic, BOOL, "label", strict)
    if batches is None:
        return None
    times: list[IntArray] = []
    values: list[np.ndarray] = []
    for batch in batches:
        if isinstance(batch, BoolBatch):
            times.append(batch.log_time_ns)
            values.append(batch.value)
    if not times:
        return np.zeros((0, 2), dtype=np.int64)
    t = np.concatenate(times).astype(np.int64)
    v = np.concatenate(values).astype(bool)
    order = np.argsort(t, kind="stable")  # equal times: the later read wins, as when held
    t, v = t[order], v[order]
    step = np.diff(np.r_[False, v].astype(np.int8))  # +1: switched on, −1: switched off
    on, off = t[step == 1], t[step == -1]
    if len(off) < len(on):
        off = np.r_[off, OPEN_END]
    return np.stack([on, off], axis=1).astype(np.int64)
