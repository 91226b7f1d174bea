"""Reports of ``detect``, ``evaluate`` and ``fit`` for people (Markdown, or one self-contained
HTML page with inline SVG figures) and for CI (a Markdown job summary), contract: Exit codes and
streams."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from twincd.errors import OutputError
from twincd.evaluation.markdown import (
    EVALUATION_COLUMNS,
    EVENT_COLUMNS,
    evaluation_markdown,
    evaluation_rows,
    markdown_table,
)
from twincd.evaluation.markdown import event_rows as event_rows_of
from twincd.reports import html
from twincd.reports.tables import event_columns, event_rows
from twincd.version import __version__

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.detection.detect import DetectionSummary
    from twincd.evaluation.results import Evaluation
    from twincd.reports.traces import ThinnedPairs

REPORT_SUFFIXES = (".md", ".html")


def check_report_kind(path: Path) -> None:
    if Path(path).suffix.lower() not in REPORT_SUFFIXES:
        raise OutputError(
            f"unknown report type {Path(path).suffix!r}",
            str(path),
            "name the report .md or .html",
            option="report",
        )


def write_text(path: Path, text: str) -> None:
    """Write a report whole or not at all."""
    from twincd.io.atomic import atomic_output

    with atomic_output(Path(path)) as stream:
        stream.write(text.encode("utf-8"))


def append_step_summary(markdown: str, environ: dict[str, str] | None = None) -> Path | None:
    """Append to the GitHub Actions job summary when ``GITHUB_STEP_SUMMARY`` names a file."""
    target = (os.environ if environ is None else environ).get("GITHUB_STEP_SUMMARY")
    if not target:
        return None
    try:
        with open(target, "a", encoding="utf-8") as stream:
            stream.write(markdown.rstrip("\n") + "\n\n")
    except OSError as exc:
        raise OutputError(
            f"cannot append the job summary: {exc.strerror}",
            target,
            "check GITHUB_STEP_SUMMARY, or turn the summary off",
            option="no_summary",
        ) from None
    return Path(target)


# ------------------------------------------------------------------ settings


def calibration_settings(cal: Calibration) -> list[tuple[str, str]]:
    """What a reader needs to reproduce the result: calibration, robot, filter, threshold."""
    lp = cal.lowpass
    rows = [
        ("calibration", cal.source or "(in memory)"),
        ("robot", cal.robot or "default"),
        ("joints", ", ".join(cal.joint_names)),
        ("filter", lp.describe()),
        ("topic", cal.options.topic),
        ("fit logs", f"{len(cal.fit.logs)} ({cal.fit.samples} samples)"),
    ]
    if cal.threshold is not None:
        th = cal.threshold
        rows.append(
            (
                "threshold",
                f"μ + {th.k_sigma:g}σ = {th.value:.6g} (μ = {th.mu:.6g}, σ = {th.sigma:.6g}, "
                f"{th.samples} samples)",
            )
        )
    return rows


def _settings_html(settings: Sequence[tuple[str, str]]) -> str:
    rows = [*settings, ("twincd", __version__)]
    table = html.table(("setting", "value"), rows, cls="settings")
    return table + f"<footer>twincd {__version__}</footer>"


def _settings_markdown(settings: Sequence[tuple[str, str]]) -> str:
    rows = [*settings, ("twincd", __version__)]
    return markdown_table(("setting", "value"), rows)


# ------------------------------------------------------------------ detect


def _detect_verdict(summaries: Sequence[DetectionSummary]) -> tuple[bool, str]:
    hit = [s for s in summaries if s.events]
    events = sum(len(s.events) for s in summaries)
    if hit:
        return True, f"Collision: {events} event(s) in {len(hit)} of {len(summaries)} log(s)"
    return False, f"No collision in {len(summaries)} log(s)"


def _log_line(s: DetectionSummary) -> str:
    coverage = s.coverage()
    return (
        f"{len(s.events)} collision event(s), {s.collision_samples} of {s.samples} "
        f"samples flagged (threshold {s.threshold:.6g})" + (f"; {coverage}" if coverage else "")
    )


def detection_markdown(
    summaries: Sequence[DetectionSummary], settings: Sequence[tuple[str, str]] = ()
) -> str:
    found, text = _detect_verdict(summaries)
    parts = ["## twincd detect", "", f"**{'❌' if found else '✅'} {text}**", ""]
    for s in summaries:
        parts += [f"### {s.source}", "", _log_line(s), ""]
        if s.events:
            parts += [markdown_table(event_columns(s), event_rows(s)), ""]
    if settings:
        parts += ["<details><summary>Settings</summary>", "", _settings_markdown(settings), ""]
        parts += ["</details>", ""]
    return "\n".join(parts)


def detection_html(
    summaries: Sequence[DetectionSummary], settings: Sequence[tuple[str, str]] = ()
) -> str:
    from twincd.reports.figures import detection_figure, svg_text
    from twincd.reports.traces import DetectionTrace

    found, text = _detect_verdict(summaries)
    summary = [html.verdict(text, found)]
    figures = []
    for i, s in enumerate(summaries, 1):
        summary.append(f"<h2>{html.escape(s.source)}</h2><p>{html.escape(_log_line(s))}</p>")
        if s.events:
            summary.append(html.table(event_columns(s), event_rows(s), cls="events"))
        if isinstance(s.trace, DetectionTrace):
            figures.append(html.figure(svg_text(detection_figure(s, s.trace)), f"{i}. {s.source}"))
    return html.page("twincd detect", summary, figures, _settings_html(settings))


def detection_report(
    path: Path,
    summaries: Sequence[DetectionSummary],
    settings: Sequence[tuple[str, str]] = (),
) -> None:
    if Path(path).suffix.lower() == ".html":
        write_text(path, detection_html(summaries, settings))
    else:
        write_text(path, detection_markdown(summaries, settings))


# ------------------------------------------------------------------ evaluate


Gates = tuple[float | None, float | None]
"""The gates of ``evaluate`` as given: (``--min-f1``, ``--min-auc``), ``None`` when not given."""


def gate_texts(gates: Gates) -> list[str]:
    """The gates given, as people read them (``F1 ≥ 0.6``); empty when none was given."""
    min_f1, min_auc = gates
    texts = [] if min_f1 is None else [f"F1 at threshold ≥ {min_f1:g}"]
    return texts + ([] if min_auc is None else [f"AUC ≥ {min_auc:g}"])


def _gate_verdict(missed: Sequence[str], gates: Gates) -> list[str]:
    """The gates' verdict: missed, passed (naming the gates), or nothing when none was given."""
    if missed:
        return [html.verdict(f"{len(missed)} gate(s) missed", True)]
    given = gate_texts(gates)
    return [html.verdict(f"Gates passed: {', '.join(given)}", False)] if given else []


def evaluation_html(
    result: Evaluation,
    missed: Sequence[str] = (),
    settings: Sequence[tuple[str, str]] = (),
    gates: Gates = (None, None),
) -> str:
    from twincd.reports.figures import evaluation_figure, svg_text

    summary = [
        *_gate_verdict(missed, gates),
        f"<p>{len(result.test_logs)} test log(s), {result.samples} samples, "
        f"{result.positives} labelled as collision.</p>",
        html.table(EVALUATION_COLUMNS, evaluation_rows(result)),
    ]
    rows = event_rows_of(result)
    if rows:
        summary += ["<h2>Events</h2>", html.table(EVENT_COLUMNS, rows)]
    notes = [f"{m.name}: {m.note}" for m in result.methods if m.note]
    notes += [f"{m.name} skipped: {m.skipped}" for m in result.methods if m.skipped]
    if missed:
        summary += ["<h2>Gates missed</h2><ul>"]
        summary += [f"<li>{html.escape(m)}</li>" for m in missed] + ["</ul>"]
    if notes:
        summary += ["<ul>"] + [f"<li>{html.escape(n)}</li>" for n in notes] + ["</ul>"]
    caption = "ROC curves and F1 against k" + (", event counts and delays" if rows else "")
    figures = [html.figure(svg_text(evaluation_figure(result)), caption)]
    all_settings = [
        *settings,
        ("test logs", ", ".join(result.test_logs)),
        ("train logs", ", ".join(result.train_logs) or "none"),
        ("validation logs", ", ".join(result.val_logs) or "none"),
    ]
    return html.page("twincd evaluate", summary, figures, _settings_html(all_settings))


def evaluation_report(
    path: Path,
    result: Evaluation,
    missed: Sequence[str] = (),
    settings: Sequence[tuple[str, str]] = (),
    gates: Gates = (None, None),
) -> None:
    if Path(path).suffix.lower() == ".html":
        write_text(path, evaluation_html(result, missed, settings, gates))
    else:
        write_text(path, evaluation_markdown(result, missed))


# ------------------------------------------------------------------ fit


def fit_rows(cal: Calibration) -> list[list[str]]:
    model = cal.model
    r2, rmse = model.r2_, model.rmse_
    return [
        [
            name,
            f"{model.a_[i]:.3f}",
            f"{model.b_[i]:+.3f}",
            "n/a" if r2 is None else f"{r2[i]:.3f}",
            "n/a" if rmse is None else f"{rmse[i]:.3g}",
        ]
        for i, name in enumerate(cal.joint_names)
    ]


FIT_COLUMNS = ("joint", "a", "b", "R²", "RMSE (N·m)")


def fit_markdown(cal: Calibration) -> str:
    return "\n".join(
        [
            "## twincd fit",
            "",
            f"Affine twin calibration from {len(cal.fit.logs)} log(s), {cal.fit.samples} samples.",
            "",
            markdown_table(FIT_COLUMNS, fit_rows(cal)),
            "",
            _settings_markdown(calibration_settings(cal)),
            "",
        ]
    )


def fit_html(cal: Calibration, pairs: ThinnedPairs | None) -> str:
    summary = [
        f"<p>Affine twin calibration from {len(cal.fit.logs)} log(s), "
        f"{cal.fit.samples} samples.</p>",
        html.table(FIT_COLUMNS, fit_rows(cal)),
    ]
    figures = []
    if pairs is not None:
        from twincd.reports.figures import fit_figure, svg_text

        figures.append(html.figure(svg_text(fit_figure(cal, pairs)), "measured against twin"))
    return html.page("twincd fit", summary, figures, _settings_html(calibration_settings(cal)))


def fit_report(path: Path, cal: Calibration, pairs: ThinnedPairs | None) -> None:
    if Path(path).suffix.lower() == ".html":
        write_text(path, fit_html(cal, pairs))
    else:
        write_text(path, fit_markdown(cal))
