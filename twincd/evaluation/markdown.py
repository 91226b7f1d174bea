"""Markdown renderings of results (e.g. for a CI job summary); plain strings, no terminal code."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # types only: rendering needs neither scikit-learn nor the runner
    from twincd.evaluation.results import Evaluation, MethodResult


def fmt(value: float | None, digits: int = 3) -> str:
    """A figure for people; n/a when missing."""
    if value is None:
        return "n/a"
    return f"{value:.{digits}f}"


def seconds(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.2g}"


def with_std(m: MethodResult, key: str) -> str:
    show = seconds if key.endswith("_s") else fmt
    text = show(getattr(m, key))
    std = m.std.get(key)
    if m.repeats > 1 and std is not None:
        text += f" ± {show(std)}"
    return text


def threshold_text(k: float | None) -> str:
    if k is None:
        return "n/a"
    if k == 0:
        return "μ"
    return f"μ + {k:g}σ"


EVALUATION_COLUMNS = (
    "method",
    "best threshold",
    "F1 (best)",
    "AUC",
    "F1 @ threshold",
    "precision",
    "recall",
    "train (s)",
    "test (s)",
)
# the same columns, narrow enough for an 80-column terminal
SHORT_COLUMNS = ("method", "best", "F1", "AUC", "F1@thr", "prec.", "recall", "train s", "test s")


def evaluation_rows(result: Evaluation) -> list[list[str]]:
    """Table II rows as text cells (shared by the Markdown report and the terminal table)."""
    rows = []
    for m in result.methods:
        name = m.name if m.unit == "sample" else f"{m.name}*"
        if m.skipped is not None:
            # the reason goes below the table: a long cell would squeeze every column
            rows.append([name, "skipped"] + [""] * (len(EVALUATION_COLUMNS) - 2))
            continue
        rows.append(
            [
                name,
                threshold_text(m.best_k),
                with_std(m, "f1_best"),
                with_std(m, "auc"),
                with_std(m, "f1_at_threshold"),
                with_std(m, "precision_at_threshold"),
                with_std(m, "recall_at_threshold"),
                with_std(m, "train_s"),
                with_std(m, "test_s"),
            ]
        )
    return rows


EVENT_COLUMNS = (
    "method",
    "events found",
    "delay median (ms)",
    "delay p95 (ms)",
    "false alarms (/h)",
    "val false alarms (/h)",
    "presses with force found",
    "isolation",
)
SHORT_EVENT_COLUMNS = ("method", "found", "delay", "p95", "FA (/h)", "val FA", "force", "isol.")


def _count(m: MethodResult, found: str, total: str) -> str:
    a, b = m.events.get(found), m.events.get(total)
    if a is None or b is None:
        return "n/a"
    return f"{a:g}/{b:g}"


def _per_hour(m: MethodResult, count: str) -> str:
    n, rate = m.events.get(count), m.events.get(f"{count}_per_hour")
    if n is None:
        return "n/a"
    return f"{n:g} ({fmt(rate, 0)})"


def event_rows(result: Evaluation) -> list[list[str]]:
    """Event metrics (contract: Metrics) as text cells, one row per method that ran."""
    rows = []
    for m in result.methods:
        if m.skipped is not None:
            continue
        iso = m.events.get("isolation_accuracy")
        rows.append(
            [
                m.name if m.unit == "sample" else f"{m.name}*",
                _count(m, "events_detected", "events_total"),
                fmt(m.events.get("delay_ms_median"), 0),
                fmt(m.events.get("delay_ms_p95"), 0),
                _per_hour(m, "false_alarms"),
                _per_hour(m, "val_false_alarms"),
                _count(m, "force_events_detected", "force_events_total"),
                "n/a" if iso is None else f"{100 * iso:.0f} %",
            ]
        )
    return rows


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(c.replace("|", "\\|") for c in row) + " |" for row in rows]
    return "\n".join(lines)


def evaluation_markdown(result: Evaluation, missed: Sequence[str] = ()) -> str:
    """The evaluation as Markdown: summary, Table II, and any missed gates."""
    k = next((m.k_sigma for m in result.methods if m.skipped is None), None)
    parts = [
        "## twincd evaluate",
        "",
        f"{len(result.test_logs)} test log(s), {result.samples} samples, "
        f"{result.positives} labelled as collision. "
        f"Threshold: {threshold_text(k)}; F1 (best) over μ + iσ, i = 0, 0.1, …, 1, 2, 3, 4, 5.",
        "",
        markdown_table(EVALUATION_COLUMNS, evaluation_rows(result)),
        "",
        "Events at the threshold (a labelled event is found by a flag inside it or within "
        "200 ms after; delay from its first labelled sample; a false alarm is a run of flags "
        "away from every labelled event, per hour of unlabelled time):",
        "",
        markdown_table(EVENT_COLUMNS, event_rows(result)),
        "",
    ]
    if any(m.unit != "sample" for m in result.methods):
        parts += ["\\* judged per time window, not per sample.", ""]
    notes = [f"- {m.name}: {m.note}" for m in result.methods if m.note]
    notes += [f"- {m.name} skipped: {m.skipped}" for m in result.methods if m.skipped]
    if notes:
        parts += ["**Notes:**", "", *notes, ""]
    if missed:
        parts += ["**Gates missed:**", ""] + [f"- {m}" for m in missed] + [""]
    return "\n".join(parts)
