"""Every model kind of the registry (``twincd.calibration.models.MODEL_KINDS``), zero-phase and
causal, goes the whole way a user takes it: fit, save, load (every coefficient its class learns
read back: a loader that drops one fails here), the same residuals, threshold, ``evaluate`` by its
method name (with the calibration and fitted anew), and for a causal calibration the live
detector in chunks = ``detect --causal``. A new kind is its module and one registry line; this
test then runs it too."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.streaming import blocks, detect_frames, pushed

from twincd.calibration import Calibration
from twincd.calibration.models import MODEL_CLASSES, MODEL_KINDS, model_class, model_inputs
from twincd.commands import evaluate_logs, fit_calibration, threshold_calibration
from twincd.evaluation.methods import METHOD_NAMES, available, method_for
from twincd.prepare.setup import Setup

SAMPLES = Path(__file__).resolve().parent.parent / "sample_logs"
TRAIN = sorted((SAMPLES / "train").glob("*.mcap"))[:3]
VAL = sorted((SAMPLES / "val").glob("*.mcap"))[:2]
TEST = SAMPLES / "test" / "test_000.mcap"


def test_the_registry_names_every_kind_once_everywhere() -> None:
    """Each class plain and whitened, the kinds earlier files hold among them; every kind but
    the paper's is an evaluate method; the --model help and the contract name every class."""
    earlier = ("affine", "friction", "identified")
    assert set(earlier) <= set(MODEL_CLASSES)
    assert {f"{s}-whitened" for s in earlier} < set(MODEL_KINDS)
    assert len(set(MODEL_KINDS)) == len(MODEL_KINDS)
    for kind in MODEL_KINDS:
        assert method_for(kind) in METHOD_NAMES and method_for(kind) in available()
        cls, whitened = model_class(kind)
        assert cls.name == kind.removesuffix("-whitened") and whitened == kind.endswith("whitened")
    from twincd_cli.calibrate import Model

    help_text = Model.__metadata__[0].help
    assert all(stem in help_text for stem in MODEL_CLASSES)
    contract = (SAMPLES.parent / "docs" / "contract.md").read_text()
    assert all(f"`{stem}`" in contract for stem in MODEL_CLASSES)
    assert all(f"`{name}`" in contract for name in METHOD_NAMES)


@pytest.mark.parametrize("causal", [False, True], ids=["zero-phase", "causal"])
@pytest.mark.parametrize("kind", MODEL_KINDS)
def test_every_model_kind_goes_the_whole_way(kind: str, causal: bool, tmp_path: Path) -> None:
    out = tmp_path / "cal.json"
    fitted = fit_calibration(TRAIN, model=kind, output=out, causal=causal).calibration
    assert fitted.model.kind == kind and fitted.lowpass.causal == causal

    # saved and loaded: every coefficient the class learns, to the bit
    loaded = Calibration.load(out)
    learned = type(fitted.model).learned
    assert set(loaded.model.coefficients()) == set(learned)
    for key in learned:
        want, got = getattr(fitted.model, f"{key}_"), getattr(loaded.model, f"{key}_")
        assert (want is None) == (got is None), key
        if want is not None:
            np.testing.assert_array_equal(got, want, err_msg=key)
    log = Setup.from_calibration(loaded).prepare(TEST, loaded.model.features)
    np.testing.assert_array_equal(
        loaded.model.residual(model_inputs(log)), fitted.model.residual(model_inputs(log))
    )

    # thresholded, then evaluated by its method name: with the calibration, and fitted anew
    cal = threshold_calibration(VAL, out, output=out).calibration
    assert cal.threshold is not None and np.isfinite(cal.threshold.value)
    name = method_for(kind)
    own = evaluate_logs([TEST], out).evaluation
    anew = evaluate_logs([TEST], methods=name, train=TRAIN, val=VAL, causal=causal).evaluation
    for evaluation in (own, anew):
        (row,) = evaluation.methods
        assert row.name == name and row.auc is not None and 0.5 < row.auc <= 1.0

    # batch = causal = live
    if causal:
        from twincd.detection.online import OnlineDetector
        from twincd.prepare.setup import read_log

        summary, frames = detect_frames(TEST, cal)
        states = read_log(TEST)
        for size in (7, 4096):
            det = OnlineDetector(cal)
            outs = [*pushed(det, states, blocks(len(states), size)), det.flush()]
            score = np.concatenate([o.score for o in outs])
            np.testing.assert_allclose(score, frames.column("score"), rtol=1e-9, atol=1e-12)
            events = [(e.start_ns, e.end_ns) for o in outs for e in o.events]
            assert events == [(e.start_ns, e.end_ns) for e in summary.events]
