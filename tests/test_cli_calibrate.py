"""``twincd fit`` and ``twincd threshold`` through typer's CliRunner."""

from __future__ import annotations

import json

import pytest
from support.clitools import assert_one_line_error, run


@pytest.fixture(scope="module")
def fitted(twin_dataset, tmp_path_factory):
    cal = tmp_path_factory.mktemp("cal") / "cal.json"
    result = run(
        "fit", twin_dataset / "train", "-o", cal, "--cutoff", "2", "--filter-order", "3",
        "--model", "affine",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    return cal, result


def test_fit_writes_the_calibration_and_prints_the_table(fitted):
    cal, result = fitted
    doc = json.loads(cal.read_text())
    assert doc["schema"] == "twincd.calibration/3"
    assert doc["filter"] == {
        "cutoff_hz": 2.0,
        "order": 3,
        "causal": False,
        "kind": "butterworth",
        "zero_phase": True,
        "sample_rate_hz": 100.0,  # the logs' nominal rate: later logs are filtered at it
    }
    assert doc["log_options"]["topic"] == "/joint_states"
    assert doc["threshold"] is None and len(doc["fit"]["logs"]) == 3
    for joint in ("j1", "j2", "j3"):
        assert joint in result.stdout
    assert "wrote" in result.stderr


def test_threshold_json(fitted, twin_dataset, tmp_path):
    """One JSON document on stdout: the value, the rule, the false alarms counted on the logs
    and the threshold object written into the calibration (contract: --json documents)."""
    cal, _ = fitted
    out = tmp_path / "c.json"
    # the paper's model: μ + 4σ by default, a budget when asked
    for options, rule in (([], "k-sigma"), (["--false-alarms-per-hour", "1"], "budget")):
        result = run("threshold", twin_dataset / "val", "-c", cal, "-o", out, "--json", *options)
        assert result.exit_code == 0, result.output
        doc = json.loads(result.stdout)
        written = json.loads(out.read_text())["threshold"]
        assert doc["rule"] == rule and doc["value"] == written["value"]
        assert doc["threshold"] == written and doc["calibration"] == str(out)
        assert doc["false_alarms"] == 0 and doc["hours"] > 0
        assert doc["errors"] == [] and isinstance(doc["warnings"], list)
        assert "threshold " not in result.stdout.split("{", 1)[0]  # nothing but the document
    line = run("threshold", twin_dataset / "val", "-c", cal, "-o", out)
    assert line.stdout.startswith("threshold ") and len(line.stdout.splitlines()) == 1
    assert len(line.stdout) < 120  # a line to read, the details in --json


def test_threshold_rewrites_in_place_or_to_output(fitted, twin_dataset, tmp_path):
    cal, _ = fitted
    copy = tmp_path / "c.json"
    copy.write_text(cal.read_text())
    result = run("threshold", twin_dataset / "val", "-c", copy, "--sigma", "3")
    assert result.exit_code == 0, result.output
    th = json.loads(copy.read_text())["threshold"]
    assert th["k_sigma"] == 3.0 and th["value"] == pytest.approx(th["mu"] + 3 * th["sigma"])
    assert "μ" in result.stdout
    out = tmp_path / "other.json"
    result = run("threshold", twin_dataset / "val", "-c", cal, "-o", out, "-q")
    assert result.exit_code == 0 and result.stderr == ""
    default = json.loads(out.read_text())["threshold"]  # the default: μ + 4σ
    assert default["k_sigma"] == 4.0 and "false_alarm_budget" not in default
    assert json.loads(cal.read_text())["threshold"] is None  # -c untouched with -o
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.json", "other.json"]


def test_causal_defaults_and_is_recorded(twin_dataset, tmp_path):
    cal = tmp_path / "causal.json"
    result = run("fit", twin_dataset / "train" / "train_0.mcap", "-o", cal, "--causal", "-q")
    assert result.exit_code == 0, result.output
    f = json.loads(cal.read_text())["filter"]
    assert f["causal"] is True and f["zero_phase"] is False and f["cutoff_hz"] == 3.0


def test_a_topic_is_the_run_s_to_name(fitted, twin_dataset):
    """The topic is how this run's logs are read, not what the calibration learned: one that
    matches nothing in them is an error of its own."""
    cal, _ = fitted
    result = run("threshold", twin_dataset / "val", "-c", cal, "--topic", "/other")
    assert_one_line_error(result, "joint-state topic /other is in none of the logs")
    assert "(option --topic)" in result.stderr
    result = run("threshold", twin_dataset / "val", "-c", cal, "--topic", "/joint_states", "-q")
    assert result.exit_code == 0  # agreeing is fine


def test_bad_inputs(tmp_path, twin_log, fitted):
    result = run("fit", tmp_path / "missing.mcap", "-o", tmp_path / "c.json")
    assert_one_line_error(result, "no such file")
    short = twin_log(tmp_path / "short.mcap", seconds=0.01)
    result = run("fit", short, "-o", tmp_path / "c.json")
    assert_one_line_error(result, "too short to filter")
    (tmp_path / "v9.json").write_text('{"schema": "twincd.calibration/9"}')
    result = run("threshold", short, "-c", tmp_path / "v9.json")
    assert_one_line_error(result, "schema")
    other = twin_log(tmp_path / "other.mcap", joints=("k1", "k2", "k3"))
    result = run("threshold", other, "-c", fitted[0])
    assert_one_line_error(result, "lacks calibrated joint(s) j1, j2, j3")
    assert not (tmp_path / "c.json").exists()


def test_help_has_examples():
    for cmd in ("fit", "threshold"):
        result = run(cmd, "--help")
        assert result.exit_code == 0 and "Example: twincd " + cmd in result.stdout


def test_threshold_on_fit_logs_warns(fitted, twin_dataset, tmp_path):
    out = tmp_path / "reused.json"
    result = run("threshold", twin_dataset / "train" / "train_0.mcap", "-c", fitted[0], "-o", out)
    assert result.exit_code == 0
    assert "also used by fit" in result.stderr


def test_a_process_pool_gives_the_same_calibration_in_any_log_order(twin_dataset, tmp_path):
    logs = sorted((twin_dataset / "train").glob("*.mcap"))
    docs = []
    for jobs, order in (("1", logs), ("2", logs[::-1])):
        out = tmp_path / f"cal{jobs}.json"
        assert run("fit", *order, "-o", out, "-j", jobs).exit_code == 0
        assert run("threshold", twin_dataset / "val", "-c", out, "-j", jobs).exit_code == 0
        docs.append(json.loads(out.read_text()))
    serial, pooled = docs
    assert pooled["model"] == serial["model"]
    for key in ("mu", "sigma", "value"):
        assert pooled["threshold"][key] == pytest.approx(serial["threshold"][key], rel=1e-12)


@pytest.mark.parametrize("robot", [None, "xarm7"])
def test_fit_without_a_model_fits_the_best_the_logs_allow(
    robot, twin_dataset, xarm_dataset, tmp_path
):
    # logs with their own twin effort and no robot model: friction-whitened; with a robot
    # model: identified-whitened. Said on stderr and in the calibration; the threshold is then
    # μ + 4σ with the median and MAD; detect finds the bumps and passes the clean log.
    data = twin_dataset if robot is None else xarm_dataset
    cal = tmp_path / "cal.json"
    args = [] if robot is None else ["--robot", robot]
    fit = run("fit", data / "train", "-o", cal, *args)
    assert fit.exit_code == 0, fit.output
    kind = "friction-whitened" if robot is None else "identified-whitened"
    assert f"model {kind}, the best these logs allow" in fit.stderr
    doc = json.loads(cal.read_text())
    assert doc["model"]["kind"] == kind and doc["model"]["statistic"] == "depth"
    assert doc["filter"]["kind"] == "critical" and doc["filter"]["cutoff_hz"] == 1.5
    threshold = run("threshold", data / "val", "-c", cal)
    assert threshold.exit_code == 0, threshold.output
    assert threshold.stdout.startswith("threshold ")
    assert "(budget 1 false alarm/h, 90 % interval " in threshold.stdout
    th = json.loads(cal.read_text())["threshold"]
    budget = th["false_alarm_budget"]
    assert th["estimator"] == "median-mad" and budget["method"] == "bulk-exponential"
    assert budget["firm_after_minutes"] > 0  # minutes of clean data cannot measure the tail
    # the estimate, or above it where the clean data themselves pass it too often, and said
    raised = "raised to" in threshold.stderr
    assert th["value"] == pytest.approx(budget["estimate"], rel=1e-12) or (
        raised and th["value"] > budget["estimate"]
    )
    assert budget["interval"][0] <= budget["estimate"] <= budget["interval"][1]
    # the clean scores' mean and sd are kept too: evaluate's F1 over μ + iσ is on them
    assert th["mean"] != th["mu"] and th["sd"] > 0
    tests_dir = data / "test"
    evaluated = json.loads(run("evaluate", tests_dir, "-c", cal, "--json", "-q").stdout)
    method = evaluated["methods"][0]
    assert (method["mu"], method["sigma"]) == (th["mean"], th["sd"])
    # ... but it judges at the calibration's own threshold, as detect flags: the same samples
    assert method["threshold"] == th["value"]
    assert method["mu"] + method["k_sigma"] * method["sigma"] == pytest.approx(th["value"])
    tests = sorted((data / "test").glob("*.mcap"))
    found = run("detect", *tests, "-c", cal, "--json")
    assert found.exit_code == 1, found.output
    assert sum(len(log["events"]) for log in json.loads(found.stdout)["logs"]) >= 1
    flagged = sum(log["collision_samples"] for log in json.loads(found.stdout)["logs"])
    hits = method["recall_at_threshold"] * method["positives"]
    assert hits / method["precision_at_threshold"] == pytest.approx(flagged, abs=0.5)
    # with other validation logs, the calibration's rule (here its budget) sets the threshold
    # on them, as `twincd threshold` would
    other = sorted((data / "val").glob("*.mcap"))[:1]
    again = tmp_path / "again.json"
    again.write_text(cal.read_text())
    assert run("threshold", *other, "-c", again, "-q").exit_code == 0
    expected = json.loads(again.read_text())["threshold"]
    rerun = run("evaluate", tests_dir, "-c", cal, "--val", *other, "--json", "-q")
    assert rerun.exit_code == 0, rerun.output
    judged = json.loads(rerun.stdout)["methods"][0]
    assert judged["threshold"] == pytest.approx(expected["value"], rel=1e-9)
    assert expected["false_alarm_budget"]["per_hour"] == budget["per_hour"]


def test_the_fast_band_is_asked_for_by_its_cut_off(twin_dataset, tmp_path):
    """fit's fast band: 10 Hz by default (as far as 100 Hz samples allow), another cut-off by
    --fast-cutoff, none with 0 (the filter's band alone, as a /2 calibration); the paper's
    model sums one band and refuses one; a calibration is not run with another."""
    from twincd import Calibration, fit_calibration

    train = twin_dataset / "train"
    fast: dict[str, float | None] = {}
    for name, args in (
        ("default", ()),
        ("five", ("--fast-cutoff", "5")),
        ("none", ("--fast-cutoff", "0")),
    ):
        cal = tmp_path / f"{name}.json"
        result = run("fit", train, "-o", cal, *args)
        assert result.exit_code == 0, result.output
        fast[name] = Calibration.load(cal).fast_hz
        doc = json.loads(cal.read_text())
        assert doc["score"]["bands"] == (1 if name == "none" else 2)
    assert fast == {"default": 10.0, "five": 5.0, "none": None}
    # the library takes it as the CLI does
    assert fit_calibration([train], fast_cutoff_hz=5.0).calibration.fast_hz == 5.0
    refused = run(
        "fit", train, "-o", tmp_path / "affine.json", "--model", "affine", "--fast-cutoff", "5"
    )
    assert_one_line_error(refused, "sums one band")
    assert (
        run(
            "fit", train, "-o", tmp_path / "a.json", "--model", "affine", "--fast-cutoff", "0"
        ).exit_code
        == 0
    )
    assert run("threshold", twin_dataset / "val", "-c", tmp_path / "five.json").exit_code == 0
    contradicted = run(
        "evaluate", twin_dataset / "test", "-c", tmp_path / "five.json", "--fast-cutoff", "10"
    )
    assert_one_line_error(contradicted, "contradicts the calibration's 5 Hz")
