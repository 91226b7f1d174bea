"""What a log path holds and how to open it when no fast reader applies.

``rosbag2_storage`` reads a rosbag2 folder's metadata (its storage format and files), the one
place that does; ``headless_storage`` finds the storage files of a rosbag2 folder whose
``metadata.yaml`` is missing (a recorder killed before writing it); ``storage_of`` says which
storage files any log path stands for (what every reader and the MCAP copy go by);
``refuse_non_logs`` turns paths that cannot be logs into one clear error; and ``open_reader``
opens any other log form with rosbags' AnyReader (ROS 1 bags, compressed bags).
"""

from __future__ import annotations

import itertools
import logging
import re
from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import Any

from twincd.errors import LogReadError
from twincd.io.cdr import typestore

__all__ = [
    "Storage",
    "first_line",
    "headless_storage",
    "open_reader",
    "refuse_non_logs",
    "rosbag2_storage",
    "storage_of",
]

log = logging.getLogger("twincd")

# how rosbag2 names a bag's storage files: NAME_0.db3, NAME_1.db3, … (or .mcap), NAME being
# the bag folder's name when the recorder named it
_PART = re.compile(r"^(?P<name>.+)_(?P<index>0|[1-9][0-9]*)\.(?P<ext>db3|mcap)$")


def first_line(exc: BaseException) -> str:
    """An exception's first line of text (its type name when it has none)."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def open_reader(path: Path) -> Any:
    """An opened rosbags AnyReader, or one clear LogReadError."""
    from rosbags.highlevel import AnyReader

    refuse_non_logs(path)
    try:
        # Humble-era rosbag2 bags store no message definitions: bring the standard ones
        reader = AnyReader([path], default_typestore=typestore())
        reader.open()
    except Exception as exc:  # the I/O edge: every reader failure becomes one line
        raise LogReadError(
            f"cannot read log: {first_line(exc)}",
            str(path),
            "check that it is a rosbag2 folder, an MCAP file or a ROS 1 bag and not truncated",
        ) from exc
    return reader


def unreadable(exc: OSError, path: Path) -> LogReadError:
    """A log (or a folder of logs) the operating system will not let twincd read: one clear
    error naming the path (exit 2), never an internal error."""
    where = exc.filename if isinstance(exc.filename, str) and exc.filename else str(path)
    return LogReadError(
        f"cannot read log: {exc.strerror or type(exc).__name__}",
        where,
        "check that the log and the folders that hold it may be read by this user",
    )


def refuse_non_logs(path: Path) -> None:
    """One clear error for a path that cannot be a log: missing or empty."""
    if not path.exists():
        raise LogReadError("no such file or folder", str(path), "check the path")
    if path.is_file() and path.stat().st_size == 0:
        raise LogReadError("empty file", str(path), "record the log again or remove it")


def rosbag2_storage(path: Path) -> tuple[str, list[Path]] | None:
    """(storage id, storage files) of an uncompressed rosbag2 folder whose files all exist;
    None sends the folder to rosbags (compressed bags, odd metadata: its errors are clear)."""
    from ruamel.yaml import YAML

    try:
        meta = YAML(typ="safe").load((path / "metadata.yaml").read_text())
        info = meta["rosbag2_bagfile_information"]
        mode = str(info.get("compression_mode") or "").lower()
        if mode not in ("", "none") or info.get("compression_format"):
            return None
        files = [path / PurePath(str(x)).name for x in info["relative_file_paths"]]
        storage = str(info["storage_identifier"])
    except Exception:  # rosbags reports bad metadata in its own words
        return None
    if not files or not all(f.is_file() for f in files):
        return None
    return storage, files


@dataclass(frozen=True)
class Storage:
    """The storage files a log path stands for, in recording order. ``headless``: a rosbag2
    bag without its ``metadata.yaml`` (a folder of parts, or a bare ``.db3``), read from the
    files' own tables and records as ``ros2 bag reindex`` would."""

    storage: str  # "mcap" or "sqlite3"
    files: tuple[Path, ...]
    headless: bool = False

    def warn(self, source: str) -> None:
        """The one warning a headless bag gets when it is read."""
        if not self.headless:
            return
        names = ", ".join(f.name for f in self.files[:4]) + (", …" if len(self.files) > 4 else "")
        if len(self.files) == 1 and self.files[0] == Path(source):
            what = f"a {self.storage} storage file read without its rosbag2 metadata.yaml"
        else:
            what = (
                f"a rosbag2 folder without metadata.yaml (a recorder killed before writing "
                f"it?): read as one log from its {len(self.files)} {self.storage} storage "
                f"file(s) in order ({names})"
            )
        log.warning(
            "%s: %s, topics and types from the files themselves; `ros2 bag reindex` would "
            "write the metadata",
            source,
            what,
        )


def storage_of(path: Path) -> Storage | None:
    """The storage files ``path`` stands for: a bare MCAP file, an uncompressed rosbag2 folder
    (``rosbag2_storage``), a folder of rosbag2 parts without metadata (``headless_storage``), a
    bare ``.db3``; None for every other form (ROS 1 bags, compressed bags: rosbags reads them).
    """
    if path.is_file():
        if path.suffix == ".db3":
            return Storage("sqlite3", (path,), headless=True)
        if path.suffix == ".mcap":
            return Storage("mcap", (path,))
        return None
    if not path.is_dir():
        return None
    if (path / "metadata.yaml").is_file():
        found = rosbag2_storage(path)
        return None if found is None else Storage(found[0], tuple(found[1]))
    return headless_storage(path)


def headless_storage(folder: Path) -> Storage | None:
    """The storage files of a rosbag2 folder without ``metadata.yaml``, in index order; None
    when the folder is not one.

    It is one when its storage files (``.db3``, ``.mcap``) are exactly one run of parts named
    as rosbag2 names them, ``NAME_0``, ``NAME_1``, … (one extension, no index missing). For
    MCAP, whose files are logs on their own too, NAME must be the folder's (as the recorder
    names it), there must be at least two parts and each must start later than the one before
    (a folder of separate recordings ``x/x_0.mcap``, ``x/x_1.mcap`` that start together is
    not a split bag)."""
    if not folder.is_dir() or (folder / "metadata.yaml").exists():
        return None
    runs: dict[tuple[str, str], dict[int, Path]] = {}
    for p in folder.iterdir():
        if p.suffix not in (".db3", ".mcap") or not p.is_file():
            continue
        part = _PART.match(p.name)
        if part is None:
            return None
        runs.setdefault((part["name"], part["ext"]), {})[int(part["index"])] = p
    if len(runs) != 1:
        return None
    (name, ext), by_index = runs.popitem()
    if sorted(by_index) != list(range(len(by_index))):
        return None
    files = tuple(by_index[i] for i in range(len(by_index)))
    if ext == "db3":
        return Storage("sqlite3", files, headless=True)
    if name != folder.name or len(files) < 2 or not _one_after_another(files):
        return None
    return Storage("mcap", files, headless=True)


def _one_after_another(files: tuple[Path, ...]) -> bool:
    """Each MCAP file's first message later than the previous file's (a split bag's parts)."""
    # the leaf modules, not the package: twincd.io.mcap's writer copies logs through this module
    from twincd.io.mcap.reader import McapFile
    from twincd.io.mcap.records import McapDamage

    starts = []
    for path in files:
        try:
            f = McapFile(path)
        except (McapDamage, OSError):
            return False
        try:
            starts.append(min((c.start_time for c in f.chunks), default=None))
        finally:
            f.close()
    known = [s for s in starts if s is not None]
    return len(known) == len(starts) and all(a < b for a, b in itertools.pairwise(known))
