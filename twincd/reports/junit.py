"""JUnit XML for CI systems (Jenkins, GitLab, GitHub test reporters), contract: Exit codes and
streams: ``detect``
gives one test case per log, failed when a collision is found; ``evaluate`` one per gate."""

from __future__ import annotations

import socket
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import TYPE_CHECKING

from twincd.reports.tables import event_columns, event_rows

if TYPE_CHECKING:
    from twincd.detection.detect import DetectionSummary
    from twincd.evaluation.results import Evaluation


@dataclass(frozen=True)
class Case:
    """One test case: passed, failed (``failure`` is the message) or skipped."""

    classname: str
    name: str
    failure: str | None = None
    details: str = ""
    skipped: str | None = None
    seconds: float = 0.0
    kind: str = "collision"  # the failure's type: what was found
    output: str = ""  # the case's <system-out>: what a reader should know beside the verdict


def junit_xml(suite: str, cases: Sequence[Case]) -> str:
    """``<testsuites>`` with one ``<testsuite>`` holding ``cases``; counts match the cases."""
    failures = sum(c.failure is not None for c in cases)
    skipped = sum(c.skipped is not None for c in cases)
    seconds = sum(c.seconds for c in cases)
    counts = {
        "tests": str(len(cases)),
        "failures": str(failures),
        "errors": "0",
        "skipped": str(skipped),
        "time": f"{seconds:.3f}",
    }
    root = ET.Element("testsuites", {"name": suite, **counts})
    node = ET.SubElement(
        root,
        "testsuite",
        {
            "name": suite,
            "id": "0",
            "hostname": socket.gethostname(),
            # Ant's format: local-less ISO time, no zone
            "timestamp": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%S"),
            **counts,
        },
    )
    for case in cases:
        element = ET.SubElement(
            node,
            "testcase",
            {"classname": case.classname, "name": case.name, "time": f"{case.seconds:.3f}"},
        )
        if case.failure is not None:
            failure = ET.SubElement(
                element, "failure", {"message": case.failure, "type": case.kind}
            )
            failure.text = case.details
        elif case.skipped is not None:
            ET.SubElement(element, "skipped", {"message": case.skipped})
        if case.output:
            ET.SubElement(element, "system-out").text = case.output
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, "unicode") + "\n"


def detection_cases(summaries: Sequence[DetectionSummary]) -> list[Case]:
    cases = []
    for s in summaries:
        failure = None
        details = ""
        if s.events:
            failure = f"{len(s.events)} collision event(s) in {s.source}"
            lines = [" | ".join(event_columns(s))]
            lines += [" | ".join(row) for row in event_rows(s)]
            details = "\n".join(lines)
        cases.append(Case("twincd.detect", s.source, failure, details, output=s.coverage() or ""))
    return cases


def detection_junit(summaries: Sequence[DetectionSummary]) -> str:
    return junit_xml("twincd detect", detection_cases(summaries))


def evaluation_cases(result: Evaluation, min_f1: float | None, min_auc: float | None) -> list[Case]:
    """One case per method and gate; with no gate, one per method (passed when it ran)."""
    cases = []
    for m in result.methods:
        gates: list[tuple[str, float | None, float | None]] = []
        if min_f1 is not None:
            gates.append((f"F1 at its threshold >= {min_f1:g}", m.f1_at_threshold, min_f1))
        if min_auc is not None:
            gates.append((f"AUC >= {min_auc:g}", m.auc, min_auc))
        if not gates:
            gates.append(("runs", None, None))
        for name, value, bound in gates:
            case_name = f"{m.name}: {name}"
            if m.skipped is not None:
                cases.append(Case("twincd.evaluate", case_name, skipped=m.skipped))
                continue
            failure = None
            if bound is not None and (value is None or value < bound):
                shown = "n/a" if value is None else f"{value:.3f}"
                at = f" at {m.judged_at}" if name.startswith("F1") and m.judged_at else ""
                failure = f"{m.name}: {name.split(' ')[0]} {shown}{at} < {bound:g}"
            seconds = m.test_s or 0.0
            cases.append(Case("twincd.evaluate", case_name, failure, seconds=seconds, kind="gate"))
    return cases


def evaluation_junit(result: Evaluation, min_f1: float | None, min_auc: float | None) -> str:
    return junit_xml("twincd evaluate", evaluation_cases(result, min_f1, min_auc))
