"""Collision events, for people to read: one push, one event (``EventRules``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from twincd.defaults import DEFAULT_EVENT_MERGE_MS, DEFAULT_EVENT_RELEASE
from twincd.types import BoolArray, FloatArray, IntArray

if TYPE_CHECKING:
    from twincd.detection.isolation import LinkIsolator


@dataclass(frozen=True)
class Event:
    """One collision event: from its first flag to its last held sample (indices inclusive)."""

    first: int
    last: int
    start_ns: int
    end_ns: int
    peak_score: float
    peak_ns: int
    joint: str  # the joint with the largest share of the event's Σ residual²
    link: str | None = None  # the link touched, when the evidence singles it out
    link_candidates: tuple[str, ...] = ()  # the links it may be, most likely first

    @property
    def samples(self) -> int:
        return self.last - self.first + 1

    @property
    def link_text(self) -> str:
        """The link as people read it: the named one, or its candidates ("link3 or link2?")."""
        if self.link or not self.link_candidates:
            return self.link or ""
        return " or ".join(self.link_candidates) + "?"

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9  # integer ns first: no float noise

    def to_dict(self) -> dict[str, object]:
        return {
            "start_ns": self.start_ns,
            "end_ns": self.end_ns,
            "duration_s": self.duration_s,
            "samples": self.samples,
            "peak_score": self.peak_score,
            "peak_ns": self.peak_ns,
            "joint": self.joint,
            "link": self.link,
            "link_candidates": list(self.link_candidates),
        }


# a flag up to this long after a labelled push still finds it, and an event this close to one is
# not a false alarm (contract: Metrics)
EVENT_TOLERANCE_NS = 200_000_000


def false_alarms(
    events: Sequence[Event],
    labelled_ns: Sequence[tuple[int, int]],
    tolerance_ns: int = EVENT_TOLERANCE_NS,
) -> int:
    """The events that touch no labelled span (first and last labelled stamp, ns) widened by
    ``tolerance_ns`` both ways: the one definition of a false alarm (``evaluate``'s metrics,
    ``threshold``'s count on its own logs)."""
    return len(false_alarm_events(events, labelled_ns, tolerance_ns))


def false_alarm_events(
    events: Sequence[Event],
    labelled_ns: Sequence[tuple[int, int]],
    tolerance_ns: int = EVENT_TOLERANCE_NS,
) -> list[Event]:
    """The events of ``false_alarms``: those that touch no labelled span."""
    if not labelled_ns:
        return list(events)
    spans = np.asarray(labelled_ns, dtype=np.int64).reshape(-1, 2)
    starts, ends = spans[:, 0] - tolerance_ns, spans[:, 1] + tolerance_ns
    return [e for e in events if not bool(np.any((starts <= e.end_ns) & (ends >= e.start_ns)))]


def allowed_false_alarms(per_hour: float, hours: float) -> int:
    """The most false alarms that ``hours`` of clean data may give under a budget of
    ``per_hour`` (its Poisson 95 % quantile: 3 in an hour at 1/h, 0 in a few minutes)."""
    from scipy import stats

    return int(stats.poisson.ppf(0.95, per_hour * hours))


class LabelSpans:
    """The labelled spans of a log whose labels arrive block by block: (first, last) stamp of
    each maximal run of labelled samples, a run across blocks counted once."""

    def __init__(self) -> None:
        self.spans: list[tuple[int, int]] = []
        self._open: int | None = None  # first stamp of a run still open at the last block's end
        self._last = 0  # the last sample's stamp

    def push(self, stamp_ns: IntArray, labels: BoolArray | None) -> None:
        if not len(stamp_ns):
            return
        lab = np.zeros(len(stamp_ns), bool) if labels is None else np.asarray(labels, bool)
        if self._open is not None and not lab[0]:
            self.spans.append((self._open, self._last))
            self._open = None
        for a, b in runs(lab):
            start = int(stamp_ns[a]) if self._open is None or a > 0 else self._open
            self._open = None
            if b == len(lab) - 1:
                self._open = start
            else:
                self.spans.append((start, int(stamp_ns[b])))
        self._last = int(stamp_ns[-1])

    def finish(self) -> list[tuple[int, int]]:
        if self._open is not None:
            self.spans.append((self._open, self._last))
            self._open = None
        return self.spans


def runs(flags: BoolArray) -> list[tuple[int, int]]:
    """(first, last) index pairs, inclusive, of every run of True."""
    f = np.asarray(flags, dtype=bool).astype(np.int8)
    edges = np.diff(np.concatenate(([0], f, [0])))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1) - 1
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


@dataclass(frozen=True)
class EventRules:
    """How flags become the events a person counts (one push, one event).

    - **hysteresis**: an event opens at the first sample whose score reaches the threshold and
      stays open while the score stays at or above the release level, ``μ + release × (threshold
      − μ)`` (μ: the clean score's mean): a score that dips below the threshold mid-push, but not
      to the release level, does not split the push;
    - **merging**: an event that opens within ``merge_ms`` of the end of the previous one
      continues it (a filter's ringing either side of a push, a push in two strokes).

    Both are in time or in score, never in samples, so 100 Hz and 1 kHz logs behave alike.
    ``release=1, merge_ms=0`` gives the maximal runs of flags. The per-sample flag stays score ≥
    threshold: an event may hold samples below the threshold (its release tail, a merged gap).
    """

    release: float = DEFAULT_EVENT_RELEASE
    merge_ms: float = DEFAULT_EVENT_MERGE_MS

    def __post_init__(self) -> None:
        if not (0.0 <= self.release <= 1.0 and 0.0 <= self.merge_ms < float("inf")):
            raise ValueError(f"event rules out of range: {self}")

    @property
    def merge_ns(self) -> int:
        return round(self.merge_ms * 1e6)

    def release_level(self, threshold: float, mu: float) -> float:
        """The score below which an open event ends."""
        return mu + self.release * (threshold - mu)

    def to_dict(self) -> dict[str, float]:
        return {"release": self.release, "merge_ms": self.merge_ms}


RUNS = EventRules(release=1.0, merge_ms=0.0)  # events = maximal runs of flags


class EventTracker:
    """Events from samples that arrive block by block, by ``EventRules``: an event still open at
    the end of a block continues into the next, and an event that ended within the merge gap of
    a block's end waits for the next block, so block boundaries never change an event.

    ``push`` takes the flags (score ≥ threshold) and ``hold`` (score ≥ release level): an event
    opens at a flag and lasts while ``hold`` (or a flag) does. State is one event (a few
    numbers, a per-joint sum and the residual at the peak score), whatever the log length.
    """

    def __init__(
        self,
        joint_names: Sequence[str],
        isolator: LinkIsolator | None = None,
        rules: EventRules = RUNS,
    ) -> None:
        self.joint_names = tuple(joint_names)
        self.isolator = isolator
        self.rules = rules
        self._offset = 0  # global index of the next sample
        self._open: dict[str, Any] | None = None  # the latest event, not yet closed

    def push(
        self,
        flags: BoolArray,
        scores: FloatArray,
        residual_: FloatArray,
        stamp_ns: IntArray,
        hold: BoolArray | None = None,
    ) -> list[Event]:
        """The events that closed within this block: an event closes once a sample arrives
        more than the merge gap after its last held sample without reopening it (or at
        ``finish``)."""
        flags = np.asarray(flags, dtype=bool)
        active = flags if hold is None else flags | np.asarray(hold, dtype=bool)
        n = len(flags)
        closed: list[Event] = []
        for first, last in runs(active):
            if first == 0 and self._holding():  # the open event goes on
                self._extend(self._part(first, last, scores, residual_, stamp_ns))
                continue
            flagged = np.flatnonzero(flags[first : last + 1])
            if not len(flagged):  # held but never reached the threshold: no event
                continue
            part = self._part(first + int(flagged[0]), last, scores, residual_, stamp_ns)
            if self._open is not None and not self._within_gap(part["start_ns"]):
                closed.append(self._close())
            if self._open is None:
                self._open = part
            else:  # within the merge gap of the previous event: one event
                self._extend(part)
        self._offset += n
        waiting = n and self._open is not None and not self._holding()
        if waiting and not self._within_gap(int(stamp_ns[-1])):  # the gap has passed
            closed.append(self._close())
        return closed

    def finish(self) -> list[Event]:
        """Close the event still open at the end of the log, if any."""
        return [self._close()] if self._open is not None else []

    def _holding(self) -> bool:
        """The open event held up to the last sample pushed."""
        return self._open is not None and self._open["last"] == self._offset - 1

    def _within_gap(self, stamp_ns: int) -> bool:
        assert self._open is not None
        gap: int = stamp_ns - self._open["end_ns"]
        return self.rules.merge_ns > 0 and gap <= self.rules.merge_ns

    def _part(
        self, first: int, last: int, scores: FloatArray, residual_: FloatArray, stamp_ns: IntArray
    ) -> dict[str, Any]:
        seg = slice(first, last + 1)
        peak = first + int(np.argmax(scores[seg]))
        return {
            "first": self._offset + first,
            "last": self._offset + last,
            "start_ns": int(stamp_ns[first]),
            "end_ns": int(stamp_ns[last]),
            "peak_score": float(scores[peak]),
            "peak_ns": int(stamp_ns[peak]),
            "share": (residual_[seg] ** 2).sum(axis=0),
            "at_peak": np.array(residual_[peak], dtype=np.float64),  # isolation's evidence
        }

    def _extend(self, part: dict[str, Any]) -> None:
        assert self._open is not None
        ev = self._open
        ev["last"], ev["end_ns"] = part["last"], part["end_ns"]
        ev["share"] = ev["share"] + part["share"]
        if part["peak_score"] > ev["peak_score"]:  # the first peak wins ties, as argmax does
            ev["peak_score"], ev["peak_ns"] = part["peak_score"], part["peak_ns"]
            ev["at_peak"] = part["at_peak"]

    def _close(self) -> Event:
        assert self._open is not None
        ev, self._open = self._open, None
        link, candidates = (
            (None, ()) if self.isolator is None else self.isolator.isolate(ev["at_peak"])
        )
        return Event(
            first=ev["first"],
            last=ev["last"],
            start_ns=ev["start_ns"],
            end_ns=ev["end_ns"],
            peak_score=ev["peak_score"],
            peak_ns=ev["peak_ns"],
            joint=self.joint_names[int(np.argmax(ev["share"]))],
            link=link,
            link_candidates=candidates,
        )


def find_events(
    flags: BoolArray,
    scores: FloatArray,
    residual_: FloatArray,
    stamp_ns: IntArray,
    joint_names: Sequence[str],
    isolator: LinkIsolator | None = None,
    rules: EventRules = RUNS,
    hold: BoolArray | None = None,
) -> list[Event]:
    """Events of a whole log; the joint is the one with the largest share of Σ residual²."""
    tracker = EventTracker(joint_names, isolator, rules)
    return tracker.push(flags, scores, residual_, stamp_ns, hold) + tracker.finish()
