"""Outputs that appear whole or not at all, and never over something that is not ours
(contract: Topics twincd writes, Exit codes and streams).

Every file twincd writes goes to a temporary file beside its target and is renamed into place
only when complete, so an interrupted run leaves no partial output. A temporary is named
``.<target>.twincd-<pid>.tmp``: a later run removes those whose process is gone (killed with
SIGKILL), and a run that finds a live one for its own target stops (two runs writing one output
at once). ``check_target`` refuses to replace anything but twincd's own output of the same kind
(a recording, a calibration, a report) unless forced, and never a read-only file.
"""

from __future__ import annotations

import contextlib
import errno
import glob
import io
import json
import logging
import os
import re
import stat
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any

from twincd.errors import OutputError

log = logging.getLogger("twincd")

# the name of the MCAP metadata record that marks twincd's own MCAP outputs; its "output" key
# says which kind ("detect", "simulate", "synth")
MARKER = "twincd"
_TEMPORARY = re.compile(r"^\.(?P<target>.+)\.twincd-(?P<pid>\d+)\.tmp$")
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_LOG_MAGICS = (b"SQLite format 3\x00", b"#ROSBAG")


def temporary_path(target: Path, pid: int | None = None) -> Path:
    """Where ``target`` is written before the rename: hidden, beside it, named by process."""
    target = Path(target)
    return target.with_name(f".{target.name}.twincd-{os.getpid() if pid is None else pid}.tmp")


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return not _zombie(pid)


def _zombie(pid: int) -> bool:
    """A killed process that its parent has not reaped yet (Linux: state Z in /proc) is dead:
    a Dask worker killed mid-write stays one for a while on a busy machine, and its temporary
    must not block the log's retry."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rfind(")") + 2 :].startswith("Z")


def remove_stale_temporaries(folder: Path, say: bool = True) -> list[Path]:
    """Remove the temporaries in ``folder`` left by twincd processes that no longer run (a
    SIGKILL gives no chance to clean up); the removed paths. ``say``: one info line each (not
    for a run's own workers' leftovers, which its caller knows about)."""
    removed: list[Path] = []
    try:
        entries = list(Path(folder).iterdir())
    except OSError:
        return removed
    for path in entries:
        match = _TEMPORARY.match(path.name)
        if match and not _alive(int(match["pid"])):
            with contextlib.suppress(OSError):
                path.unlink()
                removed.append(path)
                if say:
                    log.info("removed %s, left by a twincd run that was killed", path)
    return removed


def _live_writer(target: Path) -> int | None:
    """The pid of another live twincd process writing ``target`` right now, if any."""
    for path in target.parent.glob(f".{glob.escape(target.name)}.twincd-*.tmp"):
        match = _TEMPORARY.match(path.name)
        if match and match["target"] == target.name:
            pid = int(match["pid"])
            if pid != os.getpid() and _alive(pid):
                return pid
    return None


# errors of a disk that is full (or a file grown past its limit): space is what helps
_FULL = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})


def output_error(exc: OSError, target: Path) -> OutputError:
    """An operating-system error while writing ``target`` as one clear error (exit 2)."""
    reason = exc.strerror or type(exc).__name__
    hint = "free space on the disk, or write elsewhere" if exc.errno in _FULL else "write elsewhere"
    return OutputError(f"cannot write output: {reason}", str(target), hint)


def refuse_special(target: Path) -> None:
    """Refuse an output that exists and is neither a file nor a folder (``/dev/full``, a pipe,
    a socket): it would be replaced by the rename, or never hold a whole output."""
    target = Path(target)
    if target.exists() and not target.is_dir() and not target.is_file():
        raise OutputError(
            "output is a device, pipe or socket, not a file", str(target), "write to a file"
        )


def check_writable(target: Path) -> None:
    """Fail early, before any work, when ``target`` cannot be written."""
    target = Path(target)
    if target.is_dir():
        raise OutputError("output is a folder", str(target), "give a file name")
    refuse_special(target)
    folder = target.parent
    if not folder.is_dir():
        raise OutputError(
            "cannot write output: its folder does not exist", str(target), "create the folder first"
        )
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(
            "cannot write output: its folder is not writable", str(target), "pick another path"
        )
    if target.exists() and _read_only(target):
        raise OutputError(
            "output is read-only", str(target), "make it writable or pick another path"
        )


def _read_only(path: Path) -> bool:
    # the mode bits too: root may write anything, but a 0444 file says "keep me"
    return not os.access(path, os.W_OK) or not stat.S_IMODE(path.stat().st_mode) & 0o222


def output_kind(path: Path) -> str | None:
    """What twincd wrote at ``path``: ``"calibration"``, the MCAP output kind of its marker
    (``"detect"``, ``"simulate"``, ``"synth"``), ``"report"`` (Markdown or HTML), ``"junit"``,
    ``"table"`` (CSV/JSONL rows);
    ``"log"`` for a recording twincd did not write; None for anything else."""
    try:
        with open(path, "rb") as f:
            head = f.read(512)
    except OSError:
        return None
    if head.startswith(_MCAP_MAGIC):
        return _mcap_marker(path) or "log"
    if head.startswith(_LOG_MAGICS):
        return "log"
    text = head.decode("utf-8", errors="replace").lstrip()
    if text.startswith("{"):
        try:
            doc = json.loads(Path(path).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            doc = None
        if isinstance(doc, dict) and str(doc.get("schema", "")).startswith("twincd.calibration/"):
            return "calibration"
        if isinstance(doc, dict) and "stamp_ns" in doc:
            return "table"
        return None
    if text.startswith("stamp_ns,score,"):
        return "table"
    if text.startswith(("# twincd", "## twincd")) or (
        text.lower().startswith("<!doctype html")
        and '<meta name="generator" content="twincd">' in text
    ):
        return "report"
    if text.startswith("<?xml") and '<testsuites name="twincd' in text:
        return "junit"
    return None


def _mcap_marker(path: Path) -> str | None:
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            for record in make_reader(f).iter_metadata():
                if record.name == MARKER:
                    return str(record.metadata.get("output", "")) or None
    except Exception:  # no summary or a damaged file: not a complete twincd output
        return None
    return None


_HTML_GENERATOR = '<meta name="generator" content="twincd">'  # twincd.reports.html writes it
_WHAT = {
    "log": "a recorded log",
    "calibration": "a calibration file",
    "report": "a report",
    "junit": "a JUnit file",
    "table": "a per-sample table",
    "detect": "a detect output",
    "simulate": "a simulate output",
    "synth": "a recorded log (written by twincd synth)",
    None: "a file twincd did not write",
}


def check_target(
    target: Path, kind: str, *, force: bool = False, inputs: Iterable[Path] = ()
) -> None:
    """Fail, before any work, unless ``target`` may become an output of ``kind``: writable, and
    new or twincd's own output of that kind; ``force`` lifts the second rule for anything but
    a read-only file or an input of the run (``inputs``: a log, a folder of one, a calibration),
    which nothing overwrites."""
    target = Path(target)
    check_writable(target)
    remove_stale_temporaries(target.parent)  # a killed run's leftovers go as this one starts
    if not target.exists():
        return
    if is_input(target, inputs):  # --force would not help: no option named
        raise OutputError(
            "output would overwrite an input of this run", str(target), "write to another path"
        )
    if force:
        return
    found = output_kind(target)
    if found != kind:
        raise OutputError(
            f"output would overwrite {_WHAT.get(found, _WHAT[None])}",
            str(target),
            "pick another path, or force it",
            option="force",
        )


def is_input(target: Path, inputs: Iterable[Path]) -> bool:
    """Whether an existing ``target`` is one of ``inputs`` or inside one (a rosbag2 folder)."""
    target = Path(target)
    for given in map(Path, inputs):
        if _same_file(target, given):
            return True
        if given.is_dir() and target.resolve().is_relative_to(given.resolve()):
            return True
    return False


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


class _OutputFile(io.FileIO):
    """The temporary's raw file; remembers the first error of a write to it, so that an error
    that a writer (mcap, a text layer) raises because of it is known to be the output's."""

    failure: OSError | None = None

    def write(self, data: Any, /) -> int:
        try:
            return self.put(data)
        except OSError as exc:
            self.failure = self.failure or exc
            raise

    def put(self, data: Any) -> int:
        """The write itself (tests replace it to fail like a full disk)."""
        return super().write(data)


@contextlib.contextmanager
def atomic_output(target: Path) -> Iterator[IO[bytes]]:
    """A binary stream that becomes ``target`` only if the block finishes without error; a
    replaced file keeps its mode. A failing write (a full disk, an I/O error) is an
    ``OutputError`` naming ``target``, whatever layer it passed through; the temporary is
    removed on any error."""
    target = Path(target)
    if target.is_dir():
        raise OutputError("output is a folder", str(target), "give a file name")
    refuse_special(target)
    remove_stale_temporaries(target.parent)
    other = _live_writer(target)
    if other is not None:
        raise OutputError(
            f"another twincd run (process {other}) is writing this output",
            str(target),
            "wait for it to finish or pick another path",
        )
    tmp = temporary_path(target)
    try:
        raw = _OutputFile(tmp, "w")
    except OSError as exc:
        raise output_error(exc, target) from exc
    try:
        with io.BufferedWriter(raw) as stream:
            yield stream
        try:
            with contextlib.suppress(FileNotFoundError):
                os.chmod(tmp, stat.S_IMODE(target.stat().st_mode))  # --in-place keeps the mode
            os.replace(tmp, target)
        except OSError as exc:
            raise output_error(exc, target) from exc
    except BaseException as exc:
        with contextlib.suppress(OSError):
            raw.close()
        with contextlib.suppress(OSError):
            tmp.unlink()
        failed = raw.failure  # the write error behind whatever a layer above made of it
        if failed is not None and isinstance(exc, Exception) and not isinstance(exc, OutputError):
            raise output_error(failed, target) from exc
        raise
