"""Live detection on a running robot: ``watch`` (``twincd watch``) and its sources."""

from __future__ import annotations

from twincd.live.connect import open_source
from twincd.live.items import WatchEvent, WatchItem, WatchNotice, WatchStatus, WatchSummary
from twincd.live.source import Arrival, Connection, Source, SourceError, SourceLost, Wanted
from twincd.live.watch import watch

__all__ = [
    "Arrival",
    "Connection",
    "Source",
    "SourceError",
    "SourceLost",
    "Wanted",
    "WatchEvent",
    "WatchItem",
    "WatchNotice",
    "WatchStatus",
    "WatchSummary",
    "open_source",
    "watch",
]
