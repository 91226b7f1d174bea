"""The paper's detector (eq. 5–7): score(t) = ‖τ̃ − (a⊙τ̂̃ + b)‖², a flag where score ≥ μ + kσ,
and collision *events* (contiguous flagged runs) for people to read.

``affine_score`` and ``residual`` are pure array functions that the baselines reuse (naive-diff
is a = 1, b = 0). μ and σ come from mergeable per-log sums (``ScoreStats``), like the fit.
"""

from __future__ import annotations

import csv
import io
import json
import logging
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from twincd.calibration import AffineCalibration, Calibration, Threshold, clean_mask
from twincd.errors import DataError, NotFittedError, OutputError
from twincd.methods import ScoringMethod, register
from twincd.pipeline import PreparedLog

log = logging.getLogger("twincd")

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]

DEFAULT_K_SIGMA = 4.0  # the paper's μ + 4σ

RESIDUAL_TOPIC = "/twincd/residual"
SCORE_TOPIC = "/twincd/score"
COLLISION_TOPIC = "/twincd/collision"


def residual(
    effort_f: FloatArray, sim_effort_f: FloatArray, a: FloatArray, b: FloatArray
) -> FloatArray:
    """τ̃ − (a⊙τ̂̃ + b), (N, D)."""
    out: FloatArray = np.asarray(effort_f) - (np.asarray(a) * np.asarray(sim_effort_f) + b)
    return out


def affine_score(
    effort_f: FloatArray, sim_effort_f: FloatArray, a: FloatArray, b: FloatArray
) -> FloatArray:
    """score(t) = ‖τ̃(t) − (a⊙τ̂̃(t) + b)‖² per sample (eq. 5), (N,)."""
    r = residual(effort_f, sim_effort_f, a, b)
    out: FloatArray = np.einsum("ij,ij->i", r, r)
    return out


@dataclass(frozen=True)
class ScoreStats:
    """Mergeable n, Σs, Σs² of scores; μ and σ (population) of everything merged."""

    n: int = 0
    s: float = 0.0
    ss: float = 0.0

    @classmethod
    def from_scores(cls, scores: FloatArray, mask: BoolArray | None = None) -> ScoreStats:
        x = np.asarray(scores, dtype=np.float64)
        if mask is not None:
            x = x[mask]
        return cls(len(x), float(x.sum()), float((x * x).sum()))

    def __add__(self, other: ScoreStats) -> ScoreStats:
        return ScoreStats(self.n + other.n, self.s + other.s, self.ss + other.ss)

    @property
    def mu(self) -> float:
        self._check()
        return self.s / self.n

    @property
    def sigma(self) -> float:
        self._check()
        return float(np.sqrt(max(self.ss / self.n - self.mu**2, 0.0)))

    def _check(self) -> None:
        if self.n == 0:
            raise DataError(
                "no collision-free samples to set a threshold",
                "threshold",
                "give validation logs without collisions (or with labels)",
            )

    def threshold(self, k_sigma: float = DEFAULT_K_SIGMA, logs: Sequence[str] = ()) -> Threshold:
        return Threshold(k_sigma, self.mu, self.sigma, tuple(logs), self.n)


def score_stats(scores: Iterable[tuple[FloatArray, BoolArray | None]]) -> ScoreStats:
    """Merged statistics of (scores, collision-free mask) per log."""
    total = ScoreStats()
    for s, mask in scores:
        total = total + ScoreStats.from_scores(s, mask)
    return total


# ------------------------------------------------------------------ the method


class ProposedMethod(ScoringMethod):
    """The seed paper's method: affine regression of the twin's effort, squared residual."""

    name = "proposed"
    unit = "sample"
    learns = True

    def __init__(self, a: Sequence[float] | None = None, b: Sequence[float] | None = None):
        self.a = a
        self.b = b
        if a is not None and b is not None:
            self.a_: FloatArray = np.asarray(a, dtype=np.float64)
            self.b_: FloatArray = np.asarray(b, dtype=np.float64)

    @classmethod
    def from_calibration(cls, calibration: Calibration) -> ProposedMethod:
        return cls(list(calibration.a), list(calibration.b))

    def fit(self, train: Sequence[PreparedLog]) -> ProposedMethod:
        est = AffineCalibration().fit(train)
        self.a_, self.b_ = est.a_, est.b_
        return self

    def score(self, log: PreparedLog) -> FloatArray:
        if not hasattr(self, "a_"):
            raise NotFittedError("method 'proposed' is not fitted", "proposed", "call fit()")
        return affine_score(log.effort_f, log.sim_effort_f, self.a_, self.b_)


register("proposed", "twincd.detection:ProposedMethod")


# ------------------------------------------------------------------ events


@dataclass(frozen=True)
class Event:
    """One contiguous run of flagged samples (indices inclusive)."""

    first: int
    last: int
    start_ns: int
    end_ns: int
    peak_score: float
    peak_ns: int
    joint: str

    @property
    def samples(self) -> int:
        return self.last - self.first + 1

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9  # integer ns first: no float noise

    def to_dict(self) -> dict[str, object]:
        return {
            "start_ns": self.start_ns,
            "end_ns": self.end_ns,
            "duration_s": self.duration_s,
            "samples": self.samples,
            "peak_score": self.peak_score,
            "peak_ns": self.peak_ns,
            "joint": self.joint,
        }


def runs(flags: BoolArray) -> list[tuple[int, int]]:
    """(first, last) index pairs, inclusive, of every run of True."""
    f = np.asarray(flags, dtype=bool).astype(np.int8)
    edges = np.diff(np.concatenate(([0], f, [0])))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1) - 1
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


def find_events(
    flags: BoolArray,
    scores: FloatArray,
    residual_: FloatArray,
    stamp_ns: IntArray,
    joint_names: Sequence[str],
) -> list[Event]:
    """Events from a flag vector; the joint is the one with the largest share of Σ residual²."""
    events = []
    for first, last in runs(flags):
        seg = slice(first, last + 1)
        peak = first + int(np.argmax(scores[seg]))
        share = (residual_[seg] ** 2).sum(axis=0)
        events.append(
            Event(
                first=first,
                last=last,
                start_ns=int(stamp_ns[first]),
                end_ns=int(stamp_ns[last]),
                peak_score=float(scores[peak]),
                peak_ns=int(stamp_ns[peak]),
                joint=joint_names[int(np.argmax(share))],
            )
        )
    return events


# ------------------------------------------------------------------ one log


@dataclass(frozen=True)
class LogDetection:
    """Per-sample scores, flags and residuals of one log, and its events."""

    log: PreparedLog
    residual: FloatArray
    scores: FloatArray
    flags: BoolArray
    threshold: float
    events: list[Event]

    @property
    def source(self) -> str:
        return self.log.source

    def to_dict(self) -> dict[str, object]:
        return {
            "path": self.source,
            "samples": len(self.scores),
            "collision_samples": int(self.flags.sum()),
            "events": [e.to_dict() for e in self.events],
        }


def detect(log: PreparedLog, calibration: Calibration) -> LogDetection:
    """Score and flag every sample of ``log`` with a calibration that has a threshold."""
    threshold = calibration.require_threshold().value
    r = residual(log.effort_f, log.sim_effort_f, calibration.a, calibration.b)
    scores: FloatArray = np.einsum("ij,ij->i", r, r)
    flags = scores >= threshold
    events = find_events(flags, scores, r, log.states.stamp_ns, log.joint_names)
    return LogDetection(log, r, scores, flags, threshold, events)


def threshold_stats(logs: Iterable[PreparedLog], calibration: Calibration) -> ScoreStats:
    """μ/σ statistics of the calibrated score over the collision-free samples of ``logs``."""
    return score_stats(
        (affine_score(lg.effort_f, lg.sim_effort_f, calibration.a, calibration.b), clean_mask(lg))
        for lg in logs
    )


# ------------------------------------------------------------------ outputs

OUTPUT_SUFFIXES = (".mcap", ".csv", ".jsonl")


def write_detection(result: LogDetection, source: Path, target: Path) -> None:
    """``target`` by suffix: augmented MCAP, or one CSV/JSONL row per sample (atomic)."""
    suffix = target.suffix.lower()
    if suffix == ".mcap":
        _write_mcap(result, source, target)
    elif suffix in (".csv", ".jsonl"):
        from twincd.mcap_io import atomic_output

        with atomic_output(target) as stream:
            text = io.TextIOWrapper(stream, encoding="utf-8", newline="")
            rows = _rows(result)
            if suffix == ".csv":
                _write_csv(text, result, rows)
            else:
                for row in rows:
                    text.write(json.dumps(row) + "\n")
            text.flush()
            text.detach()
    else:
        raise OutputError(
            f"unknown output type {target.suffix!r}",
            str(target),
            "end -o with .mcap, .csv or .jsonl",
        )


def _rows(result: LogDetection) -> Iterator[dict[str, object]]:
    names = result.log.joint_names
    stamps = result.log.states.stamp_ns
    for i in range(len(result.scores)):
        row: dict[str, object] = {
            "stamp_ns": int(stamps[i]),
            "score": float(result.scores[i]),
            "collision": bool(result.flags[i]),
        }
        for j, n in enumerate(names):
            row[f"residual_{n}"] = float(result.residual[i, j])
        yield row


def _write_csv(
    text: io.TextIOWrapper, result: LogDetection, rows: Iterator[dict[str, object]]
) -> None:
    fields = ["stamp_ns", "score", "collision"] + [f"residual_{n}" for n in result.log.joint_names]
    writer = csv.DictWriter(text, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({**row, "collision": int(bool(row["collision"]))})  # 0/1 for any tool


def _write_mcap(result: LogDetection, source: Path, target: Path) -> None:
    from twincd.logs import JOINT_STATE
    from twincd.mcap_io import NewTopic, write_augmented
    from twincd.messages import bool_cdr, float64_cdr, joint_state_cdr

    if target.resolve() == Path(source).resolve():
        raise OutputError("output would overwrite the input", str(target), "pick another -o")
    states = result.log.states
    stamps, log_times = states.stamp_ns, states.log_time_ns

    def timed(payloads: Iterable[bytes]) -> Iterator[tuple[int, int, bytes]]:
        for t, data in zip(log_times, payloads, strict=False):
            yield int(t), int(t), data

    # Float64 and Bool have no header: their log time ties them to the sample
    residual_msgs = joint_state_cdr(
        stamps, states.joint_names, states.position, states.velocity, result.residual
    )
    write_augmented(
        source,
        target,
        [
            NewTopic(RESIDUAL_TOPIC, JOINT_STATE, timed(residual_msgs)),
            NewTopic(SCORE_TOPIC, "std_msgs/msg/Float64", timed(map(float64_cdr, result.scores))),
            NewTopic(COLLISION_TOPIC, "std_msgs/msg/Bool", timed(map(bool_cdr, result.flags))),
        ],
    )


def calibrate_threshold(
    logs: Iterable[PreparedLog], calibration: Calibration, k_sigma: float = DEFAULT_K_SIGMA
) -> Calibration:
    """The calibration with μ + kσ of its score on collision-free ``logs`` (streamed)."""
    seen: list[str] = []

    def stream() -> Iterator[PreparedLog]:
        for lg in logs:
            seen.append(lg.source)
            yield lg

    stats = threshold_stats(stream(), calibration)
    reused = sorted(set(seen) & set(calibration.fit_logs))
    if reused:
        log.warning(
            "%d threshold log(s) were also used by fit (%s): μ and σ will be optimistic; "
            "use separate validation logs",
            len(reused),
            reused[0],
        )
    return calibration.with_threshold(stats.threshold(k_sigma, seen))
