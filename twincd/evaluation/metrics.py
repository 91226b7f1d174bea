"""The seed paper's evaluation metrics (section IV-C, contract: Metrics), on scikit-learn's metrics.

Per unit (sample or window) over all evaluated logs together: F1 at μ + iσ for the paper's
sweep of i, precision/recall/F1 at one threshold, and the ROC AUC of the raw score.
scikit-learn is imported by the whole-array functions only (≈ 90 MB and 0.6 s).

Two forms give the same numbers: functions of whole arrays of labels and scores, and
``ScoredUnits``, the scores split by label and sorted (8 bytes a unit, what ``evaluate`` keeps
of long logs), from which every count is a binary search. Event metrics likewise: ``event_counts``
on a whole log's arrays, or ``EventTally`` fed block by block while a log streams.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from twincd.detection.events import EVENT_TOLERANCE_NS, Event, false_alarms, runs
from twincd.types import BoolArray, FloatArray

# i = 0, 0.1, …, 1.0, then 2, 3, 4, 5 (rounded so that keys read 0.3, not 0.30000000000000004)
SWEEP_K: tuple[float, ...] = (*(round(0.1 * i, 1) for i in range(11)), 2.0, 3.0, 4.0, 5.0)


@dataclass(frozen=True)
class AtThreshold:
    threshold: float
    precision: float
    recall: float
    f1: float


def at_threshold(labels: BoolArray, scores: FloatArray, threshold: float) -> AtThreshold:
    """Precision, recall and F1 of the flags score ≥ threshold (eq. 7)."""
    from sklearn.metrics import precision_recall_fscore_support

    pred = np.asarray(scores) >= threshold
    p, r, f, _ = precision_recall_fscore_support(
        np.asarray(labels, dtype=bool), pred, average="binary", zero_division=0
    )
    return AtThreshold(float(threshold), float(p), float(r), float(f))


def f1_sweep(
    labels: BoolArray, scores: FloatArray, mu: float, sigma: float, ks: Sequence[float] = SWEEP_K
) -> list[tuple[float, float]]:
    """(i, F1 at μ + iσ) for every i of the sweep."""
    return [(float(k), at_threshold(labels, scores, mu + k * sigma).f1) for k in ks]


def best_of(sweep: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """(i, F1) of the best F1; ties go to the smallest i."""
    best = max(sweep, key=lambda kf: kf[1])
    return best


def auc(labels: BoolArray, scores: FloatArray) -> float | None:
    """ROC AUC of the raw score; None when only one class is present (it is undefined)."""
    from sklearn.metrics import roc_auc_score

    y = np.asarray(labels, dtype=bool)
    if y.all() or not y.any():
        return None
    return float(roc_auc_score(y, np.asarray(scores, dtype=np.float64)))


@dataclass(frozen=True)
class ScoredUnits:
    """The units' scores split by label, each part sorted: every per-unit metric of the arrays
    they came from, computed from counts (two binary searches a threshold), at 8 bytes a unit.

    ``at_threshold``, ``f1_sweep`` and ``auc`` give the numbers of the functions above on the
    whole arrays: the counts are exact, precision, recall and F1 are scikit-learn's formulas on
    them (the same floats), and the AUC is the Mann–Whitney statistic, P(positive > negative)
    + ½ P(tie), as a ratio of exact integers (``roc_auc_score``'s trapezoids agree to rounding,
    ~1e-16)."""

    positive: FloatArray  # scores of the units labelled as collision, ascending
    negative: FloatArray  # scores of the others, ascending

    @classmethod
    def from_parts(cls, parts: Iterable[tuple[BoolArray, FloatArray]]) -> ScoredUnits:
        """From (labels, scores) pairs, e.g. one per log: one copy of the scores (into the two
        parts, sorted in place), and one part's more while it is copied."""
        pairs = [(np.asarray(y, dtype=bool), np.asarray(s, dtype=np.float64)) for y, s in parts]
        if len(pairs) == 1:  # masks copy into arrays of their own (``np.compress`` takes twice)
            ((y, s),) = pairs
            positive, negative = s[y], s[~y]
        else:
            counts = [int(np.count_nonzero(y)) for y, _ in pairs]
            positive = np.empty(sum(counts))
            negative = np.empty(sum(len(y) for y, _ in pairs) - len(positive))
            p = n = 0
            for (y, s), k in zip(pairs, counts, strict=True):
                positive[p : p + k] = s[y]
                negative[n : n + len(y) - k] = s[~y]
                p, n = p + k, n + len(y) - k
        positive.sort()
        negative.sort()
        return cls(positive, negative)

    @classmethod
    def concat(cls, parts: Sequence[ScoredUnits]) -> ScoredUnits:
        """The units of every part together (one part: itself, nothing copied)."""
        if len(parts) == 1:
            return parts[0]
        positive = np.concatenate([np.zeros(0), *(p.positive for p in parts)])
        negative = np.concatenate([np.zeros(0), *(p.negative for p in parts)])
        positive.sort()
        negative.sort()
        return cls(positive, negative)

    @classmethod
    def from_arrays(cls, labels: BoolArray, scores: FloatArray) -> ScoredUnits:
        return cls.from_parts([(labels, scores)])

    @property
    def units(self) -> int:
        return len(self.positive) + len(self.negative)

    @property
    def positives(self) -> int:
        return len(self.positive)

    @property
    def finite(self) -> bool:
        """No score is NaN or infinite (sorted: the ends say; NaN sorts last)."""
        ends = [part[[0, -1]] for part in (self.positive, self.negative) if len(part)]
        return bool(np.isfinite(np.concatenate([np.zeros(0), *ends])).all())

    def flagged(self, threshold: float) -> tuple[int, int]:
        """(positives, negatives) with score ≥ ``threshold``."""
        tp = len(self.positive) - int(np.searchsorted(self.positive, threshold, side="left"))
        fp = len(self.negative) - int(np.searchsorted(self.negative, threshold, side="left"))
        return tp, fp

    def at_threshold(self, threshold: float) -> AtThreshold:
        """``at_threshold`` of the arrays: scikit-learn's precision, recall and F1
        (``zero_division=0``; F1 = 2·tp / (2·tp + fp + fn), as ``precision_recall_fscore_support``
        computes it) on the exact counts, so the same floats; written out because importing
        scikit-learn costs ≈ 90 MB, a third of what a long log's evaluation may take."""
        tp, fp = self.flagged(threshold)
        fn = len(self.positive) - tp
        precision = tp / (tp + fp) if tp + fp else 0.0
        recall = tp / (tp + fn) if tp + fn else 0.0
        f1 = 2 * tp / (2 * tp + fp + fn) if 2 * tp + fp + fn else 0.0
        return AtThreshold(float(threshold), float(precision), float(recall), float(f1))

    def f1_sweep(
        self, mu: float, sigma: float, ks: Sequence[float] = SWEEP_K
    ) -> list[tuple[float, float]]:
        """``f1_sweep`` of the arrays."""
        return [(float(k), self.at_threshold(mu + k * sigma).f1) for k in ks]

    def auc(self) -> float | None:
        """``auc`` of the arrays (None when only one class is present)."""
        if not len(self.positive) or not len(self.negative):
            return None
        below = np.searchsorted(self.negative, self.positive, side="left")
        at_most = np.searchsorted(self.negative, self.positive, side="right")
        twice_u = 2 * int(below.sum()) + int((at_most - below).sum())
        return twice_u / (2 * len(self.positive) * len(self.negative))

    def roc_points(self, most: int = 300) -> list[tuple[float, float]]:
        """(false positive rate, true positive rate) at about ``most`` thresholds, evenly
        spaced in rank among each class's scores, ends included; empty when AUC is undefined.
        Every point lies on the exact ROC curve (for figures)."""
        if not len(self.positive) or not len(self.negative):
            return []
        picks = []
        for part in (self.positive, self.negative):
            at = np.unique(np.linspace(0, len(part) - 1, max(2, most // 2)).round().astype(int))
            picks.append(part[at])
        thresholds = np.unique(np.concatenate(picks))
        n_pos, n_neg = len(self.positive), len(self.negative)
        tpr = (n_pos - np.searchsorted(self.positive, thresholds, side="left")) / n_pos
        fpr = (n_neg - np.searchsorted(self.negative, thresholds, side="left")) / n_neg
        points = {(0.0, 0.0), *zip(fpr.tolist(), tpr.tolist(), strict=True)}
        return sorted(points)


# ------------------------------------------------------------------ event metrics (contract:
# Metrics)


@dataclass(frozen=True)
class EventCounts:
    """Event-level counts of one or more logs, mergeable with ``+`` (contract: Metrics).

    A labelled event is a maximal run of labelled samples; it is detected when a flag falls
    inside it or within 200 ms after its end, its delay running from its first labelled sample
    to that first flag. A false alarm is an event as ``detect`` reports it (``EventRules``)
    touching no labelled event (± 200 ms); ``events_per_detected`` is the number of detect's
    events touching a labelled event over the labelled events detected (1.0: one push, one
    event). Events whose ground-truth link is named (``/collision_link``) are the presses that
    exert force; isolation is judged on those that were detected, by the link of the detect
    event holding the first flag: ``isolation_named`` is the share of them with a link named,
    ``isolation_accuracy`` the share of named links that are right.
    """

    events_total: int = 0
    events_detected: int = 0
    delays_ms: tuple[float, ...] = ()
    false_alarms: int = 0
    events_on_labels: int = 0  # detect events touching a labelled event (± 200 ms)
    unlabelled_s: float = 0.0
    force_total: int = 0
    force_detected: int = 0
    force_delays_ms: tuple[float, ...] = ()
    isolation_total: int = 0  # detected presses judged for isolation
    isolation_named: int = 0  # of those, with a link named
    isolation_right: int = 0  # of those named, the right one
    has_links: bool = False
    # labelled pushes that no judged sample falls in (the label's messages say them, in a hole
    # of the recording): counted apart, never among events_total
    events_not_judged: int = 0

    def __add__(self, other: EventCounts) -> EventCounts:
        return EventCounts(
            self.events_total + other.events_total,
            self.events_detected + other.events_detected,
            self.delays_ms + other.delays_ms,
            self.false_alarms + other.false_alarms,
            self.events_on_labels + other.events_on_labels,
            self.unlabelled_s + other.unlabelled_s,
            self.force_total + other.force_total,
            self.force_detected + other.force_detected,
            self.force_delays_ms + other.force_delays_ms,
            self.isolation_total + other.isolation_total,
            self.isolation_named + other.isolation_named,
            self.isolation_right + other.isolation_right,
            self.has_links or other.has_links,
            self.events_not_judged + other.events_not_judged,
        )

    @property
    def false_alarms_per_hour(self) -> float | None:
        if self.unlabelled_s <= 0:
            return None
        return self.false_alarms * 3600.0 / self.unlabelled_s

    def to_dict(self) -> dict[str, float | int | None]:
        def pct(values: tuple[float, ...], q: float) -> float | None:
            return float(np.percentile(values, q)) if values else None

        out: dict[str, float | int | None] = {
            "events_total": self.events_total,
            "events_detected": self.events_detected,
            "delay_ms_median": pct(self.delays_ms, 50),
            "delay_ms_p95": pct(self.delays_ms, 95),
            "false_alarms": self.false_alarms,
            "false_alarms_per_hour": self.false_alarms_per_hour,
            "events_per_detected": (
                self.events_on_labels / self.events_detected if self.events_detected else None
            ),
            "events_not_judged": self.events_not_judged,
        }
        if self.has_links:
            out.update(
                force_events_total=self.force_total,
                force_events_detected=self.force_detected,
                force_delay_ms_median=pct(self.force_delays_ms, 50),
                isolation_accuracy=(
                    self.isolation_right / self.isolation_named if self.isolation_named else None
                ),
                isolation_named=(
                    self.isolation_named / self.isolation_total if self.isolation_total else None
                ),
            )
        return out


def event_counts(
    stamp_ns: NDArray[np.int64],
    labels: BoolArray,
    flag_ns: NDArray[np.int64],
    flags: BoolArray,
    links: Sequence[str] | None = None,
    events: Sequence[Event] | None = None,
    isolation: bool = False,
    tolerance_ns: int = EVENT_TOLERANCE_NS,
) -> EventCounts:
    """Event counts of one log.

    ``stamp_ns``/``labels``: the samples and their labels; ``flag_ns``/``flags``: when each
    unit's decision is known (a sample's stamp, a window's last sample) and the flags;
    ``events``: the events ``detect`` reports for those flags (default: the maximal runs of
    flags). ``links``: the true link per sample ("" where none); an event's true link is the one
    named on most of its samples (a tie: the one named first); ``isolation``: judge the link the
    events name.
    """
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    labels = np.asarray(labels, dtype=bool)
    flag_ns = np.asarray(flag_ns, dtype=np.int64)
    flags = np.asarray(flags, dtype=bool)
    if events is None:
        events = [_run_event(flag_ns, a, b) for a, b in runs(flags)]
    flag_times = flag_ns[flags]
    labelled = []
    for a, b in runs(labels):
        lo = int(stamp_ns[a])
        k = int(np.searchsorted(flag_times, lo, side="left"))
        first_flag = int(flag_times[k]) if k < len(flag_times) else None
        named = Counter(x for x in links[a : b + 1] if x) if links is not None else Counter()
        labelled.append(_Labelled(lo, int(stamp_ns[b]), named, first_flag))
    period_s = float(np.median(np.diff(stamp_ns))) / 1e9 if len(stamp_ns) > 1 else 0.0
    unlabelled_s = int((~labels).sum()) * period_s
    return _counts(labelled, events, isolation, unlabelled_s, links is not None, tolerance_ns)


@dataclass
class _Labelled:
    """One labelled event of a log: its first and last labelled sample's stamps, the links named
    on its samples (counted in the order first named) and the first flag at or after its start."""

    start_ns: int
    last_ns: int
    links: Counter[str] = field(default_factory=Counter)
    first_flag_ns: int | None = None

    @property
    def true_link(self) -> str:
        return self.links.most_common(1)[0][0] if self.links else ""


def _counts(
    labelled: Sequence[_Labelled],
    events: Sequence[Event],
    isolation: bool,
    unlabelled_s: float,
    has_links: bool,
    tolerance_ns: int,
) -> EventCounts:
    """The counts of one log from its labelled events and detect's events."""
    windows = [(ev.start_ns, ev.last_ns + tolerance_ns) for ev in labelled]
    detected = force_total = force_detected = iso_total = iso_named = iso_right = 0
    delay_list: list[float] = []
    force_delays: list[float] = []
    for ev, (lo, hi) in zip(labelled, windows, strict=True):
        flag = ev.first_flag_ns
        true_link = ev.true_link
        if true_link:
            force_total += 1
        if flag is None or flag > hi:
            continue
        detected += 1
        delay = (flag - lo) / 1e6
        delay_list.append(delay)
        if true_link:
            force_detected += 1
            force_delays.append(delay)
            if isolation:
                link = _link_at(events, flag)
                iso_total += 1
                iso_named += link is not None
                iso_right += link == true_link
    # detect's events against the labelled events widened by the tolerance both ways
    alarms = false_alarms(events, [(ev.start_ns, ev.last_ns) for ev in labelled], tolerance_ns)
    return EventCounts(
        events_total=len(labelled),
        events_detected=detected,
        delays_ms=tuple(delay_list),
        false_alarms=alarms,
        events_on_labels=len(events) - alarms,
        unlabelled_s=unlabelled_s,
        force_total=force_total,
        force_detected=force_detected,
        force_delays_ms=tuple(force_delays),
        isolation_total=iso_total,
        isolation_named=iso_named,
        isolation_right=iso_right,
        has_links=has_links,
    )


class EventTally:
    """``event_counts`` of one log whose samples arrive block by block (units are samples, as
    for every calibration model): it keeps each labelled event (two stamps, its links, its
    first flag) and the distinct sampling intervals with their counts (for the median
    interval), never a per-sample array. ``finish`` takes detect's events of the whole log.

    ``links``: the link names the log's ``/collision_link`` messages hold (None: the log has
    none); ``push`` then takes each sample's index into them (−1: none yet)."""

    def __init__(
        self, links: Sequence[str] | None = None, tolerance_ns: int = EVENT_TOLERANCE_NS
    ) -> None:
        self.links = None if links is None else tuple(links)
        self.tolerance_ns = tolerance_ns
        self._named = np.array([bool(x) for x in self.links or ()], dtype=bool)
        self._labelled: list[_Labelled] = []
        self._waiting: list[_Labelled] = []  # no flag yet at or after their start
        self._open = False  # the last sample pushed was labelled
        self._unlabelled = 0
        self._intervals = _IntervalCounts()

    def push(
        self,
        stamp_ns: NDArray[np.int64],
        labels: BoolArray,
        flags: BoolArray,
        held: NDArray[np.intp] | None = None,
    ) -> None:
        """The next samples: stamps (increasing), labels, flags and (with ``links``) each
        sample's link index."""
        stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
        if not len(stamp_ns):
            return
        labels = np.asarray(labels, dtype=bool)
        flags = np.asarray(flags, dtype=bool)
        self._intervals.push(stamp_ns)
        self._unlabelled += len(labels) - int(np.count_nonzero(labels))
        for a, b in runs(labels):
            if a == 0 and self._open:  # the event of the previous block goes on
                ev = self._labelled[-1]
                ev.last_ns = int(stamp_ns[b])
            else:
                ev = _Labelled(int(stamp_ns[a]), int(stamp_ns[b]))
                self._labelled.append(ev)
                self._waiting.append(ev)
            if held is not None and self.links is not None:
                self._count_links(ev, np.asarray(held[a : b + 1]))
        self._open = bool(labels[-1])
        if self._waiting and flags.any():
            flag_ns = stamp_ns[flags]
            at = np.searchsorted(flag_ns, [ev.start_ns for ev in self._waiting], side="left")
            waiting = []
            for ev, k in zip(self._waiting, at.tolist(), strict=True):
                if k < len(flag_ns):
                    ev.first_flag_ns = int(flag_ns[k])
                else:
                    waiting.append(ev)
            self._waiting = waiting

    def _count_links(self, ev: _Labelled, held: NDArray[np.intp]) -> None:
        assert self.links is not None
        named = held[held >= 0]
        named = named[self._named[named]]
        values, first, counts = np.unique(named, return_index=True, return_counts=True)
        for i in np.argsort(first, kind="stable"):  # in the order first named
            ev.links[self.links[int(values[i])]] += int(counts[i])

    def finish(self, events: Sequence[Event], isolation: bool = False) -> EventCounts:
        """The log's counts, with detect's ``events`` (``isolation``: judge the links they
        name)."""
        unlabelled_s = self._unlabelled * self._intervals.median_s()
        has_links = self.links is not None
        return _counts(
            self._labelled, events, isolation, unlabelled_s, has_links, self.tolerance_ns
        )


class _IntervalCounts:
    """How often each interval between consecutive stamps occurs, for their exact median.
    Intervals within ``WINDOW_NS`` of the log's first one are counted in a dense histogram (a
    jittered clock spreads them over hundreds of thousands of distinct nanosecond values; only
    the pages it touches take memory), the others (gaps, clock jumps: few) by value."""

    WINDOW_NS = 1 << 19  # ±0.52 ms around the first interval

    def __init__(self) -> None:
        self._last: int | None = None
        self._low = 0  # the interval counted in the histogram's first bin
        self._dense: NDArray[np.int64] | None = None
        self._values = np.zeros(0, dtype=np.int64)  # the others, ascending, and their counts
        self._counts = np.zeros(0, dtype=np.int64)

    def push(self, stamp_ns: NDArray[np.int64]) -> None:
        steps = np.diff(stamp_ns, prepend=stamp_ns[:1] if self._last is None else self._last)
        if self._last is None:
            steps = steps[1:]
        self._last = int(stamp_ns[-1])
        if not len(steps):
            return
        if self._dense is None:
            self._low = int(steps[0]) - self.WINDOW_NS
            self._dense = np.zeros(2 * self.WINDOW_NS, dtype=np.int64)
        at = steps - self._low
        inside = (at >= 0) & (at < len(self._dense))
        np.add.at(self._dense, at[inside], 1)
        if not inside.all():
            values, counts = np.unique(steps[~inside], return_counts=True)
            merged, where = np.unique(np.concatenate([self._values, values]), return_inverse=True)
            weights = np.concatenate([self._counts, counts])
            self._counts = np.bincount(where, weights, len(merged)).astype(np.int64)
            self._values = merged

    def median_s(self) -> float:
        """``np.median`` of the intervals, in seconds (0 for fewer than two stamps)."""
        if self._dense is None:
            return 0.0
        bins = np.flatnonzero(self._dense)
        values = np.concatenate([self._values, bins + self._low])
        counts = np.concatenate([self._counts, self._dense[bins]])
        order = np.argsort(values, kind="stable")
        values, ends = values[order], np.cumsum(counts[order])
        total = int(ends[-1])

        def nth(k: int) -> int:  # the k-th smallest interval (from 0)
            return int(values[int(np.searchsorted(ends, k, side="right"))])

        half = total // 2
        middle = np.array([nth(half)] if total % 2 else [nth(half - 1), nth(half)], np.int64)
        return float(np.mean(middle)) / 1e9


def _run_event(flag_ns: NDArray[np.int64], first: int, last: int) -> Event:
    """A run of flags as an event with only its span."""
    start, end = int(flag_ns[first]), int(flag_ns[last])
    return Event(first, last, start, end, 0.0, start, "")


def _link_at(events: Sequence[Event], t_ns: int) -> str | None:
    """The link named by the event holding time ``t_ns``, if any."""
    for e in events:
        if e.start_ns <= t_ns <= e.end_ns:
            return e.link
    return None


def roc_points(labels: BoolArray, scores: FloatArray, most: int = 300) -> list[tuple[float, float]]:
    """(false positive rate, true positive rate) of the ROC curve, at most ``most`` points
    (evenly thinned, ends kept) so that results stay small; empty when AUC is undefined."""
    from sklearn.metrics import roc_curve

    y = np.asarray(labels, dtype=bool)
    if y.all() or not y.any():
        return []
    fpr, tpr, _ = roc_curve(y, np.asarray(scores, dtype=np.float64))
    if len(fpr) > most:
        keep = np.unique(np.linspace(0, len(fpr) - 1, most).round().astype(int))
        fpr, tpr = fpr[keep], tpr[keep]
    return [(float(f), float(t)) for f, t in zip(fpr, tpr, strict=True)]
