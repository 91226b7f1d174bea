"""twincd: robot-arm collision detection in recorded ROS 2 logs with a digital twin.

The public API, by stage (each name is imported on first use, so ``import twincd`` stays light):

- read: ``LogOptions``, ``read_log``, ``expand_logs``
- prepare (read → twin → filter): ``Setup`` (``.open(path)`` streams, ``.prepare(path)`` whole)
- calibrate: ``Calibration``, ``fit_calibration``, ``threshold_calibration``
- detect: ``detect`` (a prepared log: ``twincd.detection.detect_log``), ``detect_file`` (a log
  streamed), ``OnlineDetector`` (live)
"""

from __future__ import annotations

from importlib import import_module
from importlib.metadata import PackageNotFoundError, version
from typing import Any

try:
    __version__ = version("twincd")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"

# name → "module" or "module:attribute" (when the library names it otherwise)
_EXPORTS = {
    "LogOptions": "twincd.io.logs",
    "read_log": "twincd.io.logs",
    "expand_logs": "twincd.io.logs",
    "Setup": "twincd.pipeline",
    "Calibration": "twincd.calibration",
    "fit_calibration": "twincd.calibration",
    "threshold_calibration": "twincd.threshold",
    "detect": "twincd.detection:detect_log",
    "detect_file": "twincd.detection",
    "OnlineDetector": "twincd.detection",
    "TwincdError": "twincd.errors",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str) -> Any:
    target = _EXPORTS.get(name)
    if target is None:
        raise AttributeError(f"module 'twincd' has no attribute {name!r}")
    module, _, attribute = target.partition(":")
    value = getattr(import_module(module), attribute or name)
    globals()[name] = value
    return value
