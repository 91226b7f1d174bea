"""Events as rows of text, shared by the terminal table, Markdown, HTML and JUnit (light: no
heavy import, so the CLI may use it after any command)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from twincd.detection.detect import DetectionSummary

EVENT_COLUMNS = ("#", "start (s)", "end (s)", "duration (s)", "peak score", "joint", "link")
JOINT_ONLY = len(EVENT_COLUMNS) - 1  # the columns when no event names a link


def event_columns(summary: DetectionSummary) -> tuple[str, ...]:
    """The events table's header: the link column only when some event names a link."""
    if any(e.link_text for e in summary.events):
        return EVENT_COLUMNS
    return EVENT_COLUMNS[:JOINT_ONLY]


def event_rows(summary: DetectionSummary) -> list[list[str]]:
    """One row per event; times in seconds from the log's first sample."""
    t0 = summary.first_stamp_ns
    width = len(event_columns(summary))
    rows = [
        [
            str(i),
            f"{(e.start_ns - t0) * 1e-9:.3f}",
            f"{(e.end_ns - t0) * 1e-9:.3f}",
            f"{e.duration_s:.3f}",
            f"{e.peak_score:.4g}",
            e.joint,
            e.link_text,
        ]
        for i, e in enumerate(summary.events, 1)
    ]
    return [row[:width] for row in rows]
