"""Outputs: whole or nothing, never over a file that is not twincd's own output of that kind,
temporaries of killed runs removed, two writers of one output refused (contract: Topics twincd
writes, Exit codes and streams)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from support.clitools import assert_one_line_error, run

from twincd.errors import OutputError
from twincd.io.atomic import (
    atomic_output,
    check_target,
    output_kind,
    remove_stale_temporaries,
    temporary_path,
)


@pytest.fixture(scope="module")
def cal(default_calibration):
    return default_calibration


def dead_pid() -> int:
    """The pid of a process that has ended."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_fit_refuses_to_overwrite_a_recording(twin_dataset, tmp_path):
    log = shutil.copy(twin_dataset / "train" / "train_0.mcap", tmp_path / "run_000.mcap")
    before = Path(log).read_bytes()
    result = run("fit", twin_dataset / "train", "-o", log)  # the glob typo of the issue
    assert_one_line_error(result, "would overwrite a recorded log")
    assert "--force" in result.stderr
    assert Path(log).read_bytes() == before
    # an input given as output is refused too
    result = run("fit", log, twin_dataset / "train" / "train_1.mcap", "-o", log)
    assert_one_line_error(result, "would overwrite an input")
    assert Path(log).read_bytes() == before


def test_threshold_and_report_refuse_foreign_files(cal, twin_dataset, tmp_path):
    notes = tmp_path / "notes.md"
    notes.write_text("my notes\n")
    result = run("threshold", twin_dataset / "val", "-c", cal, "-o", notes)
    assert_one_line_error(result, "would overwrite a file twincd did not write")
    result = run("evaluate", twin_dataset / "test", "-c", cal, "--report", notes)
    assert_one_line_error(result, "would overwrite a file twincd did not write")
    assert notes.read_text() == "my notes\n"
    # --force overwrites it; twincd's own outputs of the kind are replaced without it
    assert (
        run("evaluate", twin_dataset / "test", "-c", cal, "--report", notes, "--force").exit_code
        == 0
    )
    assert output_kind(notes) == "report"
    assert run("evaluate", twin_dataset / "test", "-c", cal, "--report", notes).exit_code == 0
    other = tmp_path / "cal2.json"
    shutil.copy(cal, other)
    assert run("threshold", twin_dataset / "val", "-c", cal, "-o", other, "-q").exit_code == 0


def test_detect_and_simulate_replace_only_their_own_kind(cal, twin_dataset, tmp_path):
    log = twin_dataset / "test" / "test_0.mcap"
    out = tmp_path / "out.mcap"
    assert run("detect", log, "-c", cal, "-o", out).exit_code == 1
    assert output_kind(out) == "detect"
    assert run("detect", log, "-c", cal, "-o", out).exit_code == 1  # its own: replaced
    result = run("simulate", log, "-o", out, "--robot", "xarm7")
    assert_one_line_error(result, "would overwrite a detect output")
    recording = shutil.copy(log, tmp_path / "rec.mcap")
    assert_one_line_error(run("detect", log, "-c", cal, "-o", recording), "a recorded log")
    csv = tmp_path / "rows.csv"
    assert run("detect", log, "-c", cal, "-o", csv).exit_code == 1
    assert output_kind(csv) == "table"
    assert run("detect", log, "-c", cal, "-o", csv).exit_code == 1


def test_read_only_targets_are_refused_even_forced(cal, twin_dataset, tmp_path):
    target = tmp_path / "ro.json"
    shutil.copy(cal, target)
    target.chmod(0o444)
    for args in (("-c", target), ("-c", cal, "-o", target, "--force")):
        result = run("threshold", twin_dataset / "val", *args)
        assert_one_line_error(result, "read-only")
    assert oct(target.stat().st_mode & 0o777) == "0o444"
    log = shutil.copy(twin_dataset / "val" / "val_0.mcap", tmp_path / "ro.mcap")
    os.chmod(log, 0o444)
    assert_one_line_error(run("simulate", log, "--in-place", "--robot", "xarm7"), "read-only")


def test_in_place_keeps_the_mode(twin_dataset, tmp_path):
    log = shutil.copy(twin_dataset / "val" / "val_0.mcap", tmp_path / "run.mcap")
    os.chmod(log, 0o640)
    result = run(
        "simulate",
        log,
        "--in-place",
        "--robot",
        "xarm7",
        "--joint-map",
        "j1=joint1,j2=joint2,j3=joint3",
    )
    assert result.exit_code == 0, result.output
    assert oct(os.stat(log).st_mode & 0o777) == "0o640"


def test_folder_skips_detect_copies(cal, twin_dataset, tmp_path):
    from twincd.io.logs import expand_logs

    shutil.copy(twin_dataset / "test" / "test_0.mcap", tmp_path / "x.mcap")
    assert (
        run("detect", tmp_path / "x.mcap", "-c", cal, "-o", tmp_path / "x.detect.mcap").exit_code
        == 1
    )
    (tmp_path / "x.twin.mcap").write_bytes((tmp_path / "x.mcap").read_bytes())
    assert [p.name for p in expand_logs([tmp_path])] == ["x.mcap"]
    # named, a copy is read
    assert [p.name for p in expand_logs([tmp_path / "x.detect.mcap"])] == ["x.detect.mcap"]


def test_stale_temporaries_are_removed_and_live_writers_refused(tmp_path):
    target = tmp_path / "out.json"
    stale = temporary_path(target, dead_pid())
    stale.write_bytes(b"partial")
    unrelated = tmp_path / ".keep.tmp"
    unrelated.write_bytes(b"mine")
    with atomic_output(target) as stream:
        assert not stale.exists()  # the next run removed it
        stream.write(b"{}")
    assert unrelated.exists() and target.read_bytes() == b"{}"
    # a live process (this test's parent shell stands in) writing the same target
    live = temporary_path(target, os.getppid())
    live.write_bytes(b"")
    with pytest.raises(OutputError, match="another twincd run"), atomic_output(target):
        pass
    assert remove_stale_temporaries(tmp_path) == [] and live.exists()


def test_check_target_kinds(tmp_path, cal):
    assert output_kind(cal) == "calibration"
    doc = tmp_path / "other.json"
    doc.write_text(json.dumps({"schema": "someone.else/1"}))
    with pytest.raises(OutputError, match="did not write"):
        check_target(doc, "calibration")
    check_target(doc, "calibration", force=True)
    check_target(tmp_path / "new.json", "calibration")


def test_html_and_junit_reports_are_recognised_as_twincd_own(tmp_path):
    from twincd.reports import html
    from twincd.reports.junit import Case, junit_xml

    page = tmp_path / "r.html"
    page.write_text(html.page("twincd detect", ["<p>x</p>"], [], "<p>s</p>"))
    assert output_kind(page) == "report"
    xml = tmp_path / "r.xml"
    xml.write_text(junit_xml("twincd detect", [Case("log", "a.mcap")]))
    assert output_kind(xml) == "junit"
    foreign = tmp_path / "other.html"
    foreign.write_text("<!DOCTYPE html><html><head></head><body>mine</body></html>")
    assert output_kind(foreign) is None
