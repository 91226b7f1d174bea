"""``inspect``: what logs hold and what twincd will make of them, without the twin."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from twincd.commands.runs import CommandRun, Settings

if TYPE_CHECKING:
    from typing_extensions import Unpack

    from twincd.calibration import Calibration
    from twincd.commands.inspection import Inspection


@dataclass(frozen=True, kw_only=True)
class InspectRun(CommandRun):
    """What ``inspect_logs`` gives: each log's inspection (in the order given); its warnings
    are the run's, then each log's."""

    logs: list[Inspection] = field(default_factory=list)

    @property
    def exit_code(self) -> int:
        """0 when every log is usable (``fit`` and ``detect`` would accept it), else 2."""
        return 0 if all(f.usable for f in self.logs) else 2

    def to_dict(self) -> dict[str, Any]:
        """``inspect --json``."""
        return {"logs": [f.to_dict() for f in self.logs], "warnings": list(self.warnings)}


def inspect_logs(
    logs: Iterable[str | Path],
    calibration: Calibration | str | Path | None = None,
    **settings: Unpack[Settings],
) -> InspectRun:
    """``twincd inspect``: what each of ``logs`` holds and what twincd will make of it
    (``twincd.commands.inspection.inspect_log``), read with ``settings`` (with ``calibration``:
    its recorded ones by default, its joints and robot dynamics checked)."""
    from twincd.calibration import Calibration
    from twincd.commands.inspection import inspect_log
    from twincd.executors.local import gathered_warnings
    from twincd.io.logs import expand_logs
    from twincd.prepare.settings import SetupOptions

    with gathered_warnings() as warnings:
        cal = None if calibration is None else Calibration.given(calibration)
        paths = expand_logs(logs)
        setup = SetupOptions(**settings).resolve(cal).for_logs(paths)  # named options checked
        found = [
            inspect_log(
                path, setup.options, setup.robot, cal, setup.strict, setup.allow_urdf_change
            )
            for path in paths
        ]
    per_log = (w for f in found for w in f.warnings)
    return InspectRun(logs=found, warnings=(*warnings, *per_log))
