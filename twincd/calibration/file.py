"""The calibration file (docs/contract.md): everything detection needs, as JSON."""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

from twincd.calibration.clean import BandStats, read_band_stats
from twincd.calibration.models import ResidualModel, depth_order, read_model
from twincd.calibration.score import Score, read_score
from twincd.calibration.tail import TAIL_METHODS, TailFit
from twincd.calibration.values import finite_array, finite_number
from twincd.errors import CalibrationError, NotFittedError, UsageError
from twincd.io.options import DEFAULT_LINK_TOPIC, LogOptions
from twincd.signal.filters import LowPass
from twincd.types import FloatArray
from twincd.version import __version__

log = logging.getLogger("twincd")

if TYPE_CHECKING:
    from twincd.prepare.prepared import PreparedLog
    from twincd.prepare.setup import Setup

SCHEMA = "twincd.calibration/3"
SCHEMA_V2 = "twincd.calibration/2"  # still read, through ``upgrade_v2``
SCHEMA_V1 = "twincd.calibration/1"  # still read, through ``upgrade_v1``
# the coefficients ``fit.joints.<joint>.held`` may name (``twincd.calibration.excitation``)
HELD_KEYS = ("a", "c", "d", "theta")
# what a threshold's μ and σ are (``Threshold.estimator``)
ESTIMATORS = ("mean-sd", "median-mad")


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
        where = source or "calibration"
        if not isinstance(d, Mapping):
            raise CalibrationError(
                f"calibration is a JSON {type(d).__name__}, not an object",
                where,
                "pass the JSON file written by `twincd fit`",
            )
        schema = d.get("schema")
        if schema == SCHEMA_V1:
            d = upgrade_v2(upgrade_v1(d, where))
        elif schema == SCHEMA_V2:
            d = upgrade_v2(d)
        elif schema != SCHEMA:
            raise CalibrationError(
                f"unsupported calibration schema {schema!r} (this twincd reads {SCHEMA}, "
                f"{SCHEMA_V2} and {SCHEMA_V1})",
                where,
                "re-run `twincd fit` with this version",
            )
        try:
            return _read(d, source, where)
        except CalibrationError:
            raise
        except KeyError as exc:
            raise CalibrationError(
                f"calibration lacks the field {exc.args[0]!r}",
                where,
                "re-run `twincd fit` to write a new one",
            ) from exc
        except (TypeError, ValueError, AttributeError) as exc:
            raise CalibrationError(
                f"malformed calibration: {exc}",
                where,
                "re-run `twincd fit` to write a new one",
            ) from exc

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


# what a JSON value that is not an object is, in the file's words
_JSON_KINDS = {type(None): "null", str: "a JSON string", list: "a JSON list",
               bool: "true or false", int: "a JSON number", float: "a JSON number"}  # fmt: skip


def _section(d: Mapping[str, Any], key: str, where: str, name: str = "") -> Mapping[str, Any]:
    """``d[key]``, a JSON object, or a ``CalibrationError`` naming the field (``name``: its
    path in the file) rather than Python's words for what went wrong with it."""
    field = name or key
    if key not in d:
        raise CalibrationError(
            f"calibration lacks the field {field!r}",
            where,
            "re-run `twincd fit` to write a new one",
        )
    value = d[key]
    if not isinstance(value, Mapping):
        kind = _JSON_KINDS.get(type(value), type(value).__name__)
        raise CalibrationError(
            f"calibration field {field} is {kind}, not an object",
            where,
            "re-run `twincd fit` to write a new one",
        )
    return value


def _read(d: Mapping[str, Any], source: str, where: str) -> Calibration:
    """A calibration of schema ``SCHEMA``: every section it names present."""
    for key in ("robot", "log_options", "filter", "model", "fit"):
        _section(d, key, where)
    if d.get("threshold") is not None:
        _section(d, "threshold", where)
    joints = _section(_section(d, "model", where), "joints", where, "model.joints")
    for name in _joint_names(d["robot"].get("joint_names"), where):
        _section(joints, name, where, f"model.joints.{name}")
    _section(d["fit"], "joints", where, "fit.joints")
    robot = d["robot"]
    names = _joint_names(robot["joint_names"], where)
    links, depths = robot.get("links"), robot.get("depths")
    for key, values in (("links", links), ("depths", depths)):
        if values is not None and len(values) != len(names):
            raise ValueError(f"robot.{key} has {len(values)} entries for {len(names)} joints")
    depths = None if depths is None else tuple(int(x) for x in depths)
    fit = d["fit"]
    per_joint = fit["joints"]

    def column(key: str) -> FloatArray | None:
        values = [per_joint.get(n, {}).get(key) for n in names]
        if any(v is None for v in values):
            return None
        return finite_array(values, names, f"fit.joints.{key}", where)

    order = depth_order(depths, len(names))
    model = read_model(d["model"], names, order, where, column("r2"), column("rmse"))
    opts = d["log_options"]
    options = LogOptions(
        topic=str(opts["topic"]),
        label_topic=str(opts["label_topic"]),
        sim_topic=str(opts["sim_topic"]),
        joint_map=dict(opts["joint_map"] or {}) or None,
        link_topic=str(opts.get("link_topic", DEFAULT_LINK_TOPIC)),  # files before it: default
        joint_prefix=str(opts.get("joint_prefix") or ""),
    )
    cal = Calibration(
        joint_names=names,
        model=model,
        lowpass=_lowpass(d["filter"], where),
        period_s=_period(d["filter"]["sample_rate_hz"], where),
        options=options,
        robot=robot["name"],
        urdf_sha256=robot["urdf_sha256"],
        simulated=bool(robot["simulated"]),
        links=None if links is None else tuple(str(x) for x in links),
        depths=depths,
        fit=FitInfo(
            logs=tuple(fit["logs"]),
            samples=_count(fit["samples"], "fit.samples", where),
            seconds=finite_number(fit["seconds"], "fit.seconds", where),
            held=_held(per_joint, names),
            clean=tuple(
                read_band_stats(band, f"fit.clean[{i}]", where)
                for i, band in enumerate(fit.get("clean") or ())
            ),
        ),
        threshold=_threshold(d["threshold"], where),
        score=read_score(d["score"], names, where),
        created=str(d["created"]),
        twincd_version=str(d["twincd_version"]),
        source=source,
        dynamics_sha256=_optional_text(robot, "dynamics_sha256", where),
        robot_package=_optional_text(robot, "package", where),
    )
    if cal.dynamics_sha256 is None and cal.urdf_sha256 and cal.uses_robot:
        log.info(
            "%s records its robot by the URDF file's sha256 (written before calibrations "
            "recorded the robot's dynamics): the URDF is checked byte for byte; re-fit it to "
            "have it checked by content",
            where,
        )
    return cal


def _present(**values: str | None) -> dict[str, str]:
    """The keys whose value is set (a file records what it knows, nothing for the rest)."""
    return {k: v for k, v in values.items() if v is not None}


def _optional_text(section: Mapping[str, Any], key: str, where: str) -> str | None:
    """``section[key]``, a string, when present (None when absent or null)."""
    value = section.get(key)
    if value is None:
        return None
    if not isinstance(value, str) or not value:
        raise CalibrationError(
            f"calibration field robot.{key} is {value!r}, not a string",
            where,
            "re-run `twincd fit` to write a new one",
        )
    return value


def _threshold(th: Mapping[str, Any] | None, where: str) -> Threshold | None:
    """The ``threshold`` section (None: not set yet), μ + kσ checked against its ``value``."""
    if th is None:
        return None
    threshold = Threshold(
        k_sigma=finite_number(th["k_sigma"], "threshold.k_sigma", where),
        mu=finite_number(th["mu"], "threshold.mu", where),
        sigma=finite_number(th["sigma"], "threshold.sigma", where),
        logs=tuple(th["logs"]),
        samples=_count(th["samples"], "threshold.samples", where),
        **_budget(th.get("false_alarm_budget"), where),
        estimator=_estimator(th["estimator"], where),
        mean=None if "mean" not in th else finite_number(th["mean"], "threshold.mean", where),
        sd=None if "sd" not in th else finite_number(th["sd"], "threshold.sd", where),
    )
    _check_threshold(threshold, th, where)
    return threshold


def upgrade_v2(d: Mapping[str, Any]) -> dict[str, Any]:
    """A ``twincd.calibration/2`` file's content as ``SCHEMA``'s: the same keys, and the score
    /2 files gave every model, its own band alone (``score: null``: ``twincd.calibration.score``;
    a /3 file's threshold is one of the bands' combined score, a /2 file's of the one band).
    Nothing is validated here: ``Calibration.from_dict`` validates the result."""
    return {**d, "schema": SCHEMA, "score": None}


def upgrade_v1(d: Mapping[str, Any], where: str = "calibration") -> dict[str, Any]:
    """A ``twincd.calibration/1`` file's content as ``/2``'s: the same key paths, with what
    /1 files could leave out written as /1 read it (a model scored by the sum has its
    ``statistic``; no ``log_options``: the default topics; no ``fit``: none recorded; a
    threshold without its ``estimator``: the mean and standard deviation; no sampling rate:
    none recorded). Nothing is validated here: ``Calibration.from_dict`` validates the result."""
    out = {key: value for key, value in d.items() if key != "schema"}
    out = {"schema": SCHEMA_V2, **out}
    defaults = LogOptions()
    sections: dict[str, Any] = {}
    for key in ("robot", "filter", "model", "fit", "log_options", "threshold"):
        value = d.get(key)
        sections[key] = dict(value) if isinstance(value, Mapping) else value
    if not isinstance(sections["robot"], dict) or not isinstance(sections["model"], dict):
        return out  # not a calibration: from_dict names what is missing
    sections["robot"].setdefault("name", None)
    sections["robot"].setdefault("urdf_sha256", None)
    sections["robot"].setdefault("simulated", True)
    sections["model"].setdefault("statistic", "sum")
    if isinstance(sections["filter"], dict):
        sections["filter"].setdefault("sample_rate_hz", None)
    fit = dict(sections["fit"] or {})
    fit.setdefault("logs", [])
    fit.setdefault("samples", 0)
    fit.setdefault("seconds", 0.0)
    fit.setdefault("joints", {})
    sections["fit"] = fit
    opts = dict(sections["log_options"] or {})
    opts.setdefault("topic", defaults.topic)
    opts.setdefault("label_topic", defaults.label_topic)
    opts.setdefault("sim_topic", defaults.sim_topic)
    opts.setdefault("joint_map", {})
    sections["log_options"] = opts
    if isinstance(sections["threshold"], dict):
        sections["threshold"].setdefault("estimator", "mean-sd")
        sections["threshold"].setdefault("logs", [])
        sections["threshold"].setdefault("samples", 0)
    out.update(sections)
    out.setdefault("created", "")
    out.setdefault("twincd_version", "")
    return out


def _period(rate_hz: Any, where: str) -> float | None:
    if rate_hz is None:
        return None
    return 1.0 / finite_number(rate_hz, "filter.sample_rate_hz", where, positive=True)


def _lowpass(raw: Mapping[str, Any], where: str) -> LowPass:
    finite_number(raw["cutoff_hz"], "filter.cutoff_hz", where, positive=True)
    order = raw["order"]
    if isinstance(order, bool) or not isinstance(order, int) or order < 1:
        raise CalibrationError(
            f"calibration field filter.order is {order!r}, not a positive integer",
            where,
            "re-run `twincd fit` to write a new one",
        )
    if not isinstance(raw["causal"], bool):
        raise CalibrationError(
            "calibration field filter.causal is not true or false", where, "re-run `twincd fit`"
        )
    return LowPass.from_dict(dict(raw))


def _joint_names(raw: Any, where: str) -> tuple[str, ...]:
    if not isinstance(raw, list) or not raw or not all(isinstance(n, str) and n for n in raw):
        raise CalibrationError(
            "calibration field robot.joint_names is not a list of joint names",
            where,
            "re-run `twincd fit` to write a new one",
        )
    if len(set(raw)) != len(raw):
        raise CalibrationError(
            "calibration field robot.joint_names names a joint twice", where, "re-run `twincd fit`"
        )
    return tuple(raw)


def _estimator(value: Any, where: str) -> str:
    if value not in ESTIMATORS:
        raise CalibrationError(
            f"calibration field threshold.estimator is {value!r}, not one of "
            f"{', '.join(ESTIMATORS)}",
            where,
            "re-run `twincd threshold`",
        )
    return str(value)


def _budget(raw: Any, where: str) -> dict[str, Any]:
    """The threshold's false-alarm budget fields, when k was chosen for one."""
    if raw is None:
        return {}
    hours = raw.get("hours")
    alarms = raw.get("false_alarms")
    return {
        "budget_per_hour": finite_number(raw["per_hour"], "false_alarm_budget.per_hour", where),
        "false_alarms": None
        if alarms is None
        else _count(alarms, "false_alarm_budget.false_alarms", where),
        "judged_s": None
        if hours is None
        else 3600.0 * finite_number(hours, "false_alarm_budget.hours", where),
        "tail": None if "method" not in raw else _tail(raw, where),
    }


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


def _tail(raw: Mapping[str, Any], where: str) -> TailFit:
    """The tail fit of a budget's threshold, every number checked."""
    method = raw["method"]
    if method not in TAIL_METHODS:
        raise CalibrationError(
            f"calibration field false_alarm_budget.method is {method!r}, "
            f"not one of {', '.join(TAIL_METHODS)}",
            where,
            "re-run `twincd threshold`",
        )

    def number(key: str, *, positive: bool = False) -> float:
        return finite_number(raw[key], f"false_alarm_budget.{key}", where, positive=positive)

    interval = raw["interval"]
    if not isinstance(interval, list) or len(interval) != 2:
        raise CalibrationError(
            "calibration field false_alarm_budget.interval is not a pair [low, high]",
            where,
            "re-run `twincd threshold`",
        )
    low = finite_number(interval[0], "false_alarm_budget.interval[0]", where)
    high = interval[1]
    if high is not None:
        high = finite_number(high, "false_alarm_budget.interval[1]", where)
    estimate = number("estimate")
    if not low <= estimate <= (math.inf if high is None else high):
        raise CalibrationError(
            "calibration field false_alarm_budget.interval does not hold its estimate",
            where,
            "re-run `twincd threshold`",
        )
    return TailFit(
        method=str(method),
        per_hour=number("per_hour", positive=True),
        level=number("level_u"),
        peaks=_count(raw["peaks"], "false_alarm_budget.peaks", where),
        rate_per_hour=number("rate_per_hour", positive=True),
        shape=number("shape"),
        scale=number("scale", positive=True),
        estimate=estimate,
        low=low,
        high=high,
        confidence=number("confidence", positive=True),
        gap_s=number("decluster_gap_s", positive=True),
        firm_after_minutes=None
        if raw.get("firm_after_minutes") is None
        else number("firm_after_minutes", positive=True),
    )


def _count(value: Any, name: str, where: str) -> int:
    """A count ≥ 0 (a JSON integer, not a float or a string)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise CalibrationError(
            f"calibration field {name} is {value!r}, not a count",
            where,
            "re-run `twincd threshold`",
        )
    return value


def _check_threshold(threshold: Threshold, raw: Mapping[str, Any], where: str) -> None:
    """σ ≥ 0, k ≥ 0, and a stored ``value`` that agrees with μ + kσ (a hand edit of one)."""
    if threshold.sigma < 0 or threshold.k_sigma < 0:
        raise CalibrationError(
            "calibration threshold has a negative sigma or k_sigma",
            where,
            "re-run `twincd threshold`",
        )
    if "value" in raw:
        value = finite_number(raw["value"], "threshold.value", where)
        if not math.isclose(value, threshold.value, rel_tol=1e-9, abs_tol=1e-12):
            raise CalibrationError(
                f"calibration threshold value {value!r} is not mu + k_sigma·sigma "
                f"({threshold.value!r})",
                where,
                "re-run `twincd threshold`, or edit mu, sigma or k_sigma instead",
            )


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _held(per_joint: Mapping[str, Any], names: Sequence[str]) -> tuple[tuple[str, ...], ...] | None:
    """``fit.joints.<joint>.held``, written for the joints that have held coefficients (None
    when no joint does)."""
    if not any("held" in (per_joint.get(n) or {}) for n in names):
        return None
    out = []
    for n in names:
        keys = (per_joint.get(n) or {}).get("held", [])
        if not isinstance(keys, list) or not all(k in HELD_KEYS for k in keys):
            raise ValueError(
                f"fit.joints.{n}.held must list some of {', '.join(HELD_KEYS)}, not {keys!r}"
            )
        out.append(tuple(str(k) for k in keys))
    return tuple(out)


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
