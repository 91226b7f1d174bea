"""Settings by name (``twincd.SetupOptions``) resolved to a ``Setup``: defaults without a
calibration; with one, what it learned kept (a filter that contradicts it refused) and how a
recording is read (topics, joint names, the robot's URDF) the run's own, its recorded values
the defaults."""

from __future__ import annotations

import numpy as np
import pytest

from twincd import Calibration, SetupOptions
from twincd.calibration.models import fit_features
from twincd.commands.settings import fit_setup
from twincd.defaults import (
    DEFAULT_CAUSAL_CUTOFF_HZ,
    DEFAULT_CRITICAL_CUTOFF_HZ,
    DEFAULT_CUTOFF_HZ,
)
from twincd.errors import UsageError
from twincd.io.options import LogOptions
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
        ({"causal": False}, "causal", "zero-phase filter contradicts the calibration's causal"),
        ({"cutoff_hz": 1.0}, "cutoff_hz", "cut-off (Hz) 1 contradicts the calibration's 2"),
        ({"filter_order": 2}, "filter_order", "filter order 2 contradicts"),
        ({"filter_kind": "critical"}, "filter_kind", "filter kind critical contradicts"),
    ],
)
def test_a_filter_against_the_calibration_is_refused(
    given: dict[str, object], option: str, words: str
) -> None:
    with pytest.raises(UsageError) as caught:
        SetupOptions(**given).resolve(_calibration())  # type: ignore[arg-type]
    assert caught.value.option == option and words in caught.value.message
    assert "(cal.json)" in caught.value.message


def test_how_a_recording_is_read_overrides_the_calibration_s_defaults() -> None:
    """Topics, the joint map or prefix and the robot given are the run's; what the calibration
    learned (filter, joints, dynamics) stays. A joint map or prefix given replaces both."""
    cal = _calibration(robot="xarm7")
    setup = SetupOptions(
        topic="/left/joint_states",
        label_topic="/collision",
        link_topic="/touched",
        sim_topic="/twin",
        joint_prefix="left_",
        robot="panda",
    ).resolve(cal)
    options = setup.options
    assert (options.topic, options.label_topic, options.link_topic, options.sim_topic) == (
        "/left/joint_states",
        "/collision",
        "/touched",
        "/twin",
    )
    assert options.joint_map is None and options.joint_prefix == "left_"
    assert options.rename("left_joint1") == "joint1" and options.rename("a") == "a"
    assert setup.robot == "panda" and setup.lowpass == cal.lowpass
    assert setup.joint_names == cal.joint_names
    mapped = SetupOptions(joint_map={"b": "j2"}).resolve(cal).options
    assert dict(mapped.joint_map or {}) == {"b": "j2"} and mapped.joint_prefix == ""
    assert mapped.named == {"joint_map:b"}


def test_a_joint_map_entry_comes_before_the_prefix() -> None:
    options = LogOptions(joint_map={"left_j9": "j1"}, joint_prefix="left_")
    assert [options.rename(n) for n in ("left_j9", "left_j2", "right_j2")] == [
        "j1",
        "j2",
        "right_j2",
    ]


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


def test_a_command_s_keywords_become_one_run_and_one_settings_object() -> None:
    from twincd.commands.runs import Running, split_options

    running, asked = split_options(
        {"jobs": 2, "keep_going": True, "robot": "panda", "causal": False}
    )
    assert running == Running(jobs=2, keep_going=True)  # the others at Running's defaults
    assert asked == SetupOptions(robot="panda", causal=False)
    running, asked = split_options({})
    assert (running, asked) == (Running(), SetupOptions())
    with pytest.raises(TypeError, match="cutof"):
        split_options({"cutof": 3.0})  # type: ignore[typeddict-unknown-key]


def test_the_keyword_types_and_the_objects_name_the_same_fields() -> None:
    """The keyword arguments' types (``Settings``, ``RunOptions``: what mypy checks a call
    against) and the objects they become (``SetupOptions``, ``Running``) cannot drift apart;
    the CLI's settings object goes back to the same keywords."""
    from dataclasses import fields

    from twincd.commands import RunOptions, Settings
    from twincd.commands.runs import RUN_FIELDS, Running

    assert set(Settings.__annotations__) == {f.name for f in fields(SetupOptions)}
    assert set(RunOptions.__annotations__) == set(RUN_FIELDS) == {f.name for f in fields(Running)}
    asked = SetupOptions(robot="panda", joint_map={"a": "b"}, cutoff_hz=0.0, start=1.5)
    assert SetupOptions(**asked.keywords()) == asked
