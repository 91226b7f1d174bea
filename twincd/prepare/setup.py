"""How logs are read into prepared samples: ``Setup`` (log options, robot, filter and, from a
calibration, joints and period) opens a log as a ``PreparedStream`` (``twincd.prepare.stream``)
or prepares it whole as a ``PreparedLog`` (``twincd.prepare.prepared``); ``read_log`` reads one
log's joint states as recorded, unfiltered.

``Setup.open(path)`` streams a log of any length at flat memory (what ``fit``, ``threshold``,
``detect``, ``simulate`` and ``evaluate``'s calibration model use); ``Setup.prepare(path)``
concatenates the same blocks into one ``PreparedLog`` (what the baselines and ``evaluate``'s
methods that fit on training logs use, one log at a time).
``twincd.detection.OnlineDetector`` builds the same chain for live samples.

Sampling rate and gaps: a log's nominal period is the calibration's (``Setup.period_s``) when
there is one, so batch and live detection filter alike; otherwise the median interval of the
log's first samples (``twincd.signal.nominal_period``), never the whole log. A gap is an
interval longer than 5 periods; stages restart after it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from twincd.errors import UsageError
from twincd.io.logs import JointStates
from twincd.io.options import LogOptions
from twincd.io.stream import iter_blocks
from twincd.io.window import TimeWindow
from twincd.prepare.prepared import PreparedLog
from twincd.prepare.stream import PreparedStream
from twincd.signal.derivatives import differentiate
from twincd.signal.features import FittedModel, ModelFeatures
from twincd.signal.filters import LowPass
from twincd.types import FloatArray

DEFAULT_BLOCK = 16384  # samples per block: bounded memory, per-block Python cost negligible
# samples per block with the joint-torque regressor (identified models): each sample then
# carries hundreds of filtered values, and a block's copies must stay a few MB
REGRESSOR_BLOCK = 2048


class CalibrationSettings(Protocol):
    """What a calibration records about reading logs (``twincd.calibration.Calibration``)."""

    @property
    def options(self) -> LogOptions: ...
    @property
    def robot(self) -> str | None: ...
    @property
    def lowpass(self) -> LowPass: ...
    @property
    def joint_names(self) -> tuple[str, ...]: ...
    @property
    def urdf_sha256(self) -> str | None: ...
    @property
    def dynamics_sha256(self) -> str | None: ...
    @property
    def period_s(self) -> float | None: ...
    @property
    def fast_hz(self) -> float | None: ...
    @property
    def source(self) -> str: ...
    def robot_model(self, given: str | None = None) -> str | None: ...


@dataclass(frozen=True)
class Setup:
    """How logs become prepared samples: log options, robot, filter and (optionally) joint
    order and sampling period, all taken from a calibration when there is one. What a model
    needs besides (its features, its learned values) comes from the model
    (``PreparedStream``'s ``model`` or ``features``), never from here.

    ``robot`` None means: use a log's own simulated effort, else simulate with the default
    robot model.
    """

    options: LogOptions = field(default_factory=LogOptions)
    robot: str | None = None
    lowpass: LowPass = field(default_factory=LowPass)
    joint_names: tuple[str, ...] | None = None
    urdf_sha256: str | None = None  # the calibration's (its file's bytes; older files)
    allow_urdf_change: bool = False  # other dynamics (a changed URDF) get a warning instead
    period_s: float | None = None  # the calibration's sampling period
    block_size: int = DEFAULT_BLOCK
    # False: a truncated log is read up to the damage, with one warning (contract: Inputs)
    strict: bool = False
    twin_threads: int | None = None  # None: every core this process may use
    # the fast band's upper cut-off (None: the filter's band only; twincd.signal.bands): as far
    # as the sampling rate allows (a calibration records the one it was fitted with)
    fast_hz: float | None = None
    # the calibration's robot dynamics (``RobotModel.dynamics_sha256``): other ones are refused
    dynamics_sha256: str | None = None
    # the stretch of each log judged (``twincd.io.window``; None: all of it): the run's own,
    # never a calibration's
    window: TimeWindow | None = None

    def block_size_for(self, regressor: bool) -> int:
        """Samples per block read: fewer when the regressor is filtered (``REGRESSOR_BLOCK``)."""
        return min(self.block_size, REGRESSOR_BLOCK) if regressor else self.block_size

    @classmethod
    def from_calibration(cls, calibration: CalibrationSettings) -> Setup:
        """What ``calibration`` learned (filter, joints, period, the robot's dynamics) with its
        recorded way of reading logs (topics, joint names, the robot's URDF) as it is: a run
        may read its logs otherwise (``twincd.SetupOptions.resolve``)."""
        return cls(
            options=calibration.options,
            robot=calibration.robot,
            lowpass=calibration.lowpass,
            joint_names=calibration.joint_names,
            urdf_sha256=calibration.urdf_sha256,
            period_s=calibration.period_s,
            fast_hz=calibration.fast_hz,
            dynamics_sha256=calibration.dynamics_sha256,
        )

    def check_against(self, calibration: CalibrationSettings) -> None:
        """A ``UsageError`` when this setup contradicts what ``calibration`` learned (filter,
        joints, period, the robot's dynamics): a calibration judges only logs prepared its way,
        and a contradiction is never silently resolved either way. How a recording is read
        (topics, joint names, where the URDF is) belongs to the run and is not compared; the
        robot's dynamics are checked by content as logs are read (``check_robot``)."""
        recorded = Setup.from_calibration(calibration)
        differ = [
            name
            for name, given, was in (
                ("filter", self.lowpass, recorded.lowpass),
                ("joint_names", self.joint_names, recorded.joint_names),
                ("period_s", self.period_s, recorded.period_s),
                ("fast band", self.fast_hz, recorded.fast_hz),
                ("urdf_sha256", self.urdf_sha256, recorded.urdf_sha256),
                ("dynamics_sha256", self.dynamics_sha256, recorded.dynamics_sha256),
            )
            if given != was
        ]
        if differ:
            raise UsageError(
                f"the setup's {', '.join(differ)} contradict(s) the calibration's",
                calibration.source or "calibration",
                "read logs with the calibration's settings (Setup.from_calibration, or "
                "SetupOptions.resolve(calibration))",
            )

    def for_logs(self, paths: Sequence[str | Path]) -> Setup:
        """This setup for one run over ``paths``: a named log option that none of them has is
        an error; one that some lack is said and read as unnamed there
        (``twincd.io.named.settle_named``)."""
        from dataclasses import replace

        from twincd.io.named import settle_named

        return replace(self, options=settle_named([Path(p) for p in paths], self.options))

    def open(self, path: str | Path, **kwargs: Any) -> PreparedStream:
        """Stream one log (a context manager; iterate it for Frames)."""
        return PreparedStream(path, self, **kwargs)

    def prepare(
        self,
        path: str | Path,
        features: ModelFeatures | None = None,
        model: FittedModel | None = None,
        jump: FloatArray | None = None,
    ) -> PreparedLog:
        """One whole log in memory (for the baselines, evaluate's fitted methods, studies),
        with ``features`` filtered (a fit's), or prepared for scoring with a fitted ``model``
        (its residual in each band; ``jump``: the score's, ``PreparedStream``)."""
        with self.open(path, features=features, model=model, jump=jump) as stream:
            return stream.read_whole()


def prepare_log(
    path: str | Path, setup: Setup, features: ModelFeatures | None = None
) -> PreparedLog:
    """``setup.prepare(path, features)``: the per-log step of ``evaluate``, for any
    executor."""
    return setup.prepare(path, features)


def read_log(path: str | Path, options: LogOptions | None = None) -> JointStates:
    """Read one log's joint states, labels and (if present) simulated effort, unfiltered.

    The whole log in memory: a concatenation of ``iter_blocks``' sample blocks (sorted by
    stamp, duplicates and incomplete samples dropped), velocity differentiated from position
    where the messages carry none.
    """
    options = options or LogOptions()
    path = Path(path)
    with iter_blocks(path, options, strict=True) as stream:
        blocks = list(stream)
        topic, names = stream.topic, stream.joint_names
        has_labels, has_sim = stream.has_labels, stream.has_sim

    def cat(field: str) -> Any:
        return np.concatenate([getattr(b, field) for b in blocks])

    stamp, log_time, position, velocity = (
        cat(f) for f in ("stamp_ns", "log_time_ns", "position", "velocity")
    )
    effort = None if blocks[0].effort is None else cat("effort")
    t_s = (stamp - stamp[0]).astype(np.float64) * 1e-9
    from_position = not np.isfinite(velocity).all()
    if from_position:
        from twincd.signal.unwrap import unwrap_positions

        unwrapped = unwrap_positions(stamp, position)
        velocity = np.where(np.isfinite(velocity), velocity, differentiate(t_s, unwrapped))
    has_effort = effort is not None and bool(np.isfinite(effort).all())
    return JointStates(
        source=str(path),
        topic=topic,
        joint_names=names,
        stamp_ns=stamp,
        log_time_ns=log_time,
        position=position,
        velocity=velocity,
        effort=effort if has_effort else None,
        velocity_from_position=from_position,
        labels=cat("labels") if has_labels else None,
        sim_effort=cat("sim_effort") if has_sim else None,
    )
