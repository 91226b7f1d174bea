"""The twin and the low-pass filter on a coarse grid, for logs sampled far faster than the filter
keeps (``grid_period_ns``: a 1 kHz log under a 1.5 Hz cut-off).

After the low-pass filter a 1 kHz log carries nothing above a few hertz, yet the twin (RNEA, and
for the identified models Pinocchio's joint-torque regressor, one call per sample) and the
filter would run on every sample. ``GridStage`` runs them on cells instead:

1. Cells are anchored on the stamps: cell m holds a segment's samples with
   m·G ≤ stamp < (m+1)·G in absolute nanoseconds, so the cells do not depend on where a block,
   a chunk or a live push starts, and restart with every segment (gaps cut as every stage cuts).
2. A node per cell: the mean of its samples' position, velocity, effort (and the log's own twin
   effort, or tanh(q̇/ε) for the friction models), at the mean of their stamps. The mean is the
   anti-alias filter: a box of one cell has its zeros at the grid's rate and its multiples,
   which is where noise would fold into the pass band (point samples instead let the
   acceleration's noise fold in at ~20 % of the residual's noise).
3. On the nodes, the twin's stages as they run per sample (``twincd.prepare.chain``): q̈ by the
   Savitzky–Golay derivative of the node velocities (on their real times: differentiated after
   the averaging, the noise folded in lands where a derivative is small), τ̂ = RNEA, the
   regressor, then the same low-pass filter designed for the grid's period.
4. Back on the samples: every filtered column linearly interpolated between the nodes around
   each sample's stamp (zero-phase; a segment's samples before its first node or after its
   last hold that node), or, causal, between the node of its cell and the one before
   (extrapolated by less than a cell past the node's stamp; a segment's first cell held at its
   node), so that a sample waits for its own cell to end and never longer: a causal chain or a
   live detector holds a sample at most one grid period.

``twincd.prepare.chain.build_chain`` builds the stage; scoring adds the fitted model's prediction
to the node chain (the models are linear in their filtered inputs) and ``fit`` sums the nodes
themselves (``keep_nodes``). A node depends on the stamps and values of its own cell and of
earlier nodes of its segment (and, zero-phase, later ones) only, and the cell sums add samples
in their order: chunked runs equal one run. The choice of the grid and the error it makes are
in docs/models-and-results.md.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Sequence

import numpy as np

from twincd.prepare.frames import Chain, Frame
from twincd.signal.stream import DEFAULT_GAP_FACTOR, Segmenter
from twincd.types import FloatArray, IntArray

__all__ = [
    "FAST_OVERSAMPLING",
    "GRID_MIN_PERIODS",
    "GRID_OVERSAMPLING",
    "GridStage",
    "grid_period_ns",
]

# the grid's rate in multiples of the filter's cut-off: 96 Hz under 1.5 Hz, where the nodes'
# interpolation and the grid's filter differ from the per-sample filter by ~1 % of the
# identified model's residual noise (docs/models-and-results.md)
GRID_OVERSAMPLING = 64
# with a fast band (twincd.signal.bands), at least this many nodes per period of its upper
# cut-off: 100 Hz nodes under 10 Hz, the rate the fast band was chosen at on 100 Hz arms (at
# 1 kHz under 1.5 Hz, the slow band's grid already: 10 ms)
FAST_OVERSAMPLING = 10
# the grid is used only when a cell holds at least this many sample periods: a 100 Hz log
# under any cut-off above 0.39 Hz is filtered sample by sample, bit for bit as before
GRID_MIN_PERIODS = 4
# per-sample columns the nodes average (plus the log's twin effort and tanh(q̇/ε) when asked)
_AVERAGED = ("position", "velocity", "effort")


def grid_period_ns(cutoff_hz: float, period_s: float, fast_hz: float | None = None) -> int | None:
    """The grid's period in ns for a low-pass ``cutoff_hz`` on samples every ``period_s``: a
    whole number of sample periods, the most that stays at or below 1/(64 × cut-off) and, with
    a fast band up to ``fast_hz`` (``twincd.signal.bands``), at or below 1/(``FAST_OVERSAMPLING``
    × ``fast_hz``): the grid follows the fastest band. None when that is fewer than
    ``GRID_MIN_PERIODS`` (the filters then run on every sample)."""
    if not (period_s > 0 and cutoff_hz > 0):
        return None
    longest = 1.0 / (GRID_OVERSAMPLING * cutoff_hz)
    if fast_hz:
        longest = min(longest, 1.0 / (FAST_OVERSAMPLING * fast_hz))
    periods = math.floor(longest / period_s + 1e-9)
    if periods < GRID_MIN_PERIODS:
        return None
    return round(periods * period_s * 1e9)


class _Cell:
    """The open cell of a segment: its index, the running sum of its values (added in sample
    order), count, first stamp and the sum of its stamps' offsets from that one."""

    __slots__ = ("cell", "count", "first", "offsets", "sums")

    def __init__(self, cell: int, sums: FloatArray, count: int, first: int, offsets: int) -> None:
        self.cell, self.sums, self.count, self.first, self.offsets = (
            cell, sums.copy(), count, first, offsets,
        )  # fmt: skip


def _cell_sums(
    values: FloatArray, stamps: IntArray, starts: IntArray, open_: _Cell | None
) -> tuple[FloatArray, IntArray, IntArray, IntArray]:
    """Per cell of a piece (cells begin at ``starts``; the first continues ``open_`` unless
    that is None): the sums of its values, its count, first stamp and summed stamp offsets.

    Each sum adds its samples one after the other, in their order (a loop over the position
    within the cells, vectorised across cells), the open cell's from its running sum: a cell
    split across pushes sums to the bits of one pass (``np.add.reduceat`` leaves the order of
    its additions to numpy)."""
    counts = np.diff(np.r_[starts, len(stamps)])
    first = stamps[starts].copy()
    sums = values[starts].copy()
    offsets = np.zeros(len(starts), dtype=np.int64)
    if open_ is not None:  # the open cell's running sum, then this piece's samples
        sums[0] = open_.sums + values[0]
        first[0] = open_.first
        offsets[0] = open_.offsets + (stamps[0] - open_.first)
    every = int(counts.min())  # positions every cell has: no selection of cells needed
    for j in range(1, every):
        sums += values[starts + j]
        offsets += stamps[starts + j] - first
    for j in range(max(every, 1), int(counts.max())):
        live = np.flatnonzero(counts > j)
        sums[live] += values[starts[live] + j]
        offsets[live] += stamps[starts[live] + j] - first[live]
    if open_ is not None:
        counts[0] += open_.count
    return sums, counts, first, offsets


class _Pending:
    """Per-sample frames waiting for their nodes, each row with its node's serial."""

    def __init__(self) -> None:
        self.frames: deque[Frame] = deque()
        self.n = 0

    def put(self, frame: Frame) -> None:
        if frame.n:
            self.frames.append(frame)
            self.n += frame.n

    def count_upto(self, serial: int) -> int:
        """Rows (from the oldest) whose node serial is at most ``serial``."""
        k = 0
        for frame in self.frames:
            nodes = frame["node"]
            if nodes[-1] <= serial:
                k += frame.n
                continue
            return k + int(np.searchsorted(nodes, serial, side="right"))
        return k

    def relabel(self, serial: int, to: int) -> None:
        """The rows of node ``serial`` (the newest) counted at node ``to`` instead."""
        for i in range(len(self.frames) - 1, -1, -1):
            frame = self.frames[i]
            nodes = np.asarray(frame["node"], dtype=np.int64)
            if nodes[-1] != serial:
                return
            self.frames[i] = frame.with_columns(node=np.where(nodes == serial, to, nodes))
            if nodes[0] != serial:
                return

    def take(self, k: int) -> Frame:
        parts: list[Frame] = []
        while k > 0:
            first = self.frames[0]
            if first.n <= k:
                parts.append(self.frames.popleft())
                k -= first.n
                self.n -= first.n
            else:
                parts.append(first.head(k))
                self.frames[0] = first.tail(k)
                self.n -= k
                k = 0
        return Frame.concat(parts)


class GridStage:
    """Per-sample frames in (``stamp_ns``, ``position``, ``velocity``, ``effort``, and
    ``sim_effort`` when ``average_sim``), per-sample frames out with the columns ``nodes``
    computes, interpolated at each sample's stamp (see the module's docstring).

    ``nodes`` is the chain run on the node frames (twin and filter, built by
    ``twincd.prepare.chain.build_chain``); it gets ``stamp_ns``, ``node`` (a serial number),
    ``position``, ``velocity``, ``effort``, optionally ``sim_effort`` and ``coulomb``
    ((N, E, joints): the means of tanh(q̇/ε) for each of ``coulomb_eps``, or (N, 1, joints) of
    tanh(q̇_j/ε_j) for each joint's own ``joint_eps``, what a fitted model reads). Of its output,
    the columns named in ``interpolate`` come back on the samples. With ``keep_nodes`` the
    frames out carry each sample's ``node`` serial and the node frames are kept for
    ``take_nodes`` (what ``fit`` sums instead of the samples).
    """

    def __init__(
        self,
        nodes: Chain,
        grid_ns: int,
        period_s: float,
        causal: bool,
        interpolate: Sequence[str],
        average_sim: bool = False,
        coulomb_eps: Sequence[float] = (),
        joint_eps: FloatArray | None = None,
        keep_nodes: bool = False,
        gap_factor: float = DEFAULT_GAP_FACTOR,
    ) -> None:
        if grid_ns < 1:
            raise ValueError(f"grid period {grid_ns} ns is not positive")
        self.nodes = nodes
        self.grid_ns = int(grid_ns)
        self.causal = causal
        self.interpolate = tuple(interpolate)
        self.average_sim = average_sim
        self.coulomb_eps = tuple(float(e) for e in coulomb_eps)
        self.joint_eps = None if joint_eps is None else np.asarray(joint_eps, dtype=np.float64)
        self.keep_nodes = keep_nodes
        self._segmenter = Segmenter(period_s, gap_factor)
        self._sample_ns = period_s * 1e9
        self._pending = _Pending()
        self._serial = 0  # serial of the next node
        self._first = 0  # serial of the segment's first node
        self._open: _Cell | None = None  # the last cell of the segment, still filling
        self._done: Frame = Frame()  # filtered nodes of this segment still needed
        self._kept: list[Frame] = []

    @property
    def period_s(self) -> float:
        return self.grid_ns * 1e-9

    @property
    def pending(self) -> int:
        """Samples held back right now."""
        return self._pending.n

    def take_nodes(self) -> Frame:
        """The node frames filtered since the last call (``keep_nodes``)."""
        out = Frame.concat(self._kept)
        self._kept = []
        return out

    # ------------------------------------------------------------------ the stage

    def push(self, frame: Frame) -> Frame:
        if not frame.n:
            return frame
        t = np.asarray(frame["stamp_ns"], dtype=np.int64)
        starts = set(self._segmenter.starts(t).tolist())
        edges = sorted({0, frame.n, *starts})
        out: list[Frame] = []
        for a, b in itertools.pairwise(edges):
            if a in starts:
                out.append(self._end_segment())
            out.append(self._extend(frame.head(b).tail(a)))
        return Frame.concat(out)

    def finish(self) -> Frame:
        out = self._end_segment()
        self._segmenter.reset()
        return out

    # ------------------------------------------------------------------ one segment

    def _extend(self, piece: Frame) -> Frame:
        t = np.asarray(piece["stamp_ns"], dtype=np.int64)
        cell = t // self.grid_ns
        open_ = self._open
        if open_ is None:
            self._first = self._serial
        new = np.empty(len(t), dtype=bool)
        new[0] = open_ is None or int(cell[0]) != open_.cell
        new[1:] = cell[1:] != cell[:-1]
        serial = self._serial - 1 + np.cumsum(new)
        self._serial += int(np.count_nonzero(new))
        self._pending.put(piece.with_columns(node=serial))
        starts = np.flatnonzero(new)
        going_on = not new[0]  # the first samples fill the open cell
        if going_on:
            starts = np.r_[0, starts]
        values = self._values(piece)
        sums, counts, first, offsets = _cell_sums(values, t, starts, open_ if going_on else None)
        if open_ is not None and not going_on:  # this piece's first sample closed the open cell
            sums = np.vstack((open_.sums, sums))
            counts, first = np.r_[open_.count, counts], np.r_[open_.first, first]
            offsets = np.r_[open_.offsets, offsets]
        # every cell but the last is complete; the last stays open (it may go on next push)
        last = _Cell(int(cell[-1]), sums[-1], int(counts[-1]), int(first[-1]), int(offsets[-1]))
        self._open = last
        if len(sums) > 1:
            end = int(serial[-1]) - 1
            self._feed(self._node_frame(sums[:-1], counts[:-1], first[:-1], offsets[:-1], end))
        return self._emit(final=False)

    def _end_segment(self) -> Frame:
        open_ = self._open
        if open_ is not None and self._short_tail(open_):
            # zero-phase, a last cell of a few samples is no node: its mean stamp sits closer
            # to the one before than the grid's period, and the derivative on that uneven
            # spacing turns its samples' noise into q̈ error (0.4 of a joint's clean spread at
            # 1 kHz); its samples hold the node before instead
            self._pending.relabel(self._serial - 1, self._serial - 2)
        elif open_ is not None:
            counts, first = np.array([open_.count]), np.array([open_.first], dtype=np.int64)
            offsets = np.array([open_.offsets], dtype=np.int64)
            self._feed(self._node_frame(open_.sums[None], counts, first, offsets, self._serial - 1))
        self._take(self.nodes.finish())
        out = self._emit(final=True)
        self._open = None
        self._done = Frame()
        return out

    def _short_tail(self, open_: _Cell) -> bool:
        """Whether the segment's open last cell holds under half a cell's samples (and a node
        before it), zero-phase."""
        half = 0.5 * self.grid_ns / self._sample_ns
        return not self.causal and open_.count < half and self._serial - 1 > self._first

    def _values(self, frame: Frame) -> FloatArray:
        """The per-sample values the nodes average, side by side."""
        columns = [np.asarray(frame[k], dtype=np.float64) for k in _AVERAGED]
        if self.average_sim:
            columns.append(np.asarray(frame["sim_effort"], dtype=np.float64))
        velocity = columns[1]
        if self.joint_eps is not None:
            columns.append(np.tanh(velocity / self.joint_eps))
        else:
            columns += [np.tanh(velocity / e) for e in self.coulomb_eps]
        return np.hstack(columns)

    def _node_frame(
        self, sums: FloatArray, counts: IntArray, first: IntArray, offsets: IntArray, last: int
    ) -> Frame:
        """Node frames of complete cells: the mean of each cell's values at the mean of its
        stamps (the last cell's serial ``last``)."""
        means = sums / counts[:, None]
        names = [*_AVERAGED, *(["sim_effort"] if self.average_sim else [])]
        coulomb = 1 if self.joint_eps is not None else len(self.coulomb_eps)
        joints = means.shape[1] // (len(names) + coulomb)
        columns: dict[str, FloatArray | IntArray] = {
            "stamp_ns": first + offsets // counts,
            "node": np.arange(last - len(means) + 1, last + 1, dtype=np.int64),
        }
        for i, name in enumerate(names):
            columns[name] = means[:, i * joints : (i + 1) * joints]
        if coulomb:
            at = len(names) * joints
            columns["coulomb"] = means[:, at:].reshape(len(means), coulomb, joints)
        return Frame(columns)

    def _feed(self, nodes: Frame) -> None:
        self._take(self.nodes.push(nodes))

    def _take(self, filtered: Frame) -> None:
        if not filtered.n:
            return
        self._done = Frame.concat([self._done, filtered])
        if self.keep_nodes:
            self._kept.append(filtered)

    # ------------------------------------------------------------------ back on the samples

    def _emit(self, final: bool) -> Frame:
        """The pending samples whose nodes are filtered: causal, those of cells whose node
        is; zero-phase, those before the last filtered node's cell (the next node is needed
        after a node's stamp); at a segment's end, all."""
        done = self._done
        if final:
            k = self._pending.n
        elif not done.n:
            return Frame()
        else:
            last = int(done["node"][-1])
            k = self._pending.count_upto(last if self.causal else last - 1)
        if not k:
            return Frame()
        samples = self._pending.take(k)
        out = samples.with_columns(**self._interpolated(samples, done))
        if not self.keep_nodes:
            out = Frame({c: v for c, v in out.items() if c != "node"}, out.n)
        # the nodes still needed: from the one before the oldest pending (or next) sample's
        if done.n and not final:
            pending = self._pending
            oldest = int(pending.frames[0]["node"][0]) if pending.n else self._serial - 1
            self._done = done.tail(max(0, oldest - 1 - int(done["node"][0])))
        return out

    def _interpolated(self, samples: Frame, done: Frame) -> dict[str, FloatArray]:
        """The ``interpolate`` columns of the filtered nodes ``done`` at the samples' stamps."""
        names = [name for name in self.interpolate if name in done]
        if not names:
            return {}
        lo, hi, weight = self._brackets(samples, done)
        values = [np.asarray(done[name], dtype=np.float64) for name in names]
        table = np.hstack([v.reshape(len(v), -1) for v in values])
        # each sample's row is (1 − w)·node lo + w·node hi: a sparse product makes one pass
        # over the samples (3× faster than gathering both nodes' rows) and sums each row in a
        # fixed order, whatever the block's length
        from scipy.sparse import csr_matrix

        n = len(weight)
        mix = csr_matrix(
            (
                np.column_stack((1.0 - weight, weight)).ravel(),
                np.column_stack((lo, hi)).ravel(),
                np.arange(0, 2 * n + 1, 2),
            ),
            shape=(n, len(table)),
        )
        rows = np.asarray(mix @ table)
        out: dict[str, FloatArray] = {}
        start = 0
        for name, v in zip(names, values, strict=True):
            width = int(np.prod(v.shape[1:], dtype=np.int64))
            out[name] = rows[:, start : start + width].reshape(n, *v.shape[1:])
            start += width
        return out

    def _brackets(self, samples: Frame, done: Frame) -> tuple[IntArray, IntArray, FloatArray]:
        """For each sample, the two nodes of ``done`` it is interpolated between (or
        extrapolated from) and its weight on the second."""
        t = np.asarray(samples["stamp_ns"], dtype=np.int64)
        times = np.asarray(done["stamp_ns"], dtype=np.int64)
        own = np.asarray(samples["node"], dtype=np.int64) - int(done["node"][0])
        # causal: the node before its cell's and its cell's, extrapolated past that one's
        # stamp (the next node is in the future); zero-phase: the nodes around its stamp
        lo = own - 1 if self.causal else np.where(t < times[own], own - 1, own)
        if len(times) == 1:
            lo = np.zeros_like(own)
            hi = lo
        else:
            lo = np.clip(lo, 0, len(times) - 2)
            hi = lo + 1
            if self.causal:  # a segment's first node: nothing before it, held
                lo = np.where(own == 0, 0, lo)
                hi = np.where(own == 0, 0, hi)
        span = (times[hi] - times[lo]).astype(np.float64)
        weight = np.divide(
            (t - times[lo]).astype(np.float64), span, out=np.zeros(len(t)), where=span > 0
        )
        if not self.causal:
            # a segment's samples before its first node's stamp or after its last one's hold
            # that node: extrapolated, a band's end error (the fast band's, up to 10 Hz) grew
            # past what its edge factor allows for
            weight = np.clip(weight, 0.0, 1.0)
        return lo, hi, weight
