"""The calibration file (docs/contract.md): everything detection needs, its types and how it
is written, loaded and saved as JSON (``twincd.calibration.reading`` reads the document back)."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

from twincd.calibration.clean import BandStats
from twincd.calibration.models import ResidualModel
from twincd.calibration.score import Score
from twincd.calibration.tail import TailFit
from twincd.errors import CalibrationError, NotFittedError, UsageError
from twincd.io.options import LogOptions
from twincd.signal.filters import LowPass
from twincd.version import __version__

if TYPE_CHECKING:
    from twincd.prepare.prepared import PreparedLog
    from twincd.prepare.setup import Setup

SCHEMA = "twincd.calibration/3"


@dataclass(frozen=True)
class Threshold:
    """The threshold as μ + kσ of the score on collision-free logs, whatever chose k.

    ``estimator`` says what μ and σ are: "mean-sd" the mean and standard deviation (the
    paper's), "median-mad" the median and 1.4826 × the median absolute deviation (robust: a
    stretch of unlabelled contact in the validation logs does not move them)."""

    k_sigma: float
    mu: float
    sigma: float
    logs: tuple[str, ...] = ()
    samples: int = 0
    # set when k was chosen for a false-alarm budget: the budget (per hour), the alarms the
    # validation logs gave at the threshold, and their collision-free time judged (s)
    budget_per_hour: float | None = None
    false_alarms: int | None = None
    judged_s: float | None = None
    tail: TailFit | None = None  # the tail fit that chose the threshold of a budget
    estimator: str = "mean-sd"
    # with the median and MAD: the scores' mean and standard deviation too, which evaluate's
    # F1 over μ + iσ uses (contract: Metrics)
    mean: float | None = None
    sd: float | None = None

    @property
    def mean_sd(self) -> tuple[float, float]:
        """The clean scores' mean and standard deviation (what μ + iσ means in the metrics)."""
        if self.mean is not None and self.sd is not None:
            return self.mean, self.sd
        return self.mu, self.sigma

    @property
    def value(self) -> float:
        return self.mu + self.k_sigma * self.sigma

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "k_sigma": self.k_sigma,
            "mu": self.mu,
            "sigma": self.sigma,
            "value": self.value,
            "estimator": self.estimator,
            **({} if self.mean is None else {"mean": self.mean, "sd": self.sd}),
            "logs": list(self.logs),
            "samples": self.samples,
        }
        if self.budget_per_hour is not None:
            out["false_alarm_budget"] = {
                "per_hour": self.budget_per_hour,
                "false_alarms": self.false_alarms,
                "hours": None if self.judged_s is None else self.judged_s / 3600.0,
                **({} if self.tail is None else _tail_dict(self.tail)),
            }
        return out


@dataclass(frozen=True)
class FitInfo:
    """Where a calibration's model came from (the file's ``fit``; its per-joint R² and RMSE are
    the model's own, ``ResidualModel.r2_`` and ``rmse_``)."""

    logs: tuple[str, ...] = ()
    samples: int = 0
    seconds: float = 0.0
    # per joint, the coefficients the fit logs' motion did not determine, held at their prior
    # (``twincd.calibration.excitation``: some of a, c, d, theta); None when no joint has any,
    # or not recorded
    held: tuple[tuple[str, ...], ...] | None = None
    # each band's score on the fit's own logs, each scored by a model fitted without it
    # (``twincd.calibration.crossfit``): clean data ``threshold`` sets its budget on too
    clean: tuple[BandStats, ...] = field(default=(), compare=False)


@dataclass(frozen=True)
class Calibration:
    """Everything detection needs, as stored in calibration JSON (docs/contract.md).

    What it learned, which a run may not contradict: the robot's dynamics (``dynamics_sha256``,
    ``RobotModel.dynamics_sha256``) and the joints the model was fitted on (``joint_names``,
    after the joint map), the filter and the sampling period, the fitted ``model`` (which
    alone says what scores: its coefficients and the features it needs) and the
    ``threshold``. How its logs were read, the defaults of later runs, which may read theirs
    otherwise: the log options (topics, joint map and prefix) and where the robot's URDF was
    (``robot``: a name or a path; ``robot_package``: its ``package://`` URI, when it lay in
    a package). Where it came from: ``fit``, ``created``, ``twincd_version``."""

    joint_names: tuple[str, ...]
    model: ResidualModel = field(compare=False)  # fitted, one of MODEL_KINDS
    lowpass: LowPass = field(default_factory=LowPass)
    options: LogOptions = field(default_factory=LogOptions)
    robot: str | None = None
    # the URDF file's sha256: what files written before the dynamics' hash were checked by
    urdf_sha256: str | None = None
    simulated: bool = True
    # nominal sampling period of the fitted logs: later logs are filtered at this rate, so that
    # batch and live detection agree (None: not recorded)
    period_s: float | None = None
    # the body each joint moves (its child link), for naming the link an event touched
    links: tuple[str, ...] | None = None
    depths: tuple[int, ...] | None = None  # each joint's depth in the kinematic tree
    fit: FitInfo = field(default_factory=FitInfo)
    threshold: Threshold | None = None
    # how the residual of every band becomes one score (the model's own band only: Score())
    score: Score = field(default_factory=Score, compare=False)
    created: str = ""
    twincd_version: str = __version__
    source: str = ""  # the file it was loaded from, for messages
    dynamics_sha256: str | None = None  # the robot's dynamics (None: files written before)
    robot_package: str | None = None  # ``package://…`` of the URDF, when in a package

    @property
    def uses_robot(self) -> bool:
        """Whether scoring needs the robot model: the twin is computed, or the model needs
        the joint-torque regressor (the identified models)."""
        return self.simulated or self.model.features.regressor

    def robot_model(self, given: str | None = None) -> str | None:
        """The robot model to run the twin with on this machine: ``given`` (a name, a URDF
        path or a ``package://`` URI), else the recorded one where it is (a name, or a path
        that exists), else a file of its name beside the calibration file, else the file of
        its package (``robot_package``). None when it records none, or (a model the twin does
        not need) none is found; a ``RobotModelError`` when the twin needs one and none is
        found. Which file it is does not matter: its dynamics are checked
        (``twincd.prepare.robots.check_robot``)."""
        if given is not None or self.robot is None:
            return given if given is not None else self.robot
        from twincd.twin.robot import locate_urdf

        beside = Path(self.source).parent if self.source else None
        found = locate_urdf(self.robot, self.robot_package, beside)
        if found is None and self.uses_robot:
            from twincd.errors import RobotModelError

            name = Path(self.robot).name
            raise RobotModelError(
                "the calibration's robot URDF is not found on this machine",
                f"{self.robot}, {self.source or 'calibration'}",
                f"give the robot's URDF (its path, or its package://… URI), or put {name} "
                "beside the calibration",
                option="robot",
            )
        return found

    @property
    def fast_hz(self) -> float | None:
        """The fast band's upper cut-off (None: the filter's band only)."""
        fast = self.score.fast
        return None if fast is None else fast.band.high.cutoff_hz

    def prepare(self, path: str | Path, setup: Setup | None = None) -> PreparedLog:
        """One whole log read, twinned and filtered for this calibration's model (its residual
        in each band: what ``twincd.detect`` scores), the calibration's way (``setup``: another
        way of reading it, e.g. ``SetupOptions(topic=…).resolve(calibration)``)."""
        from twincd.prepare.setup import Setup

        setup = Setup.from_calibration(self) if setup is None else setup
        return setup.prepare(path, model=self.model, jump=self.score.jump)

    def require_threshold(self) -> Threshold:
        if self.threshold is None:
            where = self.source or "calibration"
            raise NotFittedError(
                "the calibration has no threshold",
                where,
                "set its threshold on collision-free validation logs first (`twincd threshold`)",
                option="calibration",
            )
        return self.threshold

    def to_dict(self) -> dict[str, Any]:
        names = list(self.joint_names)
        r2, rmse, held = self.model.r2_, self.model.rmse_, self.fit.held
        fit: dict[str, Any] = {
            "logs": list(self.fit.logs),
            "samples": self.fit.samples,
            "seconds": self.fit.seconds,
            "joints": {
                n: {
                    "r2": None if r2 is None else float(r2[i]),
                    "rmse": None if rmse is None else float(rmse[i]),
                    **({"held": list(held[i])} if held and held[i] else {}),
                }
                for i, n in enumerate(names)
            },
        }
        if self.fit.clean:
            fit["clean"] = [band.to_dict() for band in self.fit.clean]
        return {
            "schema": SCHEMA,
            "twincd_version": self.twincd_version,
            "created": self.created or _now(),
            "robot": {
                "name": self.robot,
                "urdf_sha256": self.urdf_sha256,
                **_present(dynamics_sha256=self.dynamics_sha256, package=self.robot_package),
                "joint_names": names,
                "simulated": self.simulated,
                **({} if self.links is None else {"links": list(self.links)}),
                **({} if self.depths is None else {"depths": list(self.depths)}),
            },
            "log_options": {
                "topic": self.options.topic,
                "label_topic": self.options.label_topic,
                "sim_topic": self.options.sim_topic,
                "link_topic": self.options.link_topic,
                "joint_map": dict(self.options.joint_map or {}),
                "joint_prefix": self.options.joint_prefix,
            },
            "filter": {
                **self.lowpass.to_dict(),
                "sample_rate_hz": None if self.period_s is None else 1.0 / self.period_s,
            },
            "model": self.model.to_dict(names),
            "score": self.score.to_dict(names),
            "fit": fit,
            "threshold": None if self.threshold is None else self.threshold.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "") -> Calibration:
        """A calibration of schema ``SCHEMA``, or of ``twincd.calibration/2`` or ``/1`` through
        ``upgrade_v2`` (and ``upgrade_v1``); every number validated (a ``CalibrationError``
        naming the field)."""
        from twincd.calibration.reading import read_calibration

        return read_calibration(d, source)

    @classmethod
    def given(cls, calibration: Calibration | str | Path) -> Calibration:
        """``calibration`` itself, or the calibration of the file it names (what every library
        command takes); anything else is a ``UsageError``."""
        if isinstance(calibration, Calibration):
            return calibration
        if isinstance(calibration, str | Path):
            return cls.load(calibration)
        raise UsageError(
            "a calibration is a Calibration or the path of its file, "
            f"not {type(calibration).__name__}",
            "calibration",
            "give the JSON file written by `twincd fit`",
            option="calibration",
        )

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError as exc:
            raise CalibrationError(
                "calibration is not JSON text (binary content)",
                str(path),
                "give the JSON file written by `twincd fit`",
                option="calibration",
            ) from exc
        except OSError as exc:
            raise CalibrationError(
                f"cannot read calibration: {exc.strerror or exc}",
                str(path),
                "run `twincd fit` first or check the calibration path",
                option="calibration",
            ) from exc
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise CalibrationError(
                f"calibration is not JSON: {exc.msg} at line {exc.lineno}",
                str(path),
                "re-run `twincd fit`",
            ) from exc
        return cls.from_dict(data, str(path))

    def save(self, path: str | Path) -> None:
        """Write atomically (a temporary file renamed into place)."""
        from twincd.io.atomic import atomic_output

        text = json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n"
        with atomic_output(Path(path)) as stream:
            stream.write(text.encode("utf-8"))


def _present(**values: str | None) -> dict[str, str]:
    """The keys whose value is set (a file records what it knows, nothing for the rest)."""
    return {k: v for k, v in values.items() if v is not None}


def _tail_dict(tail: TailFit) -> dict[str, Any]:
    """The tail fit as stored beside the budget (``threshold.false_alarm_budget``)."""
    return {
        "method": tail.method,
        "level_u": tail.level,
        "peaks": tail.peaks,
        "rate_per_hour": tail.rate_per_hour,
        "shape": tail.shape,
        "scale": tail.scale,
        "estimate": tail.estimate,
        "interval": [tail.low, tail.high],
        "confidence": tail.confidence,
        "decluster_gap_s": tail.gap_s,
        # minutes of clean data that would let the tail be measured (None: it was measured)
        "firm_after_minutes": tail.firm_after_minutes,
    }


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def calibration_from_fit(
    model: ResidualModel,
    joint_names: Sequence[str],
    lowpass: LowPass,
    options: LogOptions,
    robot: str | None,
    urdf_sha256: str | None,
    simulated: bool,
    logs: Sequence[str],
    period_s: float | None = None,
    dynamics_sha256: str | None = None,
    robot_package: str | None = None,
) -> Calibration:
    """The calibration file's content from a fitted model (``fit_s_``: its training time)."""
    held = getattr(model, "held_", None)
    joints = range(len(joint_names))
    return Calibration(
        joint_names=tuple(joint_names),
        model=model,
        lowpass=lowpass,
        options=options.unnamed(*options.named),  # what the logs were read with, not how asked
        robot=robot,
        urdf_sha256=urdf_sha256,
        simulated=simulated,
        fit=FitInfo(
            logs=tuple(logs),
            samples=model.n_samples_,
            seconds=model.fit_s_,
            held=None if held is None else tuple(held.per_joint(i) for i in joints),
        ),
        created=_now(),
        period_s=period_s,
        dynamics_sha256=dynamics_sha256,
        robot_package=robot_package,
    )
