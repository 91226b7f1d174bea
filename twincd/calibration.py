"""The paper's regression τ̃ ≈ a⊙τ̂̃ + b (eq. 3–4) and the calibration file (DESIGN §4).

Fitting is split into a pure per-log step (``AffineStats.from_log``: sufficient statistics of
one log) and a merge (``+``), so memory stays flat for any number of logs and the per-log work
can run in other processes or on a cluster. Least squares per joint only needs n, Σx, Σy, Σx²,
Σxy, Σy² (x = τ̂̃, y = τ̃).
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from twincd import __version__
from twincd.errors import CalibrationError, DataError, NotFittedError
from twincd.filters import LowPass
from twincd.logs import LogOptions
from twincd.pipeline import PreparedLog

log = logging.getLogger("twincd")

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

SCHEMA = "twincd.calibration/1"
# a joint whose twin effort varies less than this fraction of the measured effort's spread gives
# a slope that mostly amplifies noise (the paper's joint 7: a = 21.7)
CONDITION_RATIO = 0.1


def clean_mask(log_: PreparedLog) -> BoolArray:
    """Samples usable for fitting and thresholds: all, or those labelled collision-free."""
    if log_.labels is None:
        return np.ones(len(log_), dtype=bool)
    return ~log_.labels


@dataclass(frozen=True)
class AffineStats:
    """Mergeable sufficient statistics of a per-joint regression y ≈ a·x + b.

    Means and *centred* sums of squares and products, merged with Chan et al.'s pairwise
    update: raw Σx² − (Σx)²/n would cancel the signal of efforts with large constant offsets.
    """

    n: int
    mean_x: FloatArray
    mean_y: FloatArray
    cxx: FloatArray  # Σ (x − x̄)²
    cyy: FloatArray  # Σ (y − ȳ)²
    cxy: FloatArray  # Σ (x − x̄)(y − ȳ)

    @classmethod
    def zeros(cls, joints: int) -> AffineStats:
        z = np.zeros(joints)
        return cls(0, z, z, z, z, z)

    @classmethod
    def from_arrays(
        cls, x: FloatArray, y: FloatArray, mask: BoolArray | None = None
    ) -> AffineStats:
        """Statistics of (N, D) arrays x = τ̂̃ and y = τ̃, rows where ``mask`` holds."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if mask is not None:
            x, y = x[mask], y[mask]
        if len(x) == 0:
            return cls.zeros(x.shape[1] if x.ndim == 2 else 0)
        mx, my = x.mean(axis=0), y.mean(axis=0)
        dx, dy = x - mx, y - my
        return cls(
            n=len(x),
            mean_x=mx,
            mean_y=my,
            cxx=(dx * dx).sum(axis=0),
            cyy=(dy * dy).sum(axis=0),
            cxy=(dx * dy).sum(axis=0),
        )

    @classmethod
    def from_log(cls, log_: PreparedLog) -> AffineStats:
        """One log's statistics over its collision-free samples (the pure per-log step)."""
        return cls.from_arrays(log_.sim_effort_f, log_.effort_f, clean_mask(log_))

    def __add__(self, other: AffineStats) -> AffineStats:
        if self.n == 0:
            return other
        if other.n == 0:
            return self
        if self.mean_x.shape != other.mean_x.shape:
            raise DataError(
                "logs with different joint counts cannot be fitted together",
                f"{self.mean_x.shape[0]} vs {other.mean_x.shape[0]} joints",
                "fit logs of one robot",
            )
        n = self.n + other.n
        dx = other.mean_x - self.mean_x
        dy = other.mean_y - self.mean_y
        w = self.n * other.n / n
        return AffineStats(
            n,
            self.mean_x + dx * (other.n / n),
            self.mean_y + dy * (other.n / n),
            self.cxx + other.cxx + dx * dx * w,
            self.cyy + other.cyy + dy * dy * w,
            self.cxy + other.cxy + dx * dy * w,
        )

    @property
    def var_x(self) -> FloatArray:
        return self.cxx / self.n

    @property
    def var_y(self) -> FloatArray:
        return self.cyy / self.n


@dataclass(frozen=True)
class AffineSolution:
    a: FloatArray
    b: FloatArray
    r2: FloatArray
    rmse: FloatArray
    ill_conditioned: BoolArray


def solve(stats: AffineStats) -> AffineSolution:
    """Least squares per joint from merged statistics (closed form of eq. 3)."""
    if stats.n < 2:
        raise DataError(
            "too few collision-free samples to fit",
            f"{stats.n} sample(s)",
            "give longer logs, or logs with collision-free parts",
        )
    n = stats.n
    cxx, cyy, cxy = stats.cxx, stats.cyy, stats.cxy
    degenerate = cxx <= 1e-12 * np.maximum(cyy, 1e-300)
    a = np.where(degenerate, 0.0, cxy / np.where(degenerate, 1.0, cxx))
    b = stats.mean_y - a * stats.mean_x
    sse = np.maximum(cyy - a * cxy, 0.0)
    r2 = np.where(cyy > 0, 1.0 - sse / np.where(cyy > 0, cyy, 1.0), 1.0)
    rmse = np.sqrt(sse / n)
    ill = degenerate | (np.sqrt(cxx) < CONDITION_RATIO * np.sqrt(cyy))
    return AffineSolution(a, b, r2, rmse, ill)


class AffineCalibration:
    """Estimator of the paper's a, b (scikit-learn style: ``fit`` returns self).

    Learned attributes: ``a_``, ``b_``, ``r2_``, ``rmse_`` (per joint), ``n_samples_``,
    ``stats_`` (the merged AffineStats, for further merging) and ``fit_s_`` (fit time).
    """

    def __init__(self, joint_names: Sequence[str] | None = None) -> None:
        self.joint_names = joint_names

    def fit(self, logs: Iterable[PreparedLog]) -> AffineCalibration:
        """Fit on collision-free samples of ``logs``, consumed one at a time (may be lazy)."""
        # timed like the paper's training time: the regression, not reading or simulating logs
        elapsed = 0.0
        total: AffineStats | None = None
        for log_ in logs:
            start = time.perf_counter()
            part = AffineStats.from_log(log_)
            total = part if total is None else total + part
            elapsed += time.perf_counter() - start
            if self.joint_names is None:
                self.joint_names = log_.joint_names
        if total is None:
            raise DataError("no logs to fit", "fit", "give at least one collision-free log")
        start = time.perf_counter()
        self.fit_stats(total)
        self.fit_s_ = elapsed + time.perf_counter() - start
        return self

    def fit_arrays(
        self, effort_f: FloatArray, sim_effort_f: FloatArray, mask: BoolArray | None = None
    ) -> AffineCalibration:
        return self.fit_stats(AffineStats.from_arrays(sim_effort_f, effort_f, mask))

    def fit_stats(self, stats: AffineStats) -> AffineCalibration:
        """Fit from statistics merged elsewhere (e.g. computed per log on workers)."""
        sol = solve(stats)
        self.stats_ = stats
        self.a_, self.b_, self.r2_, self.rmse_ = sol.a, sol.b, sol.r2, sol.rmse
        self.n_samples_ = stats.n
        self.fit_s_ = 0.0
        names = list(self.joint_names or [f"#{i}" for i in range(len(sol.a))])
        for i in np.flatnonzero(sol.ill_conditioned):
            log.warning(
                "joint %s is badly conditioned: its twin effort barely varies "
                "(std %.3g vs measured %.3g), so a = %.3g is unreliable",
                names[i],
                math.sqrt(float(stats.var_x[i])),
                math.sqrt(float(stats.var_y[i])),
                float(sol.a[i]),
            )
        return self

    def _check(self) -> None:
        if not hasattr(self, "a_"):
            raise NotFittedError("the calibration is not fitted", "AffineCalibration", "call fit()")

    def predict(self, sim_effort_f: FloatArray) -> FloatArray:
        """a⊙τ̂̃ + b: the twin's effort adjusted to the real robot."""
        self._check()
        out: FloatArray = self.a_ * sim_effort_f + self.b_
        return out


# ------------------------------------------------------------------ the calibration file


@dataclass(frozen=True)
class Threshold:
    """μ + kσ of the score on collision-free logs (DESIGN §4 ``threshold``)."""

    k_sigma: float
    mu: float
    sigma: float
    logs: tuple[str, ...] = ()
    samples: int = 0

    @property
    def value(self) -> float:
        return self.mu + self.k_sigma * self.sigma

    def to_dict(self) -> dict[str, Any]:
        return {
            "k_sigma": self.k_sigma,
            "mu": self.mu,
            "sigma": self.sigma,
            "value": self.value,
            "logs": list(self.logs),
            "samples": self.samples,
        }


@dataclass(frozen=True)
class Calibration:
    """Everything detection needs, as stored in calibration JSON (DESIGN §4)."""

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

    def require_threshold(self) -> Threshold:
        if self.threshold is None:
            where = self.source or "calibration"
            raise NotFittedError(
                "the calibration has no threshold",
                where,
                f"run `twincd threshold VAL_LOGS -c {where}` on collision-free logs first",
            )
        return self.threshold

    def with_threshold(self, threshold: Threshold) -> Calibration:
        return replace(self, threshold=threshold)

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
            },
            "log_options": {
                "topic": self.options.topic,
                "label_topic": self.options.label_topic,
                "sim_topic": self.options.sim_topic,
                "joint_map": dict(self.options.joint_map or {}),
            },
            "filter": self.lowpass.to_dict(),
            "model": {
                "kind": "affine",
                "joints": {
                    n: {"a": float(self.a[i]), "b": float(self.b[i])} for i, n in enumerate(names)
                },
            },
            "fit": fit,
            "threshold": None if self.threshold is None else self.threshold.to_dict(),
        }

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
            names = tuple(str(n) for n in robot["joint_names"])
            model = d["model"]
            if model.get("kind") != "affine":
                raise CalibrationError(
                    f"unknown model kind {model.get('kind')!r}", where, "re-run `twincd fit`"
                )
            coeff = model["joints"]
            a = np.array([float(coeff[n]["a"]) for n in names])
            b = np.array([float(coeff[n]["b"]) for n in names])
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
                    k_sigma=float(th["k_sigma"]),
                    mu=float(th["mu"]),
                    sigma=float(th["sigma"]),
                    logs=tuple(th.get("logs", ())),
                    samples=int(th.get("samples", 0)),
                )
            return cls(
                joint_names=names,
                a=a,
                b=b,
                lowpass=LowPass.from_dict(d["filter"]),
                options=options,
                robot=robot.get("name"),
                urdf_sha256=robot.get("urdf_sha256"),
                simulated=bool(robot.get("simulated", True)),
                fit_logs=tuple(fit.get("logs", ())),
                fit_samples=int(fit.get("samples", 0)),
                r2=column("r2"),
                rmse=column("rmse"),
                fit_s=float(fit.get("seconds", 0.0)),
                threshold=threshold,
                created=str(d.get("created", "")),
                twincd_version=str(d.get("twincd_version", "")),
                source=source,
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
                "pass the JSON file written by `twincd fit` to -c",
            ) from exc
        except OSError as exc:
            raise CalibrationError(
                f"cannot read calibration: {exc.strerror or exc}",
                str(path),
                "run `twincd fit LOGS -o FILE` first or check -c",
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
        from twincd.mcap_io import atomic_output

        text = json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n"
        with atomic_output(Path(path)) as stream:
            stream.write(text.encode("utf-8"))


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def calibration_from_fit(
    estimator: AffineCalibration,
    lowpass: LowPass,
    options: LogOptions,
    robot: str | None,
    urdf_sha256: str | None,
    simulated: bool,
    logs: Sequence[str],
) -> Calibration:
    """The calibration file's content from a fitted estimator."""
    estimator._check()
    assert estimator.joint_names is not None
    return Calibration(
        joint_names=tuple(estimator.joint_names),
        a=estimator.a_,
        b=estimator.b_,
        lowpass=lowpass,
        options=options,
        robot=robot,
        urdf_sha256=urdf_sha256,
        simulated=simulated,
        fit_logs=tuple(logs),
        fit_samples=estimator.n_samples_,
        r2=estimator.r2_,
        rmse=estimator.rmse_,
        fit_s=estimator.fit_s_,
        created=_now(),
    )


# ------------------------------------------------------------------ running over logs


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
        from twincd.robot import DEFAULT_ROBOT

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
