"""Settings by name (``twincd.SetupOptions``) resolved to a ``Setup``: defaults without a
calibration, a calibration's recorded settings with one, and a contradiction refused."""

from __future__ import annotations

import numpy as np
import pytest

from twincd import Calibration, SetupOptions
from twincd.calibration.models import fit_features
from twincd.defaults import (
    DEFAULT_CAUSAL_CUTOFF_HZ,
    DEFAULT_CRITICAL_CUTOFF_HZ,
    DEFAULT_CUTOFF_HZ,
)
from twincd.errors import UsageError
from twincd.io.options import LogOptions
from twincd.settings import fit_setup
from twincd.signal.filters import LowPass


def _calibration(**kwargs: object) -> Calibration:
    from twincd.calibration.models import make_model

    model = make_model("affine").with_coefficients({"a": np.ones(2), "b": np.zeros(2)})
    return Calibration(
        ("j1", "j2"),
        model,
        LowPass(cutoff_hz=2.0, order=3, causal=True),
        options=LogOptions(topic="/arm/joint_states", joint_map={"a": "j1"}),
        source="cal.json",
        **kwargs,  # type: ignore[arg-type]
    )


def test_without_a_calibration_the_defaults_fill_in() -> None:
    setup = SetupOptions(topic="/js", strict=True).resolve()
    assert setup.options.topic == "/js" and setup.strict
    assert setup.lowpass == LowPass(cutoff_hz=DEFAULT_CUTOFF_HZ, kind="butterworth")
    causal = SetupOptions(causal=True).resolve().lowpass
    assert causal.causal and causal.cutoff_hz == DEFAULT_CAUSAL_CUTOFF_HZ


def test_a_calibration_s_settings_are_the_defaults() -> None:
    cal = _calibration()
    setup = SetupOptions(robot="panda", allow_urdf_change=True).resolve(cal)
    assert setup.lowpass == cal.lowpass and setup.options == cal.options
    assert setup.joint_names == ("j1", "j2") and setup.allow_urdf_change
    assert setup.robot == "panda"  # the calibration recorded none
    agreeing = SetupOptions(topic="/arm/joint_states", causal=True, cutoff_hz=2.0)
    assert agreeing.resolve(cal).lowpass == cal.lowpass


@pytest.mark.parametrize(
    ("given", "option", "words"),
    [
        ({"topic": "/other"}, "topic", "topic /other contradicts the calibration's /arm/joint"),
        ({"joint_map": {"b": "j2"}}, "joint_map", "joint map b=j2 contradicts"),
        ({"causal": False}, "causal", "zero-phase filter contradicts the calibration's causal"),
        ({"cutoff_hz": 1.0}, "cutoff_hz", "cut-off (Hz) 1 contradicts the calibration's 2"),
        ({"filter_order": 2}, "filter_order", "filter order 2 contradicts"),
        ({"filter_kind": "critical"}, "filter_kind", "filter kind critical contradicts"),
    ],
)
def test_a_setting_against_the_calibration_is_refused(
    given: dict[str, object], option: str, words: str
) -> None:
    with pytest.raises(UsageError) as caught:
        SetupOptions(**given).resolve(_calibration())  # type: ignore[arg-type]
    assert caught.value.option == option and words in caught.value.message
    assert "(cal.json)" in caught.value.message


def test_a_robot_against_the_calibration_s_is_refused() -> None:
    with pytest.raises(UsageError, match="robot panda contradicts the calibration's xarm7"):
        SetupOptions(robot="panda").resolve(_calibration(robot="xarm7"))


def test_fit_without_a_model_prepares_for_the_best_one() -> None:
    setup, model = fit_setup(SetupOptions(), None)
    assert model is None  # chosen from the logs by merge_fits
    features = fit_features(model)
    assert features.regressor and features.regressor_optional and features.coulomb_eps
    assert setup.lowpass.kind == "critical"
    assert setup.lowpass.cutoff_hz == DEFAULT_CRITICAL_CUTOFF_HZ
    setup, model = fit_setup(SetupOptions(), "affine")
    features = fit_features(model)
    assert model == "affine" and not features.regressor and not features.coulomb_eps
    assert setup.lowpass.kind == "butterworth" and setup.lowpass.cutoff_hz == DEFAULT_CUTOFF_HZ


def test_fit_filters_identified_models_without_overshoot_unless_told() -> None:
    setup, model = fit_setup(SetupOptions(), "identified")
    assert model == "identified" and fit_features(model).regressor
    assert setup.lowpass.kind == "critical"
    setup, _ = fit_setup(SetupOptions(filter_kind="butterworth"), "identified")
    assert setup.lowpass.kind == "butterworth"
