"""twincd.evaluation.metrics against scikit-learn on small arrays (contract: Metrics)."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.metrics import f1_score, precision_score, recall_score, roc_auc_score, roc_curve

from twincd.detection.events import Event, EventRules, find_events, runs
from twincd.evaluation.metrics import (
    SWEEP_K,
    EventCounts,
    EventTally,
    ScoredUnits,
    at_threshold,
    auc,
    best_of,
    event_counts,
    f1_sweep,
)

Y = np.array([0, 0, 1, 1, 0, 1, 0, 1, 1, 0], dtype=bool)
S = np.array([0.1, 0.4, 0.35, 0.8, 0.2, 0.9, 0.7, 0.3, 0.95, 0.05])


def test_sweep_is_the_papers():
    assert SWEEP_K == (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 2.0, 3.0, 4.0, 5.0)


@pytest.mark.parametrize("threshold", [0.0, 0.3, 0.35, 0.5, 0.9, 2.0])
def test_at_threshold_matches_sklearn(threshold):
    pred = threshold <= S
    got = at_threshold(Y, S, threshold)
    assert got.f1 == pytest.approx(f1_score(Y, pred, zero_division=0))
    assert got.precision == pytest.approx(precision_score(Y, pred, zero_division=0))
    assert got.recall == pytest.approx(recall_score(Y, pred, zero_division=0))


def test_flag_is_score_at_or_above_threshold():
    # eq. 7: score ≥ thres is a collision
    assert at_threshold(np.array([True]), np.array([0.5]), 0.5).recall == 1.0


def test_sweep_and_best():
    mu, sigma = 0.3, 0.2
    sweep = f1_sweep(Y, S, mu, sigma)
    assert [k for k, _ in sweep] == list(SWEEP_K)
    for k, f in sweep:
        assert f == pytest.approx(f1_score(Y, mu + k * sigma <= S, zero_division=0))
    k, f = best_of(sweep)
    assert f == max(f for _, f in sweep)
    assert best_of([(0.0, 0.5), (0.1, 0.7), (0.2, 0.7)]) == (0.1, 0.7)  # ties: smallest i


def test_auc_matches_sklearn_and_is_none_for_one_class():
    assert auc(Y, S) == pytest.approx(roc_auc_score(Y, S))
    assert auc(np.zeros(4, dtype=bool), np.arange(4.0)) is None
    assert auc(np.ones(4, dtype=bool), np.arange(4.0)) is None


# ---------------------------------------------------------------- event metrics (contract: Metrics)

MS = 1_000_000


def _stamps(n: int) -> np.ndarray:
    return 5 * 10**18 + np.arange(n, dtype=np.int64) * 10 * MS  # 100 Hz


def test_events_found_delays_and_false_alarms_by_hand():
    n = 400
    stamps = _stamps(n)
    labels = np.zeros(n, dtype=bool)
    labels[100:150] = True  # event 1: found 30 ms after it starts
    labels[200:220] = True  # event 2: found 150 ms after its end (inside the 200 ms tolerance)
    labels[300:320] = True  # event 3: missed
    flags = np.zeros(n, dtype=bool)
    flags[103:140] = True
    flags[234:236] = True
    flags[50:52] = True  # a false alarm, far from any event
    flags[78:81] = True  # ends 200 ms before event 1: touches it, not a false alarm
    flags[370:372] = True  # a second false alarm, 500 ms after event 3
    counts = event_counts(stamps, labels, stamps, flags)
    assert (counts.events_total, counts.events_detected, counts.false_alarms) == (3, 2, 2)
    assert counts.delays_ms == (30.0, 340.0)
    assert counts.unlabelled_s == pytest.approx((n - 90) * 0.01)
    d = counts.to_dict()
    assert d["delay_ms_median"] == pytest.approx(185.0)
    assert d["false_alarms_per_hour"] == pytest.approx(2 * 3600 / 3.1)
    assert "isolation_accuracy" not in d  # no link labels given


_MERGE = EventRules(release=1.0, merge_ms=100.0)


def test_flag_at_window_end_times_and_isolation():
    n = 200
    stamps = _stamps(n)
    labels = np.zeros(n, dtype=bool)
    labels[20:60] = True
    labels[120:160] = True
    links = [""] * n
    links[20:60] = ["link4"] * 40
    # event 2 has no link: the switch went on, nothing was touched
    # a window method decides at each window's last sample (every 16 samples here)
    unit_stamps = stamps[15::16]
    unit_flags = np.zeros(len(unit_stamps), dtype=bool)
    unit_flags[[1, 2, 8]] = True  # windows ending at samples 31, 47 and 143
    # detect's events: the first holds the first flag and names link 4; the second names none
    first = Event(1, 2, int(unit_stamps[1]), int(unit_stamps[2]), 5.0, 0, "j", "link4")
    second = Event(8, 8, int(unit_stamps[8]), int(unit_stamps[8]), 5.0, 0, "j", None)
    events = [first, second]
    counts = event_counts(stamps, labels, unit_stamps, unit_flags, links, events, isolation=True)
    assert counts.events_detected == 2 and counts.delays_ms == (110.0, 230.0)
    assert (counts.force_total, counts.force_detected) == (1, 1)
    assert (counts.isolation_total, counts.isolation_named, counts.isolation_right) == (1, 1, 1)
    d = counts.to_dict()
    assert d["isolation_accuracy"] == 1.0 and d["force_events_detected"] == 1
    assert d["isolation_named"] == 1.0 and d["events_per_detected"] == 1.0
    # the same press with no link named: isolation says it does not know
    unsure = [replace(first, link=None, link_candidates=("link4", "link5")), second]
    d = event_counts(stamps, labels, unit_stamps, unit_flags, links, unsure, True).to_dict()
    assert d["isolation_named"] == 0.0 and d["isolation_accuracy"] is None


def test_false_alarms_are_counted_as_detect_events():
    n = 300
    stamps = _stamps(n)
    labels = np.zeros(n, dtype=bool)
    labels[200:220] = True
    flags = np.zeros(n, dtype=bool)
    flags[[20, 22, 24, 26]] = True  # one blip that flickers: four runs of flags
    flags[[203, 206, 209]] = True  # a push flagged three times
    runs_only = event_counts(stamps, labels, stamps, flags)
    assert runs_only.false_alarms == 4
    assert runs_only.to_dict()["events_per_detected"] == 3.0
    merged = find_events(flags, flags * 1.0, np.zeros((n, 1)), stamps, ["j"], None, _MERGE)
    counts = event_counts(stamps, labels, stamps, flags, None, merged)
    assert (counts.false_alarms, counts.events_on_labels, counts.events_detected) == (1, 1, 1)
    assert counts.to_dict()["events_per_detected"] == 1.0


def test_event_counts_add_up_over_logs():
    stamps = _stamps(100)
    labels = np.zeros(100, dtype=bool)
    labels[40:60] = True
    flags = labels.copy()
    flags[5] = True
    one = event_counts(stamps, labels, stamps, flags)
    two = one + EventCounts() + one
    assert (two.events_total, two.events_detected, two.false_alarms) == (2, 2, 2)
    assert two.unlabelled_s == pytest.approx(2 * one.unlabelled_s)
    assert two.false_alarms_per_hour == pytest.approx(one.false_alarms_per_hour)
    assert EventCounts().to_dict()["delay_ms_median"] is None
    assert EventCounts().false_alarms_per_hour is None


@settings(max_examples=50, deadline=None)
@given(
    labels=st.lists(st.booleans(), min_size=1, max_size=120),
    flags=st.lists(st.booleans(), min_size=120, max_size=120),
    extra=st.integers(0, 119),
)
def test_event_count_invariants(labels: list[bool], flags: list[bool], extra: int) -> None:
    n = len(labels)
    stamps = _stamps(n)
    lab = np.array(labels)
    flag = np.array(flags[:n])
    perfect = event_counts(stamps, lab, stamps, lab)
    assert perfect.events_detected == perfect.events_total
    assert perfect.false_alarms == 0 and all(d == 0.0 for d in perfect.delays_ms)
    none = event_counts(stamps, lab, stamps, np.zeros(n, dtype=bool))
    assert none.events_detected == 0 and none.false_alarms == 0
    counts = event_counts(stamps, lab, stamps, flag)
    assert 0 <= counts.events_detected <= counts.events_total
    assert counts.false_alarms + counts.events_on_labels == len(runs(flag))
    more = flag.copy()
    more[extra % n] = True  # one more flag never loses an event
    assert event_counts(stamps, lab, stamps, more).events_detected >= counts.events_detected


# ---------------------------------------------------------------- what evaluate keeps of long logs

finite = st.floats(-10, 10, allow_nan=False, allow_infinity=False)
tied = st.integers(-3, 3).map(float)  # few values: ties between and within the classes


@settings(max_examples=60, deadline=None)
@given(
    units=st.lists(st.tuples(st.booleans(), st.one_of(tied, finite)), min_size=1, max_size=80),
    cuts=st.lists(st.integers(0, 80), max_size=3),
    mu=finite,
    sigma=st.floats(0, 5),
)
def test_scored_units_give_the_whole_arrays_metrics(
    units: list[tuple[bool, float]], cuts: list[int], mu: float, sigma: float
) -> None:
    # evaluate keeps each log's judged scores and labels and computes the metrics from them
    # split by label and sorted: the numbers of the whole-array functions (scikit-learn's)
    y = np.array([u[0] for u in units])
    s = np.array([u[1] for u in units])
    bounds = sorted({0, len(y), *(min(c, len(y)) for c in cuts)})
    parts = [(y[a:b], s[a:b]) for a, b in itertools.pairwise(bounds)]
    kept = ScoredUnits.from_parts(parts)
    assert (kept.units, kept.positives) == (len(y), int(y.sum()))
    assert kept.f1_sweep(mu, sigma) == f1_sweep(y, s, mu, sigma)
    for threshold in (mu, *s[:4].tolist(), np.inf):
        assert kept.at_threshold(threshold) == at_threshold(y, s, threshold)
    got, want = kept.auc(), auc(y, s)
    assert (got is None) == (want is None)
    if got is not None and want is not None:
        assert got == pytest.approx(want, abs=1e-12, rel=0)
    points = kept.roc_points()
    if want is None:
        assert points == []
    else:  # every point on the ROC curve, from (0, 0) to (1, 1)
        assert points[0] == (0.0, 0.0) and points[-1] == (1.0, 1.0)
        fpr, tpr, _ = roc_curve(y, s, drop_intermediate=False)
        assert set(points) <= set(zip(fpr.tolist(), tpr.tolist(), strict=True))


@settings(max_examples=60, deadline=None)
@given(
    spans=st.lists(st.tuples(st.booleans(), st.integers(1, 25)), min_size=1, max_size=12),
    flags=st.lists(st.booleans(), min_size=300, max_size=300),
    steps=st.lists(
        st.sampled_from([10_000_000, 10_000_000, 9_999_000, 30_000_000]), min_size=300, max_size=300
    ),
    named=st.lists(st.integers(-1, 2), min_size=300, max_size=300),
    cuts=st.lists(st.integers(0, 300), max_size=4),
    isolation=st.booleans(),
)
def test_event_tally_in_blocks_equals_event_counts(
    spans: list[tuple[bool, int]],
    flags: list[bool],
    steps: list[int],
    named: list[int],
    cuts: list[int],
    isolation: bool,
) -> None:
    # a log's event counts gathered block by block while it streams, whatever the blocks: the
    # counts of its whole arrays
    labels = np.concatenate([np.full(k, on) for on, k in spans])
    n = len(labels)
    stamps = 1_700_000_000_000_000_000 + np.cumsum(np.array(steps[:n], dtype=np.int64))
    flag = np.array(flags[:n]) & (np.arange(n) % 7 != 0)
    links = ("", "link3", "link5")
    held = np.array(named[:n])
    per_sample = tuple("" if h < 0 else links[h] for h in held.tolist())
    merged = find_events(flag, flag * 1.0, np.zeros((n, 1)), stamps, ["j"], None, _MERGE)
    named_events = [replace(e, link=links[1 + e.first % 2]) for e in merged]
    want = event_counts(stamps, labels, stamps, flag, per_sample, named_events, isolation)
    tally = EventTally(links)
    bounds = sorted({0, n, *(min(c, n) for c in cuts)})
    for a, b in itertools.pairwise(bounds):
        tally.push(stamps[a:b], labels[a:b], flag[a:b], held[a:b])
    assert tally.finish(named_events, isolation) == want
    plain = EventTally()
    for a, b in itertools.pairwise(bounds):
        plain.push(stamps[a:b], labels[a:b], flag[a:b])
    assert plain.finish(merged) == event_counts(stamps, labels, stamps, flag, None, merged)
