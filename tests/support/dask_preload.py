"""Preloaded (``dask worker --preload support.dask_preload``) into the worker processes that
tests/test_cluster.py starts: while an ``arm-*`` file waits in ``$TWINCD_TEST_KILL_DIR``, the
first worker to write a block of ``detect`` output takes one and kills itself with SIGKILL,
its output half-written — a worker dying mid-run at a moment the test chooses."""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Any

KILL_DIR = os.environ.get("TWINCD_TEST_KILL_DIR")


def _take_arm(folder: Path) -> bool:
    for arm in sorted(folder.glob("arm-*")):
        try:  # a rename is atomic: only one worker takes each arm
            arm.rename(arm.with_name("fired-" + arm.name))
        except OSError:
            continue
        return True
    return False


if KILL_DIR:
    from twincd.detection.outputs import McapSink

    _write = McapSink.write

    def _write_then_die(self: Any, frame: Any, events: Any) -> None:
        _write(self, frame, events)
        if _take_arm(Path(KILL_DIR)):
            os.kill(os.getpid(), signal.SIGKILL)

    McapSink.write = _write_then_die  # type: ignore[method-assign]
