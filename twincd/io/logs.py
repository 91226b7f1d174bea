"""Which files are logs, and one whole log's joint states as plain arrays (contract: Inputs).

``expand_logs`` turns the paths a user gives (files, rosbag2 folders, folders of logs) into
logs, leaving out twincd's own copies beside their source. ``JointStates`` holds one log's
samples as per-log arrays, no global state, so per-log work stays pure and can run anywhere;
``twincd.prepare.setup.read_log`` fills it from the block stream (``twincd.io.stream``).
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


def _is_bag(path: Path) -> bool:
    """A rosbag2 folder: its metadata.yaml, or parts named as rosbag2 names them without it."""
    from twincd.io.sources import headless_storage

    if not path.is_dir():
        return False
    return (path / "metadata.yaml").is_file() or headless_storage(path) is not None


def expand_logs(paths: Iterable[str | Path]) -> list[Path]:
    """Every log the arguments stand for: files, rosbag2 folders (with their metadata.yaml, or
    without it: ``twincd.io.sources.headless_storage``), and folders of logs; each log once
    (``unique_logs``: a log named twice, or a log and a folder holding it, counts once)."""
    from twincd.io.sources import unreadable

    found: list[Path] = []
    for raw in paths:
        path = Path(raw)
        if not path.exists():
            raise LogReadError("no such file or folder", str(path), "check the path")
        try:
            if path.is_file() or _is_bag(path):
                found.append(path)
                continue
            below = _without_copies(sorted(_logs_below(path)))
        except PermissionError as exc:
            raise unreadable(exc, path) from exc
        if not below:
            raise LogReadError(
                "no logs in folder", str(path), "give .mcap, .db3, .bag or rosbag2 folders"
            )
        found.extend(below)
    return unique_logs(found)


def _logs_below(folder: Path) -> Iterator[Path]:
    for sub in folder.iterdir():
        if _is_bag(sub):
            yield sub  # the folder stands for its storage files
        elif sub.is_dir():
            yield from _logs_below(sub)
        elif sub.suffix in (".mcap", ".bag", ".db3"):
            yield sub


def log_files(path: Path) -> frozenset[Path]:
    """What a log is made of, resolved: a file itself; a bag folder, itself and its storage
    files (so that a bag's own file given beside it is the same log)."""
    from twincd.io.sources import storage_of

    resolved = path.resolve()
    if not path.is_dir():
        return frozenset({resolved})
    storage = storage_of(path)
    files = storage.files if storage is not None else ()
    return frozenset({resolved, *(f.resolve() for f in files)})


def unique_logs(paths: Sequence[Path], what: str = "") -> list[Path]:
    """``paths`` with each log once, in the order given: a path that resolves to a log already
    listed (the same file twice, through another spelling or a link; a log and the folder that
    holds it; a bag's storage file beside the bag) is left out, with one warning naming the
    repeats. A bag's storage file given before its bag gives way to the whole bag."""
    files = [log_files(p) for p in paths]
    kept: list[int] = []
    repeats: list[Path] = []
    for i, mine in enumerate(files):
        if any(mine <= files[k] for k in kept):
            repeats.append(paths[i])
            continue
        inside = [k for k in kept if files[k] < mine]  # a part given before its whole bag
        repeats.extend(paths[k] for k in inside)
        kept = [k for k in kept if k not in inside] + [i]
    if repeats:
        names = ", ".join(str(p) for p in repeats[:4]) + (", …" if len(repeats) > 4 else "")
        log.warning(
            "%d log(s) given more than once%s, used once each: %s",
            len(repeats),
            f" among the {what}" if what else "",
            names,
        )
    return [paths[k] for k in sorted(kept)]


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
