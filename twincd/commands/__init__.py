"""One function per command, with the command's defaults: what ``twincd fit``, ``threshold``,
``detect``, ``evaluate``, ``simulate`` and ``inspect`` do, the CLI only parsing, rendering and
turning the answer into an exit code (contract: The library does what the CLI does).

Each takes its inputs, then the calibration, then keyword arguments: the command's own, the
reading settings by name (``Settings``: with a calibration, its recorded ones by default, and
a filter setting that contradicts it is an error) and how to run many logs (``RunOptions``:
``jobs``, ``scheduler``, ``keep_going``, ``progress``, ``on_failure``). Each returns a
``CommandRun``: its answer, the warnings it gave (as data; also logged on the ``twincd`` logger
as they came) and the logs that failed.
"""

from twincd.commands.detect import DetectRun, detect_file, detect_files
from twincd.commands.evaluate import EvaluateRun, evaluate_logs
from twincd.commands.fit import FitRun, fit_calibration
from twincd.commands.inspect import InspectRun, inspect_logs
from twincd.commands.runs import (
    CommandRun,
    Options,
    RunOptions,
    Settings,
    filter_settings,
)
from twincd.commands.simulate import SimulateRun, simulate_logs
from twincd.commands.threshold import ThresholdRun, threshold_calibration
from twincd.executors.run import LogsFailed, ProgressDisplay

__all__ = [
    "CommandRun",
    "DetectRun",
    "EvaluateRun",
    "FitRun",
    "InspectRun",
    "LogsFailed",
    "Options",
    "ProgressDisplay",
    "RunOptions",
    "Settings",
    "SimulateRun",
    "ThresholdRun",
    "detect_file",
    "detect_files",
    "evaluate_logs",
    "filter_settings",
    "fit_calibration",
    "inspect_logs",
    "simulate_logs",
    "threshold_calibration",
]
