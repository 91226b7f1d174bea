"""The calibration file's schema: ``twincd.calibration/3`` is written; ``/2`` files (the shipped
calibrations of the release before, in tests/data/calibrations_v2) load through ``upgrade_v2``
as the one band they were scored on, and ``/1`` files (those of the release before that, in
tests/data/calibrations_v1) through ``upgrade_v1`` then ``upgrade_v2``, and score exactly as the
``/2`` files they were re-made as."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from support.streaming import detect_frames

from twincd.calibration import SCHEMA, Calibration, upgrade_v1, upgrade_v2
from twincd.errors import CalibrationError

ROOT = Path(__file__).resolve().parents[1]
V1 = ROOT / "tests" / "data" / "calibrations_v1"
V2 = ROOT / "tests" / "data" / "calibrations_v2"
V2_SCHEMA = "twincd.calibration/2"
NAMES = ["calibration", "calibration.affine", "calibration.causal", "calibration.friction"]
LOG = ROOT / "sample_logs" / "test" / "test_000.mcap"


def _scores(cal: Calibration) -> np.ndarray:
    return detect_frames(LOG, cal)[1].column("score")


def _without_provenance(doc: dict) -> dict:  # type: ignore[type-arg]
    """The file but for what a re-made one may change: when and by which version, timings."""
    out = json.loads(json.dumps(doc))
    for key in ("schema", "created", "twincd_version"):
        out.pop(key)
    out["fit"].pop("seconds")
    return out  # type: ignore[no-any-return]


@pytest.mark.parametrize("name", NAMES)
def test_a_v1_file_loads_and_scores_as_the_re_made_v2_one(name: str, tmp_path: Path) -> None:
    old_doc = json.loads((V1 / f"{name}.json").read_text())
    assert old_doc["schema"] == "twincd.calibration/1"
    old = Calibration.load(V1 / f"{name}.json")
    new = Calibration.load(V2 / f"{name}.json")
    assert json.loads((V2 / f"{name}.json").read_text())["schema"] == V2_SCHEMA
    assert _without_provenance(old.to_dict()) == _without_provenance(new.to_dict())
    np.testing.assert_array_equal(_scores(old), _scores(new))
    # written again, a /1 file is a /3 file with the same content
    old.save(tmp_path / "again.json")
    again = json.loads((tmp_path / "again.json").read_text())
    assert again["schema"] == SCHEMA
    assert _without_provenance(again) == _without_provenance(old.to_dict())


@pytest.mark.parametrize("name", NAMES)
def test_a_v2_file_is_scored_on_its_one_band(name: str, tmp_path: Path) -> None:
    """A /2 file knows one band, the model's own: read as /3 it has no fast band and its
    threshold judges that band alone, as it did; written again it names that score."""
    doc = json.loads((V2 / f"{name}.json").read_text())
    assert "score" not in doc
    up = upgrade_v2(doc)
    assert up["schema"] == SCHEMA and up["score"] is None
    cal = Calibration.load(V2 / f"{name}.json")
    assert cal.score.fast is None and cal.fast_hz is None
    cal.save(tmp_path / "again.json")
    again = Calibration.load(tmp_path / "again.json")
    assert json.loads((tmp_path / "again.json").read_text())["schema"] == SCHEMA
    np.testing.assert_array_equal(_scores(again), _scores(cal))


def test_the_converter_writes_what_v1_files_could_leave_out() -> None:
    doc = json.loads((V1 / "calibration.affine.json").read_text())
    for key in ("log_options", "fit", "created", "twincd_version"):
        doc.pop(key)
    doc["model"].pop("statistic", None)
    doc["threshold"].pop("estimator")
    del doc["filter"]["sample_rate_hz"]
    del doc["robot"]["simulated"]
    up = upgrade_v1(doc)
    assert up["schema"] == V2_SCHEMA and up["model"]["statistic"] == "sum"
    assert up["log_options"]["topic"] == "/joint_states" and up["fit"]["logs"] == []
    assert up["threshold"]["estimator"] == "mean-sd" and up["robot"]["simulated"] is True
    assert up["filter"]["sample_rate_hz"] is None
    cal = Calibration.from_dict(doc)
    assert cal.period_s is None and cal.fit.samples == 0 and cal.model.statistic == "sum"
    # a /3 file names every section: one left out is refused, not read as a default
    for section in ("log_options", "score"):
        v3 = cal.to_dict()
        del v3[section]
        with pytest.raises(CalibrationError, match=f"lacks the field '{section}'"):
            Calibration.from_dict(v3)


def edited_v1(schema: str, path: tuple[object, ...], value: object) -> dict:  # type: ignore[type-arg]
    """The shipped v1 calibration under ``schema`` with the field at ``path`` set to ``value``
    (the current schema without a score block, which v1 files lack)."""
    doc = json.loads((V1 / "calibration.json").read_text())
    doc["schema"] = schema
    if schema == SCHEMA:
        doc["score"] = None
    at = doc
    for key in path[:-1]:
        at = at[key]
    at[path[-1]] = value
    return doc  # type: ignore[no-any-return]


@pytest.mark.parametrize("schema", ["twincd.calibration/1", V2_SCHEMA, SCHEMA])
@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        (("model", "joints", "joint1", "a"), float("nan"), "not a finite number"),
        (("model", "joints", "joint1", "c"), "0.3", "not a number"),
        (("model", "joints", "joint2", "theta", 3), float("inf"), "not a finite number"),
        (("model", "joints", "joint1", "scale", 0), True, "not a number"),
        (("fit", "joints", "joint1", "rmse"), "x", "not a number"),
        (("fit", "samples"), 1.5, "not a count"),
        (("threshold", "samples"), "80", "not a count"),
        (("threshold", "mu"), float("nan"), "not a finite number"),
        (("filter", "sample_rate_hz"), 0, "positive"),
    ],
)
def test_every_number_is_validated_in_either_schema(
    schema: str, path: tuple[object, ...], value: object, message: str
) -> None:
    with pytest.raises(CalibrationError, match=message):
        Calibration.from_dict(json.loads(json.dumps(edited_v1(schema, path, value))))


@pytest.mark.parametrize("schema", ["twincd.calibration/1", V2_SCHEMA, SCHEMA])
@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        (("model",), None, "field model is null, not an object"),
        (("filter",), "x", "field filter is a JSON string, not an object"),
        (("model", "joints"), "x", "field model.joints is a JSON string, not an object"),
        (("model", "joints", "joint3"), [1.0], "field model.joints.joint3 is a JSON list, not an"),
        (("threshold",), 3, "field threshold is a JSON number, not an object"),
    ],
)
def test_a_section_of_the_wrong_kind_is_named_in_the_files_words(
    schema: str, path: tuple[str, ...], value: object, message: str
) -> None:
    """Not Python's words ("string indices must be integers", "'NoneType' object has no
    attribute 'get'"): the field and what it is instead of an object."""
    with pytest.raises(CalibrationError, match=message):
        Calibration.from_dict(edited_v1(schema, path, value))


def test_a_joint_missing_from_the_model_is_named_with_its_section() -> None:
    doc = json.loads((V1 / "calibration.json").read_text())
    del doc["model"]["joints"]["joint3"]
    with pytest.raises(CalibrationError, match=r"lacks the field 'model\.joints\.joint3'"):
        Calibration.from_dict(doc)
