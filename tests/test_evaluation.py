"""twincd.evaluation: methods judged alike on train/val/test (contract: Exit codes and streams,
Metrics, Methods)."""

from __future__ import annotations

import pickle
from collections.abc import Sequence
from dataclasses import fields, replace

import numpy as np
import pytest
from support.calibrations import threshold_prepared_logs

from twincd.calibration import Threshold
from twincd.commands import fit_calibration
from twincd.detection import detect_log
from twincd.errors import DataError, UsageError
from twincd.evaluation.methods import MethodSkipped, ScoringMethod, parse_methods, register
from twincd.evaluation.metrics import EventCounts, at_threshold, auc, event_counts, f1_sweep
from twincd.evaluation.results import SCORE_KEYS
from twincd.evaluation.runner import evaluate
from twincd.evaluation.streamed import judge_log
from twincd.io.logs import expand_logs
from twincd.prepare.prepared import PreparedLog
from twincd.prepare.setup import Setup
from twincd.signal.filters import LowPass


class SeededNoise(ScoringMethod):
    """A randomised stand-in for a deep baseline: |residual| plus seed-dependent noise."""

    name = "test-seeded"

    def __init__(self, seed: int = 0) -> None:
        self.seed = seed

    def fit(self, train: Sequence[PreparedLog]) -> SeededNoise:
        self.fitted_ = len(train)
        return self

    def score(self, log: PreparedLog) -> np.ndarray:
        rng = np.random.default_rng(self.seed)
        base = np.abs(log.effort_f - log.sim_effort_f).sum(1)
        return base + rng.normal(0, 0.5, len(log))


class AlwaysSkipped(ScoringMethod):
    name = "test-skipped"
    learns = False

    def check(self, logs: Sequence[PreparedLog]) -> None:
        raise MethodSkipped("needs a robot model whose joints match")

    def fit(self, train: Sequence[PreparedLog]) -> AlwaysSkipped:
        return self

    def score(self, log: PreparedLog) -> np.ndarray:
        raise AssertionError("never called")


class Windowed(ScoringMethod):
    name = "test-window"
    unit = "window"
    learns = False

    def fit(self, train: Sequence[PreparedLog]) -> Windowed:
        return self

    def score(self, log: PreparedLog) -> np.ndarray:
        s = ((log.effort_f - log.sim_effort_f) ** 2).sum(1)
        return s[: len(s) // 16 * 16].reshape(-1, 16).max(1)

    def unit_labels(self, log: PreparedLog) -> np.ndarray:
        y = super().unit_labels(log)
        return y[: len(y) // 16 * 16].reshape(-1, 16).any(1)

    def unit_stamps(self, log: PreparedLog) -> np.ndarray:
        return log.states.stamp_ns[15 : len(log) // 16 * 16 : 16]  # each window's last sample


register("test-seeded", "test_evaluation:SeededNoise")
register("test-skipped", "test_evaluation:AlwaysSkipped")
register("test-window", "test_evaluation:Windowed")


@pytest.fixture(scope="module")
def split(twin_dataset):
    return {s: expand_logs([twin_dataset / s]) for s in ("train", "val", "test")}


@pytest.fixture(scope="module")
def calibration(split):
    setup = Setup(lowpass=LowPass(2.0))
    cal = fit_calibration(split["train"], model="affine", cutoff_hz=2.0).calibration
    return threshold_prepared_logs([setup.prepare(p) for p in split["val"]], cal, 4.0)


def test_proposed_from_the_calibration(calibration, split):
    result = evaluate(split["test"], ["proposed"], Setup.from_calibration(calibration), calibration)
    doc = result.to_dict()
    assert doc["samples"] == 2 * 1600 and 0 < doc["positives"] < doc["samples"]
    (row,) = doc["methods"]
    assert {"f1_best", "auc", "train_s"} <= set(SCORE_KEYS)
    for key in SCORE_KEYS:
        assert isinstance(row[key], float), key
    assert row["name"] == "proposed" and "unit" not in row
    assert row["auc"] > 0.9 and row["f1_best"] > 0.7
    assert row["threshold"] == pytest.approx(calibration.threshold.value)
    assert row["train_s"] == calibration.fit.seconds
    assert row["best_k"] in [s["k"] for s in row["sweep"]]


def test_refit_on_train_and_val_matches_the_calibration(calibration, split):
    setup = Setup.from_calibration(calibration)
    a = evaluate(split["test"], ["proposed"], setup, calibration).methods[0]
    b = evaluate(split["test"], ["proposed"], setup, None, split["train"], split["val"]).methods[0]
    assert b.auc == pytest.approx(a.auc) and b.f1_best == pytest.approx(a.f1_best)
    assert b.mu == pytest.approx(a.mu)


def test_skipped_window_and_repeats(calibration, split):
    setup = Setup.from_calibration(calibration)
    names = ["proposed", "test-skipped", "test-window", "test-seeded"]
    result = evaluate(
        split["test"], names, setup, calibration, split["train"], split["val"], repeats=3
    )
    rows = {r["name"]: r for r in result.to_dict()["methods"]}
    assert rows["test-skipped"] == {
        "name": "test-skipped",
        "skipped": "needs a robot model whose joints match",
    }
    assert rows["test-window"]["unit"] == "window" and rows["test-window"]["units"] == 200
    assert rows["test-window"]["train_s"] is None  # learns nothing, as in Table II
    seeded = rows["test-seeded"]
    assert seeded["repeats"] == 3
    assert seeded["f1_best_std"] > 0 and seeded["auc_std"] > 0
    assert "repeats" not in rows["proposed"]  # not randomised: runs once


def test_methods_needing_data_are_skipped(calibration, split):
    setup = Setup.from_calibration(calibration)
    result = evaluate(split["test"], ["proposed", "test-seeded"], setup, calibration)
    assert result.methods[1].skipped == "needs collision-free training logs"


def test_nothing_to_evaluate_is_an_error_not_a_pass(calibration, split):
    # a CI gate must not pass when no method ran
    setup = Setup.from_calibration(calibration)
    with pytest.raises(UsageError, match="no method could run") as raised:
        evaluate(split["test"], ["test-seeded"], setup, calibration)
    assert raised.value.option == "calibration,train,val"


def test_test_logs_need_labels(calibration, twin_log, tmp_path):
    path = twin_log(tmp_path / "nolabels.mcap", labels=False)
    with pytest.raises(DataError, match="no collision labels") as raised:
        evaluate([path], ["proposed"], Setup.from_calibration(calibration), calibration)
    assert raised.value.option == "label_topic"


def test_gates(calibration, split):
    result = evaluate(split["test"], ["proposed"], Setup.from_calibration(calibration), calibration)
    assert result.missed_gates(0.1, 0.1) == []
    missed = result.missed_gates(0.999, None)
    assert len(missed) == 1 and missed[0].startswith("proposed: F1")


def test_parse_methods():
    assert parse_methods("proposed") == ["proposed"]
    assert parse_methods(None) == ["proposed"]
    assert parse_methods("all")[0] == "proposed"
    with pytest.raises(UsageError, match="unknown method") as raised:
        parse_methods("proposed,nope")
    assert raised.value.option == "methods"


def test_test_logs_used_for_thresholds_are_flagged(calibration, split, caplog):
    setup = Setup.from_calibration(calibration)
    with caplog.at_level("WARNING", logger="twincd"):
        evaluate(split["test"], ["proposed"], setup, calibration, val_paths=split["test"][:1])
    assert "also used for fitting or thresholds" in caplog.text


def test_every_sample_is_judged_the_ends_too(calibration, split):
    # detect judges a log's ends (with the noise their filtering leaves): evaluate judges the same
    setup = Setup.from_calibration(calibration)
    result = evaluate(split["test"], ["proposed"], setup, calibration)
    logs = [setup.prepare(p) for p in split["test"]]
    assert all((lg.edge_factor[[0, -1], 0] > 1.5).all() for lg in logs)  # noisier ends
    (row,) = result.methods
    assert row.units == sum(len(lg) for lg in logs)


# ---------------------------------------------------------------- flat memory: what is kept


@pytest.mark.parametrize("k_sigma", [None, 2.0])
def test_metrics_equal_the_whole_arrays(calibration, split, k_sigma):
    # the calibration's own model streams each log and keeps scores and labels: its figures are
    # those of the whole logs' arrays, scored and grouped into events as detect does
    setup = Setup.from_calibration(calibration)
    (row,) = evaluate(split["test"], ["proposed"], setup, calibration, k_sigma=k_sigma).methods
    th = calibration.threshold
    mu, sigma = th.mean_sd
    at = calibration
    if k_sigma is not None:  # at μ + kσ of the clean scores' mean and sd
        at = replace(calibration, threshold=Threshold(k_sigma, mu, sigma))
    logs = sorted((calibration.prepare(p) for p in split["test"]), key=lambda lg: lg.source)
    found = [detect_log(lg, at) for lg in logs]
    y = np.concatenate([lg.labels for lg in logs])
    s = np.concatenate([d.scores for d in found])
    assert row.sweep == f1_sweep(y, s, mu, sigma)
    want = at_threshold(y, s, at.threshold.value)
    assert row.threshold == want.threshold
    assert (row.f1_at_threshold, row.precision_at_threshold, row.recall_at_threshold) == (
        want.f1,
        want.precision,
        want.recall,
    )
    assert row.auc == pytest.approx(auc(y, s), abs=1e-12, rel=0)
    assert (row.units, row.positives) == (len(y), int(y.sum()))
    events = EventCounts()
    for lg, d in zip(logs, found, strict=True):
        stamps = lg.states.stamp_ns
        events = events + event_counts(stamps, lg.labels, stamps, d.flags, None, d.events)
    assert row.events == {k: v for k, v in events.to_dict().items() if k in row.events}
    assert row.events["events_detected"] > 0


def test_a_judged_log_keeps_a_score_per_sample_filed_by_label(calibration, split):
    setup = Setup.from_calibration(calibration)
    path = split["test"][0]
    judged = judge_log(path, calibration, setup)
    # the only per-sample arrays: the judged samples' scores, those labelled and the others
    arrays = [v for v in vars(judged.units).values() if isinstance(v, np.ndarray)]
    assert not [f for f in fields(judged) if isinstance(getattr(judged, f.name), np.ndarray)]
    assert [a.dtype for a in arrays] == [np.float64, np.float64] and len(arrays) == 2
    whole = calibration.prepare(path)  # prepared for its model: scored as detect scores
    assert judged.samples == len(whole) and judged.positives == int(whole.labels.sum())
    assert judged.judged == len(whole)  # every sample, the ends too
    scores = detect_log(whole, calibration).scores
    y = whole.labels
    np.testing.assert_array_equal(judged.units.positive, np.sort(scores[y]))
    np.testing.assert_array_equal(judged.units.negative, np.sort(scores[~y]))
    # 8 bytes a judged sample, and nothing else that grows with the log (events are counted)
    assert sum(a.nbytes for a in arrays) == 8 * judged.judged
    assert len(pickle.dumps(judged)) < 8 * judged.judged + 4096
    # counts only (the false alarms of validation logs): no per-sample array at all
    counted = judge_log(path, calibration, setup, keep=False)
    assert counted.judged == 0 and counted.events == judged.events


def test_logs_are_judged_one_at_a_time(calibration, split):
    calls: list[tuple[str, str, int]] = []

    def run(func, paths, desc):
        calls.append((func.func.__name__, desc, len(paths)))
        return [func(p) for p in paths]

    setup = Setup.from_calibration(calibration)
    evaluate(split["test"], ["proposed"], setup, calibration, val_paths=split["val"], run=run)
    # the calibration's model: every log streamed, none prepared whole
    assert calls == [
        ("score_log", "val logs", 2),
        ("tally_false_alarms", "counting", 2),  # its rule's threshold, as `threshold` sets it
        ("judge_log", "test logs", 2),
        ("judge_log", "val false alarms", 2),
    ]
    calls.clear()
    names = ["test-seeded", "test-window"]
    evaluate(split["test"], names, setup, None, split["train"], split["val"], run=run, batch=1)
    # whole logs: training and validation logs held; test logs prepared one at a time
    assert calls == [
        ("prepare_log", "train logs", 3),
        ("prepare_log", "val logs", 2),
        ("prepare_log", "test logs", 1),
        ("prepare_log", "test logs", 1),
    ]
