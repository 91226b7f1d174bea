"""The bands a residual is judged in: contacts of every length, from 20 ms strikes to pushes of
seconds.

A contact's torque adds to the measured effort, so it shows in the residual r = τ − model(τ̂).
The calibration's low-pass filter (critically damped, 1.5 Hz: the **slow** band) keeps a push of
seconds whole and the residual's fast noise out, but it turns a 0.2 s, 27 N·m strike into a bump
of a few N·m. The **fast** band is the residual between that cut-off and a faster one,
LP_fast(r − LP_slow(r)): what the slow band leaves out, up to ``DEFAULT_FAST_CUTOFF_HZ``
(``twincd.defaults``), where a strike's energy is and the model's own mismatch (slow: a path
the fit never saw, a payload) is not. (The slow part is taken out before the fast filter, not
after: at a segment's end the two filters extrapolate a slow trend differently, and their
difference there was a false band-pass edge.) Each band has its own noise
(``twincd.calibration.score``) and the score is one number per sample over both.

A band is defined relative to the rate its filters run at (the samples', or a coarse grid's,
``twincd.prepare.grid``): the fast cut-off is at most ``FAST_RATE_FRACTION`` of that rate, and a
fast band that would not reach ``FAST_MIN_RATIO`` times the slow cut-off is dropped (and said by
whoever asks for it: a 10 Hz log has no room for one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from twincd.defaults import DEFAULT_FAST_CUTOFF_HZ
from twincd.signal.filters import LowPass
from twincd.signal.stream import DEFAULT_GAP_FACTOR, SegmentedStage
from twincd.types import FloatArray, IntArray

__all__ = [
    "FAST_MIN_RATIO",
    "FAST_RATE_FRACTION",
    "Band",
    "JumpMask",
    "fast_band",
    "fast_band_at",
    "fast_cutoff_hz",
    "slow_band",
]

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
    def filters(self) -> tuple[LowPass, ...]:
        return (self.high,) if self.low is None else (self.high, self.low)

    def apply(
        self, stamp_ns: IntArray, x: FloatArray, period_s: float, warmup: int = 0
    ) -> FloatArray:
        """The band of whole segments ``x`` (N, channels): its low-pass, or ``high`` of what
        ``low`` leaves (the streaming stages ``twincd.prepare.chain`` runs, fed at once)."""
        from twincd.signal.filters import StreamingLowPass
        from twincd.signal.stream import run_whole

        def through(lowpass: LowPass, values: FloatArray) -> FloatArray:
            return run_whole(StreamingLowPass(lowpass, period_s, warmup=warmup), stamp_ns, values)

        if self.low is None:
            return through(self.high, x)
        return through(self.high, x - through(self.low, x))

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
    high = min(DEFAULT_FAST_CUTOFF_HZ, FAST_RATE_FRACTION * fs)
    high = min(high, 0.95 * _critical_limit(fs))
    if high < FAST_MIN_RATIO * lowpass.cutoff_hz or not math.isfinite(high):
        return None
    return high


def _critical_limit(fs_hz: float) -> float:
    from twincd.signal.iir import critical_max_cutoff

    return critical_max_cutoff(FAST_ORDER, fs_hz)


def fast_band_at(lowpass: LowPass, fast_hz: float | None, period_s: float) -> Band | None:
    """The fast band up to ``fast_hz`` as far as samples every ``period_s`` allow
    (``fast_cutoff_hz``; None: no fast band asked for, or no room for one)."""
    if fast_hz is None:
        return None
    room = fast_cutoff_hz(lowpass, period_s)
    return None if room is None else fast_band(lowpass, min(room, fast_hz))


def fast_band(lowpass: LowPass, cutoff_hz: float) -> Band:
    """The band between the slow ``lowpass`` and a critically damped low-pass at ``cutoff_hz``,
    zero-phase or causal as the slow one."""
    high = replace(lowpass, cutoff_hz=float(cutoff_hz), order=FAST_ORDER, kind="critical")
    return Band("fast", high, lowpass)


class JumpMask(SegmentedStage):
    """1.0 for samples near a **jump** of the logged velocity: a one-period change of some
    joint's above its ``jump`` threshold ((D,), ``twincd.calibration.score``), within the fast
    band's reach (the settling time of its upper filter ``fast``) before (zero-phase) or after
    it; else 0.0. A robot that stops dead in one period draws a one-sample current impulse the
    twin cannot reproduce: the fast band is not judged around it. Segments cut at gaps as every
    stage cuts; zero-phase, a sample waits for the reach after it."""

    def __init__(
        self,
        jump: FloatArray,
        fast: LowPass,
        period_s: float,
        gap_factor: float = DEFAULT_GAP_FACTOR,
    ) -> None:
        super().__init__(period_s, gap_factor)
        from twincd.signal.filters import settling_samples

        self.jump = np.asarray(jump, dtype=np.float64)
        self.reach = max(1, settling_samples(fast.sos(1.0 / self.period_s)))
        self.causal = fast.causal
        self.lookahead = 0 if self.causal else self.reach
        self._reset()

    def _reset(self) -> None:
        self._last: FloatArray | None = None  # the segment's last velocity
        self._jumps = np.zeros(0, dtype=bool)  # from the oldest still needed
        self._base = 0  # segment index of ``_jumps[0]``
        self._next = 0  # segment index of the next sample to emit

    def _extend(self, t: IntArray, y: FloatArray) -> FloatArray:
        previous = y[:1] if self._last is None else self._last[None, :]
        change = np.abs(np.diff(np.concatenate((previous, y)), axis=0))
        self._last = y[-1].copy()
        self._jumps = np.concatenate((self._jumps, (change > self.jump[None, :]).any(axis=1)))
        known = self._base + len(self._jumps)
        return self._emit(known if self.causal else known - self.reach)

    def _end_segment(self) -> FloatArray:
        out = self._emit(self._base + len(self._jumps))
        self._reset()
        return out

    def _emit(self, stop: int) -> FloatArray:
        """Samples [next, stop) of the segment: 1.0 where a jump lies within reach."""
        index = np.arange(self._next, max(stop, self._next))
        if not len(index):
            return np.zeros((0, 1))
        at = np.flatnonzero(self._jumps) + self._base
        after = self.reach if not self.causal else 0
        # a jump at j covers samples [j − after, j + reach]
        lo = np.searchsorted(at, index - self.reach, side="left")
        hi = np.searchsorted(at, index + after, side="right")
        near = (hi > lo).astype(np.float64)[:, None]
        self._next = int(index[-1]) + 1
        keep = max(self._base, self._next - self.reach)  # the backward reach of what is next
        self._jumps = self._jumps[keep - self._base :]
        self._base = keep
        return near
