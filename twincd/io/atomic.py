"""Outputs that appear whole or not at all (DESIGN §3, §5).

Every file twincd writes goes to a temporary file beside its target and is renamed into place
only when complete, so an interrupted run leaves no partial output.
"""

from __future__ import annotations

import contextlib
import glob
import os
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from twincd.errors import OutputError


def temporary_path(target: Path) -> Path:
    """Where ``target`` is written before the rename: hidden, beside it, named by process."""
    target = Path(target)
    return target.with_name(f".{target.name}.{os.getpid()}.tmp")


def remove_temporaries(target: Path) -> None:
    """Remove what writers of ``target`` that were killed mid-write left beside it (a run
    that owns ``target`` calls this once its workers are done)."""
    target = Path(target)
    with contextlib.suppress(OSError):
        for stale in target.parent.glob(f".{glob.escape(target.name)}.*.tmp"):
            with contextlib.suppress(OSError):
                stale.unlink()


def check_writable(target: Path) -> None:
    """Fail early, before any work, when ``target`` cannot be written."""
    target = Path(target)
    if target.is_dir():
        raise OutputError("output is a folder", str(target), "give a file name")
    folder = target.parent
    if not folder.is_dir():
        raise OutputError(
            "cannot write output: its folder does not exist", str(target), "create the folder first"
        )
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(
            "cannot write output: its folder is not writable", str(target), "pick another path"
        )


@contextlib.contextmanager
def atomic_output(target: Path) -> Iterator[IO[bytes]]:
    """A binary stream that becomes ``target`` only if the block finishes without error."""
    target = Path(target)
    if target.is_dir():
        raise OutputError("output is a folder", str(target), "give a file name")
    tmp = temporary_path(target)
    try:
        stream = open(tmp, "wb")  # noqa: SIM115 - closed below, before the rename
    except OSError as exc:
        raise OutputError(
            f"cannot write output: {exc.strerror}", str(target), "pick a writable output path"
        ) from exc
    try:
        with stream:
            yield stream
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
