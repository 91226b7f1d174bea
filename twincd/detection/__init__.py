"""Score, flag and group: the paper's residual score, per-sample flags, collision events — on
whole logs, streamed logs and live samples (one code path)."""

from twincd.detection.detect import (
    DetectionSummary,
    LogDetection,
    ScoringStage,
    detect_log,
)
from twincd.detection.events import Event, EventRules, EventTracker, find_events, runs
from twincd.detection.files import detect_streamed
from twincd.detection.online import OnlineDetector, OnlineResult
from twincd.detection.score import affine_score, residual
from twincd.frames import FrameSink

__all__ = [
    "DetectionSummary",
    "Event",
    "EventRules",
    "EventTracker",
    "FrameSink",
    "LogDetection",
    "OnlineDetector",
    "OnlineResult",
    "ScoringStage",
    "affine_score",
    "detect_log",
    "detect_streamed",
    "find_events",
    "residual",
    "runs",
]
