"""What a log path holds and how to open it when no fast reader applies.

``rosbag2_storage`` reads a rosbag2 folder's metadata (its storage format and files), the one
place that does; ``refuse_non_logs`` turns paths that cannot be logs into one clear error; and
``open_reader`` opens any log form with rosbags' AnyReader (ROS 1 bags, compressed bags, small
topics read message by message).
"""

from __future__ import annotations

from pathlib import Path, PurePath
from typing import Any

from twincd.errors import LogReadError
from twincd.io.cdr import typestore

__all__ = ["first_line", "open_reader", "refuse_non_logs", "rosbag2_storage"]


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


def refuse_non_logs(path: Path) -> None:
    """One clear error for a path that cannot be a log: missing, empty, a bare .db3."""
    if not path.exists():
        raise LogReadError("no such file or folder", str(path), "check the path")
    if path.is_file() and path.stat().st_size == 0:
        raise LogReadError("empty file", str(path), "record the log again or remove it")
    if path.is_file() and path.suffix == ".db3":
        raise LogReadError(
            "a bare .db3 file is not a log", str(path), "give the rosbag2 folder that holds it"
        )


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
