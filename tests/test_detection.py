"""twincd.detection: score (eq. 5), threshold (μ + kσ), events, outputs, the `proposed` method."""

from __future__ import annotations

import csv
import itertools
import json

import numpy as np
import pytest
from conftest import DEFAULT_BUMPS, GAINS, T0_NS, TWIN_JOINTS
from hypothesis import given, settings
from hypothesis import strategies as st
from support.calibrations import threshold_prepared_logs
from support.streaming import write_detection

from twincd.calibration import Calibration, Threshold
from twincd.calibration.threshold import ScoreStats
from twincd.commands import detect_file, fit_calibration
from twincd.detection import affine_score, detect_log, find_events, residual, runs
from twincd.errors import DataError, NotFittedError, OutputError
from twincd.evaluation.methods import make_method
from twincd.evaluation.proposed import ProposedMethod
from twincd.io.logs import expand_logs
from twincd.prepare.setup import Setup, read_log
from twincd.signal.edges import edge_scaled
from twincd.signal.filters import LowPass


def test_score_by_hand():
    eff = np.array([[1.0, 2.0], [0.0, -1.0]])
    sim = np.array([[0.5, 1.0], [1.0, 1.0]])
    a, b = np.array([2.0, 1.0]), np.array([0.0, 0.5])
    # row 0: 1 - (1 + 0) = 0, 2 - (1 + .5) = .5 → .25; row 1: 0 - 2 = -2, -1 - 1.5 = -2.5 → 10.25
    np.testing.assert_allclose(residual(eff, sim, a, b), [[0.0, 0.5], [-2.0, -2.5]])
    np.testing.assert_allclose(affine_score(eff, sim, a, b), [0.25, 10.25])


def test_score_stats_merge_and_match_numpy():
    s = np.array([1.0, 2.0, 4.0, 7.0, 3.0])
    whole = ScoreStats.from_scores(s)
    merged = ScoreStats.from_scores(s[:2]) + ScoreStats.from_scores(s[2:])
    assert merged.mu == pytest.approx(s.mean()) == whole.mu
    assert merged.sigma == pytest.approx(s.std())
    th = merged.threshold(4.0, ["v"])
    assert th.value == pytest.approx(s.mean() + 4 * s.std())
    assert th.samples == 5 and th.logs == ("v",)
    masked = ScoreStats.from_scores(s, np.array([True, True, False, False, True]))
    assert masked.mu == pytest.approx(2.0)
    with pytest.raises(DataError):
        _ = ScoreStats().mu


def test_runs_and_events_from_a_flag_vector():
    flags = np.array([0, 1, 1, 0, 0, 1, 0, 1, 1, 1], dtype=bool)
    assert runs(flags) == [(1, 2), (5, 5), (7, 9)]
    assert runs(np.zeros(4, dtype=bool)) == []
    scores = np.arange(10, dtype=float)
    res = np.zeros((10, 2))
    res[1:3, 1] = 3.0
    res[5, 0] = 1.0
    res[7:10, 0] = 2.0
    res[7:10, 1] = 1.0
    stamps = np.arange(10, dtype=np.int64) * 10_000_000 + 5
    events = find_events(flags, scores, res, stamps, ["a", "b"])
    assert [(e.first, e.last) for e in events] == [(1, 2), (5, 5), (7, 9)]
    assert [e.joint for e in events] == ["b", "a", "a"]
    assert events[2].start_ns == 70_000_005 and events[2].end_ns == 90_000_005
    assert events[2].peak_score == 9.0 and events[2].samples == 3
    assert events[2].duration_s == pytest.approx(0.02)


@pytest.fixture(scope="module")
def calibrated(twin_dataset):
    setup = Setup(lowpass=LowPass(2.0))
    cal = fit_calibration([twin_dataset / "train"], model="affine", cutoff_hz=2.0).calibration
    val = [setup.prepare(p) for p in expand_logs([twin_dataset / "val"])]
    return threshold_prepared_logs(val, cal, 4.0)


def test_threshold_streams_val_logs(calibrated, twin_dataset):
    th = calibrated.threshold
    setup = Setup.from_calibration(calibrated)
    logs = [setup.prepare(p) for p in expand_logs([twin_dataset / "val"])]
    # every sample counts, each in the noise units of its distance from the log's ends
    assert th.k_sigma == 4.0 and th.samples == sum(len(lg) for lg in logs) and len(th.logs) == 2
    model = calibrated.model
    scores = np.concatenate(
        [
            np.sum(
                edge_scaled(
                    residual(lg.effort_f, lg.sim_effort_f, model.a_, model.b_), lg.edge_factor
                )
                ** 2,
                axis=1,
            )
            for lg in logs
        ]
    )
    ends = np.concatenate([lg.edge_factor[:, 0] > 1.01 for lg in logs])
    assert 0 < ends.sum() < 0.2 * len(ends)  # the ends' noisier estimates weigh less
    assert th.mu == pytest.approx(scores.mean())
    assert th.sigma == pytest.approx(scores.std())


def test_detect_finds_the_bumps_and_not_the_clean_log(calibrated, twin_dataset):
    setup = Setup.from_calibration(calibrated)
    hit = detect_log(setup.prepare(twin_dataset / "test" / "test_0.mcap"), calibrated)
    assert len(hit.events) == len(DEFAULT_BUMPS)
    for event, (start, duration, _) in zip(hit.events, DEFAULT_BUMPS, strict=True):
        t = (event.start_ns - int(hit.log.states.stamp_ns[0])) * 1e-9
        assert start - 0.3 < t < start + duration
    clean = detect_log(setup.prepare(twin_dataset / "val" / "val_0.mcap"), calibrated)
    assert clean.events == [] and not clean.flags.any()
    assert clean.to_dict()["collision_samples"] == 0


def test_detect_needs_a_threshold(calibrated, twin_dataset):
    from dataclasses import replace

    bare: Calibration = replace(calibrated, threshold=None)
    log = Setup.from_calibration(bare).prepare(twin_dataset / "val" / "val_0.mcap")
    with pytest.raises(NotFittedError):
        detect_log(log, bare)


def test_outputs_csv_jsonl_mcap(calibrated, twin_dataset, tmp_path):
    src = twin_dataset / "test" / "test_1.mcap"
    result = detect_log(Setup.from_calibration(calibrated).prepare(src), calibrated)
    write_detection(result, src, tmp_path / "out.csv")
    rows = list(csv.DictReader((tmp_path / "out.csv").open()))
    assert len(rows) == 1600
    assert list(rows[0]) == ["stamp_ns", "score", "collision"] + [
        f"residual_{j}" for j in TWIN_JOINTS
    ]
    assert float(rows[10]["score"]) == pytest.approx(result.scores[10])
    write_detection(result, src, tmp_path / "out.jsonl")
    lines = (tmp_path / "out.jsonl").read_text().splitlines()
    assert len(lines) == 1600 and json.loads(lines[3])["stamp_ns"] == result.log.states.stamp_ns[3]

    write_detection(result, src, tmp_path / "out.mcap")
    states = read_log(tmp_path / "out.mcap")
    assert len(states) == 1600
    from mcap.reader import make_reader

    with open(tmp_path / "out.mcap", "rb") as f:
        reader = make_reader(f)
        by_topic: dict[str, list[int]] = {}
        for _s, channel, message in reader.iter_messages():
            by_topic.setdefault(channel.topic, []).append(message.log_time)
    js = by_topic["/joint_states"]
    for topic in ("/twincd/residual", "/twincd/score", "/twincd/collision"):
        assert by_topic[topic] == js, topic
    from twincd.io.options import LogOptions

    residual_log = read_log(tmp_path / "out.mcap", LogOptions(topic="/twincd/residual"))
    np.testing.assert_array_equal(residual_log.stamp_ns, result.log.states.stamp_ns)
    np.testing.assert_allclose(residual_log.effort, result.residual)
    assert residual_log.joint_names == TWIN_JOINTS
    with pytest.raises(OutputError):
        write_detection(result, src, tmp_path / "out.txt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv", "out.jsonl", "out.mcap"]


def test_proposed_method_is_registered_and_fits(twin_dataset):
    setup = Setup(lowpass=LowPass(2.0))
    train = [setup.prepare(p) for p in expand_logs([twin_dataset / "train"])]
    method = make_method("proposed")
    assert isinstance(method, ProposedMethod) and method.unit == "sample"
    with pytest.raises(NotFittedError):
        method.score(train[0])
    method.fit(train)
    np.testing.assert_allclose(method.a_, GAINS, rtol=0.02)
    assert method.score(train[0]).shape == (1600,)
    fixed = ProposedMethod(a=[1, 1, 1], b=[0, 0, 0])
    # the squared residual, in the noise units of each sample's distance from the log's ends
    lg = train[0]
    judged = edge_scaled(lg.effort_f - lg.sim_effort_f, lg.edge_factor)
    np.testing.assert_allclose(fixed.score(lg), (judged**2).sum(1))
    middle = lg.edge_factor[:, 0] == 1.0
    assert middle.sum() > 1000
    np.testing.assert_allclose(
        fixed.score(lg)[middle], ((lg.effort_f - lg.sim_effort_f)[middle] ** 2).sum(1)
    )


def test_threshold_dataclass_value():
    assert Threshold(3.0, 1.0, 0.5).value == 2.5


@given(
    flags=st.lists(st.booleans(), min_size=1, max_size=80),
    cuts=st.lists(st.integers(0, 80), max_size=10),
    seed=st.integers(0, 2**16),
)
@settings(max_examples=300, deadline=None)
def test_events_are_the_same_in_any_chunking(flags: list[bool], cuts: list[int], seed: int) -> None:
    from twincd.detection import EventTracker

    rng = np.random.default_rng(seed)
    f = np.array(flags)
    n = len(f)
    scores = rng.random(n)
    resid = rng.normal(size=(n, 3))
    stamps = np.cumsum(rng.integers(1, 5, n)).astype(np.int64)
    whole = find_events(f, scores, resid, stamps, ["a", "b", "c"])
    tracker = EventTracker(["a", "b", "c"])
    edges = [0, *sorted({c for c in cuts if 0 < c < n}), n]
    chunked = []
    for a, b in itertools.pairwise(edges):
        chunked += tracker.push(f[a:b], scores[a:b], resid[a:b], stamps[a:b])
    chunked += tracker.finish()
    assert chunked == whole
    assert [(e.first, e.last) for e in whole] == runs(f)


def test_a_bump_at_a_logs_end_is_found_as_in_the_middle(tmp_path, twin_dataset):
    """A log's ends are judged (with the noise their filtering leaves there): a bump 0.2 s
    before the end is found, as the same bump in the middle; the clean end of the same log
    raises nothing (clean ends at 50 Hz–1 kHz: tests/test_edges.py)."""
    from conftest import build_twin_log

    from twincd.commands import threshold_calibration

    cal = fit_calibration([twin_dataset / "train"], model="affine", cutoff_hz=1.0).calibration
    cal = threshold_calibration([twin_dataset / "val"], cal).calibration
    at_end = build_twin_log(tmp_path / "end.mcap", seed=7, bumps=[(15.8, 0.2, 8.0)], labels=False)
    middle = build_twin_log(tmp_path / "mid.mcap", seed=7, bumps=[(8.0, 0.2, 8.0)], labels=False)
    (found,) = detect_file(middle, cal).events
    assert found.start_ns - T0_NS < 8.4e9 and found.end_ns - T0_NS > 8.0e9
    (found,) = detect_file(at_end, cal).events
    assert found.end_ns - T0_NS > 15.8e9


def test_the_detect_module_is_not_shadowed_by_a_function():
    """``twincd.detection.detect`` is the module whatever was imported before; the function
    that scores a prepared log is ``detect_log``, and ``twincd.detect`` stays that function."""
    import importlib

    import twincd
    import twincd.detection

    module = importlib.import_module("twincd.detection.detect")
    assert twincd.detection.detect is module
    assert twincd.detect is twincd.detection.detect_log is module.detect_log
