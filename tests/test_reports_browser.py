"""The HTML report in a real browser: headless Chromium (Debian's ``chromium``) with networking
off opens it; no console error, no failed load, a screenshot that is not blank, and the events
table lists the events of ``detect --json``. Outside CI the test skips when Chromium is absent;
in CI (``CI=true``) that is a failure, so that it never silently stops running."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from support.chromium import Browser, find_chromium
from support.clitools import run

from twincd.evaluation.methods import method_for

SAMPLE_LOGS = Path(__file__).resolve().parent.parent / "sample_logs"


IN_CI = os.environ.get("CI", "").lower() in ("1", "true", "yes")
# outside CI the browser tests need a local Chromium (apt-get install chromium); CI must have one
pytestmark = pytest.mark.skipif(
    find_chromium() is None and not IN_CI, reason="chromium is not installed"
)


@pytest.fixture(scope="module")
def browser():
    executable = find_chromium()
    if executable is None:  # only in CI: elsewhere the module is skipped (pytestmark)
        pytest.fail("chromium is not installed, and CI must run the browser test")
    with Browser(executable) as b:
        yield b


def open_clean(browser: Browser, page: Path) -> None:
    browser.events.clear()
    browser.open(page.resolve().as_uri())
    assert browser.errors() == []


def not_blank(png: Path) -> None:
    from PIL import Image

    image = np.asarray(Image.open(png).convert("L"), dtype=float)
    assert image.shape[0] > 500 and image.shape[1] > 500
    assert image.std() > 10 and (image < 128).mean() > 0.005


def test_the_check_catches_errors_and_network(browser, tmp_path):
    """The checks below can fail: a console error and a remote resource are both caught."""
    bad = tmp_path / "bad.html"
    bad.write_text(
        '<!DOCTYPE html><html><head><link rel="icon" href="data:,"></head><body>'
        '<img src="https://example.com/x.png"><script>console.error("boom")</script>'
        "</body></html>"
    )
    browser.events.clear()
    browser.open(bad.as_uri())
    errors = browser.errors()
    assert "boom" in errors
    assert any("ERR_PROXY_CONNECTION_FAILED" in e or "ERR_NAME" in e for e in errors), errors


def test_detect_report_in_a_browser(browser, tmp_path):
    report, junit = tmp_path / "r.html", tmp_path / "r.xml"
    result = run(
        "detect",
        SAMPLE_LOGS / "test" / "test_000.mcap",
        "-c",
        SAMPLE_LOGS / "calibration.json",
        "--report",
        report,
        "--junit",
        junit,
        "--json",
        "--no-summary",
    )
    assert result.exit_code == 1, result.output
    events = json.loads(result.stdout)["logs"][0]["events"]
    assert events and junit.exists()
    open_clean(browser, report)
    rows = browser.evaluate(
        "[...document.querySelectorAll('table.events tbody tr')]"
        ".map(r => [...r.cells].map(c => c.textContent))"
    )
    header = browser.evaluate(
        "[...document.querySelectorAll('table.events thead th')].map(c => c.textContent)"
    )
    assert len(rows) == len(events)
    t0 = min(e["start_ns"] for e in events)  # the first event starts after the first sample
    for row, event in zip(rows, events, strict=True):
        cells = dict(zip(header, row, strict=True))
        assert cells["joint"] == event["joint"]
        assert float(cells["peak score"]) == pytest.approx(event["peak_score"], rel=1e-3)
        assert float(cells["duration (s)"]) == pytest.approx(event["duration_s"], abs=1e-3)
        start = float(cells["start (s)"]) - float(rows[0][1])
        assert start == pytest.approx((event["start_ns"] - t0) * 1e-9, abs=1e-3)
        if event.get("link"):
            assert cells["link"] == event["link"]
    # the figure is drawn: an <svg> with the per-joint axes and the score
    assert browser.evaluate("document.querySelectorAll('#figures svg').length") == 1
    not_blank(browser.screenshot(tmp_path / "r.png"))


def test_evaluate_report_in_a_browser(browser, twin_dataset, twin_calibration, tmp_path):
    cal = twin_calibration
    report = tmp_path / "e.html"
    result = run("evaluate", twin_dataset / "test", "-c", cal, "--report", report, "-q")
    assert result.exit_code == 0, result.output
    open_clean(browser, report)
    kind = json.loads(cal.read_text())["model"]["kind"]  # evaluate runs the calibration's model
    # under its method name ("proposed" for the paper's affine model)
    assert method_for(kind) in browser.evaluate("document.querySelector('table').textContent")
    not_blank(browser.screenshot(tmp_path / "e.png"))
