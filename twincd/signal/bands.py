"""The bands a residual is judged in: contacts of every length, from 20 ms strikes to pushes of
seconds.

A contact's torque adds to the measured effort, so it shows in the residual r = τ − model(τ̂).
The calibration's low-pass filter (critically damped, 1.5 Hz: the **slow** band) keeps a push of
seconds whole and the residual's fast noise out, but it turns a 0.2 s, 27 N·m strike into a bump
of a few N·m. The **fast** band is the residual between that cut-off and a faster one,
LP_fast(r) − LP_slow(r): what the slow band leaves out, up to ``FAST_CUTOFF_HZ``, where a strike's
energy is and the model's own mismatch (slow: a path the fit never saw, a payload) is not. Each
band has its own noise (``twincd.calibration.score``) and the score is one number per sample over
both.

A band is defined relative to the rate its filters run at (the samples', or a coarse grid's,
``twincd.prepare.grid``): the fast cut-off is at most ``FAST_RATE_FRACTION`` of that rate, and a
fast band that would not reach ``FAST_MIN_RATIO`` times the slow cut-off is dropped (and said by
whoever asks for it: a 10 Hz log has no room for one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from twincd.signal.filters import LowPass

__all__ = [
    "FAST_CUTOFF_HZ",
    "FAST_MIN_RATIO",
    "FAST_RATE_FRACTION",
    "Band",
    "fast_band",
    "slow_band",
]

# the fast band's upper edge: where a hand strike's energy still is (a 0.1–0.7 s controller
# answer, 1–10 Hz), chosen on injected contacts of three real arms (docs/models-and-results.md)
FAST_CUTOFF_HZ = 10.0
# ... and at most this fraction of the rate the filters run at (10 Hz at 100 Hz)
FAST_RATE_FRACTION = 0.1
# a fast band whose upper edge is not at least this many times the slow cut-off is dropped
FAST_MIN_RATIO = 2.0
# the fast band's filter: critically damped (no ringing around a strike), of this order
FAST_ORDER = 2


@dataclass(frozen=True)
class Band:
    """A band of the residual: its ``high`` low-pass, minus its ``low`` one when it has one (a
    band between two cut-offs). ``name``: ``"slow"`` or ``"fast"``."""

    name: str
    high: LowPass
    low: LowPass | None = None

    @property
    def terms(self) -> tuple[tuple[int, LowPass], ...]:
        """The band as a sum of signed low-passes (``twincd.signal.edges.Terms``)."""
        return ((1, self.high),) if self.low is None else ((1, self.high), (-1, self.low))

    def describe(self) -> str:
        """For people: "1.5 Hz low-pass" or "1.5–10 Hz"."""
        if self.low is None:
            return f"{self.high.cutoff_hz:g} Hz low-pass"
        return f"{self.low.cutoff_hz:g}–{self.high.cutoff_hz:g} Hz"

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"name": self.name, "high": self.high.to_dict()}
        if self.low is not None:
            d["low"] = self.low.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Band:
        low = d.get("low")
        return cls(
            str(d["name"]),
            LowPass.from_dict(d["high"]),
            None if low is None else LowPass.from_dict(low),
        )


def slow_band(lowpass: LowPass) -> Band:
    """The calibration's own filter: the band pushes are judged in."""
    return Band("slow", lowpass)


def fast_cutoff_hz(lowpass: LowPass, run_period_s: float) -> float | None:
    """The fast band's upper cut-off for filters that run every ``run_period_s`` under the slow
    ``lowpass`` (None: the rate has no room for one, ``FAST_MIN_RATIO``)."""
    fs = 1.0 / run_period_s
    high = min(FAST_CUTOFF_HZ, FAST_RATE_FRACTION * fs)
    high = min(high, 0.95 * _critical_limit(fs))
    if high < FAST_MIN_RATIO * lowpass.cutoff_hz or not math.isfinite(high):
        return None
    return high


def _critical_limit(fs_hz: float) -> float:
    from twincd.signal.iir import critical_max_cutoff

    return critical_max_cutoff(FAST_ORDER, fs_hz)


def fast_band(lowpass: LowPass, cutoff_hz: float) -> Band:
    """The band between the slow ``lowpass`` and a critically damped low-pass at ``cutoff_hz``,
    zero-phase or causal as the slow one."""
    high = replace(lowpass, cutoff_hz=float(cutoff_hz), order=FAST_ORDER, kind="critical")
    return Band("fast", high, lowpass)
