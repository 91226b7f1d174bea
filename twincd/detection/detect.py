"""Detection: score every sample, flag where score ≥ the threshold, group flags into events (one
push, one event: ``twincd.detection.events.EventRules``) — on a whole log in memory, or on a log
streamed block by block at flat memory."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from twincd.calibration.models import ResidualModel, model_inputs
from twincd.detection.events import Event, EventRules, EventTracker, LabelSpans, false_alarms
from twincd.detection.isolation import isolator_for
from twincd.errors import DataError
from twincd.prepare.frames import Frame, FrameSink
from twincd.signal.features import FittedModel, ModelInputs
from twincd.signal.stream import DEFAULT_GAP_FACTOR
from twincd.types import BoolArray, FloatArray, IntArray

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.prepare.prepared import PreparedLog

log = logging.getLogger("twincd")


# more flagged than this share of a log's judged collision-free samples: the calibration does
# not fit the log (a collision is brief; a log flagged throughout is a misfit, not a finding)
MOSTLY_FLAGGED = 0.5


@dataclass
class FlagCount:
    """Judged and flagged samples of one log, counted block by block (every sample is judged,
    a segment's ends with their own noise: ``twincd.signal.edges``); samples labelled as
    collisions (when the log has labels) are left out of the clean counts, so a labelled
    collision never makes a log "mostly flagged"."""

    judged: int = 0  # judged samples, labelled ones included
    clean: int = 0  # judged samples not labelled as collisions
    clean_flagged: int = 0

    def add(self, flags: BoolArray, judged: BoolArray, labels: BoolArray | None = None) -> None:
        judged = np.asarray(judged, dtype=bool)
        self.judged += int(np.count_nonzero(judged))
        clean = judged if labels is None else judged & ~np.asarray(labels, dtype=bool)
        self.clean += int(np.count_nonzero(clean))
        self.clean_flagged += int(np.count_nonzero(np.asarray(flags, dtype=bool) & clean))

    @property
    def mostly_flagged(self) -> bool:
        return self.clean > 0 and self.clean_flagged > MOSTLY_FLAGGED * self.clean

    def warn(self, source: str, by: str = "") -> None:
        """Say when most of the log is flagged (``by``: the method, where there are several)."""
        if self.mostly_flagged:
            log.warning(
                "%s: %.0f %% of its judged samples are flagged%s: the calibration does not fit "
                "this log: check the effort's sign and scale, the robot model and the payload",
                source,
                100 * self.clean_flagged / self.clean,
                f" by {by}" if by else "",
            )


class ScoringStage:
    """Residual, score and flag per sample, events across blocks (state: one open event)."""

    def __init__(
        self,
        calibration: Calibration,
        joint_names: Sequence[str] | None = None,
        coulomb_eps: Sequence[float] | None = None,
        rules: EventRules | None = None,
    ):
        """``coulomb_eps``: the ε of the frames' ``coulomb_f`` (default: those the
        calibration's model needs, ``ResidualModel.features``); ``rules``: how flags become
        events (default: ``EventRules()``)."""
        threshold = calibration.require_threshold()
        self.threshold = threshold.value
        self.rules = EventRules() if rules is None else rules
        self.release = self.rules.release_level(threshold.value, threshold.mu)
        self.model = calibration.model
        self.score = calibration.score
        eps = self.model.features.coulomb_eps if coulomb_eps is None else coulomb_eps
        self.coulomb_eps = tuple(float(e) for e in eps)
        isolator = isolator_for(calibration.links, calibration.depths, self.model.joint_scale)
        self.events = EventTracker(joint_names or calibration.joint_names, isolator, self.rules)
        self.counts = FlagCount()
        # what the frames were prepared with, set by whoever builds the stages: (D, P) entries
        # of their (N, kept) regressor, the θ of their Ỹθ (the model's own, by construction)
        self.regressor_mask: BoolArray | None = None
        self.regressor_theta: FloatArray | None = None

    def push(self, frame: Frame) -> tuple[Frame, list[Event]]:
        """``frame`` plus ``predicted`` (the model's effort), ``residual``, ``score`` and ``flag``
        columns, and the events that closed in it. ``frame``: the scoring chain's (its
        ``residual`` in each band: ``twincd.prepare.chain.build_chain`` with a model), or a
        fit's filtered inputs (``effort_f``, ``sim_effort_f``, … of the model's features: the
        filter's band only)."""
        if "residual" in frame:
            r, predicted = frame["residual"], frame["predicted"]
        else:
            eps, mask, theta = self.coulomb_eps, self.regressor_mask, self.regressor_theta
            inputs = ModelInputs.of(frame, eps, mask, theta)
            predicted = self.model.predict(inputs)
            r = self.model.residual(inputs, predicted)
        # the events weigh joints as the score does: by their noise at their speed, if known,
        # near a segment's end by the noise its filtering leaves there, in the band that scored
        scores, evidence = self.score.weigh(
            *self.score.band_scores(
                self.model,
                r,
                frame.get("velocity"),
                frame.get("residual_fast"),
                frame.get("edge_factor"),
                frame.get("fast_off"),
            )
        )
        flags = scores >= self.threshold
        hold = scores >= self.release
        judged = np.ones(len(flags), dtype=bool)
        self.counts.add(flags, judged, frame.get("labels"))
        closed = self.events.push(flags, scores, evidence, frame["stamp_ns"], hold)
        columns = {"predicted": predicted, "residual": r, "score": scores, "flag": flags}
        return frame.with_columns(**columns), closed

    def finish(self) -> list[Event]:
        return self.events.finish()


# ------------------------------------------------------------------ a whole log in memory


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


def detect_log(
    log: PreparedLog, calibration: Calibration, rules: EventRules | None = None
) -> LogDetection:
    """Score and flag every sample of ``log`` with a calibration that has a threshold."""
    if log.residual is None and calibration.score.fast is not None:
        raise DataError(
            "this log was prepared for a fit (its inputs filtered), and the calibration judges "
            "a fast band too, which is scored from its model's residual",
            log.source,
            "prepare the log for the calibration's model: calibration.prepare(path)",
        )
    if log.model is not None and not _same_model(log.model, calibration, log.joint_names):
        raise DataError(
            "this log was prepared for another model than the calibration's (its residual is "
            "that model's)",
            log.source,
            "prepare the log for the calibration's model: calibration.prepare(path)",
        )
    stage = ScoringStage(calibration, log.joint_names, log.coulomb_eps, rules)
    stage.regressor_theta = log.features.theta
    scored = {  # prepared for the model: its residual in each band
        "residual": log.residual,
        "predicted": log.predicted,
        "residual_fast": log.residual_fast,
        "fast_off": log.fast_off,
        "velocity": log.states.velocity,
    }
    inputs = model_inputs(log).columns() if log.residual is None else scored
    frame = Frame(
        {
            **inputs,
            "stamp_ns": log.states.stamp_ns,
            "edge_factor": log.edge_factor,
            "labels": log.labels,
        }
    )
    out, events = stage.push(frame)
    events += stage.finish()
    stage.counts.warn(log.source)
    return LogDetection(log, out["residual"], out["score"], out["flag"], stage.threshold, events)


def _same_model(model: FittedModel, calibration: Calibration, names: Sequence[str]) -> bool:
    """Whether ``model`` is the calibration's: the same kind and coefficients."""
    if model is calibration.model:
        return True
    own = calibration.model
    return isinstance(model, ResidualModel) and model.to_dict(names) == own.to_dict(names)


# ------------------------------------------------------------------ a log streamed


@dataclass
class DetectionSummary:
    """What ``detect`` reports of one log: counts and events, never per-sample arrays."""

    source: str
    threshold: float
    samples: int = 0
    collision_samples: int = 0
    judged_samples: int = 0  # samples scored (every sample: its ends with their own noise)
    events: list[Event] = field(default_factory=list)
    joint_names: tuple[str, ...] = ()
    first_stamp_ns: int = 0
    warnings: list[str] = field(default_factory=list)  # the run's, when detect_file made it
    # what a report's figure draws (a sink of bounded envelopes), when a report was asked for
    trace: FrameSink | None = None
    clean_samples: int = 0  # judged samples not labelled as collisions
    clean_flagged: int = 0  # of those, the flagged ones
    period_s: float = 0.0  # the log's nominal sampling period
    labels: LabelSpans = field(default_factory=LabelSpans)  # labelled spans, when labelled
    # the log's stretches without a sample to judge: (last stamp before, first stamp after) of
    # each interval over DEFAULT_GAP_FACTOR periods, a gap in the recording or samples left
    # out (absurd, drives off, not finite), ns
    unjudged: list[tuple[int, int]] = field(default_factory=list)
    _last_ns: int | None = None  # the last sample's stamp so far

    @property
    def clean_s(self) -> float:
        """Judged collision-free time (s): what a false-alarm rate is per."""
        return self.clean_samples * self.period_s

    @property
    def false_alarms(self) -> int:
        """Events that touch no labelled push (± 200 ms; every event when the log has no
        labels): ``twincd.detection.events.false_alarms``."""
        return false_alarms(self.events, self.labels.finish())

    def to_dict(self) -> dict[str, object]:
        return {
            "path": self.source,
            "samples": self.samples,
            "collision_samples": self.collision_samples,
            "judged_samples": self.judged_samples,
            "too_short": self.too_short,
            "unjudged_spans": self.unjudged_spans_s(),
            "unjudged_s": round(self.unjudged_s, 6),
            "events": [e.to_dict() for e in self.events],
        }

    def unjudged_spans_s(self) -> list[list[float]]:
        """Each stretch without a sample to judge, [from, to] in seconds from the first
        sample."""
        first = self.first_stamp_ns
        return [
            [round((a - first) * 1e-9, 6), round((b - first) * 1e-9, 6)] for a, b in self.unjudged
        ]

    @property
    def unjudged_s(self) -> float:
        """The time without a sample to judge (s): the gaps' lengths."""
        return sum(b - a for a, b in self.unjudged) * 1e-9

    def coverage(self) -> str | None:
        """One clause on the time not judged ("10.0 s not judged: 1 gap, 12.30–22.30 s"), or
        None when every stretch of the log was judged."""
        if not self.unjudged:
            return None
        spans = self.unjudged_spans_s()
        shown = ", ".join(f"{a:.2f}–{b:.2f} s" for a, b in spans[:3])
        more = ", …" if len(spans) > 3 else ""
        return f"{self.unjudged_s:.3g} s not judged: {len(spans)} gap(s), {shown}{more}"

    @property
    def too_short(self) -> bool:
        """No sample could be judged (a log with samples always has some judged)."""
        return self.samples > 0 and self.judged_samples == 0

    def _note_gaps(self, stamps: IntArray) -> None:
        """The gaps between this block's samples and the last block's, once the period is
        known."""
        if self.period_s > 0:
            before = stamps[:-1] if self._last_ns is None else np.r_[self._last_ns, stamps[:-1]]
            after = stamps[1:] if self._last_ns is None else stamps
            wide = np.flatnonzero(after - before > DEFAULT_GAP_FACTOR * self.period_s * 1e9)
            self.unjudged += [(int(before[i]), int(after[i])) for i in wide]
        self._last_ns = int(stamps[-1])

    def add(self, frame: Frame, events: list[Event]) -> None:
        self.events.extend(events)
        if not frame.n:
            return
        if not self.samples:
            self.first_stamp_ns = int(frame["stamp_ns"][0])
        self._note_gaps(np.asarray(frame["stamp_ns"], dtype=np.int64))
        self.samples += frame.n
        self.collision_samples += int(frame["flag"].sum())
        self.judged_samples += frame.n
        labels = frame.get("labels")
        clean = np.ones(frame.n, bool) if labels is None else ~np.asarray(labels, dtype=bool)
        self.clean_samples += int(np.count_nonzero(clean))
        self.clean_flagged += int(np.count_nonzero(clean & np.asarray(frame["flag"], dtype=bool)))
        self.labels.push(frame["stamp_ns"], labels)
