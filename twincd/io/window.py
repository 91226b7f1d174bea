"""A time window of a log (``--start`` / ``--end``): the stretch a run judges. Each bound is
seconds from the log's first sample (``12.5``) or, with an ``@``, an absolute time in seconds
since the epoch, as header stamps are (``@1695811234.5``). A window belongs to the run: it is
never recorded in a calibration. Samples before it still warm the filters and the derivative
(and, zero-phase, those after it finish the backward pass), so a sample in the window gets the
score it gets in the whole log; only the window's samples are judged."""

from __future__ import annotations

from dataclasses import dataclass
from decimal import Decimal, InvalidOperation

from twincd.errors import UsageError

__all__ = ["TimeBound", "TimeWindow"]

NS = 1_000_000_000


@dataclass(frozen=True)
class TimeBound:
    """One bound: ``ns`` from the log's first sample, or since the epoch (``absolute``), kept
    in integer nanoseconds (a time since the epoch has more digits than a float holds)."""

    ns_value: int
    absolute: bool = False

    @classmethod
    def of(cls, value: float | str, option: str) -> TimeBound:
        """``12.5``, ``"12.5"`` or ``"@1695811234.5"``; a ``UsageError`` naming ``option``
        for anything else."""
        text = str(value).strip()
        absolute = text.startswith("@")
        try:
            seconds = Decimal(text[1:] if absolute else text)
        except InvalidOperation:
            seconds = Decimal("NaN")
        if not seconds.is_finite() or seconds < 0:
            raise UsageError(
                f"time {value!r} is not a time in seconds",
                option,
                "give seconds from the log's first sample (12.5) or, after @, seconds since "
                "the epoch as the header stamps are (@1695811234.5)",
                option=option,
            )
        return cls(int((seconds * NS).to_integral_value()), absolute)

    @property
    def seconds(self) -> float:
        return self.ns_value / NS

    def ns(self, first_ns: int) -> int:
        """The bound as a stamp (ns), for a log whose first sample is at ``first_ns``."""
        return self.ns_value + (0 if self.absolute else first_ns)

    def __str__(self) -> str:
        return f"@{Decimal(self.ns_value) / NS}" if self.absolute else f"{self.seconds:g} s"


@dataclass(frozen=True)
class TimeWindow:
    """[start, end] of a log, either open."""

    start: TimeBound | None = None
    end: TimeBound | None = None

    @classmethod
    def of(cls, start: float | str | None, end: float | str | None) -> TimeWindow | None:
        """The window of ``--start`` and ``--end`` (None: neither given)."""
        if start is None and end is None:
            return None
        lo = None if start is None else TimeBound.of(start, "start")
        hi = None if end is None else TimeBound.of(end, "end")
        same_kind = lo is not None and hi is not None and lo.absolute == hi.absolute
        if same_kind and hi is not None and lo is not None and hi.ns_value <= lo.ns_value:
            raise UsageError(
                f"the window ends ({hi}) before it starts ({lo})",
                "end",
                "give an end after the start",
                option="start,end",
            )
        return cls(lo, hi)

    def bounds_ns(self, first_ns: int) -> tuple[int, int]:
        """[low, high] stamps, inclusive, for a log whose first sample is at ``first_ns``."""
        low = -(2**63) if self.start is None else self.start.ns(first_ns)
        high = 2**63 - 1 if self.end is None else self.end.ns(first_ns)
        return low, high

    def __str__(self) -> str:
        return f"[{self.start or 'the start'}, {self.end or 'the end'}]"
