"""The calibration file read back (``Calibration.from_dict``): the JSON document's schema
upgraded (``upgrade_v1``, ``upgrade_v2``), every section present and every number validated,
a ``CalibrationError`` naming the field of anything that is not."""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from typing import Any

from twincd.calibration.clean import read_band_stats
from twincd.calibration.file import SCHEMA, Calibration, FitInfo, Threshold
from twincd.calibration.models import depth_order, read_model
from twincd.calibration.score import read_score
from twincd.calibration.tail import TAIL_METHODS, TailFit
from twincd.calibration.values import finite_array, finite_number
from twincd.errors import CalibrationError
from twincd.io.options import DEFAULT_LINK_TOPIC, LogOptions
from twincd.signal.filters import LowPass
from twincd.types import FloatArray

log = logging.getLogger("twincd")

SCHEMA_V2 = "twincd.calibration/2"  # still read, through ``upgrade_v2``
SCHEMA_V1 = "twincd.calibration/1"  # still read, through ``upgrade_v1``
# the coefficients ``fit.joints.<joint>.held`` may name (``twincd.calibration.excitation``)
HELD_KEYS = ("a", "c", "d", "theta")
# what a threshold's μ and σ are (``Threshold.estimator``)
ESTIMATORS = ("mean-sd", "median-mad")


def read_calibration(d: Mapping[str, Any], source: str = "") -> Calibration:
    """The calibration of a JSON document (``Calibration.from_dict``): of schema ``SCHEMA``, or
    of ``/2`` or ``/1`` upgraded first; every section present and every number validated."""
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
