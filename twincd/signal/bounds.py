"""Absurd values: samples no arm makes, dropped as data faults (contract: Inputs, bad samples).

A recorder glitch leaves finite values that NaN handling does not catch: positions of 253 rad on
three joints, an effort of 1e300 or 3.4e38 (float32's largest). Filtered with its neighbours, one
such sample raises an event seconds before it, overflows a score to ``inf``, or doubles a
threshold. ``SampleBounds`` judges each sample against bounds from the robot model's limits,
**causally** (from the samples before it only), so that a log read whole, streamed in any block
size, or pushed live sample by sample drops the same samples. A sample is absurd when one of its
values is

- a position beyond the joint's limits by more than the joint's range (at least π);
- a velocity beyond ``VELOCITY_BOUND`` × the joint's velocity limit;
- an effort (or the log's own twin effort) beyond ``EFFORT_BOUND`` × the joint's effort limit;

**and** that value lies further from the last sample kept than such a bound (for a position: the
margin plus what the joint travels at ``VELOCITY_BOUND`` × its velocity limit in the time between):
a jump no motor makes in one period. The second condition keeps a log recorded in other units,
degrees say, whose values are far out but continuous (``SignalChecks`` names those); the first
keeps every real motion, push and strike. A sample with nothing kept before it is compared with
the last sample read; the very first sample of a stream, with nothing before it, by the bounds
alone. Limits a URDF does not give (and every limit without a robot model) are taken as
``FALLBACK_VELOCITY`` and ``FALLBACK_EFFORT``.

**Jumps within the limits** (kind ``jump``): a recorder starting up can publish rows of other
states between real ones, every value within the limits (a real UR10e's first 0.2 s: joints
jumping 1.5 rad and back in 30 ms, efforts of 250 N·m at rest). A sample is absurd too when a
joint with limits, inside them (by ``STEP_MARGIN``) on both samples, lies further from the last
sample kept (modulo a turn: angles a driver wraps to ±π are no jump) than ``STEP_MARGIN`` plus
what it travels at ``STEP_SPEED`` × its velocity limit in between — unless it ends a run of
``STEP_RUN`` samples read, each within such a step of the one before: consistent motion, so the
sample kept before was the glitch (a stream that starts with one) and the run is kept from there.
At 100 Hz the margin alone is 10 rad/s over any limit.

Rows within the bounds that move less than such a step from the row before always pass, so the
check costs each block's column extremes and one difference of its positions; only the other rows
are judged one by one.

The dropped samples are counted with their times, and ``warning`` says so in one line.

**Drives off** (``drives_off``): a sample whose efforts are all exactly 0 on every joint (two or
more) measures nothing: a real arm's drives report some current on some joint at every instant,
gravity's at least, and a driver whose motors are off publishes zeros in their place (a
Doosan's log 22 s long, at rest, while its twin asks 60 N·m of joint 2). Compared with the twin,
such a stretch is one long event, and fitted, it triples a joint's noise: it is left out, its
spans counted and said in one line (``off_warning``). Not for a command that does not compare
efforts (``simulate``: a simulation's log without efforts is its input).
"""

from __future__ import annotations

import heapq
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from twincd.types import BoolArray, FloatArray, IntArray

log = logging.getLogger("twincd")

__all__ = [
    "EFFORT_BOUND",
    "FALLBACK_EFFORT",
    "FALLBACK_VELOCITY",
    "VELOCITY_BOUND",
    "DrivesOff",
    "Dropped",
    "SampleBounds",
]

VELOCITY_BOUND = 10.0  # × the velocity limit: no joint turns that fast
EFFORT_BOUND = 20.0  # × the effort limit (URDF limits are often nominal: a real push reached 6.5×)
FALLBACK_VELOCITY = 10.0  # rad/s: a joint whose model gives no velocity limit
FALLBACK_EFFORT = 1000.0  # N·m: a joint whose model gives no effort limit
EXAMPLES = 8  # times of dropped samples kept for the warning and inspect
# a jump within the limits: further than the margin plus STEP_SPEED × the velocity limit × the
# time since the last sample kept; STEP_RUN samples each within a step of the one before re-anchor
STEP_SPEED = 2.0
STEP_MARGIN = 0.1  # rad
STEP_RUN = 5

CHANNELS = ("position", "velocity", "effort", "sim_effort")
KINDS = (*CHANNELS, "jump")  # the kinds of absurd value named (``Dropped.joints``)


@dataclass
class DrivesOff:
    """The samples left out as drives off so far: how many, and the first spans' first and
    last times (seconds from the first sample judged)."""

    samples: int = 0
    spans: int = 0
    spans_s: list[list[float]] = field(default_factory=list)

    def to_dict(self) -> dict[str, object]:
        return {
            "samples": self.samples,
            "spans": self.spans,
            "spans_s": [list(s) for s in self.spans_s],
        }


@dataclass
class Dropped:
    """The absurd samples dropped so far: how many, the first ones' times (seconds from the
    first sample judged) and, per value kind, the joints that were beyond their bound."""

    samples: int = 0
    times_s: list[float] = field(default_factory=list)
    joints: dict[str, list[str]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, object]:
        return {"samples": self.samples, "times_s": list(self.times_s), "joints": dict(self.joints)}


def _limit(values: Mapping[str, float], names: Sequence[str], fallback: float) -> FloatArray:
    out = [float(values.get(n, math.nan)) for n in names]
    return np.array([v if math.isfinite(v) and v > 0 else fallback for v in out])


class SampleBounds:
    """The causal bound on one stream's samples (see the module docstring).

    ``position_limits`` maps a joint to its (lower, upper) limits (a joint it lacks is not
    bounded in position: a continuous joint); ``velocity_limits`` and ``effort_limits`` map a
    joint to its limit. Columns follow ``joint_names``.
    """

    def __init__(
        self,
        joint_names: Sequence[str],
        position_limits: Mapping[str, tuple[float, float]],
        velocity_limits: Mapping[str, float] | None = None,
        effort_limits: Mapping[str, float] | None = None,
        drives_off: bool = True,
    ) -> None:
        self.joint_names = tuple(joint_names)
        self.drives_off = drives_off and len(self.joint_names) >= 2
        self.off = DrivesOff()
        self._off_open = False  # the last sample read was off: its span goes on
        names = self.joint_names
        inf = (-math.inf, math.inf)
        lower = np.array([position_limits.get(n, inf)[0] for n in names], dtype=np.float64)
        upper = np.array([position_limits.get(n, inf)[1] for n in names], dtype=np.float64)
        margin = np.where(np.isfinite(upper - lower), np.maximum(upper - lower, math.pi), math.inf)
        limited = np.isfinite(margin)
        self._center = np.zeros(len(names))
        self._center[limited] = (lower[limited] + upper[limited]) / 2
        speed = VELOCITY_BOUND * _limit(velocity_limits or {}, names, FALLBACK_VELOCITY)
        effort = EFFORT_BOUND * _limit(effort_limits or {}, names, FALLBACK_EFFORT)
        # per channel: the half-width of the plausible band around its centre, which is also
        # the largest jump from the last kept sample
        self._bound = {
            "position": (upper - lower) / 2 + margin,
            "velocity": speed,
            "effort": effort,
            "sim_effort": effort,
        }
        self._jump = {"position": margin, "velocity": speed, "effort": effort, "sim_effort": effort}
        self._speed = speed  # the position's allowance per second since the last kept sample
        # the jump within the limits: per joint with limits, the band where it is judged and
        # the allowance per second (NaN bounds: a joint without limits is never judged)
        self._step_low = np.where(limited, lower - STEP_MARGIN, np.nan)
        self._step_high = np.where(limited, upper + STEP_MARGIN, np.nan)
        self._step_speed = STEP_SPEED * _limit(velocity_limits or {}, names, FALLBACK_VELOCITY)
        self._run = 0  # samples read up to the last, each within a step of the one before
        self._last_dropped = False  # the last sample read was dropped
        self._kept: dict[str, FloatArray] | None = None  # the last sample kept, per channel
        self._kept_ns = 0
        self._read: dict[str, FloatArray] | None = None  # the last sample read, per channel
        self._read_ns = 0
        self.first_ns: int | None = None
        self.dropped = Dropped()

    def keep(self, stamp_ns: IntArray, **values: FloatArray | None) -> BoolArray:
        """Which of these samples (finite, in stamp order) are kept; ``values``: ``position``,
        ``velocity``, ``effort``, ``sim_effort`` (N, joints), None or NaN where absent."""
        n = len(stamp_ns)
        ok = np.ones(n, dtype=bool)
        if not n:
            return ok
        if self.first_ns is None:
            self.first_ns = int(stamp_ns[0])
        columns = {c: v for c, v in values.items() if v is not None and c in self._bound}
        # each column's extremes first (a read of the block, no temporaries): the usual block
        # lies within every bound, and no row needs a look of its own
        beyond = {c: self._beyond(c, v) for c, v in columns.items() if self._outside(c, v)}
        stepped, run = self._steps(stamp_ns, columns.get("position"))
        if beyond or stepped.any() or self._last_dropped:
            must = stepped.copy()  # judged one by one
            must[0] |= self._last_dropped  # its previous sample is gone: judged alone
            suspects = must.copy()
            for b in beyond.values():
                suspects |= b.any(axis=1)
            ok = self._judge(stamp_ns, columns, beyond, (suspects, must), run)
        effort = columns.get("effort")
        if self.drives_off and effort is not None:
            ok &= ~self._off_rows(stamp_ns, effort, ok)
        kept = np.flatnonzero(ok)
        if len(kept):
            last = int(kept[-1])
            self._kept = {c: v[last].copy() for c, v in columns.items()}
            self._kept_ns = int(stamp_ns[last])
        self._read = {c: v[-1].copy() for c, v in columns.items()}
        self._read_ns = int(stamp_ns[-1])
        self._last_dropped = not bool(ok[-1])
        return ok

    def _steps(self, stamp_ns: IntArray, position: FloatArray | None) -> tuple[BoolArray, IntArray]:
        """(n,) the samples that jumped (``_stepped``) from the sample read before them, and (n,)
        how many samples up to each were read each within a step of the one before (itself
        counted; carried from the last block)."""
        n = len(stamp_ns)
        run = np.arange(1, n + 1) + self._run
        stepped: BoolArray = np.zeros(n, dtype=bool)
        if position is not None and n and np.isfinite(self._step_low).any():
            before = self._read.get("position") if self._read else None
            # each row's change from the row before: the raw difference is never below the
            # wrapped one, so only rows it marks are looked at again (the usual block: none)
            delta = np.empty_like(position)
            delta[0] = 0.0 if before is None else position[0] - before
            np.subtract(position[1:], position[:-1], out=delta[1:])
            dt = np.empty(n)
            dt[0] = 0.0 if before is None else max(int(stamp_ns[0]) - self._read_ns, 0) * 1e-9
            dt[1:] = np.maximum(np.diff(stamp_ns), 0) * 1e-9
            with np.errstate(invalid="ignore"):  # NaN: no value
                raw = np.abs(delta) > STEP_MARGIN + self._step_speed * dt[:, None]
            rows = np.flatnonzero(raw.any(axis=1))
            if len(rows):
                prev = position[np.maximum(rows - 1, 0)]
                if before is not None and rows[0] == 0:
                    prev[0] = before
                stepped[rows] = self._stepped(position[rows], prev, dt[rows, None]).any(axis=1)
            if stepped.any():
                starts = np.maximum.accumulate(np.where(stepped, np.arange(n), -1))
                run = np.where(starts >= 0, np.arange(n) - starts + 1, run)
        self._run = int(run[-1]) if n else self._run
        return stepped, run

    def _stepped(self, values: FloatArray, ref: FloatArray, dt_s: FloatArray | float) -> BoolArray:
        """Where a joint with limits, within them on ``values`` and ``ref``, lies further from
        ``ref`` (modulo a turn) than ``STEP_MARGIN`` plus ``STEP_SPEED`` × its velocity limit over
        ``dt_s``."""
        low, high = self._step_low, self._step_high
        with np.errstate(invalid="ignore"):  # NaN: no limits, or no value
            inside = (values >= low) & (values <= high) & (ref >= low) & (ref <= high)
            # a turn is no jump: a driver that wraps angles to ±π is unwrapped downstream
            step = np.abs(np.remainder(values - ref + math.pi, 2 * math.pi) - math.pi)
            far = step > STEP_MARGIN + self._step_speed * dt_s
        out: BoolArray = inside & far
        return out

    def _off_rows(self, stamp_ns: IntArray, effort: FloatArray, ok: BoolArray) -> BoolArray:
        """The rows (among ``ok``) whose efforts are all exactly 0, their spans noted."""
        if not (effort[:, 0] == 0).any():  # most blocks: none, at the cost of one column
            self._off_open = False
            return np.zeros(len(effort), dtype=bool)
        off: BoolArray = (effort == 0).all(axis=1) & ok
        rows = np.flatnonzero(off)
        if not len(rows):
            self._off_open = False
            return off
        self.off.samples += len(rows)
        first = self.first_ns or int(stamp_ns[0])
        # spans: runs of off rows, the first one continuing the last block's open span
        breaks = np.flatnonzero(np.diff(rows) > 1)
        starts = np.r_[rows[0], rows[breaks + 1]]
        ends = np.r_[rows[breaks], rows[-1]]
        spans = self.off.spans_s
        for k, (a, b) in enumerate(zip(starts.tolist(), ends.tolist(), strict=True)):
            end_s = round((int(stamp_ns[b]) - first) * 1e-9, 6)
            if k == 0 and a == 0 and self._off_open:
                if self.off.spans <= len(spans):  # the open span is among those kept
                    spans[-1][1] = end_s
                continue
            self.off.spans += 1
            if len(spans) < EXAMPLES:
                spans.append([round((int(stamp_ns[a]) - first) * 1e-9, 6), end_s])
        self._off_open = bool(off[-1])
        return off

    def _outside(self, channel: str, values: FloatArray) -> bool:
        """Whether any value of the block lies beyond its joint's bound (NaN never does): the
        block's extremes against the band every joint allows, then, only when they leave it,
        each joint against its own."""
        centre = self._center if channel == "position" else 0.0
        low, high = centre - self._bound[channel], centre + self._bound[channel]
        least, most = np.fmin.reduce(values, axis=None), np.fmax.reduce(values, axis=None)
        if not (least < low.max() or most > high.min()):
            return False
        return bool(((values < low) | (values > high)).any())

    def _beyond(self, channel: str, values: FloatArray) -> BoolArray:
        centre = self._center if channel == "position" else 0.0
        out: BoolArray = np.abs(values - centre) > self._bound[channel]
        return out

    def _judge(
        self,
        stamp_ns: IntArray,
        columns: dict[str, FloatArray],
        beyond: dict[str, BoolArray],
        suspects: tuple[BoolArray, BoolArray],
        run: IntArray,
    ) -> BoolArray:
        """Rows beyond a bound: dropped when the value also jumped from the last sample kept;
        rows that jumped within the limits (``_stepped``) from it, unless ``run`` says they end
        a run of steady samples. A row beyond a bound whose previous row is kept and within a
        jump of it is kept without a look of its own (a log in other units is such a run), so
        only rows after a jump or after a dropped row are judged one by one. ``suspects``: the rows
        that may be dropped, and those among them judged one by one whatever the look says."""
        n = len(stamp_ns)
        ok = np.ones(n, dtype=bool)
        steady = np.zeros(n, dtype=bool)  # within a jump of the previous row on every bound
        dt = np.maximum(np.diff(stamp_ns), 0).astype(np.float64)[:, None] * 1e-9
        for c, out in beyond.items():
            v = columns[c]
            steady[1:] |= (out[1:] & self._far(c, v[1:], v[:-1], dt)).any(axis=1)
        steady[1:] = ~steady[1:]
        maybe, must = suspects
        visit = np.flatnonzero(maybe & (~steady | must)).tolist()
        heapq.heapify(visit)
        popped, last_kept = -1, -1  # the last row judged, and the last row kept up to it
        while visit:
            i = heapq.heappop(visit)
            if i == popped:
                continue
            # rows between the last one judged and this one were kept
            before = i - 1 if i - 1 > popped else last_kept
            ref, ref_ns = self._reference(i, before, stamp_ns, columns)
            bad: dict[str, list[int]] = {}
            for c, out in beyond.items():
                joints = out[i]
                if c in ref and joints.any():
                    dt_i = max(int(stamp_ns[i]) - ref_ns, 0) * 1e-9
                    joints = joints & self._far(c, columns[c][i], ref[c], dt_i)
                if joints.any():
                    bad[c] = np.flatnonzero(joints).tolist()
            if "position" in ref and "position" in columns and run[i] < STEP_RUN:
                dt_i = max(int(stamp_ns[i]) - ref_ns, 0) * 1e-9
                jumped = self._stepped(columns["position"][i], ref["position"], dt_i)
                if jumped.any():
                    bad["jump"] = np.flatnonzero(jumped).tolist()
            if bad:
                ok[i] = False
                self._note(int(stamp_ns[i]), bad)
                if i + 1 < n:
                    heapq.heappush(visit, i + 1)  # its previous row is gone: judge it alone
            popped, last_kept = i, i if ok[i] else before
        return ok

    def _reference(
        self, i: int, before: int, stamp_ns: IntArray, columns: dict[str, FloatArray]
    ) -> tuple[dict[str, FloatArray], int]:
        """What row ``i`` is compared with: the last sample kept (``before`` in this block, else
        an earlier block's); with none kept yet, the last sample read; with none read, nothing
        (the bounds alone judge the very first sample)."""
        if before < 0 and self._kept is not None:
            return self._kept, self._kept_ns
        row = before if before >= 0 else i - 1
        if row >= 0:
            return {c: v[row] for c, v in columns.items()}, int(stamp_ns[row])
        return self._read or {}, self._read_ns

    def _far(
        self, channel: str, values: FloatArray, ref: FloatArray, dt_s: FloatArray | float
    ) -> BoolArray:
        """Where ``values`` lie further from ``ref`` than a motor moves them in ``dt_s``."""
        jump = self._jump[channel] + (self._speed * dt_s if channel == "position" else 0.0)
        out: BoolArray = np.abs(values - ref) > jump
        return out

    def _note(self, stamp_ns: int, bad: dict[str, list[int]]) -> None:
        d = self.dropped
        d.samples += 1
        if len(d.times_s) < EXAMPLES:
            d.times_s.append(round((stamp_ns - (self.first_ns or stamp_ns)) * 1e-9, 6))
        for c, cols in bad.items():
            names = d.joints.setdefault(c, [])
            names.extend(self.joint_names[j] for j in cols if self.joint_names[j] not in names)

    def warning(self, source: str) -> str | None:
        """One line on the absurd samples dropped, or None."""
        d = self.dropped
        if not d.samples:
            return None
        what = {
            "position": "positions far outside the joint limits",
            "velocity": f"velocities over {VELOCITY_BOUND:g} × the velocity limit",
            "effort": f"efforts over {EFFORT_BOUND:g} × the effort limit",
            "sim_effort": f"twin efforts over {EFFORT_BOUND:g} × the effort limit",
            "jump": f"positions jumping faster than {STEP_SPEED:g} × the velocity limit",
        }
        kinds = "; ".join(f"{what[c]} on {', '.join(d.joints[c])}" for c in KINDS if c in d.joints)
        more = ", …" if d.samples > len(d.times_s) else ""
        times = ", ".join(f"{t:.3f}" for t in d.times_s)
        return (
            f"{source}: dropping {d.samples} sample(s) with absurd values at {times}{more} s from "
            f"the first sample ({kinds}, reached by a jump no motor makes): a recorder glitch, "
            "not motion"
        )

    def off_warning(self, source: str) -> str | None:
        """One line on the samples left out as drives off, or None."""
        off = self.off
        if not off.samples:
            return None
        spans = ", ".join(f"{a:.3f}–{b:.3f}" for a, b in off.spans_s)
        more = ", …" if off.spans > len(off.spans_s) else ""
        return (
            f"{source}: leaving out {off.samples} sample(s) whose efforts are all exactly 0 at "
            f"{spans}{more} s from the first sample: the drives were off (or the driver "
            "measures no effort there), nothing to compare with the twin"
        )

    def warn(self, source: str) -> None:
        for line in (self.warning(source), self.off_warning(source)):
            if line is not None:
                log.warning("%s", line)
