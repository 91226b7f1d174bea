"""What scores a log is the calibration's model, through every path: a calibration whose
coefficients change (θ zeroed, a or b changed, friction zeroed) scores differently in batch
(``detect_streamed``, ``detect_log``), streamed (``judge_log``), causal, live (``OnlineDetector``),
in ``evaluate`` (the calibration's own method) and in the detect report's trace — even when
the logs are read with a setup made from the original calibration."""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from support.streaming import detect_frames

from twincd.calibration import Calibration, Threshold
from twincd.calibration.models import ResidualModel
from twincd.calibration.score import Score
from twincd.commands import fit_calibration
from twincd.detection import OnlineDetector, detect_log, detect_streamed
from twincd.errors import DataError, UsageError
from twincd.prepare.setup import Setup
from twincd.signal.features import ModelInputs

SAMPLE_LOGS = Path(__file__).resolve().parents[1] / "sample_logs"
LOG = SAMPLE_LOGS / "test" / "test_000.mcap"


def _zero_theta(model: ResidualModel) -> None:
    model.theta_ = np.zeros_like(model.theta_)  # type: ignore[attr-defined]


def _scale_a(model: ResidualModel) -> None:
    model.a_ = model.a_ * 1.1


def _shift_b(model: ResidualModel) -> None:
    model.b_ = model.b_ + 0.5


def _zero_friction(model: ResidualModel) -> None:
    model.c_ = np.zeros_like(model.c_)  # type: ignore[attr-defined]
    model.d_ = np.zeros_like(model.d_)  # type: ignore[attr-defined]


CHANGES: dict[str, Callable[[ResidualModel], None]] = {
    "theta zeroed": _zero_theta,
    "a changed": _scale_a,
    "b changed": _shift_b,
    "friction zeroed": _zero_friction,
}


def changed(cal: Calibration, change: str) -> Calibration:
    """The calibration with its model's coefficients changed (the original left as it was)."""
    model = copy.deepcopy(cal.model)
    CHANGES[change](model)
    return replace(cal, model=model)


def batch_scores(cal: Calibration, setup: Setup) -> np.ndarray:
    return detect_frames(LOG, cal, setup)[1].column("score")


def with_changed(
    cal: Calibration, change: str
) -> tuple[tuple[Calibration, Calibration], Setup, list[np.ndarray]]:
    """(the changed calibration, ``cal``), the setup made from ``cal`` (both are read the
    original's way: allowed, and no θ in it) and their batch scores, which differ."""
    both, setup = (changed(cal, change), cal), Setup.from_calibration(cal)
    batch = [batch_scores(c, setup) for c in both]
    assert_differ(*batch)
    return both, setup, batch


def assert_differ(a: np.ndarray, b: np.ndarray) -> None:
    assert a.shape == b.shape
    assert not np.allclose(a, b, rtol=1e-6, atol=0.0)


@pytest.fixture(scope="module")
def shipped() -> Calibration:
    cal = Calibration.load(SAMPLE_LOGS / "calibration.json")
    assert cal.model.kind == "identified-whitened"
    return cal


@pytest.fixture(scope="module")
def causal() -> Calibration:
    """An identified causal calibration (what live detection runs), on three training logs."""
    train = sorted((SAMPLE_LOGS / "train").glob("*.mcap"))[:3]
    cal = fit_calibration(train, model="identified", causal=True).calibration
    return replace(cal, threshold=Threshold(4.0, 1.0, 1.0))


@pytest.mark.parametrize("change", list(CHANGES))
def test_batch_and_whole_log_score_the_calibration_s_own_model(
    shipped: Calibration, change: str
) -> None:
    both, setup, batch = with_changed(shipped, change)
    whole = [detect_log(c.prepare(LOG, setup), c).scores for c in both]
    assert_differ(*whole)
    np.testing.assert_allclose(whole[1], batch[1], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("change", list(CHANGES))
def test_streamed_evaluate_and_the_report_score_the_calibration_s_own_model(
    shipped: Calibration, change: str
) -> None:
    from twincd.commands.detect import detect_and_write
    from twincd.evaluation.methods import method_for
    from twincd.evaluation.runner import evaluate
    from twincd.evaluation.streamed import judge_log

    both, setup, _ = with_changed(shipped, change)
    judged = [judge_log(LOG, c, setup).units for c in both]
    assert_differ(np.sort(judged[0].negative), np.sort(judged[1].negative))
    rows = [evaluate([LOG], [method_for(c.model.kind)], setup, c).methods[0].roc for c in both]
    assert rows[0] != rows[1]
    traces = []
    for c in both:
        summary = detect_and_write((LOG, None), c, setup, trace=True)
        assert summary.trace is not None
        d = len(c.joint_names)  # channels: measured (d), the model's twin (d), score, label
        traces.append(np.asarray(summary.trace.line(d + 1)[1], dtype=float))
    assert_differ(*traces)


@pytest.mark.parametrize("change", list(CHANGES))
def test_causal_and_live_score_the_calibration_s_own_model(
    causal: Calibration, change: str
) -> None:
    both, setup, batch = with_changed(causal, change)
    states = setup.prepare(LOG).states
    live = []
    for c in both:
        detector = OnlineDetector(c)
        out = detector.push(states.stamp_ns, states.position, states.velocity, states.effort)
        detector.close()
        live.append(out.score)
    assert_differ(*live)
    np.testing.assert_allclose(live[0], batch[0], rtol=1e-9, atol=1e-12)


def test_a_setup_that_contradicts_the_calibration_is_refused(shipped: Calibration) -> None:
    for contradiction in (
        Setup(),  # no joints, no period: another way of reading the log
        replace(Setup.from_calibration(shipped), period_s=0.002),
        replace(Setup.from_calibration(shipped), lowpass=replace(shipped.lowpass, order=4)),
    ):
        with pytest.raises(UsageError, match="contradict"):
            detect_streamed(LOG, shipped, contradiction)


def test_samples_prepared_for_another_model_are_refused(shipped: Calibration) -> None:
    """Ỹθ filtered with another θ is never added to this model's prediction, nor another
    model's residual scored as this one's."""
    other = changed(shipped, "theta zeroed")
    setup = Setup.from_calibration(shipped)
    with pytest.raises(DataError, match="prepared for another model"):
        detect_log(shipped.prepare(LOG, setup), other)
    with pytest.raises(DataError, match="another θ"):  # prepared for a fit, with its θ
        detect_log(setup.prepare(LOG, shipped.model.features), replace(other, score=Score()))


def test_a_model_s_own_residual_is_what_every_path_scores(shipped: Calibration) -> None:
    """A kind may define its residual (``ResidualModel.residual``): the streamed chain scores
    that, as the whole-log path does — not its own measured-less-predicted."""

    class Shifted(type(shipped.model)):  # type: ignore[misc]
        def residual(self, inputs: ModelInputs, predicted: np.ndarray | None = None) -> np.ndarray:
            out: np.ndarray = super().residual(inputs, predicted) + 1.0
            return out

    model = copy.deepcopy(shipped.model)
    model.__class__ = Shifted
    other = replace(shipped, model=model)
    setup = Setup.from_calibration(shipped)
    batch = [batch_scores(c, setup) for c in (other, shipped)]
    assert_differ(*batch)
    whole = detect_log(other.prepare(LOG, setup), other).scores
    np.testing.assert_allclose(whole, batch[0], rtol=1e-9, atol=1e-12)
