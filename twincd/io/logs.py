"""Log I/O: find logs, read joint states, labels and simulated effort into arrays (contract:
Inputs).

Logs are read by ``twincd.io.blocks`` (time-ordered sample blocks at flat memory) on top of
``twincd.io.batches`` (every log form: rosbag2 sqlite3 or MCAP folders, bare ``.mcap`` files,
ROS 1 ``.bag``). ``read_log`` gathers one log into a ``JointStates``: plain per-log arrays, no
global state, so per-log work stays pure and can run anywhere.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from twincd.errors import JointMismatchError, LogReadError
from twincd.io.batches import open_reader as open_reader  # re-exported: older imports
from twincd.io.blocks import OWN_PREFIX as OWN_PREFIX
from twincd.io.blocks import choose_topic as choose_topic
from twincd.io.blocks import iter_blocks
from twincd.io.cdr import BOOL as BOOL
from twincd.io.cdr import JOINT_STATE as JOINT_STATE
from twincd.io.options import DEFAULT_LABEL_TOPIC as DEFAULT_LABEL_TOPIC
from twincd.io.options import DEFAULT_SIM_TOPIC as DEFAULT_SIM_TOPIC
from twincd.io.options import DEFAULT_TOPIC as DEFAULT_TOPIC
from twincd.io.options import LogOptions as LogOptions
from twincd.io.options import parse_joint_map as parse_joint_map
from twincd.signal.derivatives import differentiate
from twincd.types import BoolArray, FloatArray, IntArray

log = logging.getLogger("twincd")


TWIN_SUFFIX = ".twin.mcap"  # what `simulate` writes beside a log
DETECT_SUFFIX = ".detect.mcap"  # what `detect -o FOLDER` writes per log
# copies of a log that twincd writes: in a folder beside their source, they are not more logs
COPY_SUFFIXES = (TWIN_SUFFIX, DETECT_SUFFIX)


@dataclass(frozen=True)
class JointStates:
    """One log's joint states as arrays, sorted by time, one row per sample.

    ``stamp_ns`` is the header stamp (the log time where the stamp is zero); ``log_time_ns`` is
    when the recorder got the message. Columns follow ``joint_names``.
    """

    source: str
    topic: str
    joint_names: tuple[str, ...]
    stamp_ns: IntArray
    log_time_ns: IntArray
    position: FloatArray
    velocity: FloatArray
    effort: FloatArray | None
    velocity_from_position: bool = False
    labels: BoolArray | None = None
    sim_effort: FloatArray | None = None

    def __len__(self) -> int:
        return len(self.stamp_ns)

    @property
    def t_s(self) -> FloatArray:
        """Seconds since the first stamp (subtracted in integer ns to keep precision)."""
        seconds: FloatArray = (self.stamp_ns - self.stamp_ns[0]).astype(np.float64) * 1e-9
        return seconds

    def select(self, names: Sequence[str]) -> JointStates:
        """The same log restricted to ``names``, in that order."""
        missing = [n for n in names if n not in self.joint_names]
        if missing:
            raise JointMismatchError(
                f"joints {', '.join(missing)} are not in the log",
                self.source,
                "check the robot model, the topic and the joint map",
            )
        cols = [self.joint_names.index(n) for n in names]

        def pick(a: FloatArray | None) -> FloatArray | None:
            return None if a is None else a[:, cols]

        return replace(
            self,
            joint_names=tuple(names),
            position=self.position[:, cols],
            velocity=self.velocity[:, cols],
            effort=pick(self.effort),
            sim_effort=pick(self.sim_effort),
        )


# ---------------------------------------------------------------- finding logs


def _is_rosbag2_dir(path: Path) -> bool:
    return path.is_dir() and (path / "metadata.yaml").is_file()


def expand_logs(paths: Iterable[str | Path]) -> list[Path]:
    """Every log the arguments stand for: files, rosbag2 folders, and folders of logs."""
    found: list[Path] = []
    for raw in paths:
        path = Path(raw)
        if not path.exists():
            raise LogReadError("no such file or folder", str(path), "check the path")
        if path.is_file() or _is_rosbag2_dir(path):
            found.append(path)
            continue
        below = _without_copies(sorted(_logs_below(path)))
        if not below:
            raise LogReadError(
                "no logs in folder", str(path), "give .mcap, .bag or rosbag2 folders"
            )
        found.extend(below)
    return found


def _logs_below(folder: Path) -> Iterator[Path]:
    for sub in folder.iterdir():
        if _is_rosbag2_dir(sub):
            yield sub  # the folder stands for its storage files
        elif sub.is_dir():
            yield from _logs_below(sub)
        elif sub.suffix in (".mcap", ".bag"):
            yield sub


def source_of_copy(path: Path) -> str | None:
    """``x`` for ``x.twin.mcap`` or ``x.detect.mcap`` (twincd's copies of log ``x``), else None."""
    for suffix in COPY_SUFFIXES:
        if path.name.endswith(suffix) and len(path.name) > len(suffix):
            return path.name.removesuffix(suffix)
    return None


def _without_copies(paths: list[Path]) -> list[Path]:
    """Drop ``x.twin.mcap`` and ``x.detect.mcap`` files (simulate and detect outputs) whose
    source log ``x`` is also here (``x.twin.detect.mcap``: ``x.twin.mcap``), so a folder does
    not count the same run twice; name a copy to use it. The one place that decides which
    files of a folder are logs of their own."""
    names = {p.name for p in paths}
    kept = []
    for p in paths:
        stem = source_of_copy(p)
        if stem is not None and {stem, f"{stem}.mcap", f"{stem}.bag"} & names:
            log.info("skipping %s: twincd's copy of a log in the same folder", p)
            continue
        kept.append(p)
    return kept


# ---------------------------------------------------------------- reading


def read_log(path: str | Path, options: LogOptions | None = None) -> JointStates:
    """Read one log's joint states, labels and (if present) simulated effort.

    The whole log in memory: a concatenation of ``iter_blocks``' sample blocks (sorted by
    stamp, duplicates and incomplete samples dropped), velocity differentiated from position
    where the messages carry none.
    """
    options = options or LogOptions()
    path = Path(path)
    with iter_blocks(path, options, strict=True) as stream:
        blocks = list(stream)
        topic, names = stream.topic, stream.joint_names
        has_labels, has_sim = stream.has_labels, stream.has_sim

    def cat(field: str) -> Any:
        return np.concatenate([getattr(b, field) for b in blocks])

    stamp, log_time, position, velocity = (
        cat(f) for f in ("stamp_ns", "log_time_ns", "position", "velocity")
    )
    effort = None if blocks[0].effort is None else cat("effort")
    t_s = (stamp - stamp[0]).astype(np.float64) * 1e-9
    from_position = not np.isfinite(velocity).all()
    if from_position:
        velocity = np.where(np.isfinite(velocity), velocity, differentiate(t_s, position))
    has_effort = effort is not None and bool(np.isfinite(effort).all())
    return JointStates(
        source=str(path),
        topic=topic,
        joint_names=names,
        stamp_ns=stamp,
        log_time_ns=log_time,
        position=position,
        velocity=velocity,
        effort=effort if has_effort else None,
        velocity_from_position=from_position,
        labels=cat("labels") if has_labels else None,
        sim_effort=cat("sim_effort") if has_sim else None,
    )
