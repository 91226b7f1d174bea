"""Events as a person counts them (twincd/detection/events.py): hysteresis and merging in time,
the same in any block split, in batch, causal-file and live detection."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from twincd.detection.events import RUNS, Event, EventRules, EventTracker, find_events, runs

NAMES = ("a", "b")


def _events(scores, stamps, rules, threshold=1.0, mu=0.0):
    scores = np.asarray(scores, dtype=np.float64)
    resid = np.column_stack([scores, scores / 2])
    flags = scores >= threshold
    hold = scores >= rules.release_level(threshold, mu)
    return find_events(flags, scores, resid, np.asarray(stamps), NAMES, None, rules, hold)


def _push(level: float, start: int, n: int, length: int) -> np.ndarray:
    s = np.zeros(length)
    s[start : start + n] = level
    return s


def test_a_push_with_a_dip_and_a_ringing_lobe_is_one_event():
    stamps = np.arange(200, dtype=np.int64) * 10_000_000  # 100 Hz
    score = _push(3.0, 50, 20, 200)
    score[58:61] = 0.7  # dips below the threshold mid-push, not below the release level
    score[80:84] = 1.5  # the filter's ringing, 100 ms after the push
    rules = EventRules(release=0.5, merge_ms=200.0)
    (event,) = _events(score, stamps, rules)
    assert (event.first, event.last) == (50, 83)
    assert event.start_ns == stamps[50] and event.peak_score == 3.0
    # as maximal runs of flags, the same score is three events
    assert len(_events(score, stamps, RUNS)) == 3


def test_two_pushes_further_apart_than_the_merge_gap_are_two_events():
    stamps = np.arange(400, dtype=np.int64) * 10_000_000
    score = _push(3.0, 50, 20, 400) + _push(3.0, 100, 20, 400)  # 310 ms apart
    assert len(_events(score, stamps, EventRules(0.5, merge_ms=300.0))) == 2
    assert len(_events(score, stamps, EventRules(0.5, merge_ms=320.0))) == 1


def test_rules_are_in_time_so_1_khz_and_100_hz_agree():
    slow = np.arange(300, dtype=np.int64) * 10_000_000
    fast = np.arange(3000, dtype=np.int64) * 1_000_000
    rules = EventRules(0.5, merge_ms=200.0)
    s100 = _push(3.0, 50, 20, 300) + _push(3.0, 85, 10, 300)  # 150 ms gap
    s1k = np.repeat(s100, 10)
    assert len(_events(s100, slow, rules)) == len(_events(s1k, fast, rules)) == 1


def test_a_held_run_that_never_reaches_the_threshold_is_no_event():
    stamps = np.arange(50, dtype=np.int64)
    score = _push(0.8, 10, 10, 50)
    assert _events(score, stamps, EventRules(0.5, 0.0)) == []


def test_release_level_and_bounds():
    assert EventRules(0.5, 0.0).release_level(5.0, 1.0) == 3.0
    assert RUNS.release_level(5.0, 1.0) == 5.0
    with pytest.raises(ValueError):
        EventRules(release=1.5)


@given(
    levels=st.lists(st.sampled_from([0.0, 0.3, 0.6, 1.0, 2.0]), min_size=1, max_size=120),
    cuts=st.lists(st.integers(0, 120), max_size=10),
    release=st.sampled_from([1.0, 0.5, 0.25]),
    merge=st.sampled_from([0.0, 2.0, 5.0]),
    seed=st.integers(0, 2**16),
)
@settings(max_examples=300, deadline=None)
def test_events_are_the_same_in_any_block_split(levels, cuts, release, merge, seed):
    rng = np.random.default_rng(seed)
    n = len(levels)
    scores = np.array(levels) + rng.random(n) * 0.01
    resid = rng.normal(size=(n, 2))
    stamps = np.cumsum(rng.integers(1, 3, n)).astype(np.int64) * 1_000_000  # 1-2 ms apart
    rules = EventRules(release, merge)
    flags = scores >= 1.0
    hold = scores >= rules.release_level(1.0, 0.0)
    whole = find_events(flags, scores, resid, stamps, NAMES, None, rules, hold)
    tracker = EventTracker(NAMES, None, rules)
    edges = [0, *sorted({c for c in cuts if 0 < c < n}), n]
    chunked = []
    for a, b in itertools.pairwise(edges):
        chunked += tracker.push(flags[a:b], scores[a:b], resid[a:b], stamps[a:b], hold[a:b])
    chunked += tracker.finish()
    assert chunked == whole
    # every event opens at a flag and every flag is inside an event
    assert all(flags[e.first] for e in whole)
    inside = np.zeros(n, dtype=bool)
    for e in whole:
        inside[e.first : e.last + 1] = True
    assert not (flags & ~inside).any()
    if rules == RUNS:
        assert [(e.first, e.last) for e in whole] == runs(flags)


def test_an_unsure_link_is_null_with_its_candidates_in_json_and_text():
    from twincd.detection.events import Event

    unsure = Event(0, 4, 0, 40, 3.0, 20, "joint3", None, ("link3", "link4"))
    d = unsure.to_dict()
    assert d["link"] is None and d["link_candidates"] == ["link3", "link4"]
    assert unsure.link_text == "link3 or link4?"
    sure = Event(0, 4, 0, 40, 3.0, 20, "joint3", "link3", ("link3",))
    assert sure.link_text == "link3" and sure.to_dict()["link_candidates"] == ["link3"]


@settings(max_examples=60, deadline=None)
@given(
    labels=st.lists(st.booleans(), min_size=1, max_size=60),
    cuts=st.lists(st.integers(1, 59), max_size=6),
)
def test_labelled_spans_in_any_blocks_are_the_runs_of_the_whole(
    labels: list[bool], cuts: list[int]
) -> None:
    from twincd.detection.events import LabelSpans

    lab = np.asarray(labels)
    stamps = np.arange(len(lab), dtype=np.int64) * 10_000_000 + 5
    spans = LabelSpans()
    bounds = [0, *sorted({c for c in cuts if c < len(lab)}), len(lab)]
    for a, b in itertools.pairwise(bounds):
        spans.push(stamps[a:b], lab[a:b])
    assert spans.finish() == [(int(stamps[a]), int(stamps[b])) for a, b in runs(lab)]


def test_a_false_alarm_is_an_event_touching_no_labelled_span_within_200_ms() -> None:
    from twincd.detection.events import false_alarms

    def event(start_ms: int, end_ms: int) -> Event:
        return Event(0, 1, start_ms * 10**6, end_ms * 10**6, 9.0, start_ms * 10**6, "j1")

    spans = [(1000 * 10**6, 2000 * 10**6)]
    assert false_alarms([event(2150, 2300)], spans) == 0  # starts 150 ms after the push
    assert false_alarms([event(2250, 2300)], spans) == 1  # 250 ms after: a false alarm
    assert false_alarms([event(700, 810)], spans) == 0  # ends 190 ms before it
    assert false_alarms([event(700, 790)], spans) == 1
    assert false_alarms([event(700, 790), event(5000, 5100)], []) == 2  # no labels: every one
