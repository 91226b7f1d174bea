"""Figures with matplotlib (the ``twincd[plot]`` extra): a detected log, an evaluation, a fit.

matplotlib is imported inside these functions only (≈ 0.3–0.5 s and ≈ 80 MB with its
dependencies), so ``twincd --help`` and installs without plots stay light. Each function returns
a matplotlib ``Figure``; ``svg_text`` and ``save`` turn it into SVG text or a PNG/SVG file.
"""

from __future__ import annotations

import io
import itertools
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from twincd.errors import UsageError

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.detection.detect import DetectionSummary
    from twincd.evaluation.results import Evaluation
    from twincd.reports.traces import DetectionTrace, ThinnedPairs

WIDTH_IN = 10.0
DPI = 100  # 1000 pixels wide: one envelope column per pixel
# the event metrics drawn, one chart per unit: (metrics as (key, label), title, unit)
EVENT_CHARTS = (
    (
        (("events_detected", "events detected"), ("false_alarms", "false alarms")),
        "events at the threshold",
        "count",
    ),
    (
        (("delay_ms_median", "median"), ("delay_ms_p95", "p95")),
        "detection delay",
        "ms",
    ),
)
EVENT_METRICS = tuple(metric for metrics, _, _ in EVENT_CHARTS for metric in metrics)


def pyplot() -> Any:
    """matplotlib's pyplot on the file-only Agg backend, or a clear error when not installed
    or not importable (pyplot too: a check before the work must import what the work uses)."""
    try:
        import matplotlib

        matplotlib.use("Agg", force=True)
        import matplotlib.backends.backend_svg
        import matplotlib.patches
        import matplotlib.pyplot as plt
    except ImportError as exc:
        missing = exc.name or "a part"
        raise UsageError(
            "figures need matplotlib, which is not installed"
            if missing == "matplotlib"
            else f"figures need matplotlib, whose {missing} cannot be imported",
            "report",
            "install twincd's plot extra: pip install 'twincd[plot]'",
            option="report",
        ) from None
    return plt


def _figure(rows: int, cols: int, height_in: float, **kwargs: Any) -> tuple[Any, Any]:
    plt = pyplot()
    # SVG text stays text (small, searchable); no hash salt, so output is reproducible
    plt.rcParams.update({"svg.fonttype": "none", "svg.hashsalt": "twincd", "font.size": 9})
    fig, axes = plt.subplots(
        rows, cols, figsize=(WIDTH_IN, height_in), dpi=DPI, squeeze=False, **kwargs
    )
    return fig, axes


def event_label(joint: str, link: str | None) -> str:
    return joint if not link else f"{joint} / {link}"


def detection_figure(summary: DetectionSummary, trace: DetectionTrace) -> Any:
    """Per joint: measured effort against the calibrated twin; below, the score against its
    threshold; labelled spans (when the log has labels) and detected events shaded, each event
    named by its joint (and link, when known)."""
    d = len(trace.joint_names)
    fig, axes = _figure(d + 1, 1, 1.0 * (d + 1) + 0.8, sharex=True)
    axes = axes[:, 0]
    t0 = trace.first_ns or summary.first_stamp_ns
    events = [((e.start_ns - t0) * 1e-9, (e.end_ns - t0) * 1e-9, e) for e in summary.events]
    labels = trace.label_spans()
    seconds = trace.seconds()
    min_width = 2 * (float(seconds[-1]) if len(seconds) else 0.0) / (WIDTH_IN * DPI) or 1e-3
    for j, name in enumerate(trace.joint_names):
        ax = axes[j]
        ax.plot(*trace.measured(j), lw=0.7, color="tab:blue", label="measured τ̃")
        ax.plot(*trace.twin(j), lw=0.7, color="tab:orange", label="twin (the model's prediction)")
        ax.set_ylabel(f"{name}\n(N·m)", rotation=0, ha="right", va="center")
    ax = axes[d]
    x, y = trace.score()
    floor = trace.threshold * 1e-3
    ax.plot(x, np.clip(y, floor, None), lw=0.7, color="black", label="score")
    ax.axhline(trace.threshold, color="tab:red", lw=0.9, ls="--", label="threshold")
    ax.set_yscale("log")
    ax.set_ylabel("score", rotation=0, ha="right", va="center")
    ax.set_xlabel("time (s)")
    for ax in axes:
        for start, end in labels:
            ax.axvspan(start, end, color="tab:green", alpha=0.15, lw=0)
        for start, end, _ in events:
            # at least ~2 pixels wide: a short event on a long log stays visible
            ax.axvspan(start, max(end, start + min_width), color="tab:red", alpha=0.25, lw=0)
    for i, (start, _end, e) in enumerate(events[:30], 1):
        axes[0].annotate(
            f"{i}: {event_label(e.joint, e.link_text)}",
            (start, 1.0),
            xycoords=("data", "axes fraction"),
            xytext=(0, 2),
            textcoords="offset points",
            fontsize=7,
            color="tab:red",
            rotation=30,
        )
    from matplotlib.patches import Patch

    handles, names = axes[0].get_legend_handles_labels()
    handles += [Patch(color="tab:red", alpha=0.25)]
    names += ["detected event"]
    if labels:
        handles += [Patch(color="tab:green", alpha=0.15)]
        names += ["labelled collision"]
    handles += axes[d].get_legend_handles_labels()[0]
    names += axes[d].get_legend_handles_labels()[1]
    fig.legend(handles, names, loc="lower center", ncol=len(names), frameon=False)
    fig.suptitle(f"{summary.source}: {len(summary.events)} collision event(s)", y=0.995)
    fig.tight_layout(rect=(0, 0.03, 1, 0.96))
    return fig


def evaluation_figure(result: Evaluation) -> Any:
    """ROC curves of every method on one axis, F1 against k (μ + kσ) per method and, when the
    results carry event metrics, below them one bar chart per unit: event counts, delays in ms."""
    ran = [m for m in result.methods if m.skipped is None]
    with_events = [(m.name, event_metrics(m)) for m in ran if event_metrics(m)]
    rows = 2 if with_events else 1
    fig, axes = _figure(rows, 2, 3.8 * rows)
    roc, sweep = axes[0, 0], axes[0, 1]
    for m in ran:
        label = m.name if m.auc is None else f"{m.name} (AUC {m.auc:.3f})"
        if m.roc:
            fpr, tpr = zip(*m.roc, strict=True)
            roc.plot(fpr, tpr, lw=1.2, label=label)
        if m.sweep:
            ks, f1 = zip(*m.sweep, strict=True)
            sweep.plot(ks, f1, marker="o", ms=3, lw=1.2, label=m.name)
    roc.plot([0, 1], [0, 1], color="grey", lw=0.8, ls=":")
    roc.set(xlabel="false positive rate", ylabel="true positive rate", title="ROC")
    roc.set_xlim(0, 1)
    roc.set_ylim(0, 1.01)
    roc.legend(fontsize=7, loc="lower right")
    sweep.set(xlabel="k (threshold μ + kσ)", ylabel="F1", title="F1 against k")
    sweep.set_ylim(0, 1.01)
    sweep.legend(fontsize=7)
    if with_events:
        for ax, (metrics, title, unit) in zip(axes[1], EVENT_CHARTS, strict=True):
            _event_bars(ax, with_events, metrics, title, unit)
    fig.tight_layout()
    return fig


def _event_bars(
    ax: Any,
    methods: Sequence[tuple[str, dict[str, Any]]],
    metrics: Sequence[tuple[str, str]],
    title: str,
    unit: str,
) -> None:
    """Grouped bars: one group per metric (all in ``unit``), one bar per method."""
    width = 0.8 / len(methods)
    x = np.arange(len(metrics))
    for i, (name, values) in enumerate(methods):
        heights = [float(values.get(key) or 0.0) for key, _ in metrics]
        ax.bar(x + i * width, heights, width, label=name)
    ax.set_xticks(x + 0.4 - width / 2, [label for _, label in metrics])
    ax.set(title=title, ylabel=unit)
    ax.legend(fontsize=7)


def event_metrics(method: Any) -> dict[str, Any]:
    """The event metrics a method result carries (contract: Metrics), if any: read from its JSON
    form so that whichever way they are stored, they show."""
    if method.skipped is not None:
        return {}
    doc = method.to_dict()
    return {key: doc[key] for key, _ in EVENT_METRICS if doc.get(key) is not None}


def fit_figure(cal: Calibration, pairs: ThinnedPairs) -> Any:
    """Per joint: measured against twin effort (a thinned sample) and R²; for the affine models
    the fitted line a·τ̂̃ + b, which is what they predict. The friction and identified models
    predict from more than the twin's effort (friction, re-fitted inertia): no line of τ̂̃
    alone is their prediction, so none is drawn (the detect report draws their prediction)."""
    d = len(cal.joint_names)
    cols = min(4, d)
    rows = -(-d // cols)
    fig, axes = _figure(rows, cols, 2.6 * rows + 0.4)
    model = cal.model
    affine = model.name == "affine"
    for j, name in enumerate(cal.joint_names):
        ax = axes[j // cols, j % cols]
        x, y = pairs.twin[:, j], pairs.measured[:, j]
        # a raster inside the SVG: thousands of dots as vector marks would weigh megabytes
        ax.scatter(x, y, s=2, alpha=0.3, color="tab:blue", lw=0, rasterized=True)
        if len(x) and affine:
            line = np.array([x.min(), x.max()])
            ax.plot(line, model.a_[j] * line + model.b_[j], color="tab:red", lw=1)
        r2 = "" if model.r2_ is None else f"\nR² = {model.r2_[j]:.3f}"
        fitted = f"a = {model.a_[j]:.3f}, b = {model.b_[j]:+.3f}" if affine else model.kind
        ax.set_title(f"{name}: {fitted}{r2}", fontsize=8)
        ax.set_xlabel("twin τ̂̃ (N·m)")
        if j % cols == 0:
            ax.set_ylabel("measured τ̃ (N·m)")
    for k in range(d, rows * cols):
        axes[k // cols, k % cols].set_visible(False)
    fig.tight_layout()
    return fig


# no <metadata> block: its RDF names external namespaces, and a date makes output differ
SVG_METADATA = {"Date": None, "Creator": None, "Format": None, "Type": None}
_inline_figures = itertools.count()


def svg_text(fig: Any) -> str:
    """The figure as an inline ``<svg>`` element (no XML prolog, no DOCTYPE)."""
    buffer = io.StringIO()
    # several SVGs share one HTML page: a salt per figure keeps their clip-path ids apart
    with pyplot().rc_context({"svg.hashsalt": f"twincd-{next(_inline_figures)}"}):
        fig.savefig(buffer, format="svg", metadata=SVG_METADATA)
    pyplot().close(fig)
    text = buffer.getvalue()
    return text[text.index("<svg") :]


def save(fig: Any, path: Path, formats: Sequence[str] = ("png", "svg")) -> list[Path]:
    """Write the figure beside ``path`` in every format (``path`` with each suffix)."""
    written = []
    for fmt in formats:
        target = Path(path).with_suffix(f".{fmt}")
        fig.savefig(target, format=fmt, metadata=SVG_METADATA if fmt == "svg" else None)
        written.append(target)
    pyplot().close(fig)
    return written
