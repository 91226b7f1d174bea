"""What people look at and what CI reads (contract: Exit codes and streams): figures (matplotlib,
the ``plot``
extra), Markdown and self-contained HTML reports, JUnit XML and the GitHub job summary; the
figure data of long logs collected while they stream, at bounded memory."""

from twincd.reports.documents import (
    REPORT_SUFFIXES,
    append_step_summary,
    calibration_settings,
    check_report_kind,
    detection_html,
    detection_markdown,
    detection_report,
    evaluation_html,
    evaluation_report,
    fit_html,
    fit_markdown,
    fit_report,
)
from twincd.reports.envelope import Envelope
from twincd.reports.junit import Case, detection_junit, evaluation_junit, junit_xml
from twincd.reports.tables import EVENT_COLUMNS, event_columns, event_rows
from twincd.reports.traces import DetectionTrace, ThinnedPairs

__all__ = [
    "EVENT_COLUMNS",
    "REPORT_SUFFIXES",
    "Case",
    "DetectionTrace",
    "Envelope",
    "ThinnedPairs",
    "append_step_summary",
    "calibration_settings",
    "check_report_kind",
    "detection_html",
    "detection_junit",
    "detection_markdown",
    "detection_report",
    "evaluation_html",
    "evaluation_junit",
    "evaluation_report",
    "event_columns",
    "event_rows",
    "fit_html",
    "fit_markdown",
    "fit_report",
    "junit_xml",
]
