"""Score, flag and group: the paper's residual score, per-sample flags and collision events."""

from twincd.detection.detect import LogDetection, detect
from twincd.detection.events import Event, find_events, runs
from twincd.detection.score import affine_score, residual

__all__ = ["Event", "LogDetection", "affine_score", "detect", "find_events", "residual", "runs"]
