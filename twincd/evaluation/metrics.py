"""The seed paper's evaluation metrics (section IV-C, contract: Metrics), on scikit-learn's metrics.

Per unit (sample or window) over all evaluated logs together: F1 at μ + iσ for the paper's
sweep of i, precision/recall/F1 at one threshold, and the ROC AUC of the raw score.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from sklearn.metrics import precision_recall_fscore_support, roc_auc_score

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
    y = np.asarray(labels, dtype=bool)
    if y.all() or not y.any():
        return None
    return float(roc_auc_score(y, np.asarray(scores, dtype=np.float64)))


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
    flags). ``links``: the true link per sample ("" where none); ``isolation``: judge the link
    the events name.
    """
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    labels = np.asarray(labels, dtype=bool)
    flag_ns = np.asarray(flag_ns, dtype=np.int64)
    flags = np.asarray(flags, dtype=bool)
    if events is None:
        events = [_run_event(flag_ns, a, b) for a, b in runs(flags)]
    flag_times = flag_ns[flags]
    labelled = runs(labels)
    windows = [(int(stamp_ns[a]), int(stamp_ns[b]) + tolerance_ns) for a, b in labelled]
    detected = force_total = force_detected = iso_total = iso_named = iso_right = 0
    delay_list: list[float] = []
    force_delays: list[float] = []
    for (a, b), (lo, hi) in zip(labelled, windows, strict=True):
        k = int(np.searchsorted(flag_times, lo, side="left"))
        hit = k < len(flag_times) and flag_times[k] <= hi
        true_link = ""
        if links is not None:
            named = [x for x in links[a : b + 1] if x]
            true_link = max(set(named), key=named.count) if named else ""
        if true_link:
            force_total += 1
        if not hit:
            continue
        detected += 1
        delay = (int(flag_times[k]) - lo) / 1e6
        delay_list.append(delay)
        if true_link:
            force_detected += 1
            force_delays.append(delay)
            if isolation:
                link = _link_at(events, int(flag_times[k]))
                iso_total += 1
                iso_named += link is not None
                iso_right += link == true_link
    # detect's events against the labelled events widened by the tolerance both ways
    spans = [(int(stamp_ns[a]), int(stamp_ns[b])) for a, b in labelled]
    alarms = false_alarms(events, spans, tolerance_ns)
    period_s = float(np.median(np.diff(stamp_ns))) / 1e9 if len(stamp_ns) > 1 else 0.0
    return EventCounts(
        events_total=len(labelled),
        events_detected=detected,
        delays_ms=tuple(delay_list),
        false_alarms=alarms,
        events_on_labels=len(events) - alarms,
        unlabelled_s=float((~labels).sum()) * period_s,
        force_total=force_total,
        force_detected=force_detected,
        force_delays_ms=tuple(force_delays),
        isolation_total=iso_total,
        isolation_named=iso_named,
        isolation_right=iso_right,
        has_links=links is not None,
    )


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
