"""What a watch session yields (``twincd.live.watch``): ``WatchEvent``, ``WatchStatus``,
``WatchNotice`` and, last, one ``WatchSummary``; each as its ``--json`` line (``to_dict``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Union

from twincd.detection.events import Event

__all__ = ["WatchEvent", "WatchItem", "WatchNotice", "WatchStatus", "WatchSummary"]


@dataclass(frozen=True)
class WatchEvent:
    """A collision event, once it closed."""

    event: Event
    segment: int

    def to_dict(self) -> dict[str, object]:
        return {"type": "event", **self.event.to_dict(), "segment": self.segment}


@dataclass(frozen=True)
class WatchStatus:
    """How the session goes (every ``status_every_s``)."""

    elapsed_s: float
    samples: int
    rate_hz: float  # samples scored per second over the last interval
    latency_ms: float  # median over the last interval (NaN when nothing was scored)
    score: float  # the latest score (NaN before the first)
    threshold: float
    events: int
    segment: int

    def to_dict(self) -> dict[str, object]:
        return {"type": "status", **self.__dict__}


@dataclass(frozen=True)
class WatchNotice:
    """Something the session says as it goes, in one line (``text``): ``kind`` "source gone"
    (the source went away; it is waited for up to the connect timeout), "source back" (it
    came back, ``away_s`` later) or "rate" (it is sampled at another rate than the
    calibration: the filter and the gap rule follow the calibration's)."""

    kind: str
    text: str
    elapsed_s: float
    away_s: float | None = None

    @property
    def warning(self) -> bool:
        """Whether it is a warning (else a note: the source is back)."""
        return self.kind != "source back"

    def to_dict(self) -> dict[str, object]:
        return {"type": "notice", **self.__dict__}


@dataclass(frozen=True)
class WatchSummary:
    """The end of the session."""

    samples: int
    events: int
    collision: bool
    ended: str  # "duration", "interrupted", "idle", "stopped", "source lost"
    elapsed_s: float
    segments: int
    late: int
    duplicates: int
    unusable: int  # JointState messages without the calibrated joints, ragged or undecodable
    skipped: int  # samples the detector skipped (non-finite values)
    judged: int
    flagged: int
    latency_ms: dict[str, float] = field(default_factory=dict)  # p50, p95, p99, max
    filter_delay_ms: float = float("nan")
    error: str = ""
    reconnects: int = 0  # times the source went away and came back

    def to_dict(self) -> dict[str, object]:
        return {"type": "summary", **self.__dict__}


WatchItem = Union[WatchEvent, WatchStatus, WatchNotice, WatchSummary]  # noqa: UP007 - Python 3.10
