"""``twincd detect`` through typer's CliRunner: exit codes, --json shape, files written."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from support.clitools import assert_one_line_error, run


@pytest.fixture(scope="module")
def cal(default_calibration):
    return default_calibration


def test_collision_found_exits_1_and_lists_events(cal, twin_dataset):
    result = run("detect", twin_dataset / "test" / "test_0.mcap", "-c", cal)
    assert result.exit_code == 1, result.output
    assert "collision event(s)" in result.stdout and "test_0.mcap" in result.stdout
    assert result.stderr == ""


def test_clean_log_exits_0(cal, twin_dataset):
    result = run("detect", twin_dataset / "val" / "val_0.mcap", "-c", cal)
    assert result.exit_code == 0, result.output
    assert "no collision" in result.stdout


def test_json_shape(cal, twin_dataset):
    result = run(
        "detect", twin_dataset / "test", twin_dataset / "val" / "val_1.mcap", "-c", cal, "--json"
    )
    assert result.exit_code == 1
    doc = json.loads(result.stdout)
    assert doc["collision"] is True
    assert [lg["path"].rsplit("/", 1)[1] for lg in doc["logs"]] == [
        "test_0.mcap",
        "test_1.mcap",
        "val_1.mcap",
    ]
    first = doc["logs"][0]
    assert first["samples"] == 1600 and first["collision_samples"] > 0
    event = first["events"][0]
    assert {"start_ns", "end_ns", "peak_score", "joint"} <= set(event)
    assert isinstance(event["start_ns"], int) and event["joint"] in ("j1", "j2", "j3")
    assert doc["logs"][2]["events"] == []


@pytest.mark.parametrize("suffix", [".mcap", ".csv", ".jsonl"])
def test_outputs_written(cal, twin_dataset, tmp_path, suffix):
    """Every format holds one row (or message) per sample, the flags detect counted, scores at
    or above the threshold exactly where flagged, and the joints' residuals."""
    log = twin_dataset / "test" / "test_1.mcap"
    out = tmp_path / f"out{suffix}"
    result = run("detect", log, "-c", cal, "-o", out, "--json", "-q")
    assert result.exit_code == 1, result.output
    assert [p.name for p in tmp_path.iterdir()] == [out.name]
    doc = json.loads(result.stdout)
    summary = doc["logs"][0]
    if suffix == ".mcap":
        from rosbags.highlevel import AnyReader

        with AnyReader([out]) as reader:
            by_topic: dict[str, list] = {}
            for conn, _, raw in reader.messages():
                if conn.topic.startswith("/twincd/"):
                    msg = reader.deserialize(raw, conn.msgtype)
                    by_topic.setdefault(conn.topic, []).append(msg)
        scores = [m.data for m in by_topic["/twincd/score"]]
        flags = [m.data for m in by_topic["/twincd/collision"]]
        residuals = [len(m.effort) for m in by_topic["/twincd/residual"]]
        assert len(by_topic["/twincd/event"]) == len(summary["events"])
    elif suffix == ".csv":
        import csv

        with out.open() as f:
            rows = list(csv.DictReader(f))
        scores = [float(r["score"]) for r in rows]
        flags = [r["collision"] == "1" for r in rows]
        residuals = [sum(k.startswith("residual_") for k in r) for r in rows]
    else:
        rows = [json.loads(line) for line in out.read_text().splitlines()]
        scores = [r["score"] for r in rows]
        flags = [r["collision"] for r in rows]
        residuals = [sum(k.startswith("residual_") for k in r) for r in rows]
    assert len(scores) == len(flags) == summary["samples"]
    assert sum(flags) == summary["collision_samples"] > 0
    assert all(s >= doc["threshold"] for s, f in zip(scores, flags, strict=True) if f)
    assert set(residuals) == {3}


@pytest.mark.parametrize("suffix", [".mcap", ".csv"])
def test_detect_says_what_it_wrote(cal, twin_dataset, tmp_path, suffix):
    """As fit, threshold and simulate do: one line on stderr per output written (results stay
    alone on stdout)."""
    out = tmp_path / f"out{suffix}"
    result = run("detect", twin_dataset / "test" / "test_0.mcap", "-c", cal, "-o", out)
    assert result.exit_code == 1, result.output
    assert f"twincd: wrote {out} (" in result.stderr and str(out) not in result.stdout
    folder = run("detect", twin_dataset / "test", "-c", cal, "-o", tmp_path / "d", "--force")
    written = [ln for ln in folder.stderr.splitlines() if ln.startswith("twincd: wrote ")]
    assert len(written) == 2 and all(".detect.mcap" in ln for ln in written)
    quiet = run("detect", twin_dataset / "test" / "test_0.mcap", "-c", cal, "-o", out, "-q")
    assert quiet.stderr == ""


def test_several_logs_into_a_folder(cal, twin_dataset, tmp_path):
    result = run("detect", twin_dataset / "test", "-c", cal, "-o", tmp_path / "out", "-q")
    assert result.exit_code == 1
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "test_0.detect.mcap",
        "test_1.detect.mcap",
    ]


def test_errors(cal, twin_dataset, tmp_path, twin_log):
    fitted_only = tmp_path / "fit.json"
    assert run("fit", twin_dataset / "train", "-o", fitted_only, "-q").exit_code == 0
    result = run("detect", twin_dataset / "val" / "val_0.mcap", "-c", fitted_only)
    assert_one_line_error(result, "no threshold")
    other = twin_log(tmp_path / "other.mcap", joints=("a1", "a2", "a3"))
    assert_one_line_error(run("detect", other, "-c", cal), "lacks calibrated joint")
    result = run("detect", twin_dataset / "val" / "val_0.mcap", "-c", cal, "-o", tmp_path / "x.txt")
    assert_one_line_error(result, "unknown output type")
    result = run("detect", twin_dataset / "val" / "val_0.mcap", "-c", cal, "--robot", "panda")
    # the calibration recorded no robot (the logs carry the twin), so --robot is not a
    # contradiction; but panda has none of the log's joints
    assert_one_line_error(result, "no joint of the log is in the robot model")
    # a label topic is the run's to name, and one that matches nothing is an error
    result = run("detect", twin_dataset / "val" / "val_0.mcap", "-c", cal, "--label-topic", "/l")
    assert_one_line_error(result, "label topic /l is in none of the logs")
    result = run("detect", twin_dataset / "val" / "val_0.mcap", "-c", cal, "--causal")
    assert_one_line_error(result, "causal filter contradicts the calibration's zero-phase")
    (tmp_path / "broken.mcap").write_bytes(b"\x89MCAP0\r\n garbage")
    assert_one_line_error(run("detect", tmp_path / "broken.mcap", "-c", cal), "cannot read")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken.mcap", "fit.json", "other.mcap"]


def test_help_has_an_example():
    result = run("detect", "--help")
    assert result.exit_code == 0 and "Example: twincd detect" in result.stdout


def test_a_failing_log_removes_the_run_outputs(cal, twin_dataset, tmp_path):
    # one good log, then a truncated one: the run fails and leaves no output behind
    good = twin_dataset / "test" / "test_0.mcap"
    cut = tmp_path / "logs" / "z_cut.mcap"
    cut.parent.mkdir()
    data = good.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    out = tmp_path / "out"
    for jobs in ("1", "2"):  # in this process and on a pool: the same clean failure
        result = run("detect", good, cut, "-c", cal, "-o", out, "--json", "-j", jobs, "--strict")
        assert_one_line_error(result, "damaged")
        assert list(out.iterdir()) == []


def test_unwritable_output_fails_before_any_work(cal, twin_dataset, tmp_path):
    result = run(
        "detect", twin_dataset / "test" / "test_0.mcap", "-c", cal, "-o", tmp_path / "no" / "x.csv"
    )
    assert_one_line_error(result, match="folder does not exist")
    result = run("fit", twin_dataset / "train", "-o", tmp_path / "no" / "cal.json")
    assert_one_line_error(result, match="folder does not exist")
    assert result.stdout == ""  # no fit table: nothing was fitted


SAMPLE = Path(__file__).resolve().parents[1] / "sample_logs"


@pytest.mark.skipif(not (SAMPLE / "test").exists(), reason="no shipped sample logs")
def test_detect_names_the_link_of_each_event_or_its_candidates(tmp_path):
    cal = SAMPLE / "calibration.friction.json"
    result = run("detect", SAMPLE / "test" / "test_001.mcap", "-c", cal, "--json")
    assert result.exit_code == 1, result.output
    events = json.loads(result.stdout)["logs"][0]["events"]
    links = {f"link{i}" for i in range(1, 8)}
    assert events and all(set(e["link_candidates"]) <= links for e in events)
    assert all(e["link"] in (None, e["link_candidates"][0]) for e in events)
    table = run("detect", SAMPLE / "test" / "test_001.mcap", "-c", cal)
    assert "link" in table.stdout and events[0]["link_candidates"][0] in table.stdout
