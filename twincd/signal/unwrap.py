"""Positions made continuous before they are differentiated (contract: Inputs).

Continuous joints (a wrist that turns without end) are often reported in (−π, π]: their
position jumps by 2π where it wraps, and a derivative of it sees a spike of 2π over one sample
(a false velocity, a false acceleration, a false alarm). Between two samples a joint moves far
less than π, so a step of more than π is a wrap when it lies within ``WRAP_TOLERANCE`` of a
whole number of turns (its rest being the joint's motion), on any joint, whatever the robot
model says (a URDF's continuous joint wraps so; one that claims limits may too). A step of more
than π that is not a whole number of turns cannot be a wrap: it is kept, counted and named (a
glitch, or two joints' values swapped). The unwrapped position only feeds the derivative: the
twin and the outputs keep the logged one (the dynamics are periodic in it).

Whole turns are counted in integers, so the result does not depend on how the stream is cut
into blocks; the count restarts with every segment (after a gap the derivative restarts too).
"""

from __future__ import annotations

import math

import numpy as np

from twincd.signal.stream import DEFAULT_GAP_FACTOR, SegmentedStage, nominal_period, run_whole
from twincd.types import FloatArray, IntArray

__all__ = ["WRAP_TOLERANCE", "StreamingUnwrap", "unwrap_positions"]

TURN = 2.0 * math.pi
# the most a joint moves between two samples besides its wrap: 0.79 rad (45°), e.g. 7.9 rad/s
# at 10 Hz, beyond any arm's joint speed at the rates logs are recorded at
WRAP_TOLERANCE = math.pi / 4


class StreamingUnwrap(SegmentedStage):
    """Unwraps (n,) or (n, joints) positions pushed in chunks of any size; no delay.

    ``wraps`` counts the wraps per joint, ``jumps`` the steps of more than π that are not a
    wrap, ``largest_jump`` the largest of those (rad) and ``first_jump_ns`` the stamp of the
    first (-1: none)."""

    def __init__(
        self,
        period_s: float,
        gap_factor: float = DEFAULT_GAP_FACTOR,
        tolerance: float = WRAP_TOLERANCE,
    ) -> None:
        super().__init__(period_s, gap_factor)
        self.tolerance = float(tolerance)
        self._last: FloatArray | None = None  # the segment's last logged position
        self._turns: IntArray | None = None  # whole turns taken off, per joint
        self.wraps: IntArray = np.zeros(0, dtype=np.int64)
        self.jumps: IntArray = np.zeros(0, dtype=np.int64)
        self.largest_jump: FloatArray = np.zeros(0)
        self.first_jump_ns: IntArray = np.zeros(0, dtype=np.int64)

    def _extend(self, t: IntArray, y: FloatArray) -> FloatArray:
        k = y.shape[1]
        if len(self.wraps) != k:
            self.wraps = np.zeros(k, dtype=np.int64)
            self.jumps = np.zeros(k, dtype=np.int64)
            self.largest_jump = np.zeros(k)
            self.first_jump_ns = np.full(k, -1, dtype=np.int64)
        before = y[:1] if self._last is None else self._last[None]
        step = np.diff(np.concatenate((before, y)), axis=0)
        turns = np.rint(step / TURN)
        rest = step - turns * TURN
        large = np.abs(step) > math.pi
        wrap = large & (np.abs(rest) <= self.tolerance)
        jump = large & ~wrap
        taken = np.cumsum(np.where(wrap, turns, 0.0).astype(np.int64), axis=0)
        if self._turns is not None:
            taken += self._turns
        self._turns, self._last = taken[-1].copy(), y[-1].copy()
        self.wraps += wrap.sum(axis=0)
        if jump.any():
            self.jumps += jump.sum(axis=0)
            self.largest_jump = np.maximum(self.largest_jump, np.where(jump, abs(step), 0).max(0))
            first = np.where(jump.any(axis=0), t[np.argmax(jump, axis=0)], -1)
            self.first_jump_ns = np.where(self.first_jump_ns < 0, first, self.first_jump_ns)
        out: FloatArray = y - TURN * taken
        return out

    def _end_segment(self) -> FloatArray:
        self._last = self._turns = None
        return np.zeros((0, max(self._width, 1)))


def unwrap_positions(stamp_ns: IntArray, position: FloatArray) -> FloatArray:
    """A whole log's positions unwrapped (``StreamingUnwrap`` fed it at once)."""
    ns = np.asarray(stamp_ns, dtype=np.int64)
    if len(ns) < 2:
        return np.asarray(position, dtype=np.float64)
    return run_whole(StreamingUnwrap(nominal_period(ns)), ns - ns[0], position)
