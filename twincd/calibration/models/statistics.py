"""The mergeable statistics every model kind fits from (one pass per log or block, an exact
merge: ``twincd.signal.moments.Moments``), and ``FitStats``, all of them at once."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from twincd.calibration.affine import AffineStats, same_joints
from twincd.calibration.excitation import MotionStats
from twincd.calibration.models.constants import EPSILON_GRID, SPEED_BINS
from twincd.errors import DataError
from twincd.signal.features import ModelInputs
from twincd.signal.moments import Moments
from twincd.types import BoolArray, FloatArray, IntArray


def coulomb_grid(coulomb_f: Any, where: str) -> FloatArray:
    """(N, E, D) Coulomb features with one column per ε of ``EPSILON_GRID``, or a clear error."""
    f: FloatArray = np.asarray(coulomb_f, dtype=np.float64)
    if f.ndim != 3 or f.shape[1] != len(EPSILON_GRID):
        raise DataError(
            f"Coulomb features of shape {f.shape} do not match the ε grid",
            where,
            "prepare the logs with coulomb_eps=EPSILON_GRID",
        )
    return f


def compact_regressor(
    regressor_f: Any, regressor_mask: BoolArray | None
) -> tuple[FloatArray, BoolArray]:
    """The regressor as (N, kept) entries where the (D, P) mask holds, and that mask: a whole
    (N, D, P) regressor is cut down to ``regressor_mask`` (every entry without one)."""
    y: FloatArray = np.asarray(regressor_f, dtype=np.float64)
    if y.ndim == 3:
        if regressor_mask is None:
            regressor_mask = np.ones(y.shape[1:], dtype=bool)
        return y[:, regressor_mask], regressor_mask
    if regressor_mask is None or y.ndim != 2 or y.shape[1] != np.count_nonzero(regressor_mask):
        raise DataError(
            f"a regressor of shape {y.shape} without its (joints, parameters) mask",
            "identified model",
            "pass the mask of the regressor's entries (twincd.twin.dynamics.regressor_mask)",
        )
    return y, np.asarray(regressor_mask, dtype=bool)


def _joint_moments(
    kept: BoolArray,
    sim: FloatArray,
    y: FloatArray,
    velocity: FloatArray,
    coulomb: FloatArray,
    effort: FloatArray,
    weight: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Mean (K,) and centred cross-products (K, K) of one joint's columns τ̂̃, Ỹ_j (its
    ``kept`` entries, zero elsewhere), q̇̃, Coulomb (E), τ̃. The full width keeps BLAS's
    summation order: any block size gives the bits of one (N, D, K) product. ``weight``:
    how many samples each row stands for (a grid's node for its cell's samples)."""
    params = len(kept)
    cols = np.zeros((len(sim), params + 3 + coulomb.shape[1]))
    cols[:, 0] = sim
    cols[:, 1 + np.flatnonzero(kept)] = y
    cols[:, params + 1] = velocity
    cols[:, params + 2 : -1] = coulomb
    cols[:, -1] = effort
    if weight is not None:
        mean_w: FloatArray = weight @ cols / weight.sum()
        cols -= mean_w
        return mean_w, (cols * weight[:, None]).T @ cols
    mean: FloatArray = cols.mean(axis=0)
    cols -= mean
    return mean, cols.T @ cols


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """BLAS on one thread: a block's products are small (thousands × ~80), and OpenBLAS's
    threads spin against the reader's and the other processes' on a busy machine (16× slower
    measured at 4096 × 79 on two shared cores)."""
    with _blas_threads().limit(limits=1, user_api="blas"):
        yield


@lru_cache(maxsize=1)
def _blas_threads() -> Any:
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


@dataclass(frozen=True)
class FrictionStats:
    """Mergeable statistics of the friction-aware regression for every ε of ``EPSILON_GRID``.

    ``mean`` (E, D, 4) and centred cross-products ``cross`` (E, D, 4, 4) of the columns
    [τ̂̃, tanh(q̇̃/ε), q̇̃, τ̃] over ``n`` samples.
    """

    n: int
    mean: FloatArray
    cross: FloatArray

    @classmethod
    def zeros(cls, joints: int) -> FrictionStats:
        e = len(EPSILON_GRID)
        return cls(0, np.zeros((e, joints, 4)), np.zeros((e, joints, 4, 4)))

    @classmethod
    def from_arrays(
        cls,
        sim_effort_f: FloatArray,
        velocity_f: FloatArray,
        coulomb_f: FloatArray,
        effort_f: FloatArray,
        mask: BoolArray | None = None,
    ) -> FrictionStats:
        """Statistics of (N, D) efforts and velocity and the (N, E, D) Coulomb features, one
        per ε of ``EPSILON_GRID``, rows where ``mask`` holds."""
        x = np.asarray(sim_effort_f, dtype=np.float64)
        v = np.asarray(velocity_f, dtype=np.float64)
        f = coulomb_grid(coulomb_f, "friction fit")
        y = np.asarray(effort_f, dtype=np.float64)
        if mask is not None:
            x, v, f, y = x[mask], v[mask], f[mask], y[mask]
        joints = x.shape[1] if x.ndim == 2 else 0
        if len(x) == 0:
            return cls.zeros(joints)
        cols = np.stack(
            np.broadcast_arrays(x[None], np.moveaxis(f, 1, 0), v[None], y[None]), axis=-1
        )  # (E, N, D, 4)
        mean = cols.mean(axis=1)
        centred = cols - mean[:, None]
        cross = np.einsum("enda,endb->edab", centred, centred)
        return cls(len(x), mean, cross)

    @classmethod
    def from_weighted(
        cls,
        sim_effort_f: FloatArray,
        velocity_f: FloatArray,
        coulomb_f: FloatArray,
        effort_f: FloatArray,
        weight: IntArray,
    ) -> FrictionStats:
        """``from_arrays`` of rows that each stand for ``weight`` samples (a grid's nodes)."""
        rows = np.flatnonzero(weight)
        w = np.asarray(weight, dtype=np.float64)[rows]
        x = np.asarray(sim_effort_f, dtype=np.float64)[rows]
        f = coulomb_grid(coulomb_f, "friction fit")[rows]
        v = np.asarray(velocity_f, dtype=np.float64)[rows]
        y = np.asarray(effort_f, dtype=np.float64)[rows]
        if len(rows) == 0:
            return cls.zeros(x.shape[1] if x.ndim == 2 else 0)
        cols = np.stack(
            np.broadcast_arrays(x[None], np.moveaxis(f, 1, 0), v[None], y[None]), axis=-1
        )  # (E, N, D, 4)
        n = float(w.sum())
        mean = np.einsum("n,endk->edk", w, cols) / n
        centred = cols - mean[:, None]
        weighted = centred * w[None, :, None, None]
        cross = np.einsum("enda,endb->edab", weighted, centred)
        return cls(int(n), mean, cross)

    def __add__(self, other: FrictionStats) -> FrictionStats:
        merged = _merged(self, other, joint_axis=1)
        return FrictionStats(int(merged.n), merged.mean, merged.m2)


def _merged(
    mine: FrictionStats | IdentifiedStats, theirs: FrictionStats | IdentifiedStats, joint_axis: int
) -> Moments:
    """The two statistics' moments merged (of the same joints: ``joint_axis`` of their means)."""
    if mine.n and theirs.n:
        same_joints(mine.mean.shape[joint_axis], theirs.mean.shape[joint_axis])
    return Moments(mine.n, mine.mean, mine.cross) + Moments(theirs.n, theirs.mean, theirs.cross)


@dataclass(frozen=True)
class IdentifiedStats:
    """Mergeable statistics of the identified model's regression, every ε at once.

    ``mean`` (D, K) and centred cross-products ``cross`` (D, K, K) of the per-joint columns
    [τ̂̃, Ỹ_j (P), q̇̃, LP[tanh(q̇/ε)] for each ε of ``EPSILON_GRID``, τ̃] over ``n`` samples:
    one Gram matrix per joint serves every ε, since only the Coulomb column changes with it.
    """

    n: int
    mean: FloatArray
    cross: FloatArray

    @classmethod
    def zeros(cls, joints: int, params: int) -> IdentifiedStats:
        k = params + 3 + len(EPSILON_GRID)
        return cls(0, np.zeros((joints, k)), np.zeros((joints, k, k)))

    @classmethod
    def from_arrays(
        cls,
        sim_effort_f: FloatArray,
        regressor_f: FloatArray,
        velocity_f: FloatArray,
        coulomb_f: FloatArray,
        effort_f: FloatArray,
        mask: BoolArray | None = None,
        regressor_mask: BoolArray | None = None,
    ) -> IdentifiedStats:
        """Statistics of (N, D) efforts and velocity, the filtered regressor and the (N, E, D)
        Coulomb features (one per ε of ``EPSILON_GRID``), rows where ``mask`` holds.

        The regressor is either whole, (N, D, P), or only its entries where ``regressor_mask``
        (D, P) holds, (N, kept) in row-major order (what the streamed stages carry; the entries
        outside it are structurally zero). One joint's (N, K) columns at a time, never the
        (N, D, K) stack: the same bits, a seventh of the memory."""
        f = coulomb_grid(coulomb_f, "identified fit")
        sim = np.asarray(sim_effort_f, dtype=np.float64)
        y, regressor_mask = compact_regressor(regressor_f, regressor_mask)
        joints, params = regressor_mask.shape
        if mask is not None:
            sim, y, f = sim[mask], y[mask], f[mask]
            velocity_f, effort_f = np.asarray(velocity_f)[mask], np.asarray(effort_f)[mask]
        if len(sim) == 0:
            return cls.zeros(joints, params)
        k = params + 3 + len(EPSILON_GRID)
        mean, cross = np.zeros((joints, k)), np.zeros((joints, k, k))
        ends = np.cumsum(regressor_mask.sum(axis=1))  # joint j's entries end at ends[j] in y
        with one_blas_thread():
            for j in range(joints):
                mean[j], cross[j] = _joint_moments(
                    regressor_mask[j],
                    sim[:, j],
                    y[:, ends[j] - np.count_nonzero(regressor_mask[j]) : ends[j]],
                    np.asarray(velocity_f, dtype=np.float64)[:, j],
                    f[:, :, j],
                    np.asarray(effort_f, dtype=np.float64)[:, j],
                )
        return cls(len(sim), mean, cross)

    @property
    def params(self) -> int:
        return int(self.mean.shape[1]) - 3 - len(EPSILON_GRID)

    def __add__(self, other: IdentifiedStats) -> IdentifiedStats:
        merged = _merged(self, other, joint_axis=0)
        return IdentifiedStats(int(merged.n), merged.mean, merged.m2)


def speed_bin(speed: FloatArray, edges: Sequence[float] = SPEED_BINS) -> IntArray:
    """Each sample's bin of |speed| (any shape) among the interior ``edges``: 0 … len(edges)."""
    out: IntArray = np.searchsorted(np.asarray(edges), np.abs(speed), side="right").astype(np.int64)
    return out


@dataclass(frozen=True)
class _Columns:
    """The per-joint columns ``SpeedStats`` bins: (N, D) efforts and velocity, the (N, E, D)
    Coulomb features and the compact regressor with its mask (None: without them)."""

    sim: FloatArray
    effort: FloatArray
    velocity: FloatArray
    coulomb: FloatArray | None
    y: FloatArray | None
    kept: BoolArray | None

    @classmethod
    def of(
        cls,
        sim_effort_f: FloatArray,
        effort_f: FloatArray,
        velocity_f: FloatArray | None,
        coulomb_f: FloatArray | None,
        regressor_f: FloatArray | None,
        regressor_mask: BoolArray | None,
    ) -> _Columns:
        """The columns of every row (zero velocity when ``velocity_f`` is None)."""
        sim = np.asarray(sim_effort_f, dtype=np.float64)
        f = None if coulomb_f is None else coulomb_grid(coulomb_f, "whitening scale")
        y, kept = None, None
        if regressor_f is not None:
            y, kept = compact_regressor(regressor_f, regressor_mask)
        effort = np.asarray(effort_f, dtype=np.float64)
        velocity = np.zeros_like(sim) if velocity_f is None else np.asarray(velocity_f, np.float64)
        return cls(sim, effort, velocity, f, y, kept)

    def select(self, rows: BoolArray) -> _Columns:
        """The columns of the rows where ``rows`` holds."""
        return _Columns(
            self.sim[rows],
            self.effort[rows],
            self.velocity[rows],
            None if self.coulomb is None else self.coulomb[rows],
            None if self.y is None else self.y[rows],
            self.kept,
        )


@dataclass(frozen=True)
class SpeedStats:
    """Mergeable statistics of each joint's model columns in bins of the joint's own speed.

    Per bin b and joint j: the count ``n`` (B, D), the means ``mean`` (B, D, K) and centred
    cross-products ``cross`` (B, D, K, K) of the columns [τ̂̃, Ỹ_j (P, zero without the
    regressor), q̇̃, LP[tanh(q̇/ε)] (E: every ε of ``EPSILON_GRID``, or none), τ̃]. Any model
    fitted from the same samples is linear in these columns, so its residual's sum of squares
    in a bin is a quadratic form of them (``speed_scale``): the whitening scale comes out of
    the one pass that fits the model, exactly.
    """

    n: IntArray
    mean: FloatArray
    cross: FloatArray
    params: int  # P: regressor entries per joint (0 without it)
    coulomb: int  # E: Coulomb features per joint (0 without them)

    @classmethod
    def zeros(cls, joints: int, params: int = 0, coulomb: int = 0) -> SpeedStats:
        b, k = len(SPEED_BINS) + 1, params + 3 + coulomb
        return cls(
            np.zeros((b, joints), np.int64),
            np.zeros((b, joints, k)),
            np.zeros((b, joints, k, k)),
            params,
            coulomb,
        )

    @classmethod
    def from_arrays(
        cls,
        speed: FloatArray,
        sim_effort_f: FloatArray,
        effort_f: FloatArray,
        velocity_f: FloatArray | None = None,
        coulomb_f: FloatArray | None = None,
        regressor_f: FloatArray | None = None,
        regressor_mask: BoolArray | None = None,
        mask: BoolArray | None = None,
    ) -> SpeedStats:
        """Statistics of (N, D) speeds |q̇| (raw, as scoring sees them), efforts and velocity,
        the (N, E, D) Coulomb features and the regressor (whole or masked, as
        ``IdentifiedStats.from_arrays``), rows where ``mask`` holds."""
        columns = _Columns.of(
            sim_effort_f, effort_f, velocity_f, coulomb_f, regressor_f, regressor_mask
        )
        return cls._from_rows(speed, columns, mask)

    @classmethod
    def _from_rows(
        cls, speed: FloatArray, columns: _Columns, mask: BoolArray | None = None
    ) -> SpeedStats:
        """``from_arrays`` of ``columns``."""
        rows = np.ones(len(columns.sim), bool) if mask is None else np.asarray(mask, bool)
        bins = speed_bin(np.asarray(speed, dtype=np.float64)[rows])

        def cells(j: int) -> Iterator[tuple[int, Any, int, FloatArray | None]]:
            for b in np.unique(bins[:, j]):
                at = bins[:, j] == b
                yield int(b), at, int(np.count_nonzero(at)), None

        return cls._by_bin(columns.select(rows), cells)

    @classmethod
    def _by_bin(
        cls, columns: _Columns, cells: Callable[[int], Iterable[tuple[int, Any, int, Any]]]
    ) -> SpeedStats:
        """The statistics of each joint's ``columns`` in each of its ``cells(j)``: (bin, the
        rows in it, the samples they stand for, each row's weight or None)."""
        sim, y, kept, f = columns.sim, columns.y, columns.kept, columns.coulomb
        params = 0 if kept is None else kept.shape[1]
        out = cls.zeros(sim.shape[1], params, 0 if f is None else f.shape[1])
        n, mean, cross = out.n.copy(), out.mean.copy(), out.cross.copy()
        ends = None if kept is None else np.cumsum(kept.sum(axis=1))
        with one_blas_thread():
            for j in range(sim.shape[1]):
                if kept is None or y is None or ends is None:
                    joint_kept, joint_y = np.zeros(0, bool), np.zeros((len(sim), 0))
                else:
                    joint_kept = kept[j]
                    joint_y = y[:, ends[j] - np.count_nonzero(kept[j]) : ends[j]]
                coulomb = np.zeros((len(sim), 0)) if f is None else f[:, :, j]
                for b, at, count, weight in cells(j):
                    n[b, j] = count
                    mean[b, j], cross[b, j] = _joint_moments(
                        joint_kept,
                        sim[at, j],
                        joint_y[at],
                        columns.velocity[at, j],
                        coulomb[at],
                        columns.effort[at, j],
                        weight,
                    )
        return cls(n, mean, cross, params, out.coulomb)

    @classmethod
    def _from_weighted(cls, weight: IntArray, columns: _Columns) -> SpeedStats:
        """``from_arrays`` of rows that stand for samples (a grid's nodes for their cells'):
        ``weight`` (N, D, B) counts, per row, joint and bin of the joint's speed, the samples
        a row stands for."""
        w = np.asarray(weight, dtype=np.float64)

        def cells(j: int) -> Iterator[tuple[int, Any, int, FloatArray | None]]:
            for b in np.flatnonzero(w[:, j].any(axis=0)):
                at = np.flatnonzero(w[:, j, b])
                yield int(b), at, int(w[at, j, b].sum()), w[at, j, b]

        return cls._by_bin(columns, cells)

    def __add__(self, other: SpeedStats) -> SpeedStats:
        if (self.params, self.coulomb) != (other.params, other.coulomb):
            raise DataError(
                "whitening statistics of logs prepared differently do not merge",
                f"{self.params}/{self.coulomb} vs {other.params}/{other.coulomb} columns",
                "prepare every log with the same settings",
            )
        same_joints(self.n.shape[1], other.n.shape[1])
        merged = Moments(self.n, self.mean, self.cross) + Moments(other.n, other.mean, other.cross)
        return SpeedStats(np.asarray(merged.n), merged.mean, merged.m2, self.params, self.coulomb)

    def pooled(self) -> tuple[int, FloatArray, FloatArray]:
        """Count, means (D, K) and cross-products (D, K, K) over every bin: the statistics of
        one joint's columns regardless of speed (``IdentifiedStats``'s, in the same layout)."""
        total = Moments(self.n[0], self.mean[0], self.cross[0])
        for b in range(1, len(self.n)):
            total = total + Moments(self.n[b], self.mean[b], self.cross[b])
        return int(np.max(total.n, initial=0)), total.mean, total.m2


def _by_model(
    inputs: ModelInputs,
    speed: bool,
    friction_stats: Callable[[FloatArray, FloatArray], FrictionStats],
    speed_stats: Callable[[_Columns], SpeedStats],
) -> tuple[FrictionStats | None, SpeedStats | None, IdentifiedStats | None]:
    """What ``FitStats`` holds beyond the affine map: the friction statistics
    ``friction_stats`` gives of the filtered velocity and the Coulomb features, the speed bins
    ``speed_stats`` gives of the model's columns (friction, Coulomb features and regressor: None
    unless the logs were prepared with every ε), and the identified model's statistics (None
    without a regressor; no bins unless ``speed`` or the regressor asks)."""
    grid = inputs.coulomb_eps == EPSILON_GRID
    friction = None
    if grid:
        friction = friction_stats(_required(inputs.velocity_f), _required(inputs.coulomb_f))
    regressor = inputs.regressor_f if grid else None
    if not speed and regressor is None:
        return friction, None, None
    bins = speed_stats(
        _Columns.of(
            inputs.sim_effort_f,
            inputs.measured,
            inputs.velocity_f,
            inputs.coulomb_f if grid else None,
            regressor,
            inputs.regressor_mask,
        )
    )
    if regressor is None:
        return friction, bins, None
    # the identified model's moments are the speed bins' pooled: one product, not two
    n, mean, cross = bins.pooled()
    return friction, bins, IdentifiedStats(n, mean, cross)


@dataclass(frozen=True)
class FitStats:
    """Everything a fit of any model kind needs from some samples, from one pass: mergeable
    (``+``, exact and in any order), small and picklable (what one log sends back from a
    worker). ``friction`` and ``identified`` exist when the samples were prepared with every
    ε's Coulomb feature (and the regressor); ``speed`` (the whitening scale) unless only the
    affine map was asked for (``AffineModel.stats``)."""

    affine: AffineStats
    speed: SpeedStats | None = None
    friction: FrictionStats | None = None
    identified: IdentifiedStats | None = None
    motion: MotionStats | None = None  # how far each joint moved (``excitation``)
    # how many independent samples the filtered samples hold (``excitation.independent_samples``;
    # None: not known, and no coefficient is held for want of them)
    independent: float | None = None

    @property
    def resting(self) -> BoolArray | None:
        """The joints that do not move (None: not known)."""
        return None if self.motion is None else self.motion.resting

    @classmethod
    def from_inputs(cls, inputs: ModelInputs, clean: BoolArray, speed: bool = True) -> FitStats:
        """The statistics of prepared samples (``ResidualModel.predict``'s inputs plus
        ``effort_f`` and the raw ``velocity``), rows where ``clean`` holds; ``speed`` False:
        no speed bins (an unwhitened model's fit, unless the identified model needs them)."""
        sim, effort = inputs.sim_effort_f, inputs.measured
        affine = AffineStats.from_arrays(sim, effort, clean)
        motion = motion_stats(inputs, clean)
        friction, bins, identified = _by_model(
            inputs,
            speed,
            lambda velocity_f, coulomb_f: FrictionStats.from_arrays(
                sim, velocity_f, coulomb_f, effort, clean
            ),
            lambda columns: SpeedStats._from_rows(_required(inputs.velocity), columns, clean),
        )
        return cls(affine, bins, friction, identified, motion)

    @classmethod
    def from_cells(
        cls, inputs: ModelInputs, count: IntArray, by_speed: IntArray, speed: bool = True
    ) -> FitStats:
        """``from_inputs`` of a grid's nodes (``twincd.prepare.grid``), each standing for the
        samples of its cell: ``count`` (N,) the clean samples each row stands for, ``by_speed``
        (N, D, B) those per joint and bin of the joint's own speed (what ``speed_bin`` gives
        each sample, as scoring bins it). The sums are the samples', each sample counted at
        its cell's node."""
        sim, effort = inputs.sim_effort_f, inputs.measured
        affine = AffineStats.from_weighted(sim, effort, count)
        friction, bins, identified = _by_model(
            inputs,
            speed,
            lambda velocity_f, coulomb_f: FrictionStats.from_weighted(
                sim, velocity_f, coulomb_f, effort, count
            ),
            lambda columns: SpeedStats._from_weighted(by_speed, columns),
        )
        return cls(affine, bins, friction, identified)

    def __add__(self, other: FitStats) -> FitStats:
        def both(mine: Any, theirs: Any) -> Any:
            return None if mine is None or theirs is None else mine + theirs

        return FitStats(
            self.affine + other.affine,
            both(self.speed, other.speed),
            both(self.friction, other.friction),
            both(self.identified, other.identified),
            both(self.motion, other.motion),
            both(self.independent, other.independent),
        )


def motion_stats(inputs: ModelInputs, clean: BoolArray) -> MotionStats | None:
    """How far each joint moved over the ``clean`` rows (None without positions)."""
    position = inputs.position
    return None if position is None else MotionStats.from_arrays(position, clean)


def _required(values: FloatArray | None) -> FloatArray:
    """Inputs a fit of the prepared features needs (the stream computed them)."""
    if values is None:
        raise DataError(
            "the prepared samples lack an input the fit's features need",
            "fit",
            "prepare the logs with the model's features (fit_features)",
        )
    return values
