"""twincd: robot-arm collision detection in recorded ROS 2 logs with a digital twin.

The public API, by stage (each name is imported on first use, so ``import twincd`` stays light;
type checkers see the real types):

- read: ``LogOptions``, ``read_log``, ``expand_logs``
- prepare (read → twin → filter): ``Setup`` (``.open(path)`` streams, ``.prepare(path)`` whole),
  resolved from ``SetupOptions`` (settings by name, checked against a calibration's)
- the commands, one function each with the CLI's defaults (``twincd.commands``):
  ``fit_calibration`` (``twincd fit``), ``threshold_calibration``, ``detect_file`` (one log)
  and ``detect_files``, ``evaluate_logs``, ``simulate_logs``, ``inspect_logs``; each returns
  its answer with its warnings as data
- calibrate: ``Calibration``
- detect: ``detect`` (a prepared log: ``twincd.detection.detect_log``), ``OnlineDetector``
  (live)
- live: ``watch`` (a running robot's joint states through a Foxglove bridge, ROS 2 or rmw_zenoh)
- many logs: ``run_logs`` (a per-log function over paths: local processes or Dask, keep-going)

Arguments come in one order: inputs, calibration, then settings by keyword
(``detect_file(log, calibration, causal=True)``).
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.commands import (
        detect_file,
        detect_files,
        evaluate_logs,
        fit_calibration,
        inspect_logs,
        simulate_logs,
        threshold_calibration,
    )
    from twincd.detection import OnlineDetector
    from twincd.detection.detect import detect_log as detect
    from twincd.errors import TwincdError
    from twincd.executors.run import LogFailure, LogRun, run_logs
    from twincd.io.logs import expand_logs
    from twincd.io.options import LogOptions
    from twincd.live import watch
    from twincd.prepare.settings import SetupOptions
    from twincd.prepare.setup import Setup, read_log

from twincd.version import __version__

# name → "module" or "module:attribute" (when the library names it otherwise)
_EXPORTS = {
    "LogOptions": "twincd.io.options",
    "read_log": "twincd.prepare.setup",
    "expand_logs": "twincd.io.logs",
    "Setup": "twincd.prepare.setup",
    "SetupOptions": "twincd.prepare.settings",
    "Calibration": "twincd.calibration",
    "fit_calibration": "twincd.commands",
    "threshold_calibration": "twincd.commands",
    "detect_file": "twincd.commands",
    "detect_files": "twincd.commands",
    "evaluate_logs": "twincd.commands",
    "simulate_logs": "twincd.commands",
    "inspect_logs": "twincd.commands",
    "detect": "twincd.detection:detect_log",
    "OnlineDetector": "twincd.detection",
    "run_logs": "twincd.executors.run",
    "LogRun": "twincd.executors.run",
    "LogFailure": "twincd.executors.run",
    "TwincdError": "twincd.errors",
    "watch": "twincd.live",
}

__all__ = [
    "Calibration",
    "LogFailure",
    "LogOptions",
    "LogRun",
    "OnlineDetector",
    "Setup",
    "SetupOptions",
    "TwincdError",
    "__version__",
    "detect",
    "detect_file",
    "detect_files",
    "evaluate_logs",
    "expand_logs",
    "fit_calibration",
    "inspect_logs",
    "read_log",
    "run_logs",
    "simulate_logs",
    "threshold_calibration",
    "watch",
]


def __getattr__(name: str) -> Any:
    target = _EXPORTS.get(name)
    if target is None:
        raise AttributeError(f"module 'twincd' has no attribute {name!r}")
    module, _, attribute = target.partition(":")
    value = getattr(import_module(module), attribute or name)
    globals()[name] = value
    return value
