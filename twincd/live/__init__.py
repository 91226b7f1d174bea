"""Live detection on a running robot: ``watch`` (``twincd watch``) and its sources."""

from __future__ import annotations

from twincd.live.connect import open_source
from twincd.live.source import Arrival, Source, SourceError, SourceLost, Wanted
from twincd.live.watch import WatchEvent, WatchItem, WatchStatus, WatchSummary, watch

__all__ = [
    "Arrival",
    "Source",
    "SourceError",
    "SourceLost",
    "Wanted",
    "WatchEvent",
    "WatchItem",
    "WatchStatus",
    "WatchSummary",
    "open_source",
    "watch",
]
