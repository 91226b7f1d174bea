"""The fit's own logs scored by models fitted without them (cross-fitting): the noise each band
of the score has on motion the model did not see, and clean data for the threshold.

A model's residual on its own training samples is smaller than on any other: the noise scale of
a whitened model measured there is optimistic, and a threshold set on it raises alarms on fresh
logs. So ``fit`` makes a second pass over its logs (``crossfit_log``), each scored by a model
fitted without it — fold by fold (``Folds``): with several logs, the logs dealt into at most
``MAX_FOLDS`` groups in the order of their paths, each group scored by the model of all the
others; with one log, its time cut into blocks of ``FOLD_BLOCK_S`` dealt into as many groups
(so a single 20 min log is scored by five models each fitted on 16 of its minutes). From these
scores come (``cross_fitted``):

- each band's noise per joint and speed bin (the slow band's is the whitened model's
  ``scale_``, the fast band's ``twincd.calibration.score.FastBand``, its tail's where heavier:
  ``FAST_TAIL_QUANTILE``), over the samples a fit sums (``fit_rows``);
- each band's score statistics and excursions on every collision-free sample
  (``FitInfo.clean``), which ``threshold`` merges with its validation logs' for a false-alarm
  budget set on all the clean data a user has, and which still travel with the calibration
  when its fit logs do not.

A second pass costs a detect over the fit logs; it keeps at most ``KEPT_PER_SECOND`` samples a
second of what it scores (a grid's nodes at 1 kHz: the bands carry nothing faster), as float32,
so a 20 min 1 kHz log holds ≈ 10 MB of it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from twincd.calibration.affine import FIT_EDGE_FACTOR
from twincd.calibration.clean import BandStats, band_stats, near_labels
from twincd.calibration.models.constants import MIN_BIN_SAMPLES, MIN_SCALE
from twincd.calibration.models.statistics import speed_bin
from twincd.executors.run import Each
from twincd.signal.features import FittedModel, ModelFeatures, ModelInputs
from twincd.types import BoolArray, FloatArray, IntArray

if TYPE_CHECKING:
    from twincd.calibration.file import Calibration
    from twincd.calibration.fitting import LogFit
    from twincd.calibration.models import ResidualModel
    from twincd.calibration.score import Score
    from twincd.prepare.setup import Setup
    from twincd.signal.bands import Band

__all__ = [
    "FAST_TAIL_QUANTILE",
    "FOLD_BLOCK_S",
    "MAX_FOLDS",
    "CrossScored",
    "Folds",
    "TimeFolded",
    "VelocitySteps",
    "cross_fitted",
    "crossfit_log",
]

Float32Array = NDArray[np.float32]

MAX_FOLDS = 5
FOLD_BLOCK_S = 10.0
# the fast band's noise at a joint's speed is its residual's RMS there or, if heavier, its tail's:
# the 99.9th percentile of |r| over a normal's (3.29 σ). A joint whose clean fast residual bursts
# (at rest while the others move, at speed reversals) then holds the band's excursions no more
# than the others, and its share of the budget no longer blinds the band to the others' strikes
# (the tail the threshold fits begins about there: ``twincd.calibration.tail``). Chosen on the
# injection study of three real arms (docs: models and results, "Contacts of every length"). A bin
# of fewer than a thousand samples gets about its largest |r|: cautious where little is known.
FAST_TAIL_QUANTILE = 0.999
# samples a second the second pass keeps at most (a 1 kHz log: every tenth, a grid node's)
KEPT_PER_SECOND = 100.0
# a jump of the velocity: a one-period change above this many times the joint's 99th percentile
# of one-period changes in the fit's clean data (a robot that stops dead in one period)
JUMP_FACTOR = 3.0
JUMP_QUANTILE = 0.99
# |Δq̇| histogram: log10 bins from 1e-9 to 1e3 rad/s, 100 a decade (mergeable, 1.2 k ints a joint)
_STEP_LOW, _STEP_BINS, _STEP_PER_DECADE = -9.0, 1200, 100


@dataclass(frozen=True)
class VelocitySteps:
    """Mergeable: per joint the histogram of one-period velocity changes |Δq̇| (within a gap-free
    stretch) on a fit's samples, whose ``JUMP_QUANTILE`` sets the jump threshold."""

    counts: IntArray | None = None  # (D, bins)

    @classmethod
    def of(cls, velocity: FloatArray, stamp_ns: IntArray, period_s: float) -> VelocitySteps:
        v = np.asarray(velocity, dtype=np.float64)
        if len(v) < 2:
            return cls()
        steady = np.diff(stamp_ns) <= 5 * period_s * 1e9  # not across a gap
        step = np.abs(np.diff(v, axis=0))[steady]
        at = np.floor((np.log10(np.maximum(step, 1e-300)) - _STEP_LOW) * _STEP_PER_DECADE)
        at = np.clip(at, 0, _STEP_BINS - 1).astype(np.intp)
        counts = np.zeros((v.shape[1], _STEP_BINS), dtype=np.int64)
        for j in range(v.shape[1]):
            counts[j] = np.bincount(at[:, j], minlength=_STEP_BINS)
        return cls(counts)

    def __add__(self, other: VelocitySteps) -> VelocitySteps:
        if other.counts is None:
            return self
        if self.counts is None:
            return other
        return VelocitySteps(self.counts + other.counts)

    def jump(self) -> FloatArray | None:
        """(D,) the jump threshold: ``JUMP_FACTOR`` × each joint's ``JUMP_QUANTILE`` of |Δq̇|
        (None: nothing counted)."""
        if self.counts is None or not self.counts.sum():
            return None
        cumulative = np.cumsum(self.counts, axis=1)
        at = (cumulative >= JUMP_QUANTILE * cumulative[:, -1:]).argmax(axis=1)
        upper = 10.0 ** (_STEP_LOW + (at + 1) / _STEP_PER_DECADE)  # the bin's upper edge
        out: FloatArray = JUMP_FACTOR * upper
        return out


@dataclass(frozen=True)
class Folds:
    """Which model scores which fit data: ``groups`` the fold of each log (several logs), or
    (one log) its time blocks of ``FOLD_BLOCK_S`` from ``first_ns`` dealt into ``count``
    folds."""

    count: int
    groups: Mapping[str, int] = field(default_factory=dict)
    first_ns: int = 0

    @classmethod
    def of_logs(cls, sources: Sequence[str]) -> Folds:
        """Logs dealt into at most ``MAX_FOLDS`` folds in the order of their paths."""
        ordered = sorted(sources)
        count = min(len(ordered), MAX_FOLDS)
        return cls(count, {s: i % count for i, s in enumerate(ordered)})

    @property
    def by_time(self) -> bool:
        return not self.groups

    def time_fold(self, stamp_ns: IntArray) -> IntArray:
        """Each sample's fold by time (one log's folds)."""
        block = (np.asarray(stamp_ns, dtype=np.int64) - self.first_ns) // round(FOLD_BLOCK_S * 1e9)
        out: IntArray = block % max(self.count, 1)
        return out


def time_folds(stamp_ns: IntArray, first_ns: int) -> IntArray:
    """Each sample's fold among ``MAX_FOLDS`` by its time block (pass 1 of a one-log fit: the
    statistics of each fold, before the log's length, and so the folds it has, is known)."""
    return Folds(MAX_FOLDS, first_ns=first_ns).time_fold(stamp_ns)


class TimeFolded:
    """One log's fold models as one fitted model (``FittedModel``): each sample predicted by the
    model of its time block's fold (``Folds.time_fold``; the chain passes the stamps in
    ``ModelInputs.stamp_ns``), from the raw features every fold model reads (their ε, and the
    regressor's entries rather than one θ's Yθ)."""

    def __init__(self, models: Sequence[ResidualModel], folds: Folds) -> None:
        self.models = list(models)
        self.folds = folds

    @property
    def features(self) -> ModelFeatures:
        own = [m.features for m in self.models]
        eps = sorted({float(e) for f in own for e in f.coulomb_eps})
        return ModelFeatures(
            coulomb_eps=tuple(eps),
            regressor=any(f.regressor for f in own),
            speed_stats=False,
        )

    def predict(self, inputs: ModelInputs) -> FloatArray:
        if inputs.stamp_ns is None:
            raise ValueError("time-folded models predict from inputs with their stamps")
        fold = self.folds.time_fold(inputs.stamp_ns)
        out = np.zeros(np.shape(inputs.sim_effort_f))
        for k in np.unique(fold).tolist():
            rows = fold == k
            out[rows] = self.models[int(k)].predict(inputs.take(rows))
        return out

    def residual(self, inputs: ModelInputs, predicted: FloatArray | None = None) -> FloatArray:
        """Each sample's residual under its fold's model (``ResidualModel.residual``)."""
        twin = self.predict(inputs) if predicted is None else predicted
        return self.models[0].residual(inputs, twin)


@dataclass(frozen=True)
class CrossScored:
    """One fit log scored by a model fitted without it, at most ``KEPT_PER_SECOND`` samples a
    second: each band's residual and the joints' velocity (float32), where a fit sums
    (``fit``) and what is collision-free (``clean``: labels and their margin), the edge factors
    and where the fast band is not judged, their stamps and the period between them."""

    source: str
    residual: tuple[Float32Array, ...]
    velocity: Float32Array
    fit: BoolArray
    clean: BoolArray
    edge_factor: Float32Array
    fast_off: BoolArray | None
    stamp_ns: IntArray
    period_s: float


def crossfit_log(
    path: str | Path,
    setup: Setup,
    models: Sequence[ResidualModel],
    folds: Folds,
    jump: FloatArray | None,
) -> CrossScored:
    """Score one fit log by the model of its fold (``models[k]``: the one fitted without fold
    k; one log: each time block by its fold's, ``TimeFolded``) down the scoring chain, with the
    setup's bands and ``jump`` threshold: what ``cross_fitted`` turns into noise and clean
    statistics."""
    from twincd.prepare.notices import said_already

    source = str(path)
    model: FittedModel = (
        TimeFolded(models, folds) if folds.by_time else models[folds.groups[source]]
    )
    # each column kept as it will be stored (float32, bool) block by block: a 20 min 1 kHz log
    # keeps 120 000 rows, whose float64 blocks and their concatenation were 75 MB of peak memory
    kept: dict[str, list[np.ndarray]] = {}
    read = 0  # rows read so far: they decide which are kept, so any chunking keeps the same
    with said_already(), setup.open(path, model=model, jump=jump) as stream:
        for frame in stream:
            step = _step(stream.period_s)
            keep = (np.arange(frame.n) + read) % step == 0 if step > 1 else slice(None)
            read += frame.n
            for c in ("stamp_ns", "residual", "velocity", "edge_factor", "residual_fast"):
                if c in frame:
                    dtype = np.int64 if c == "stamp_ns" else np.float32
                    kept.setdefault(c, []).append(np.asarray(frame[c][keep], dtype=dtype))
            if "fast_off" in frame:
                off = np.asarray(frame["fast_off"][keep]).reshape(-1) > 0
                kept.setdefault("fast_off", []).append(off)
            if "labels" in frame:
                kept.setdefault("labels", []).append(np.asarray(frame["labels"][keep], bool))
        period = stream.period_s * _step(stream.period_s)
    # column by column, each column's blocks freed as it is joined: never two copies of all
    whole: dict[str, np.ndarray] = {c: np.concatenate(kept.pop(c)) for c in list(kept)}
    n = len(whole["stamp_ns"])
    residual = [whole[c] for c in ("residual", "residual_fast") if c in whole]
    factor = whole["edge_factor"].reshape(n, -1)
    labels = whole.get("labels")
    near = near_labels(labels, period)
    clean = np.ones(n, dtype=bool) if near is None else ~near
    fit = clean & (factor.max(axis=1) <= FIT_EDGE_FACTOR)
    return CrossScored(
        source=source,
        residual=tuple(residual),
        velocity=whole["velocity"],
        fit=fit,
        clean=clean,
        edge_factor=factor,
        fast_off=np.asarray(whole["fast_off"], bool) if "fast_off" in whole else None,
        stamp_ns=np.asarray(whole["stamp_ns"], np.int64),
        period_s=period,
    )


def _step(period_s: float) -> int:
    """Every how many samples the second pass keeps one (``KEPT_PER_SECOND``)."""
    return max(1, math.floor(1.0 / (KEPT_PER_SECOND * period_s) + 1e-9))


def band_noise(
    parts: Sequence[CrossScored],
    band: int,
    speed_bins: Sequence[float],
    tail: float | None = None,
) -> tuple[FloatArray, FloatArray]:
    """(D, bins) a band's noise scale per joint and speed bin over the samples a fit sums (a
    bin with fewer than ``MIN_BIN_SAMPLES`` takes the joint's overall scale), and (D,) that
    overall scale: the residual's RMS, or with ``tail`` (a quantile q) the larger of the RMS
    and the q-th quantile of |r| over a normal's (``FAST_TAIL_QUANTILE``)."""
    joints = parts[0].residual[band].shape[1]
    bins = len(speed_bins) + 1
    r = np.concatenate([p.residual[band][p.fit] for p in parts]).astype(np.float64)
    b = np.concatenate([speed_bin(p.velocity[p.fit].astype(np.float64), speed_bins) for p in parts])
    ss = np.zeros((joints, bins))
    n = np.zeros((joints, bins))
    for j in range(joints):
        ss[j] = np.bincount(b[:, j], weights=r[:, j] ** 2, minlength=bins)
        n[j] = np.bincount(b[:, j], minlength=bins)
    overall = np.sqrt(ss.sum(axis=1) / np.maximum(n.sum(axis=1), 1))
    scale = np.sqrt(ss / np.maximum(n, 1))
    if tail is not None and len(r):
        tails = _tail_scales(np.abs(r), b, bins, tail)
        overall = np.maximum(overall, tails[:, -1])
        scale = np.maximum(scale, tails[:, :-1])
    scale = np.where(n >= MIN_BIN_SAMPLES, scale, overall[:, None])
    return np.maximum(scale, MIN_SCALE), np.maximum(overall, MIN_SCALE)


def _tail_scales(size: FloatArray, bins_of: IntArray, bins: int, q: float) -> FloatArray:
    """(D, bins + 1) the q-th quantile of each joint's |r| (``size``, (N, D)) in each speed bin
    (``bins_of``; 0 where a bin has fewer than ``MIN_BIN_SAMPLES``) and, last, over all its
    samples, each over the q-th quantile of |x| for a standard normal x."""
    # the standard library's normal quantile (the same value as scipy.stats.norm.ppf to the last
    # bits): fit imports nothing else of scipy.stats, whose import alone took 0.5-1 s of a fit
    from statistics import NormalDist

    if not 0.0 < q < 1.0:
        raise ValueError(f"a tail quantile is within (0, 1), not {q:g}")
    normal = NormalDist().inv_cdf(0.5 + q / 2.0)
    out = np.zeros((size.shape[1], bins + 1))
    for j in range(size.shape[1]):
        out[j, -1] = np.quantile(size[:, j], q)
        for k in range(bins):
            in_bin = size[bins_of[:, j] == k, j]
            if len(in_bin) >= MIN_BIN_SAMPLES:
                out[j, k] = np.quantile(in_bin, q)
    return out / normal


def cross_fitted(
    calibration: Calibration,
    parts: Sequence[CrossScored],
    fast: Band | None,
    jump: FloatArray | None,
) -> Calibration:
    """The calibration with the noise its fit's logs show to models fitted without them (its
    whitened model's ``scale_`` per speed bin; with a ``fast`` band, that band's and the
    ``jump`` threshold: ``twincd.calibration.score.Score``), and each band's clean statistics
    of them (``FitInfo.clean``), scored as ``detect`` scores."""
    from twincd.calibration.score import FAST_FLOOR, FastBand, Score

    parts = sorted(parts, key=lambda p: p.source)
    model = calibration.model
    bins = model.speed_bins
    slow, overall = band_noise(parts, 0, bins)
    if model.whitened:
        model.scale_ = slow
    score = Score()
    if fast is not None and len(parts[0].residual) > 1:
        noise, _ = band_noise(parts, 1, bins, tail=FAST_TAIL_QUANTILE)
        score = Score(FastBand(fast, noise, FAST_FLOOR * overall), jump)
    calibration = replace(calibration, score=score)
    clean = [BandStats() for _ in range(score.bands)]
    for part in parts:
        scores = _scored(part, score, model)
        clean = [
            mine + band_stats(s, part.clean, part.period_s)
            for mine, s in zip(clean, scores, strict=True)
        ]
    return replace(calibration, fit=replace(calibration.fit, clean=tuple(clean)))


SCORED_ROWS = 1 << 14  # rows scored at once: the depth statistic's float64 temporaries


def _scored(part: CrossScored, score: Score, model: ResidualModel) -> list[FloatArray]:
    """Each band's score of one cross-scored log, ``SCORED_ROWS`` rows at a time (a score is
    a function of its row alone; the whole log at once was 45 MB of temporaries at 1 kHz)."""
    n = len(part.stamp_ns)
    out = [np.empty(n) for _ in range(score.bands)]
    for a in range(0, n, SCORED_ROWS):
        rows = slice(a, min(a + SCORED_ROWS, n))
        fast = None if len(part.residual) < 2 else part.residual[1][rows].astype(np.float64)
        scores, _ = score.band_scores(
            model,
            part.residual[0][rows].astype(np.float64),
            part.velocity[rows].astype(np.float64),
            fast,
            part.edge_factor[rows].astype(np.float64),
            None if part.fast_off is None else part.fast_off[rows],
        )
        for band, s in zip(out, scores, strict=True):
            band[rows] = s
    return out


def crossfit_calibration(
    calibration: Calibration, parts: Sequence[LogFit], setup: Setup, each: Each
) -> Calibration:
    """``fit``'s second pass: the calibration with its noise and clean scores from its fit's
    logs, each scored by a model fitted without it (``each`` maps ``crossfit_log`` over them),
    and the fast band the sampling rate has room for (``setup.fast_hz``: asked for)."""
    from twincd.calibration.fitting import crossfit_plan, fold_models
    from twincd.executors.local import Bound
    from twincd.prepare.setup import Setup as Reading
    from twincd.signal.bands import fast_band_at

    assert calibration.period_s is not None
    fast = fast_band_at(calibration.lowpass, setup.fast_hz, calibration.period_s)
    steps = sum((p.steps for p in parts), VelocitySteps())
    jump = None if fast is None else steps.jump()
    folds = crossfit_plan(parts)
    models = fold_models(calibration, parts, folds)
    fast_hz = None if fast is None else fast.high.cutoff_hz
    # the fit's own way of reading (its window, strictness), smaller blocks: this pass holds the
    # first pass's statistics and what it keeps beside a detect's stream
    scoring = replace(
        Reading.from_calibration(calibration),
        fast_hz=fast_hz,
        window=setup.window,
        strict=setup.strict,
        block_size=setup.block_size // 2,
    )
    work: Bound[Path, CrossScored] = Bound(crossfit_log, scoring, models, folds, jump)
    done = each(work, [Path(p.source) for p in parts], "cross-fitting")
    return cross_fitted(calibration, done, fast, jump)
