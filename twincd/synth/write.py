"""Synthetic logs to files: a path (or run) as a bare ros2 MCAP file or a rosbag2 sqlite3
folder, a segment at a time, and a whole run set in the paper's protocol (``write_dataset``)."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from twincd.errors import OutputError, UsageError
from twincd.executors.local import Executor, Progress
from twincd.io.cdr import typestore
from twincd.synth.config import SPLITS, SynthConfig, check_seed
from twincd.synth.messages import TOPICS, run_messages
from twincd.synth.simulate import SynthRun, path_segments

# samples written so far (for a progress display); called after each segment
SampleProgress = Callable[[int], None]


def _stream(
    segments: Iterable[SynthRun],
    add_topic: Callable[[str, str], Any],
    write: Callable[[Any, int, bytes], None],
    progress: SampleProgress | None = None,
) -> int:
    """Every message of ``segments`` to a writer, a segment at a time; returns the samples.

    A topic is registered when first used, in the order of ``TOPICS`` within a segment.
    """
    channels: dict[str, Any] = {}
    samples = 0
    for segment in segments:
        messages = run_messages(segment)
        count = len(segment.stamp_ns)
        del segment  # its arrays go before the writer's buffers grow
        used = {m[0] for m in messages}
        for topic, msgtype in TOPICS:
            if topic in used and topic not in channels:
                channels[topic] = add_topic(topic, msgtype)
        for topic, log_time, data in messages:
            write(channels[topic], log_time, data)
        samples += count
        if progress:
            progress(count)
    return samples


def _mcap_messages(
    segments: Iterable[SynthRun], path: Path, progress: SampleProgress | None = None
) -> int:
    from twincd.io.mcap import McapLogWriter

    with McapLogWriter(Path(path)) as out:
        return _stream(segments, out.add_topic, out.write, progress)


def write_mcap(run: SynthRun, path: Path) -> Path:
    """A run held in memory as a bare ros2 MCAP file (atomic)."""
    _mcap_messages([run], path)
    return Path(path)


def write_path(
    config: SynthConfig,
    seed: int,
    split: str,
    index: int,
    path: Path,
    progress: SampleProgress | None = None,
) -> int:
    """A path of a run set as a bare ros2 MCAP file (atomic), made and written a segment at a
    time: memory does not grow with its length. Returns its samples. Same bytes as
    ``write_mcap(simulate_path(...))`` whenever log times do not interleave across a join
    (latency below one sample period)."""
    return _mcap_messages(path_segments(config, seed, split, index), path, progress)


def write_rosbag2(run: SynthRun | Iterable[SynthRun], path: Path) -> Path:
    """A run, or the segments of a path, as a rosbag2 sqlite3 folder (written beside, renamed
    into place)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.metadata import parse_qos

    from twincd.io.mcap import DEFAULT_QOS

    qos = parse_qos(DEFAULT_QOS)
    segments = [run] if isinstance(run, SynthRun) else run

    path = Path(path)
    tmp_parent = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    shutil.rmtree(tmp_parent, ignore_errors=True)
    try:
        tmp_parent.mkdir(parents=True)
        writer = Writer(tmp_parent / path.name, version=8, storage_plugin=StoragePlugin.SQLITE3)
        writer.open()
        try:
            _stream(
                segments,
                lambda topic, msgtype: writer.add_connection(
                    topic, msgtype, typestore=typestore(), offered_qos_profiles=qos
                ),
                writer.write,
            )
        finally:
            writer.close()
        if path.exists():
            shutil.rmtree(path)
        os.replace(tmp_parent / path.name, path)
    except OSError as exc:
        raise OutputError(
            f"cannot write rosbag2 folder: {exc}", str(path), "pick a writable OUTDIR"
        ) from exc
    finally:
        shutil.rmtree(tmp_parent, ignore_errors=True)
    return path


def log_name(split: str, index: int) -> str:
    return f"{split}_{index:03d}"


@dataclass(frozen=True)
class _Written:
    path: Path
    samples: int  # those not yet reported to a progress display


def _make_one(
    args: tuple[SynthConfig, int, str, int, Path], progress: Progress | None = None
) -> _Written:
    """One path written; with ``progress`` (in this process), its samples reported as its
    segments are written."""
    config, seed, split, index, target = args
    if progress is None:
        return _Written(target, write_path(config, seed, split, index, target))
    write_path(config, seed, split, index, target, lambda samples: progress(0, samples))
    return _Written(target, 0)


def write_dataset(
    outdir: Path,
    config: SynthConfig | None = None,
    seed: int = 0,
    counts: Sequence[int] = (30, 5, 5),
    rosbag2_copy: bool = True,
    jobs: int = 1,
    progress: Progress | None = None,
) -> list[Path]:
    """The paper's protocol: ``outdir/{train,val,test}/<split>_NNN.mcap``.

    Train and val paths are collision-free, test paths have presses. With ``rosbag2_copy``, the
    first test path is also written as a rosbag2 sqlite3 folder ``outdir/rosbag2/test_000``
    (outside ``test/``, so a folder argument does not read the same log twice).
    ``progress(paths, samples)`` is told of the paths and samples written as they are (of each
    segment with ``jobs`` 1, of each path otherwise). Returns the paths written, in order.
    """
    config = config or SynthConfig()
    check_seed(seed)
    if len(counts) != len(SPLITS) or any(c < 0 for c in counts):
        raise UsageError(
            "path counts must be three numbers ≥ 0",
            "train/val/test counts",
            "give 0 or more each",
            option="train,val,test",
        )
    if jobs < 1:
        raise UsageError(f"jobs must be ≥ 1, got {jobs}", "jobs", "give 1 or more", option="jobs")
    outdir = Path(outdir)
    if outdir.exists() and not outdir.is_dir():
        raise OutputError("output exists and is not a folder", str(outdir), "give a folder name")
    tasks: list[tuple[SynthConfig, int, str, int, Path]] = []
    for split, count in zip(SPLITS, counts, strict=True):
        for index in range(count):
            tasks.append(
                (config, seed, split, index, outdir / split / f"{log_name(split, index)}.mcap")
            )
    try:
        for split, count in zip(SPLITS, counts, strict=True):
            if count:
                (outdir / split).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(
            f"cannot create folder: {exc.strerror}", str(outdir), "pick a writable OUTDIR"
        ) from exc
    executor = Executor(jobs)
    make = partial(_make_one, progress=progress) if executor.workers == 1 else _make_one
    written = [w.path for w in executor.map(make, tasks, progress)]
    if rosbag2_copy and counts[2] > 0:
        (outdir / "rosbag2").mkdir(exist_ok=True)
        target = outdir / "rosbag2" / log_name("test", 0)
        written.append(write_rosbag2(path_segments(config, seed, "test", 0), target))
    return written
