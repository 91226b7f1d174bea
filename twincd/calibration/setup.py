"""Running the calibration over logs: how logs become PreparedLogs, and ``fit`` over many."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

from twincd.calibration.affine import AffineCalibration
from twincd.calibration.file import Calibration, calibration_from_fit
from twincd.io.logs import LogOptions
from twincd.pipeline import PreparedLog
from twincd.signal.filters import LowPass

log = logging.getLogger("twincd")

_WARNED_URDF: set[str] = set()


@dataclass(frozen=True)
class Setup:
    """How logs become PreparedLogs: log options, robot, filter and (optionally) joint order.

    ``robot`` None means: use a log's own simulated effort, else simulate with the default
    robot model.
    """

    options: LogOptions = field(default_factory=LogOptions)
    robot: str | None = None
    lowpass: LowPass = field(default_factory=LowPass)
    joint_names: tuple[str, ...] | None = None
    urdf_sha256: str | None = None  # the calibration's: a changed URDF gets a warning

    @classmethod
    def from_calibration(cls, calibration: Calibration) -> Setup:
        return cls(
            calibration.options,
            calibration.robot,
            calibration.lowpass,
            calibration.joint_names,
            calibration.urdf_sha256,
        )

    def prepare(self, path: str | Path) -> PreparedLog:
        from twincd.pipeline import prepare
        from twincd.twin.robot import DEFAULT_ROBOT

        prepared = prepare(
            path,
            self.options,
            self.robot,
            self.lowpass,
            self.joint_names,
            fallback_robot=DEFAULT_ROBOT,
        )
        model = prepared.robot
        if (
            prepared.simulated
            and model is not None
            and self.urdf_sha256
            and model.urdf_sha256 != self.urdf_sha256
            and model.urdf_sha256 not in _WARNED_URDF
        ):
            _WARNED_URDF.add(model.urdf_sha256)
            log.warning(
                "the URDF %s differs from the one the calibration was fitted with; "
                "re-run `twincd fit` if the model changed",
                model.urdf_path,
            )
        return prepared

    def prepare_all(self, paths: Iterable[str | Path]) -> Iterator[PreparedLog]:
        """Prepare logs lazily; the first log pins the joint order when none is set."""
        setup = self
        for path in paths:
            prepared = setup.prepare(path)
            if setup.joint_names is None:
                setup = replace(setup, joint_names=prepared.joint_names)
            yield prepared


def fit_calibration(paths: Iterable[str | Path], setup: Setup) -> Calibration:
    """Fit a, b over ``paths`` log by log (memory flat in the number of logs)."""
    seen: list[str] = []
    robot: list[tuple[str, str]] = []
    simulated = [False]

    def stream() -> Iterator[PreparedLog]:
        for prepared in setup.prepare_all(paths):
            seen.append(prepared.source)
            simulated[0] = simulated[0] or prepared.simulated
            if prepared.robot is not None and not robot:
                robot.append((prepared.robot.name, prepared.robot.urdf_sha256))
            yield prepared

    estimator = AffineCalibration().fit(stream())
    name, sha = robot[0] if robot else (setup.robot, None)
    return calibration_from_fit(
        estimator, setup.lowpass, setup.options, name, sha, simulated[0], seen
    )
