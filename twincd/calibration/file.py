"""The calibration file (docs/contract.md): everything detection needs, as JSON."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from twincd.calibration.models import (
    AFFINE,
    COEFFICIENTS,
    MODEL_KINDS,
    SPEED_BINS,
    STATISTICS,
    ResidualModel,
    depth_order,
    make_model,
    model_class,
)
from twincd.errors import CalibrationError, NotFittedError
from twincd.io.options import LogOptions
from twincd.signal.filters import LowPass
from twincd.tail import TAIL_METHODS, TailFit
from twincd.types import FloatArray
from twincd.version import __version__

SCHEMA = "twincd.calibration/1"
# what a threshold's μ and σ are (``Threshold.estimator``)
ESTIMATORS = ("mean-sd", "median-mad")


def finite_number(value: Any, name: str, where: str, *, positive: bool = False) -> float:
    """``value`` as a float, or a ``CalibrationError``: JSON numbers only (no strings, no
    booleans), finite, and above 0 when ``positive`` (every number of the calibration file is
    validated: docs/contract.md)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CalibrationError(
            f"calibration field {name} is {type(value).__name__} {value!r}, not a number",
            where,
            "re-run `twincd fit` to write a new one",
        )
    number = float(value)
    if not math.isfinite(number) or (positive and number <= 0):
        need = "a positive finite number" if positive else "a finite number"
        raise CalibrationError(
            f"calibration field {name} is {value!r}, not {need}",
            where,
            "re-run `twincd fit` to write a new one",
        )
    return number


def finite_array(values: Sequence[Any], names: Sequence[str], field: str, where: str) -> FloatArray:
    """One finite float per joint of ``names`` (a per-joint coefficient of any model kind), or a
    ``CalibrationError`` naming the joint and the field at fault."""
    if isinstance(values, (str, bytes)) or not isinstance(values, Sequence):
        raise CalibrationError(
            f"calibration field {field} is not a list of numbers", where, "re-run `twincd fit`"
        )
    if len(values) != len(names):
        raise CalibrationError(
            f"calibration field {field} has {len(values)} value(s) for {len(names)} joint(s)",
            where,
            "re-run `twincd fit` to write a new one",
        )
    return np.array(
        [finite_number(v, f"{field}[{n}]", where) for v, n in zip(values, names, strict=True)],
        dtype=np.float64,
    )


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
class Calibration:
    """Everything detection needs, as stored in calibration JSON (docs/contract.md)."""

    joint_names: tuple[str, ...]
    a: FloatArray
    b: FloatArray
    lowpass: LowPass
    options: LogOptions = field(default_factory=LogOptions)
    robot: str | None = None
    urdf_sha256: str | None = None
    simulated: bool = True
    fit_logs: tuple[str, ...] = ()
    fit_samples: int = 0
    r2: FloatArray | None = None
    rmse: FloatArray | None = None
    fit_s: float = 0.0
    threshold: Threshold | None = None
    created: str = ""
    twincd_version: str = __version__
    source: str = ""  # the file it was loaded from, for messages
    # nominal sampling period of the fitted logs: later logs are filtered at this rate, so that
    # batch and live detection agree (None in files written before it was recorded)
    period_s: float | None = None
    # the calibration model (``model``): the seed's affine map, or one of MODEL_KINDS
    kind: str = AFFINE
    c: FloatArray | None = None  # friction models: Coulomb coefficient of tanh(q̇̃/ε)
    d: FloatArray | None = None  # friction models: viscous coefficient of q̇̃
    epsilon: FloatArray | None = None  # friction models: ε (rad/s) chosen on the training logs
    # whitened models: each joint's residual RMS on the clean training samples, (D, B) in bins
    # of the joint's speed (edges ``speed_bins``), or (D,) in files written before the bins
    scale: FloatArray | None = None
    speed_bins: tuple[float, ...] = SPEED_BINS
    # identified models: per joint the weights (D, P) of the filtered joint-torque regressor
    theta: FloatArray | None = None
    # the body each joint moves (its child link), for naming the link an event touched
    links: tuple[str, ...] | None = None
    depths: tuple[int, ...] | None = None  # each joint's depth in the kinematic tree
    # per joint, the coefficients the fit logs' motion did not determine, held at their prior
    # (``twincd.calibration.excitation``); None in files written before it was recorded
    held: tuple[tuple[str, ...], ...] | None = None

    @property
    def coulomb_eps(self) -> tuple[float, ...]:
        """The ε whose filtered Coulomb features scoring needs (none for non-friction models)."""
        return () if self.epsilon is None else tuple(sorted({float(e) for e in self.epsilon}))

    @property
    def regressor(self) -> bool:
        """Scoring needs the filtered joint-torque regressor (identified models)."""
        return self.theta is not None

    @property
    def regressor_weights(self) -> FloatArray | None:
        """θ, with which the chain filters Ỹθ per joint rather than Ỹ (``twincd.chain``)."""
        return self.theta

    @property
    def model(self) -> ResidualModel:
        """The fitted model that detection applies (one of ``MODEL_KINDS``)."""
        model = make_model(
            self.kind, depth_order(self.depths, len(self.joint_names)), self.speed_bins
        )
        coefficients = {key: getattr(self, key) for key in COEFFICIENTS}
        return model.with_coefficients(coefficients, self.r2, self.rmse)

    @property
    def joint_scale(self) -> FloatArray | None:
        """One noise scale per joint, what isolation compares joints by (``ResidualModel``)."""
        return self.model.joint_scale

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
        fit: dict[str, Any] = {
            "logs": list(self.fit_logs),
            "samples": self.fit_samples,
            "seconds": self.fit_s,
            "joints": {
                n: {
                    "r2": None if self.r2 is None else float(self.r2[i]),
                    "rmse": None if self.rmse is None else float(self.rmse[i]),
                    **({"held": list(self.held[i])} if self.held and self.held[i] else {}),
                }
                for i, n in enumerate(names)
            },
        }
        return {
            "schema": SCHEMA,
            "twincd_version": self.twincd_version,
            "created": self.created or _now(),
            "robot": {
                "name": self.robot,
                "urdf_sha256": self.urdf_sha256,
                "joint_names": names,
                "simulated": self.simulated,
                **({} if self.links is None else {"links": list(self.links)}),
                **({} if self.depths is None else {"depths": list(self.depths)}),
            },
            "log_options": {
                "topic": self.options.topic,
                "label_topic": self.options.label_topic,
                "sim_topic": self.options.sim_topic,
                "joint_map": dict(self.options.joint_map or {}),
            },
            "filter": {
                **self.lowpass.to_dict(),
                "sample_rate_hz": None if self.period_s is None else 1.0 / self.period_s,
            },
            "model": {
                "kind": self.kind,
                **self._statistic(),
                "joints": {n: self._coefficients(i) for i, n in enumerate(names)},
            },
            "fit": fit,
            "threshold": None if self.threshold is None else self.threshold.to_dict(),
        }

    def _statistic(self) -> dict[str, Any]:
        """How the model scores: written for the depth statistic (its speed bins' edges)."""
        if self.scale is None or self.scale.ndim == 1:
            return {}
        return {"statistic": "depth", "speed_bins": list(self.speed_bins)}

    def _coefficients(self, i: int) -> dict[str, Any]:
        out: dict[str, Any] = {"a": float(self.a[i]), "b": float(self.b[i])}
        for key in ("c", "d", "epsilon", "scale"):
            values = getattr(self, key)
            if values is not None:
                out[key] = values[i].tolist() if values.ndim == 2 else float(values[i])
        if self.theta is not None:
            out["theta"] = [float(x) for x in self.theta[i]]
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "") -> Calibration:
        where = source or "calibration"
        if not isinstance(d, Mapping):
            raise CalibrationError(
                f"calibration is a JSON {type(d).__name__}, not an object",
                where,
                "pass the JSON file written by `twincd fit`",
            )
        schema = d.get("schema")
        if schema != SCHEMA:
            raise CalibrationError(
                f"unsupported calibration schema {schema!r} (this twincd reads {SCHEMA})",
                where,
                "re-run `twincd fit` with this version",
            )
        try:
            robot = d["robot"]
            names = _joint_names(robot["joint_names"], where)
            model = d["model"]
            kind = model.get("kind")
            if kind not in MODEL_KINDS:
                raise CalibrationError(
                    f"unknown model kind {kind!r} (this twincd knows {', '.join(MODEL_KINDS)})",
                    where,
                    "re-run `twincd fit`",
                )
            coeff = model["joints"]
            a = finite_array([coeff[n]["a"] for n in names], names, "a", where)
            b = finite_array([coeff[n]["b"] for n in names], names, "b", where)
            extra = {key: _optional_column(coeff, names, key) for key in ("c", "d", "epsilon")}
            speed_bins = _speed_bins(model, where)
            extra["scale"] = _scale(coeff, names, speed_bins, where)
            theta = _theta(coeff, names, where)
            _require_coefficients(str(kind), {**extra, "theta": theta}, where)
            links, depths = robot.get("links"), robot.get("depths")
            for key, values in (("links", links), ("depths", depths)):
                if values is not None and len(values) != len(names):
                    raise ValueError(
                        f"robot.{key} has {len(values)} entries for {len(names)} joints"
                    )
            fit = d.get("fit") or {}
            per_joint = fit.get("joints") or {}

            def column(key: str) -> FloatArray | None:
                vals = [per_joint.get(n, {}).get(key) for n in names]
                return None if any(v is None for v in vals) else np.array(vals, dtype=float)

            opts = d.get("log_options") or {}
            defaults = LogOptions()
            options = LogOptions(
                topic=str(opts.get("topic", defaults.topic)),
                label_topic=str(opts.get("label_topic", defaults.label_topic)),
                sim_topic=str(opts.get("sim_topic", defaults.sim_topic)),
                joint_map=dict(opts.get("joint_map") or {}) or None,
            )
            th = d.get("threshold")
            threshold = None
            if th is not None:
                threshold = Threshold(
                    k_sigma=finite_number(th["k_sigma"], "threshold.k_sigma", where),
                    mu=finite_number(th["mu"], "threshold.mu", where),
                    sigma=finite_number(th["sigma"], "threshold.sigma", where),
                    logs=tuple(th.get("logs", ())),
                    samples=int(th.get("samples", 0)),
                    **_budget(th.get("false_alarm_budget"), where),
                    estimator=_estimator(th.get("estimator", "mean-sd"), where),
                    mean=None
                    if "mean" not in th
                    else finite_number(th["mean"], "threshold.mean", where),
                    sd=None if "sd" not in th else finite_number(th["sd"], "threshold.sd", where),
                )
            if th is not None and threshold is not None:
                _check_threshold(threshold, th, where)
            return cls(
                joint_names=names,
                a=a,
                b=b,
                lowpass=_lowpass(d["filter"], where),
                period_s=_period(d["filter"].get("sample_rate_hz"), where),
                options=options,
                robot=robot.get("name"),
                urdf_sha256=robot.get("urdf_sha256"),
                simulated=bool(robot.get("simulated", True)),
                fit_logs=tuple(fit.get("logs", ())),
                fit_samples=int(fit.get("samples", 0)),
                r2=column("r2"),
                rmse=column("rmse"),
                held=_held(per_joint, names),
                fit_s=float(fit.get("seconds", 0.0)),
                threshold=threshold,
                created=str(d.get("created", "")),
                twincd_version=str(d.get("twincd_version", "")),
                source=source,
                kind=str(kind),
                links=None if links is None else tuple(str(x) for x in links),
                depths=None if depths is None else tuple(int(x) for x in depths),
                theta=theta,
                speed_bins=SPEED_BINS if speed_bins is None else speed_bins,
                **extra,
            )
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


def _optional_number(section: Mapping[str, Any], key: str, where: str) -> float | None:
    """``threshold.<key>`` when the file has it (a finite number), else None."""
    return None if key not in section else finite_number(section[key], f"threshold.{key}", where)


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
        "false_alarms": None if alarms is None else _count(alarms, "false_alarms", where),
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
        peaks=_count(raw["peaks"], "peaks", where),
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
    """A count ≥ 0 of the budget's fields (a JSON integer, not a float or a string)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise CalibrationError(
            f"calibration field false_alarm_budget.{name} is {value!r}, not a count",
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


def _optional_column(coeff: Mapping[str, Any], names: Sequence[str], key: str) -> FloatArray | None:
    """A per-joint coefficient that only some models have: all joints or none."""
    values = [coeff[n].get(key) for n in names]
    if all(v is None for v in values):
        return None
    if any(v is None for v in values):
        raise ValueError(f"coefficient {key!r} is missing for some joints")
    return np.array([float(v) for v in values])


def _speed_bins(model: Mapping[str, Any], where: str) -> tuple[float, ...] | None:
    """The depth statistic's speed bins (None: a model scored by the sum, as files written
    before the bins): rising, positive, finite edges."""
    statistic = model.get("statistic", "sum")
    if statistic not in STATISTICS:
        raise CalibrationError(
            f"calibration field model.statistic is {statistic!r}, not one of "
            f"{', '.join(STATISTICS)}",
            where,
            "re-run `twincd fit`",
        )
    if statistic == "sum":
        return None
    edges = model["speed_bins"]
    if not isinstance(edges, list) or not edges:
        raise CalibrationError(
            "calibration field model.speed_bins is not a list of speeds",
            where,
            "re-run `twincd fit`",
        )
    out = tuple(finite_number(e, "model.speed_bins", where, positive=True) for e in edges)
    if any(b <= a for a, b in pairwise(out)):
        raise CalibrationError(
            "calibration field model.speed_bins does not rise", where, "re-run `twincd fit`"
        )
    return out


def _scale(
    coeff: Mapping[str, Any],
    names: Sequence[str],
    speed_bins: tuple[float, ...] | None,
    where: str,
) -> FloatArray | None:
    """The whitening scale: one number per joint (the sum), or one per speed bin (the depth
    statistic), all joints or none."""
    if speed_bins is None:
        return _optional_column(coeff, names, "scale")
    rows = [coeff[n].get("scale") for n in names]
    bins = len(speed_bins) + 1
    if any(not isinstance(r, list) or len(r) != bins for r in rows):
        raise CalibrationError(
            f"calibration field scale is not a list of {bins} numbers (one per speed bin) for "
            "every joint",
            where,
            "re-run `twincd fit`",
        )
    return np.array(
        [
            [finite_number(v, f"scale[{n}]", where) for v in r]
            for r, n in zip(rows, names, strict=True)
        ]
    )


def _theta(coeff: Mapping[str, Any], names: Sequence[str], where: str) -> FloatArray | None:
    """The identified models' per-joint regressor weights: all joints, of one length, or none."""
    rows = [coeff[n].get("theta") for n in names]
    if all(r is None for r in rows):
        return None
    if any(r is None for r in rows):
        raise ValueError("coefficient 'theta' is missing for some joints")
    lengths = {len(r) if isinstance(r, list) else -1 for r in rows}
    if len(lengths) != 1 or -1 in lengths:
        raise CalibrationError(
            "calibration field theta is not a list of numbers of one length per joint",
            where,
            "re-run `twincd fit`",
        )
    length = lengths.pop()
    if length == 0 or length % 10:
        raise CalibrationError(
            f"calibration field theta has {length} numbers per joint, not 10 per link",
            where,
            "re-run `twincd fit`",
        )
    return np.array(
        [
            [finite_number(v, f"theta[{n}]", where) for v in r]
            for r, n in zip(rows, names, strict=True)
        ],
        dtype=np.float64,
    )


def _require_coefficients(kind: str, extra: Mapping[str, FloatArray | None], where: str) -> None:
    cls, whitened = model_class(kind)
    needed = (
        (["c", "d", "epsilon"] if cls.needs_coulomb else [])
        + (["scale"] if whitened else [])
        + (["theta"] if cls.needs_regressor else [])
    )
    if extra.get("theta") is not None and not cls.needs_regressor:
        raise CalibrationError(
            f"the {kind} model has regressor weights (theta), which only identified models use",
            where,
            "re-run `twincd fit`",
        )
    missing = [k for k in needed if extra.get(k) is None]
    if missing:
        raise CalibrationError(
            f"the {kind} model lacks its coefficient(s) {', '.join(missing)}",
            where,
            "re-run `twincd fit`",
        )
    eps, scale = extra.get("epsilon"), extra.get("scale")
    if (eps is not None and not np.all(eps > 0)) or (scale is not None and not np.all(scale > 0)):
        raise CalibrationError("epsilon and scale must be positive", where, "re-run `twincd fit`")


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
        if not isinstance(keys, list) or not all(k in ("a", "c", "d") for k in keys):
            raise ValueError(f"fit.joints.{n}.held must list some of a, c, d, not {keys!r}")
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
) -> Calibration:
    """The calibration file's content from a fitted model (``fit_s_``: its training time)."""
    coefficients = model.coefficients()
    held = getattr(model, "held_", None)
    return Calibration(
        joint_names=tuple(joint_names),
        a=model.a_,
        b=model.b_,
        lowpass=lowpass,
        options=options.unnamed(*options.named),  # what the logs were read with, not how asked
        robot=robot,
        urdf_sha256=urdf_sha256,
        simulated=simulated,
        fit_logs=tuple(logs),
        fit_samples=model.n_samples_,
        held=None if held is None else tuple(held.per_joint(i) for i in range(len(joint_names))),
        r2=model.r2_,
        rmse=model.rmse_,
        fit_s=model.fit_s_,
        created=_now(),
        period_s=period_s,
        kind=model.kind,
        c=coefficients["c"],
        d=coefficients["d"],
        epsilon=coefficients["epsilon"],
        scale=coefficients["scale"],
        theta=coefficients["theta"],
    )
