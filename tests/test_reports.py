"""Reports: figures, Markdown and HTML reports, JUnit XML, the GitHub job summary (contract: Exit
codes and streams)."""

from __future__ import annotations

import io
import json
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from support.clitools import assert_one_line_error, run

from twincd.calibration import Calibration
from twincd.commands.detect import detect_and_write
from twincd.errors import OutputError, UsageError
from twincd.prepare.setup import Setup
from twincd.reports import (
    append_step_summary,
    calibration_settings,
    detection_html,
    detection_junit,
    detection_markdown,
)
from twincd.reports.figures import detection_figure, save

SAMPLE_LOGS = Path(__file__).resolve().parent.parent / "sample_logs"
XSD = Path(__file__).resolve().parent / "data" / "junit.xsd"


def validate_junit(path_or_text: Path | str) -> ET.Element:
    """Valid against the bundled JUnit schema, and the counts match the test cases."""
    import xmlschema

    text = path_or_text.read_text() if isinstance(path_or_text, Path) else path_or_text
    xmlschema.XMLSchema(XSD).validate(text)
    root = ET.fromstring(text)
    for suite in [root, *root.iter("testsuite")]:
        cases = list(suite.iter("testcase"))
        assert int(suite.get("tests", -1)) == len(cases)
        assert int(suite.get("failures", -1)) == sum(c.find("failure") is not None for c in cases)
        assert int(suite.get("skipped", -1)) == sum(c.find("skipped") is not None for c in cases)
    return root


@pytest.fixture(scope="module")
def sample_detection():
    """The shipped sample log detected with its calibration, with the figure's data."""
    cal = Calibration.load(SAMPLE_LOGS / "calibration.json")
    log = SAMPLE_LOGS / "test" / "test_000.mcap"
    summary = detect_and_write((log, None), cal, Setup.from_calibration(cal), trace=True)
    return cal, summary


def assert_drawn(fig, path: Path) -> None:
    """Saved as PNG and SVG; the PNG has the figure's size (1000 px wide) and is not blank."""
    from PIL import Image

    width, height = fig.get_size_inches() * fig.dpi
    png, svg = save(fig, path)
    assert svg.read_text().lstrip().startswith("<?xml") and "<svg" in svg.read_text()
    image = np.asarray(Image.open(png).convert("L"), dtype=float)
    assert image.shape == (round(height), round(width))
    assert width == 1000
    # a drawn figure: many non-white pixels and many grey levels, not a blank canvas
    assert (image < 250).mean() > 0.03 and len(np.unique(image)) > 20


def test_detection_figure_has_the_size_asked_and_is_not_blank(sample_detection, tmp_path):
    _, summary = sample_detection
    assert summary.events and summary.trace is not None
    assert_drawn(detection_figure(summary, summary.trace), tmp_path / "detect")


def test_fit_figure_is_drawn(twin_dataset, tmp_path):
    from twincd.calibration import merge_fits
    from twincd.calibration.models import fit_features
    from twincd.reports.figures import fit_figure
    from twincd.reports.traces import ThinnedPairs, fit_log_with_pairs

    setup = Setup()
    both = [fit_log_with_pairs(p, setup) for p in sorted((twin_dataset / "train").iterdir())]
    cal = merge_fits([part for part, _ in both], setup, "affine")
    pairs = ThinnedPairs.merge([p for _, p in both])
    assert pairs.seen == cal.fit.samples
    figure = fit_figure(cal, pairs)
    # the affine model's prediction is the line a·τ̂̃ + b: drawn on every joint's axes
    lines = [ax.lines for ax in figure.axes if ax.get_visible()]
    assert len(lines) == len(cal.joint_names) and all(len(drawn) == 1 for drawn in lines)
    assert_drawn(figure, tmp_path / "fit")
    # a friction model predicts from more than τ̂̃: no line of τ̂̃ alone claims to be it
    features = fit_features("friction")
    paths = sorted((twin_dataset / "train").iterdir())
    both = [fit_log_with_pairs(p, setup, features) for p in paths]
    friction = merge_fits([part for part, _ in both], setup, "friction")
    figure = fit_figure(friction, ThinnedPairs.merge([p for _, p in both]))
    assert not any(ax.lines for ax in figure.axes)
    assert all("friction" in ax.get_title() for ax in figure.axes if ax.get_visible())


def test_trace_follows_the_summary(sample_detection):
    _, summary = sample_detection
    trace = summary.trace
    assert trace.envelope.samples == summary.samples
    _, score = trace.score()
    # the highest score of the log is the highest event peak, and the envelope keeps it
    assert np.nanmax(score) == pytest.approx(max(e.peak_score for e in summary.events))
    assert trace.label_spans(), "the sample log has labels"


def test_html_report_is_self_contained_with_summary_first(sample_detection):
    cal, summary = sample_detection
    page = detection_html([summary], calibration_settings(cal))
    assert page.startswith("<!DOCTYPE html>")
    order = [page.index(k) for k in ('id="summary"', 'id="figures"', 'id="settings"')]
    assert order == sorted(order)
    assert "<svg" in page and "<script" not in page.lower()
    # nothing fetched: no http(s) reference but the SVG/XML namespaces
    external = [
        token
        for token in page.split('"')
        if token.startswith(("http://", "https://")) and "w3.org" not in token
    ]
    assert external == [], external
    assert "Collision" in page and "calibration.json" in page
    # the settings name the filter the calibration records (the shipped one: critically damped)
    assert (
        cal.lowpass.kind == "critical" and "critically damped order 2, 1.5 Hz, zero-phase" in page
    )
    for e in summary.events:
        assert f"{e.peak_score:.4g}" in page


def test_markdown_summary_lists_events_and_links(sample_detection):
    from dataclasses import replace

    cal, summary = sample_detection
    unnamed = replace(
        summary, events=[replace(e, link=None, link_candidates=()) for e in summary.events]
    )
    text = detection_markdown([unnamed], calibration_settings(cal))
    assert f"{len(summary.events)} event(s)" in text and "| link |" not in text
    linked = replace(summary, events=[replace(e, link="link5") for e in summary.events])
    text = detection_markdown([linked])
    assert "| link |" in text and "link5" in text


def test_junit_of_detect_is_valid_and_counts_match(sample_detection):
    _, summary = sample_detection
    clean = type(summary)("clean.mcap", summary.threshold, samples=10)
    root = validate_junit(detection_junit([summary, clean]))
    failures = root.findall(".//failure")
    assert len(failures) == 1
    assert f"{len(summary.events)} collision event(s)" in failures[0].get("message")
    assert failures[0].text.count("\n") == len(summary.events)


def test_step_summary_is_appended(tmp_path):
    target = tmp_path / "summary.md"
    target.write_text("earlier step\n")
    assert append_step_summary("## mine", {"GITHUB_STEP_SUMMARY": str(target)}) == target
    assert target.read_text() == "earlier step\n## mine\n\n"
    assert append_step_summary("## mine", {}) is None
    with pytest.raises(OutputError, match="job summary"):
        append_step_summary("x", {"GITHUB_STEP_SUMMARY": str(tmp_path / "no" / "such")})


# ---------------------------------------------------------------- through the CLI


@pytest.fixture
def cal(twin_calibration):
    return twin_calibration


def test_detect_writes_report_junit_and_summary(cal, twin_dataset, tmp_path, monkeypatch):
    summary = tmp_path / "step_summary.md"
    monkeypatch.setenv("GITHUB_STEP_SUMMARY", str(summary))
    logs = [twin_dataset / "test" / "test_0.mcap", twin_dataset / "val" / "val_0.mcap"]
    html, xml = tmp_path / "r.html", tmp_path / "r.xml"
    result = run("detect", *logs, "-c", cal, "--report", html, "--junit", xml, "--json")
    assert result.exit_code == 1, result.output
    doc = json.loads(result.stdout)
    root = validate_junit(xml)
    assert len(root.findall(".//testcase")) == 2 and len(root.findall(".//failure")) == 1
    page = html.read_text()
    assert page.count("<svg") >= 2  # one figure per log
    assert "1 of 2 log(s)" in page
    text = summary.read_text()
    assert "## twincd detect" in text
    assert text.count("|") > 0 and str(len(doc["logs"][0]["events"])) in text

    md = tmp_path / "r.md"
    again = run("detect", logs[1], "-c", cal, "--report", md, "--no-summary")
    assert again.exit_code == 0 and "No collision in 1 log(s)" in md.read_text()
    assert summary.read_text() == text  # --no-summary: nothing appended


def test_report_errors(cal, twin_dataset, tmp_path, monkeypatch):
    log = twin_dataset / "test" / "test_0.mcap"
    assert_one_line_error(run("detect", log, "-c", cal, "--report", tmp_path / "r.pdf"), "--report")
    missing = tmp_path / "no" / "r.html"
    assert_one_line_error(run("detect", log, "-c", cal, "--report", missing), "folder")
    assert not missing.parent.exists()
    # without the plot extra: a clear error naming the extra, before any work
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    result = run("detect", log, "-c", cal, "--report", tmp_path / "r.html")
    assert_one_line_error(result, "twincd[plot]")
    assert not (tmp_path / "r.html").exists()


def test_missing_matplotlib_is_a_usage_error(monkeypatch):
    from twincd.reports.figures import pyplot

    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(UsageError, match=r"twincd\[plot\]"):
        pyplot()


def test_evaluate_report_and_junit_per_gate(cal, twin_dataset, tmp_path):
    html, xml, md = tmp_path / "e.html", tmp_path / "e.xml", tmp_path / "e.md"
    test = twin_dataset / "test"
    args = ["evaluate", test, "-c", cal, "--train", twin_dataset / "train"]
    args += ["--val", twin_dataset / "val", "-m", "proposed,naive-diff", "--no-summary"]
    result = run(*args, "--report", html, "--junit", xml, "--min-f1", "0.999", "--min-auc", "0.5")
    root = validate_junit(xml)
    names = [c.get("name") for c in root.iter("testcase")]
    assert names == [
        "proposed: F1 at its threshold >= 0.999",
        "proposed: AUC >= 0.5",
        "naive-diff: F1 at its threshold >= 0.999",
        "naive-diff: AUC >= 0.5",
    ]
    failed = {c.get("name") for c in root.iter("testcase") if c.find("failure") is not None}
    assert failed == {
        "proposed: F1 at its threshold >= 0.999",
        "naive-diff: F1 at its threshold >= 0.999",
    }
    assert all(f.get("type") == "gate" for f in root.iter("failure"))
    assert result.exit_code == 1, result.output
    page = html.read_text()
    assert "ROC" in page and "F1 against k" in page and page.count("<svg") == 1
    assert "proposed (AUC" in page and "naive-diff (AUC" in page
    assert run(*args, "--report", md).exit_code == 0
    assert "| proposed |" in md.read_text()


@pytest.fixture(scope="module")
def evaluation(twin_calibration, twin_dataset):
    """``evaluate -m proposed`` on the twin dataset's test logs, as the library returns it."""
    from twincd.evaluation.runner import evaluate

    calibration = Calibration.load(twin_calibration)
    return evaluate(
        sorted((twin_dataset / "test").iterdir()),
        ["proposed"],
        Setup.from_calibration(calibration),
        calibration=calibration,
    )


def test_evaluate_report_shows_event_metrics(evaluation, tmp_path):
    from twincd.evaluation.markdown import evaluation_markdown
    from twincd.reports import evaluation_html

    result = evaluation
    method = result.methods[0]
    assert method.roc and method.roc[0] == (0.0, 0.0) and method.roc[-1] == (1.0, 1.0)
    found = f"{method.events['events_detected']:g}/{method.events['events_total']:g}"
    text = evaluation_markdown(result)
    assert text.count("| method | events found |") == 1 and f"| proposed | {found} |" in text
    page = evaluation_html(result)
    assert "<h2>Events</h2>" in page and "events detected" in page  # table and bar chart
    from twincd.reports.figures import evaluation_figure

    fig = evaluation_figure(result)
    assert len(fig.axes) == 4  # ROC, F1 against k, event counts, delays
    assert_drawn(fig, tmp_path / "evaluate")


def test_evaluate_event_charts_keep_one_unit_per_axis(evaluation):
    """Counts and milliseconds never share an axis: each bar chart holds the metrics of one unit,
    says it on its y axis, and its bars are those metrics' values."""
    from twincd.reports.figures import evaluation_figure

    events = evaluation.methods[0].to_dict()
    counts = {"events detected": events["events_detected"], "false alarms": events["false_alarms"]}
    delays = {"median": events["delay_ms_median"], "p95": events["delay_ms_p95"]}
    fig = evaluation_figure(evaluation)
    charts = {}
    for ax in fig.axes:
        bars = [p for p in ax.patches if p.get_width() > 0]
        if bars:
            ticks = [t.get_text() for t in ax.get_xticklabels()]
            charts[ax.get_ylabel()] = dict(zip(ticks, [b.get_height() for b in bars], strict=True))
    assert charts == {"count": pytest.approx(counts), "ms": pytest.approx(delays)}
    fig.clf()


def test_evaluate_html_shows_gates_only_when_given(evaluation):
    from twincd.reports import evaluation_html

    no_gates = evaluation_html(evaluation)
    assert "Gates" not in no_gates and 'class="verdict' not in no_gates
    passed = evaluation_html(evaluation, gates=(0.0, 0.25))
    assert '<p class="verdict good">Gates passed: F1 at threshold ≥ 0, AUC ≥ 0.25</p>' in passed
    missed = evaluation_html(evaluation, ["proposed: F1 0.500 < 0.9"], gates=(0.9, None))
    assert '<p class="verdict bad">1 gate(s) missed</p>' in missed and "Gates passed" not in missed
    assert "<li>proposed: F1 0.500 &lt; 0.9</li>" in missed


def test_evaluate_cli_report_without_gates_claims_none(cal, twin_dataset, tmp_path):
    html = tmp_path / "e.html"
    args = ["evaluate", twin_dataset / "test", "-c", cal, "--no-summary", "--report", html]
    assert run(*args).exit_code == 0
    assert "Gates" not in html.read_text()
    assert run(*args, "--min-auc", "0.0").exit_code == 0
    assert "Gates passed: AUC ≥ 0" in html.read_text()


def test_fit_report_has_one_scatter_per_joint(twin_dataset, tmp_path):
    html = tmp_path / "f.html"
    result = run("fit", twin_dataset / "train", "-o", tmp_path / "c.json", "--report", html)
    assert result.exit_code == 0, result.output
    page = html.read_text()
    kind = json.loads((tmp_path / "c.json").read_text())["model"]["kind"]  # the default model
    for joint in ("j1", "j2", "j3"):  # each panel names the joint and what was fitted
        assert f"{joint}: a = " in page if kind.startswith("affine") else f"{joint}: {kind}" in page
    assert "R²" in page and str(tmp_path / "c.json") in page
    assert len(page) < 1_000_000  # the scatter is a raster inside the SVG
    md = tmp_path / "f.md"
    assert (
        run("fit", twin_dataset / "train", "-o", tmp_path / "c.json", "--report", md).exit_code == 0
    )
    assert "| j1 |" in md.read_text()


def test_thinned_pairs_stay_bounded():
    from twincd.prepare.frames import Frame
    from twincd.reports import ThinnedPairs

    pairs = ThinnedPairs(points=100)
    x = np.arange(10_000, dtype=float)[:, None]
    labels = np.zeros(10_000, dtype=bool)
    labels[5000:5100] = True
    for start in range(0, 10_000, 333):
        part = slice(start, start + 333)
        pairs.write(
            Frame({"sim_effort_f": x[part], "effort_f": 2 * x[part], "labels": labels[part]}), []
        )
    assert 100 <= len(pairs.twin) <= 200 and pairs.seen == 9900
    np.testing.assert_array_equal(pairs.measured, 2 * pairs.twin)
    assert not np.any((pairs.twin >= 5000) & (pairs.twin < 5100))  # labelled: left out
    merged = ThinnedPairs.merge([pairs, pairs])
    assert len(merged.twin) <= 200


def test_svg_text_is_an_inline_element():
    from twincd.reports.figures import pyplot, svg_text

    fig = pyplot().figure()
    fig.add_subplot().plot([0, 1], [1, 0])
    text = svg_text(fig)
    assert text.startswith("<svg") and "<?xml" not in text and "DOCTYPE" not in text
    assert io.StringIO(text).read().rstrip().endswith("</svg>")


def test_report_figures_come_back_from_worker_processes(cal, twin_dataset, tmp_path):
    html = tmp_path / "pool.html"
    logs = sorted((twin_dataset / "test").iterdir())
    result = run("detect", *logs, "-c", cal, "-j", "2", "--report", html, "--no-summary")
    assert result.exit_code == 1, result.output
    page = html.read_text()
    assert page.count("<svg") == len(logs)
    for log in logs:
        assert str(log) in page


def test_the_drawn_twin_is_what_the_model_predicts(sample_detection):
    """The figure's twin line is the calibration model's prediction (the identified model of the
    shipped calibration), not the affine part a⊙τ̂̃ + b of its coefficients."""
    from twincd.calibration.models import model_inputs
    from twincd.reports.envelope import Envelope

    cal, summary = sample_detection
    trace = summary.trace
    assert cal.model.kind == "identified-whitened" and trace is not None
    log = Setup.from_calibration(cal).prepare(
        SAMPLE_LOGS / "test" / "test_000.mcap", cal.model.features
    )
    d = len(cal.joint_names)
    lines = {}
    for name, values in (
        ("predicted", cal.model.predict(model_inputs(log))),
        ("affine", cal.model.a_ * log.sim_effort_f + cal.model.b_),
    ):
        envelope = Envelope(d, trace.envelope.columns)
        envelope.push(log.states.stamp_ns, values)
        lines[name] = [envelope.line(j)[1] for j in range(d)]
    farthest = 0.0
    for j in range(d):
        drawn = trace.twin(j)[1]
        np.testing.assert_allclose(drawn, lines["predicted"][j], rtol=0, atol=1e-9)
        farthest = max(farthest, float(np.max(np.abs(drawn - lines["affine"][j]))))
    assert farthest > 1.0  # N·m: the identified model's other terms are visible
