"""Which files are logs, and one whole log's joint states as plain arrays (contract: Inputs).

``expand_logs`` turns the paths a user gives (files, rosbag2 folders, folders of logs) into
logs, leaving out twincd's own copies beside their source. ``JointStates`` holds one log's
samples as per-log arrays, no global state, so per-log work stays pure and can run anywhere;
``twincd.pipeline.read_log`` fills it from the block stream (``twincd.io.stream``).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from twincd.errors import JointMismatchError, LogReadError
from twincd.types import BoolArray, FloatArray, IntArray

__all__ = [
    "COPY_SUFFIXES",
    "DETECT_SUFFIX",
    "TWIN_SUFFIX",
    "JointStates",
    "expand_logs",
    "source_of_copy",
]

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
