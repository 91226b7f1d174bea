"""Per-sample detection outputs, written while a log streams (contract: Topics twincd writes): the
input copied losslessly into MCAP plus twincd's channels (``twincd.detection.channels``:
``/twincd/residual``, ``/twincd/score``, ``/twincd/collision`` and ``/twincd/event``), or one
CSV/JSONL row per sample with those channels' columns. Every output is written to a temporary
file and renamed into place only when the log has been processed completely."""

from __future__ import annotations

import contextlib
import csv
import io
import json
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from twincd.detection.channels import (
    COLLISION_TOPIC,
    EVENT_TOPIC,
    RESIDUAL_TOPIC,
    SAMPLE_CHANNELS,
    SCORE_TOPIC,
    event_payloads,
    table_columns,
    table_header,
)
from twincd.detection.events import Event
from twincd.errors import OutputError, UsageError
from twincd.prepare.frames import Frame, FrameSink

OUTPUT_SUFFIXES = (".mcap", ".csv", ".jsonl")


def check_output_kind(target: Path) -> None:
    if target.suffix.lower() not in OUTPUT_SUFFIXES:
        raise OutputError(
            f"unknown output type {target.suffix!r}",
            str(target),
            "name the output .mcap, .csv or .jsonl",
        )


DETECT_SUFFIX = ".detect.mcap"


def log_stem(path: Path) -> str:
    """A log's name without its suffix (a rosbag2 folder: its name)."""
    return path.name if path.is_dir() else path.stem


def distinct_targets(
    paths: Sequence[Path], name: Callable[[Path], Path], folder: Path | None = None
) -> list[Path]:
    """Where each log's output goes: ``name(path)`` (a path beside the log), or its file name
    in ``folder``. Logs whose outputs would be one file each get their parent folders' names
    in front (``d1/run.mcap``, ``d2/run.mcap`` → ``d1_run…``, ``d2_run…``), as few as make
    them distinct; the names depend on the set of logs, not their order. Logs that no prefix
    tells apart are refused, naming both, before any work."""
    base = [name(p) if folder is None else folder / name(p).name for p in paths]
    parents = [[part for part in reversed(p.absolute().parent.parts) if part != "/"] for p in paths]
    depth = [0] * len(paths)
    while True:
        targets = [
            t.with_name("_".join([*reversed(up[:d]), t.name]))
            for t, up, d in zip(base, parents, depth, strict=True)
        ]
        seen: dict[Path, list[int]] = {}
        for i, target in enumerate(targets):
            seen.setdefault(target.absolute(), []).append(i)
        clashes = [group for group in seen.values() if len(group) > 1]
        if not clashes:
            return targets
        grown = False
        for i in (i for group in clashes for i in group):
            if depth[i] < len(parents[i]):
                depth[i] += 1
                grown = True
        if not grown:
            a, b = (paths[i] for i in clashes[0][:2])
            raise UsageError(
                "two logs would write one output",
                f"{a} and {b}: {targets[clashes[0][0]]}",
                "give each log once, or rename one of them",
            )


def detect_targets(paths: Sequence[Path], output: Path | None) -> list[Path | None]:
    """Where ``detect`` writes each log's per-sample output: nowhere (None), ``output`` itself
    (one log, a file name), or one ``<log>.detect.mcap`` per log in folder ``output``."""
    from twincd.io.atomic import refuse_special

    if output is None:
        return [None] * len(paths)
    refuse_special(output)  # /dev/full has no suffix, and is no folder either
    if len(paths) == 1 and (output.suffix or output.is_file()):
        check_output_kind(output)
        return [output]
    if output.suffix or output.is_file():
        raise UsageError(
            "several logs need an output folder", str(output), "give a folder name", option="output"
        )
    make_output_folder(output)
    named = distinct_targets(paths, lambda p: p.with_name(log_stem(p) + DETECT_SUFFIX), output)
    return list(named)


def make_output_folder(folder: Path) -> None:
    """Create the output folder of a multi-log run (and its parents), or fail in one line."""
    from twincd.io.atomic import output_error, refuse_special

    refuse_special(folder)
    if folder.exists() and not folder.is_dir():
        raise UsageError(
            "several logs need an output folder", str(folder), "give a folder name", option="output"
        )
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise output_error(exc, folder) from exc


@contextlib.contextmanager
def open_sink(
    source: Path, target: Path, joint_names: Sequence[str], partial: bool = False
) -> Iterator[FrameSink]:
    """A sink for ``target`` by its suffix; the file appears only if the block completes.
    ``partial``: an MCAP copy of a truncated source stops at the damage (as reading does)."""
    check_output_kind(target)
    if target.suffix.lower() == ".mcap":
        if target.resolve() == Path(source).resolve():
            raise OutputError("output would overwrite the input", str(target), "pick another")
        with McapSink(source, target, joint_names, partial) as sink:
            yield sink
        return
    from twincd.io.atomic import atomic_output

    with atomic_output(target) as stream:
        text = io.TextIOWrapper(stream, encoding="utf-8", newline="")
        table: FrameSink = (
            CsvSink(text, joint_names)
            if target.suffix.lower() == ".csv"
            else JsonlSink(text, joint_names)
        )
        yield table
        text.flush()
        text.detach()


class McapSink:
    """The input log plus twincd's channels; each message stamped like its joint state."""

    def __init__(
        self, source: Path, target: Path, joint_names: Sequence[str], partial: bool = False
    ) -> None:
        from twincd.io.mcap import AugmentedMcap

        self.joint_names = list(joint_names)
        replaced = (*(c.topic for c in SAMPLE_CHANNELS), EVENT_TOPIC)
        self._out = AugmentedMcap(source, target, replaced, output="detect", partial=partial)

    def __enter__(self) -> McapSink:
        from twincd.io.cdr import STRING

        self._out.__enter__()
        self._channels = [self._out.add_channel(c.topic, c.msgtype) for c in SAMPLE_CHANNELS]
        self._event = self._out.add_channel(EVENT_TOPIC, STRING)
        return self

    def __exit__(self, *exc: Any) -> None:
        self._out.__exit__(*exc)

    def write(self, frame: Frame, events: list[Event]) -> None:
        if frame.n:
            t = frame["log_time_ns"]
            for channel, cid in zip(SAMPLE_CHANNELS, self._channels, strict=True):
                self._out.write(cid, t, channel.encode(frame, self.joint_names))
        if events:
            # an event is published when it ends: at its last sample's time
            times = np.array([e.end_ns for e in events], dtype=np.int64)
            self._out.write(self._event, times, event_payloads(events))


class CsvSink:
    """One CSV row per sample (``table_header``'s columns); a flag as 0/1 so that any tool
    reads it, every float as Python writes it back exactly."""

    def __init__(self, text: IO[str], joint_names: Sequence[str]) -> None:
        self._writer = csv.writer(text, lineterminator="\n")
        self._writer.writerow(table_header(joint_names))

    def write(self, frame: Frame, events: list[Event]) -> None:
        if not frame.n:
            return
        columns = [
            map(repr, c.tolist()) if c.dtype.kind == "f" else c.astype(np.int64).tolist()
            for c in table_columns(frame)
        ]
        self._writer.writerows(zip(*columns, strict=True))


class JsonlSink:
    """One JSON object per sample, keyed by ``table_header``'s columns."""

    def __init__(self, text: IO[str], joint_names: Sequence[str]) -> None:
        self._text = text
        self._keys = table_header(joint_names)

    def write(self, frame: Frame, events: list[Event]) -> None:
        if not frame.n:
            return
        columns = [c.tolist() for c in table_columns(frame)]
        for values in zip(*columns, strict=True):
            self._text.write(json.dumps(dict(zip(self._keys, values, strict=True))) + "\n")


__all__ = [
    "COLLISION_TOPIC",
    "DETECT_SUFFIX",
    "EVENT_TOPIC",
    "OUTPUT_SUFFIXES",
    "RESIDUAL_TOPIC",
    "SCORE_TOPIC",
    "CsvSink",
    "JsonlSink",
    "McapSink",
    "check_output_kind",
    "detect_targets",
    "distinct_targets",
    "log_stem",
    "make_output_folder",
    "open_sink",
]
