"""The calibration models (contract: The calibration file ``model``): one class per kind with
one interface (``ResidualModel``: ``stats`` → ``merge`` → ``solve``, then ``predict``,
``residual`` and ``score``), the mergeable statistics they fit from, and their scores.

- ``affine``: τ̃ ≈ a⊙τ̂̃ + b, score ‖r‖² (the seed paper, eq. 3–5).
- ``friction``: per joint τ̃ ≈ a·τ̂̃ + b + c·LP[tanh(q̇/ε)] + d·q̇̃, the joint friction (Coulomb
  and viscous) that the twin does not model; LP is the low-pass filter of the efforts and q̇̃
  the velocity through it, so that the features lag and smooth as the efforts do. ε is picked
  per joint from ``EPSILON_GRID`` by the smallest training residual: statistics for every
  candidate are gathered in one pass, so the choice uses the training logs only and still
  merges exactly.
- ``identified``: per joint τ̃ ≈ a·τ̂̃ + Ỹ_j θ_j + b + c·LP[tanh(q̇/ε)] + d·q̇̃, with Ỹ the
  joint-torque regressor (Pinocchio) through the same filter: θ_j corrects the URDF's inertial
  parameters (masses, centres of mass, inertias) as joint j sees them, which the gain a alone
  cannot (a payload or a heavier link changes the torque differently along each path). It
  needs the robot's URDF; ε is chosen as for ``friction``. Least squares with a small ridge on
  standardised columns, because most of θ is not identifiable from joint torques.
- ``…-whitened`` (``whitened=True``, a property of the score, not of the map): the same map,
  each joint's residual over its RMS s_j on the collision-free training samples (per bin of the
  joint's speed: the depth statistic), so that one noisy joint does not drown a push on a quiet
  one.

Fitting is a pure per-log step (``FrictionStats.from_arrays``) and an exact merge (``+``, Chan
et al.'s pairwise update of means and centred cross-products), like ``AffineStats``.
"""

from __future__ import annotations

import logging
import operator
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from functools import lru_cache, reduce
from itertools import pairwise
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

import numpy as np

from twincd.calibration.affine import (
    AffineStats,
    clean_mask,
    gain_share,
    r_squared,
    require_samples,
    same_joints,
    solve,
    warn_ill_conditioned,
)
from twincd.calibration.excitation import (
    COULOMB,
    GAIN,
    PRIOR,
    VISCOUS,
    Held,
    MotionStats,
    check_motion,
    conditioning,
    friction_held,
    solve_held,
    squared_error,
    undetermined,
)
from twincd.calibration.values import finite_array, finite_number
from twincd.errors import (
    CalibrationError,
    DataError,
    JointMismatchError,
    NotFittedError,
    UsageError,
)
from twincd.signal.features import ModelFeatures, ModelInputs
from twincd.signal.moments import Moments
from twincd.types import BoolArray, FloatArray, IndexArray, IntArray

if TYPE_CHECKING:
    from twincd.pipeline import PreparedLog

log = logging.getLogger("twincd")


AFFINE = "affine"
IDENTIFIED_WHITENED = "identified-whitened"
FRICTION_WHITENED = "friction-whitened"
MODEL_KINDS = (
    "affine",
    "affine-whitened",
    "friction",
    "friction-whitened",
    "identified",
    "identified-whitened",
)
# ε candidates (rad/s) of the Coulomb term tanh(q̇/ε): from a near step to a soft ramp
EPSILON_GRID: tuple[float, ...] = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2)
# a joint whose residual is almost zero on training data must not get an infinite weight
_MIN_SCALE = 1e-6
# Whitened models: interior edges (rad/s) of the bins of a joint's own speed |q̇_j| in which its
# residual's RMS is measured (bins 0 … len): rest, creep, slow, … fast. Chosen in
# studies/real_arm_statistics.py on the real arm's rotations and synth.
SPEED_BINS: tuple[float, ...] = (0.003, 0.01, 0.03, 0.1, 0.3)
# a bin with fewer clean training samples than this takes the joint's overall RMS
MIN_BIN_SAMPLES = 100
# the statistics a whitened model scores with: "sum" Σ_j (r_j/s_j)² (files without speed bins),
# "depth" the largest χ²_k z over the first k joints (``depth_score``)
STATISTICS = ("sum", "depth")


# ridge of the identified model's least squares, relative to each (standardised) column's own
# spread: enough to pin θ's unidentifiable combinations at zero, far below any real signal
IDENTIFIED_RIDGE = 1e-6


def coulomb_columns(
    coulomb_f: FloatArray, coulomb_eps: Sequence[float], epsilon: FloatArray
) -> FloatArray:
    """(N, D): each joint's filtered tanh(q̇/ε_j) out of ``coulomb_f`` (N, E, D) for the ε
    values ``coulomb_eps``."""
    eps = [float(e) for e in coulomb_eps]
    try:
        index = np.array([eps.index(float(e)) for e in epsilon], dtype=np.intp)
    except ValueError:
        raise DataError(
            "the prepared samples lack the Coulomb feature of an ε the model uses",
            f"ε {', '.join(f'{e:g}' for e in epsilon)} vs prepared {', '.join(map(str, eps))}",
            "prepare logs with the calibration's settings (Setup.from_calibration)",
        ) from None
    out: FloatArray = coulomb_f[:, index, np.arange(len(index))]
    return out


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
        sim = np.asarray(sim_effort_f, dtype=np.float64)
        rows = np.ones(len(sim), bool) if mask is None else np.asarray(mask, bool)
        joints = sim.shape[1]
        f = None if coulomb_f is None else coulomb_grid(coulomb_f, "whitening scale")[rows]
        y, kept = None, None
        if regressor_f is not None:
            y, kept = compact_regressor(regressor_f, regressor_mask)
            y = y[rows]
        params = 0 if kept is None else kept.shape[1]
        out = cls.zeros(joints, params, 0 if f is None else f.shape[1])
        bins = speed_bin(np.asarray(speed, dtype=np.float64)[rows])
        sim, effort = sim[rows], np.asarray(effort_f, dtype=np.float64)[rows]
        velocity = (
            np.zeros_like(sim) if velocity_f is None else np.asarray(velocity_f, np.float64)[rows]
        )
        n, mean, cross = out.n.copy(), out.mean.copy(), out.cross.copy()
        ends = None if kept is None else np.cumsum(kept.sum(axis=1))
        with one_blas_thread():
            for j in range(joints):
                if kept is None or y is None or ends is None:
                    joint_kept, joint_y = np.zeros(0, bool), np.zeros((len(sim), 0))
                else:
                    joint_kept = kept[j]
                    joint_y = y[:, ends[j] - np.count_nonzero(kept[j]) : ends[j]]
                coulomb = np.zeros((len(sim), 0)) if f is None else f[:, :, j]
                for b in np.unique(bins[:, j]):
                    at = bins[:, j] == b
                    n[b, j] = np.count_nonzero(at)
                    mean[b, j], cross[b, j] = _joint_moments(
                        joint_kept,
                        sim[at, j],
                        joint_y[at],
                        velocity[at, j],
                        coulomb[at],
                        effort[at, j],
                    )
        return cls(n, mean, cross, params, out.coulomb)

    @classmethod
    def from_weighted(
        cls,
        weight: IntArray,
        sim_effort_f: FloatArray,
        effort_f: FloatArray,
        velocity_f: FloatArray | None = None,
        coulomb_f: FloatArray | None = None,
        regressor_f: FloatArray | None = None,
        regressor_mask: BoolArray | None = None,
    ) -> SpeedStats:
        """``from_arrays`` of rows that stand for samples (a grid's nodes for their cells'):
        ``weight`` (N, D, B) counts, per row, joint and bin of the joint's speed, the samples
        a row stands for."""
        sim = np.asarray(sim_effort_f, dtype=np.float64)
        joints = sim.shape[1]
        f = None if coulomb_f is None else coulomb_grid(coulomb_f, "whitening scale")
        y, kept = None, None
        if regressor_f is not None:
            y, kept = compact_regressor(regressor_f, regressor_mask)
        params = 0 if kept is None else kept.shape[1]
        out = cls.zeros(joints, params, 0 if f is None else f.shape[1])
        effort = np.asarray(effort_f, dtype=np.float64)
        velocity = np.zeros_like(sim) if velocity_f is None else np.asarray(velocity_f, np.float64)
        w = np.asarray(weight, dtype=np.float64)
        n, mean, cross = out.n.copy(), out.mean.copy(), out.cross.copy()
        ends = None if kept is None else np.cumsum(kept.sum(axis=1))
        with one_blas_thread():
            for j in range(joints):
                if kept is None or y is None or ends is None:
                    joint_kept, joint_y = np.zeros(0, bool), np.zeros((len(sim), 0))
                else:
                    joint_kept = kept[j]
                    joint_y = y[:, ends[j] - np.count_nonzero(kept[j]) : ends[j]]
                coulomb = np.zeros((len(sim), 0)) if f is None else f[:, :, j]
                for b in np.flatnonzero(w[:, j].any(axis=0)):
                    at = np.flatnonzero(w[:, j, b])
                    n[b, j] = int(w[at, j, b].sum())
                    mean[b, j], cross[b, j] = _joint_moments(
                        joint_kept,
                        sim[at, j],
                        joint_y[at],
                        velocity[at, j],
                        coulomb[at],
                        effort[at, j],
                        w[at, j, b],
                    )
        return cls(n, mean, cross, params, out.coulomb)

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


def speed_scale(stats: SpeedStats, model: ResidualModel, overall: FloatArray) -> FloatArray:
    """(D, B) each joint's residual RMS under ``model`` in each bin of its own speed, exact
    from ``stats``; a bin with fewer than ``MIN_BIN_SAMPLES`` samples takes ``overall`` (D,)."""
    w = model.residual_weights(stats.params, stats.coulomb)
    spread = np.einsum("dk,bdkl,dl->bd", w, stats.cross, w)
    offset = np.einsum("bdk,dk->bd", stats.mean, w) - model.b_
    sse = np.maximum(spread, 0.0) + stats.n * offset**2
    rms = np.sqrt(sse / np.maximum(stats.n, 1))
    enough = stats.n >= MIN_BIN_SAMPLES
    out: FloatArray = np.where(enough, rms, np.asarray(overall, np.float64)[None, :]).T
    return np.maximum(out, _MIN_SCALE)


def wilson_hilferty(x: FloatArray, k: int) -> FloatArray:
    """χ²_k values as standard-normal z by Wilson and Hilferty's cube root (finite for x ≥ 0)."""
    c = 2.0 / (9.0 * k)
    out: FloatArray = (np.cbrt(x / k) - (1.0 - c)) / np.sqrt(c)
    return out


def depth_score(whitened: FloatArray, order: IndexArray | None = None) -> FloatArray:
    """(N,) the largest over k of the z of Σ_{i≤k} w_i² (χ²_k without a collision), the joints
    of (N, D) ``whitened`` taken in ``order`` (base first): a push on the k-th link loads
    joints 1…k, and one scale serves every k."""
    w = whitened if order is None else whitened[:, order]
    energy = np.cumsum(w * w, axis=1)
    z = np.empty_like(energy)
    for k in range(energy.shape[1]):
        z[:, k] = wilson_hilferty(energy[:, k], k + 1)
    out: FloatArray = z.max(axis=1) if z.shape[1] else np.zeros(len(z))
    return out


@lru_cache(maxsize=16)
def depth_noise_median(joints: int, ratio: float = 1.0) -> float:
    """The median of ``depth_score`` over ``joints`` independent normal residuals of standard
    deviation ``ratio``: with 1, the clean score of a model whose residual is exactly its noise
    (0.648 for 6 joints, 0.688 for 7); with 3, of a residual three times its noise (5.46 and
    5.92). By simulation with a fixed seed (2¹⁸ draws: ±0.003), the same in every run."""
    rng = np.random.default_rng(0)
    draws = rng.standard_normal((1 << 18, max(joints, 1)))
    if ratio != 1.0:
        draws = draws * ratio
    return float(np.median(depth_score(draws)))


@dataclass(frozen=True)
class FrictionSolution:
    a: FloatArray
    b: FloatArray
    c: FloatArray
    d: FloatArray
    epsilon: FloatArray
    r2: FloatArray
    rmse: FloatArray
    # (D, 3) which of a, c, d the logs do not determine (held at ``excitation.PRIOR``), at the
    # chosen ε (``twincd.calibration.excitation``)
    held: BoolArray | None = None


def _friction_prior() -> FloatArray:
    return np.array([PRIOR["a"], PRIOR["c"], PRIOR["d"]])


def solve_friction(stats: FrictionStats, resting: BoolArray | None = None) -> FrictionSolution:
    """Least squares per joint and ε from merged statistics; per joint the ε of least error.
    Coefficients the logs do not determine (``excitation.friction_held``; ``resting``: the
    joints that do not move) are held at their prior and the others fitted around them."""
    require_samples(stats.n, 5)
    cxx = stats.cross[..., :3, :3]  # (E, D, 3, 3)
    cxy = stats.cross[..., :3, 3]  # (E, D, 3)
    cyy = stats.cross[..., 3, 3]  # (E, D)
    # a column that does not vary (a joint at rest the whole time) must not make it singular
    ridge = 1e-9 * (np.trace(cxx, axis1=-2, axis2=-1)[..., None, None] + 1e-12) * np.eye(3)
    beta = np.linalg.solve(cxx + ridge, cxy[..., None])[..., 0]  # (E, D, 3)
    sse = np.maximum(cyy - np.einsum("eda,eda->ed", beta, cxy), 0.0)
    rmse = np.sqrt(sse / stats.n)
    held = friction_held(stats.n, stats.mean[..., :3], stats.cross[..., :3, :3], resting, rmse)
    if held.any():  # fitted again around the held ones (the shortcut for the error is LS's)
        beta = solve_held(cxx, cxy, held, _friction_prior(), ridge)
        sse = np.where(held.any(axis=-1), squared_error(cyy, cxy, cxx, beta), sse)
    best = np.argmin(sse, axis=0)  # (D,)
    joints = np.arange(sse.shape[1])
    coef = beta[best, joints]  # (D, 3)
    mean = stats.mean[best, joints]  # (D, 4)
    b = mean[:, 3] - np.einsum("da,da->d", coef, mean[:, :3])
    err = sse[best, joints]
    total = cyy[best, joints]
    r2 = r_squared(err, total)
    return FrictionSolution(
        a=coef[:, 0],
        b=b,
        c=coef[:, 1],
        d=coef[:, 2],
        epsilon=np.asarray(EPSILON_GRID)[best],
        r2=r2,
        rmse=np.sqrt(err / stats.n),
        held=held[best, joints],
    )


@dataclass(frozen=True)
class IdentifiedSolution:
    friction: FrictionSolution
    theta: FloatArray  # (D, P): per joint, the regressor's weights


def _ridge_solve(
    cxx: FloatArray, cxy: FloatArray, dead: BoolArray, prior: FloatArray
) -> FloatArray:
    """(D, m) ridge least squares on standardised columns, the ``dead`` ones held at ``prior``
    (the others fit what they leave); columns that never vary get a zero weight."""
    target = cxy - np.einsum("dab,db->da", cxx, prior)
    spread = np.sqrt(np.diagonal(cxx, axis1=1, axis2=2))
    live = spread > 1e-12 * np.maximum(spread.max(axis=1, keepdims=True), 1e-300)
    live &= ~dead
    unit = np.where(live, spread, 1.0)
    gram = cxx / (unit[:, :, None] * unit[:, None, :]) * (live[:, :, None] & live[:, None, :])
    gram = gram + IDENTIFIED_RIDGE * np.eye(cxx.shape[-1])
    beta = np.linalg.solve(gram, (target / unit * live)[..., None])[..., 0] / unit
    out: FloatArray = np.where(dead, prior, beta)
    return out


def _squared_error(
    stats: IdentifiedStats, cxx: FloatArray, cxy: FloatArray, beta: FloatArray
) -> FloatArray:
    fitted = np.einsum("da,dab,db->d", beta, cxx, beta)
    out: FloatArray = np.maximum(stats.cross[:, -1, -1] - 2 * (beta * cxy).sum(1) + fitted, 0.0)
    return out


def solve_identified(
    stats: IdentifiedStats, resting: BoolArray | None = None
) -> IdentifiedSolution:
    """Ridge least squares per joint and ε on standardised columns; per joint the ε of least
    training error (as ``solve_friction``). Coefficients the logs do not determine are held at
    their prior (a, c, d as ``solve_friction`` judges them on the same columns; a correction θ
    of an inertial parameter whose regressor column stays at one level, at 0)."""
    require_samples(stats.n, 5)
    p, e = stats.params, len(EPSILON_GRID)
    # the regressor's columns the intercept reproduces (zero columns excepted: never live)
    share = conditioning(
        stats.n,
        stats.mean[:, :, None],
        np.diagonal(stats.cross, axis1=1, axis2=2)[:, :, None, None],
    )[:, :, 0]  # (D, K): each column's spread over its RMS
    flat = undetermined(share) & (np.diagonal(stats.cross, axis1=1, axis2=2) > 0)
    sse = []
    betas = []
    helds = []
    for i in range(e):
        # columns: τ̂̃, Ỹ (P), q̇̃, this ε's Coulomb feature; target τ̃ (the last)
        use = np.r_[0 : p + 2, p + 2 + i]
        cxx = stats.cross[:, use[:, None], use[None, :]]  # (D, m, m)
        cxy = stats.cross[:, use, -1]  # (D, m)
        dead = np.zeros((len(cxx), len(use)), dtype=bool)
        dead[:, 1 : p + 1] = flat[:, 1 : p + 1]
        prior = np.zeros((len(cxx), len(use)))
        beta = _ridge_solve(cxx, cxy, dead, prior)
        error = _squared_error(stats, cxx, cxy, beta)
        cols = np.array([0, p + 2 + i, p + 1])  # τ̂̃, Coulomb, q̇̃: as FrictionStats
        held = friction_held(
            stats.n,
            stats.mean[:, cols],
            stats.cross[:, cols[:, None], cols[None, :]],
            resting,
            np.sqrt(error / stats.n),
        )  # (D, 3)
        if held.any():  # fitted again around the held ones
            dead[:, 0] = held[:, GAIN]
            dead[:, -1] = held[:, COULOMB]
            dead[:, p + 1] = held[:, VISCOUS]
            prior[:, 0] = np.where(held[:, GAIN], PRIOR["a"], 0.0)
            beta = _ridge_solve(cxx, cxy, dead, prior)
            error = _squared_error(stats, cxx, cxy, beta)
        sse.append(error)
        betas.append(beta)
        helds.append(held)
    errors = np.array(sse)  # (E, D)
    best = np.argmin(errors, axis=0)
    joints = np.arange(errors.shape[1])
    coef = np.array(betas)[best, joints]  # (D, P + 3)
    x_mean = np.concatenate(
        [stats.mean[joints, : p + 2], stats.mean[joints, p + 2 + best][:, None]], axis=1
    )
    b = stats.mean[:, -1] - np.einsum("da,da->d", coef, x_mean)
    err = errors[best, joints]
    total = stats.cross[:, -1, -1]
    r2 = r_squared(err, total)
    friction = FrictionSolution(
        a=coef[:, 0],
        b=b,
        c=coef[:, p + 2],
        d=coef[:, p + 1],
        epsilon=np.asarray(EPSILON_GRID)[best],
        r2=r2,
        rmse=np.sqrt(err / stats.n),
        held=np.array(helds)[best, joints],
    )
    return IdentifiedSolution(friction, coef[:, 1 : p + 1])


M = TypeVar("M", bound="ResidualModel")
# the per-joint coefficients a calibration file may hold (``ResidualModel.coefficients``)
COEFFICIENTS = ("a", "b", "c", "d", "epsilon", "scale", "theta")


class ResidualModel:
    """A map from the twin's effort (and the model's other prepared inputs) to the measured one,
    and the score of its residual; one subclass per model kind (scikit-learn style: parameters
    in ``__init__``, never changed by fitting; learned values end in ``_``).

    Fitting is ``stats`` per log or block, an exact merge (``merge``, ``+``), then ``solve``.
    Whitening is a property of the score: ``whitened`` models divide each joint's residual by
    its training RMS, per bin of the joint's speed (``speed_bins``; the depth statistic over the
    joints in ``order``, base first), or one per joint in files written before the bins (the
    sum); the others score Σ_j r_j².
    """

    name: ClassVar[str] = AFFINE  # the kind's stem in calibration files
    needs_coulomb: ClassVar[bool] = False  # prepared with the Coulomb features of every ε
    needs_regressor: ClassVar[bool] = False  # prepared with the joint-torque regressor
    learned: ClassVar[tuple[str, ...]] = ("a", "b", "scale")  # its ``COEFFICIENTS``

    a_: FloatArray
    b_: FloatArray
    scale_: FloatArray | None
    r2_: FloatArray | None
    rmse_: FloatArray | None
    n_samples_: int
    fit_s_: float
    joint_names_: tuple[str, ...]  # the joints of the logs ``fit`` saw
    held_: Held  # what the logs' motion did not determine (set by ``solve``)

    def __init__(
        self,
        whitened: bool = False,
        order: Sequence[int] | None = None,
        speed_bins: tuple[float, ...] = SPEED_BINS,
    ) -> None:
        self.whitened = whitened
        self.order = order
        self.speed_bins = speed_bins

    @property
    def kind(self) -> str:
        """The kind as calibration files name it (``MODEL_KINDS``)."""
        return f"{self.name}-whitened" if self.whitened else self.name

    # ------------------------------------------------------------------ its features

    @classmethod
    def fit_features(cls, whitened: bool) -> ModelFeatures:
        """What fitting a model of this class needs from the chain: the Coulomb features of
        every ε candidate (friction), the whole regressor (identified), the speed bins'
        statistics (whitened)."""
        return ModelFeatures(
            coulomb_eps=EPSILON_GRID if cls.needs_coulomb else (),
            regressor=cls.needs_regressor,
            speed_stats=whitened,
        )

    @property
    def features(self) -> ModelFeatures:
        """What this fitted model scores from (the chain computes exactly these)."""
        self._check()
        return ModelFeatures()

    # ------------------------------------------------------------------ fitting

    def stats(self, inputs: ModelInputs, clean: BoolArray) -> FitStats:
        """The statistics this model fits from, of prepared samples (``predict``'s inputs plus
        ``effort_f`` and the raw ``velocity``), rows where ``clean`` holds."""
        return FitStats.from_inputs(inputs, clean)

    @staticmethod
    def merge(parts: Iterable[FitStats]) -> FitStats:
        """Statistics of several logs or blocks together (exact, in any order)."""
        return reduce(operator.add, parts)

    def solve(self: M, stats: FitStats) -> M:
        """Fit from merged statistics; a whitened model also takes its scale from them (per
        speed bin with ``stats.speed``, else one per joint). Logs in which no joint moves are
        refused; coefficients their motion does not determine are held (``held_``,
        ``twincd.calibration.excitation``)."""
        check_motion(stats.motion, getattr(self, "joint_names_", None))
        self._solve_map(stats)
        self.scale_ = None
        if self.whitened:
            assert self.rmse_ is not None
            speed = stats.speed
            self.scale_ = self.rmse_ if speed is None else speed_scale(speed, self, self.rmse_)
        return self

    def fit(self: M, logs: Iterable[PreparedLog]) -> M:
        """Fit on the collision-free samples of prepared ``logs``, one at a time (may be lazy);
        ``fit_s_`` times the statistics and the solve, as the paper times training."""
        elapsed = 0.0
        parts = []
        for log_ in logs:
            start = time.perf_counter()
            parts.append(self.stats(model_inputs(log_), clean_mask(log_)))
            self.joint_names_ = log_.joint_names
            elapsed += time.perf_counter() - start
        if not parts:
            raise DataError("no logs to fit", "fit", "give at least one collision-free log")
        start = time.perf_counter()
        self.solve(self.merge(parts))
        self.fit_s_ = elapsed + time.perf_counter() - start
        return self

    def _solve_map(self, stats: FitStats) -> None:
        sol = solve(stats.affine)
        self.a_, self.b_, self.r2_, self.rmse_ = sol.a, sol.b, sol.r2, sol.rmse
        self.n_samples_ = stats.affine.n
        none = np.zeros_like(sol.held)
        resting = none if stats.resting is None else stats.resting
        self.held_ = Held(sol.held, none, none, resting, sol.gain_share)

    def with_coefficients(
        self: M,
        coefficients: Mapping[str, FloatArray | None],
        r2: FloatArray | None = None,
        rmse: FloatArray | None = None,
    ) -> M:
        """This model fitted with stored ``coefficients`` (``COEFFICIENTS``: those of the kind;
        what a calibration file holds)."""
        for key in self.learned:
            setattr(self, f"{key}_", coefficients.get(key))
        self.r2_, self.rmse_ = r2, rmse
        return self

    def coefficients(self) -> dict[str, FloatArray | None]:
        """Every field of ``COEFFICIENTS``, None where this kind has none."""
        self._check()
        return {key: getattr(self, f"{key}_", None) for key in COEFFICIENTS}

    def to_dict(self, joint_names: Sequence[str]) -> dict[str, Any]:
        """The model's block of the calibration file (``model``, read back by ``read_model``):
        its kind, how it scores (``statistic``; the depth statistic's ``speed_bins``) and each
        joint's coefficients."""
        coefficients = self.coefficients()
        statistic: dict[str, Any] = {"statistic": self.statistic}
        if self.statistic == "depth":
            statistic["speed_bins"] = list(self.speed_bins)

        def joint(i: int) -> dict[str, Any]:
            out: dict[str, Any] = {}
            for key in COEFFICIENTS:
                values = coefficients[key]
                if values is not None:
                    out[key] = values[i].tolist() if values.ndim == 2 else float(values[i])
            return out

        return {
            "kind": self.kind,
            **statistic,
            "joints": {n: joint(i) for i, n in enumerate(joint_names)},
        }

    # ------------------------------------------------------------------ the map

    def predict(self, inputs: ModelInputs) -> FloatArray:
        """The twin's effort mapped to the real robot's, (N, D), from prepared samples
        (``sim_effort_f``; friction models also ``velocity_f``, ``coulomb_f`` and
        ``coulomb_eps``; identified ones ``regressor_f`` or ``regressor_effort_f``)."""
        self._check()
        out: FloatArray = self.a_ * np.asarray(inputs.sim_effort_f, dtype=np.float64) + self.b_
        return out

    def residual(self, inputs: ModelInputs, predicted: FloatArray | None = None) -> FloatArray:
        """τ̃ − f(τ̂̃, …), (N, D) (``predicted``: ``predict(inputs)``, when already known)."""
        twin = self.predict(inputs) if predicted is None else predicted
        out: FloatArray = np.asarray(inputs.measured, np.float64) - twin
        return out

    def residual_weights(self, params: int, coulomb: int) -> FloatArray:
        """(D, K) the residual τ̃ − f(…) + b as weights on the columns of ``SpeedStats`` with
        ``params`` regressor entries and ``coulomb`` Coulomb features per joint."""
        w = np.zeros((len(self.a_), params + 3 + coulomb))
        w[:, 0] = -self.a_
        w[:, -1] = 1.0
        return w

    def _check(self) -> None:
        if not hasattr(self, "a_"):
            raise NotFittedError(
                f"the {self.kind} model is not fitted", type(self).__name__, "call fit()"
            )

    # ------------------------------------------------------------------ the score

    @property
    def statistic(self) -> str:
        """How residuals become a score (one of ``STATISTICS``; "sum" for unwhitened models)."""
        scale = getattr(self, "scale_", None)
        return "depth" if scale is not None and scale.ndim == 2 else "sum"

    def score(self, residual: FloatArray, velocity: FloatArray | None = None) -> FloatArray:
        """(N,) Σ_j r_j² (unwhitened), the depth statistic of r_j / s_j(|q̇_j|) (whitened,
        from the (N, D) joint ``velocity``), or Σ_j (r_j/s_j)² (whitened, written before the
        speed bins)."""
        scale = self.scale_
        if scale is None or scale.ndim == 1:
            r = residual if scale is None else residual / np.maximum(scale, _MIN_SCALE)
            out: FloatArray = np.einsum("ij,ij->i", r, r)
            return out
        return self.weigh(residual, velocity)[0]

    def weigh(
        self, residual: FloatArray, velocity: FloatArray | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """(N,) scores and the (N, D) evidence events weigh joints by: the residual whitened by
        speed for the depth statistic (computed once for both), else the residual itself."""
        if self.statistic != "depth":
            return self.score(residual), residual
        whitened = self._by_speed(residual, velocity)
        order = None if self.order is None else np.asarray(self.order, dtype=np.intp)
        return depth_score(whitened, order), whitened

    def whitened_residual(
        self, residual: FloatArray, velocity: FloatArray | None
    ) -> FloatArray | None:
        """(N, D) each joint's residual over its noise scale at its speed, the evidence the
        depth statistic weighs (None for models without speed bins)."""
        if self.statistic != "depth":
            return None
        return self._by_speed(residual, velocity)

    def _by_speed(self, residual: FloatArray, velocity: FloatArray | None) -> FloatArray:
        assert self.scale_ is not None
        if velocity is None:
            raise DataError(
                f"the {self.kind} model scores with the joints' speeds",
                "scoring",
                "pass the joint velocity with the residual",
            )
        bins = speed_bin(np.asarray(velocity, dtype=np.float64), self.speed_bins)
        joints = np.arange(residual.shape[1])
        out: FloatArray = residual / np.maximum(self.scale_, _MIN_SCALE)[joints[None, :], bins]
        return out

    def in_noise_units(
        self, residual: FloatArray, velocity: FloatArray | None = None
    ) -> FloatArray | None:
        """(N, D) each joint's residual over the noise the fit left it: over its scale at its
        speed (the depth statistic), its whitening scale, or its training RMSE (unwhitened);
        on clean data the calibration fits, an RMS of about 1 per joint. None when the model
        records no such scale."""
        if self.statistic == "depth":
            return self._by_speed(residual, velocity)
        scale = self.scale_ if self.scale_ is not None else self.rmse_
        if scale is None:
            return None
        out: FloatArray = residual / np.maximum(np.asarray(scale, np.float64), _MIN_SCALE)
        return out

    def scores(self, inputs: ModelInputs) -> FloatArray:
        """Per-sample scores of prepared samples (``predict``'s inputs, ``effort_f``, and the raw
        ``velocity`` for the depth statistic)."""
        return self.score(self.residual(inputs), inputs.velocity)

    @property
    def joint_scale(self) -> FloatArray | None:
        """The per-joint scale isolation divides an event's residual by: ones for a model
        with speed bins (its evidence is already ``whitened_residual``), the flat whitening
        scale, else the training residual RMS (None when unknown)."""
        if self.scale_ is not None:
            return self.scale_ if self.scale_.ndim == 1 else np.ones(len(self.scale_))
        return self.rmse_


class AffineModel(ResidualModel):
    """The seed paper's τ̃ ≈ a⊙τ̂̃ + b (eq. 3–4); unwhitened, its score is eq. 5."""

    def stats(self, inputs: ModelInputs, clean: BoolArray) -> FitStats:
        """Only the affine statistics, unless the whitening scale needs the speed bins."""
        if self.whitened:
            return super().stats(inputs, clean)
        affine = AffineStats.from_arrays(inputs.sim_effort_f, inputs.measured, clean)
        return FitStats(affine, motion=motion_stats(inputs, clean))


class FrictionModel(ResidualModel):
    """Per joint τ̃ ≈ a·τ̂̃ + b + c·LP[tanh(q̇/ε)] + d·q̇̃ (ε per joint from ``EPSILON_GRID``)."""

    name = "friction"
    needs_coulomb = True
    learned = (*ResidualModel.learned, "c", "d", "epsilon")

    c_: FloatArray
    d_: FloatArray
    epsilon_: FloatArray

    @property
    def features(self) -> ModelFeatures:
        """The Coulomb features at the ε its joints use (with the filtered velocity)."""
        self._check()
        return ModelFeatures(coulomb_eps=tuple(sorted({float(e) for e in self.epsilon_})))

    def _solve_map(self, stats: FitStats) -> None:
        if stats.friction is None:
            raise DataError(
                f"the {self.kind} model needs Coulomb features for every ε candidate",
                "fit",
                "prepare the logs with the model's fit_features",
            )
        self._set_friction(solve_friction(stats.friction, stats.resting), stats)

    def _set_friction(self, fr: FrictionSolution, stats: FitStats) -> None:
        self.a_, self.b_, self.c_, self.d_, self.epsilon_ = fr.a, fr.b, fr.c, fr.d, fr.epsilon
        self.r2_, self.rmse_ = fr.r2, fr.rmse
        self.n_samples_ = stats.affine.n
        held = np.zeros((len(fr.a), 3), dtype=bool) if fr.held is None else fr.held
        share = gain_share(stats.affine)
        resting = np.zeros(len(fr.a), dtype=bool) if stats.resting is None else stats.resting
        self.held_ = Held(held[:, GAIN], held[:, COULOMB], held[:, VISCOUS], resting, share)

    def predict(self, inputs: ModelInputs) -> FloatArray:
        out = super().predict(inputs)
        if inputs.coulomb_f is None or inputs.velocity_f is None:
            raise DataError(
                f"the {self.kind} model needs the filtered velocity and Coulomb features",
                "scoring",
                "prepare logs with the model's features (ResidualModel.features)",
            )
        coulomb = coulomb_columns(inputs.coulomb_f, inputs.coulomb_eps, self.epsilon_)
        # (τ̂ term + Coulomb) + viscous, in this order (the order fixes the rounding)
        with_friction: FloatArray = out + self.c_ * coulomb + self.d_ * inputs.velocity_f
        return with_friction

    def residual_weights(self, params: int, coulomb: int) -> FloatArray:
        if coulomb != len(EPSILON_GRID):
            raise DataError(
                f"the {self.kind} model's whitening needs every ε candidate's Coulomb feature",
                "fit",
                "prepare the logs with the model's fit_features",
            )
        w = super().residual_weights(params, coulomb)
        w[:, params + 1] = -self.d_
        at = [EPSILON_GRID.index(float(x)) for x in self.epsilon_]
        w[np.arange(len(w)), params + 2 + np.array(at, dtype=np.intp)] = -self.c_
        return w


class IdentifiedModel(FrictionModel):
    """Per joint τ̃ ≈ a·τ̂̃ + Ỹ_j θ_j + b + c·LP[tanh(q̇/ε)] + d·q̇̃: the friction model plus
    the URDF's inertial parameters corrected as each joint sees them (``solve_identified``)."""

    name = "identified"
    needs_regressor = True
    learned = (*FrictionModel.learned, "theta")

    theta_: FloatArray  # (D, P): per joint, the regressor's weights

    @property
    def features(self) -> ModelFeatures:
        """Its Coulomb features, and Ỹθ filtered per joint with its own θ."""
        return replace(super().features, regressor=True, theta=self.theta_)

    def _solve_map(self, stats: FitStats) -> None:
        if stats.friction is None:
            super()._solve_map(stats)  # the same error: the features of every ε are missing
        if stats.identified is None:
            raise DataError(
                f"the {self.kind} model needs the joint-torque regressor's statistics",
                "fit",
                "prepare the logs with the robot model (fit_features)",
            )
        ident = solve_identified(stats.identified, stats.resting)
        self._set_friction(ident.friction, stats)
        self.theta_ = ident.theta

    def predict(self, inputs: ModelInputs) -> FloatArray:
        out = super().predict(inputs)
        effort = inputs.regressor_effort_f
        if effort is not None:  # Ỹθ filtered as one channel per joint (twincd.chain)
            theta = inputs.regressor_theta
            if theta is None or theta.shape != self.theta_.shape or np.any(theta != self.theta_):
                raise DataError(
                    f"the samples carry Ỹθ filtered with another θ than this {self.kind} model's",
                    "scoring",
                    "prepare logs with the model's own features (ResidualModel.features)",
                )
            summed: FloatArray = out + np.asarray(effort, dtype=np.float64)
            return summed
        regressor = inputs.regressor_f
        regressor_mask = inputs.regressor_mask
        if regressor is None:
            raise DataError(
                f"the {self.kind} model needs the filtered joint-torque regressor",
                "scoring",
                "prepare logs with the model's features (ResidualModel.features)",
            )
        if regressor_mask is not None and np.ndim(regressor) == 2:
            if np.shape(regressor_mask) != self.theta_.shape:
                raise self._theta_mismatch(np.shape(regressor_mask)[1])
            from twincd.twin.dynamics import regressor_effort

            y = np.asarray(regressor, dtype=np.float64)
            return out + regressor_effort(y, self.theta_, np.asarray(regressor_mask, dtype=bool))
        if np.shape(regressor)[1:] != self.theta_.shape:
            raise self._theta_mismatch(np.shape(regressor)[-1])
        inertial: FloatArray = np.einsum("ndp,dp->nd", regressor, self.theta_)
        return out + inertial

    def residual_weights(self, params: int, coulomb: int) -> FloatArray:
        if self.theta_.shape[1] != params:
            raise self._theta_mismatch(params)
        w = super().residual_weights(params, coulomb)
        w[:, 1 : params + 1] = -self.theta_
        return w

    def _theta_mismatch(self, params: int) -> JointMismatchError:
        return JointMismatchError(
            f"the calibration's theta holds {self.theta_.shape[1]} inertial parameters "
            f"per joint, the robot model has {params}",
            "scoring",
            "use a calibration fitted with this robot's URDF, or re-run `twincd fit`",
        )


MODEL_CLASSES: dict[str, type[ResidualModel]] = {
    cls.name: cls for cls in (AffineModel, FrictionModel, IdentifiedModel)
}


def model_class(kind: str) -> tuple[type[ResidualModel], bool]:
    """The class of a model kind of ``MODEL_KINDS`` and whether it is whitened."""
    stem, whitened = kind.removesuffix("-whitened"), kind.endswith("-whitened")
    if kind not in MODEL_KINDS:
        raise UsageError(
            f"unknown calibration model {kind!r}",
            "fit",
            f"choose one of {', '.join(MODEL_KINDS)}",
            option="model",
        )
    return MODEL_CLASSES[stem], whitened


def fit_features(kind: str | None) -> ModelFeatures:
    """What fitting ``kind`` (``MODEL_KINDS``) needs from the chain; None, the best model the
    logs allow: every candidate's features, the regressor where a robot model is known."""
    if kind is None:
        return ModelFeatures(EPSILON_GRID, regressor=True, regressor_optional=True)
    cls, whitened = model_class(kind)
    return cls.fit_features(whitened)


def make_model(
    kind: str, order: Sequence[int] | None = None, speed_bins: tuple[float, ...] = SPEED_BINS
) -> ResidualModel:
    """An unfitted model of ``kind`` (``MODEL_KINDS``), its depth statistic over ``order``."""
    cls, whitened = model_class(kind)
    joints = None if order is None else tuple(int(i) for i in order)
    return cls(whitened, joints, speed_bins)


def model_inputs(log: PreparedLog) -> ModelInputs:
    """What a ``ResidualModel`` reads, from a whole prepared log."""
    return ModelInputs(
        effort_f=log.effort_f,
        sim_effort_f=log.sim_effort_f,
        velocity_f=log.velocity_f,
        coulomb_f=log.coulomb_f,
        coulomb_eps=log.coulomb_eps,
        regressor_f=log.regressor_f,
        regressor_effort_f=log.regressor_effort_f,
        regressor_theta=log.features.theta,
        velocity=log.states.velocity,
        position=log.states.position,
    )


def fit_model(
    kind: str,
    affine: AffineStats,
    friction: FrictionStats | None = None,
    identified: IdentifiedStats | None = None,
    speed: SpeedStats | None = None,
    order: Sequence[int] | None = None,
) -> ResidualModel:
    """``kind`` fitted from merged statistics (``ResidualModel.solve``): a whitened model takes
    its scale per speed bin from ``speed``, or without it one per joint (the sum, as files
    written before the speed bins)."""
    return make_model(kind, order).solve(FitStats(affine, speed, friction, identified))


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
        grid = inputs.coulomb_eps == EPSILON_GRID
        friction = None
        if grid:
            friction = FrictionStats.from_arrays(
                sim, _required(inputs.velocity_f), _required(inputs.coulomb_f), effort, clean
            )
        regressor = inputs.regressor_f if grid else None
        if not speed and regressor is None:
            return cls(affine, None, friction, None, motion)
        bins = SpeedStats.from_arrays(
            _required(inputs.velocity),
            sim,
            effort,
            inputs.velocity_f,
            inputs.coulomb_f if grid else None,
            regressor,
            inputs.regressor_mask,
            clean,
        )
        identified = None
        if regressor is not None:
            # the identified model's moments are the speed bins' pooled: one product, not two
            n, mean, cross = bins.pooled()
            identified = IdentifiedStats(n, mean, cross)
        return cls(affine, bins, friction, identified, motion)

    @classmethod
    def from_cells(
        cls, inputs: ModelInputs, count: IntArray, by_speed: IntArray, speed: bool = True
    ) -> FitStats:
        """``from_inputs`` of a grid's nodes (``twincd.grid``), each standing for the samples of
        its cell: ``count`` (N,) the clean samples each row stands for, ``by_speed``
        (N, D, B) those per joint and bin of the joint's own speed (what ``speed_bin`` gives
        each sample, as scoring bins it). The sums are the samples', each sample counted at
        its cell's node."""
        sim, effort = inputs.sim_effort_f, inputs.measured
        affine = AffineStats.from_weighted(sim, effort, count)
        grid = inputs.coulomb_eps == EPSILON_GRID
        friction = None
        if grid:
            friction = FrictionStats.from_weighted(
                sim, _required(inputs.velocity_f), _required(inputs.coulomb_f), effort, count
            )
        regressor = inputs.regressor_f if grid else None
        if not speed and regressor is None:
            return cls(affine, None, friction, None)
        bins = SpeedStats.from_weighted(
            by_speed,
            sim,
            effort,
            inputs.velocity_f,
            inputs.coulomb_f if grid else None,
            regressor,
            inputs.regressor_mask,
        )
        identified = None
        if regressor is not None:
            n, mean, cross = bins.pooled()
            identified = IdentifiedStats(n, mean, cross)
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


def depth_order(depths: Sequence[int] | None, joints: int) -> tuple[int, ...]:
    """The joints base first: by their depth in the kinematic tree when known (ties keep the
    joints' order), else as they come."""
    if depths is None:
        return tuple(range(joints))
    return tuple(int(i) for i in np.argsort(np.asarray(depths), kind="stable"))


class AffineCalibration(AffineModel):
    """The paper's a, b as an estimator on its own (the affine model, unwhitened), which also
    warns about joints whose slope is badly conditioned and predicts from the twin's effort
    alone. Learned attributes as ``AffineModel``'s, and ``stats_`` (the merged AffineStats)."""

    def __init__(
        self, joint_names: Sequence[str] | None = None, warn_ill_conditioned: bool = True
    ) -> None:
        super().__init__()
        self.joint_names = joint_names
        self.warn_ill_conditioned = warn_ill_conditioned

    def fit_arrays(
        self, effort_f: FloatArray, sim_effort_f: FloatArray, mask: BoolArray | None = None
    ) -> AffineCalibration:
        return self.fit_stats(AffineStats.from_arrays(sim_effort_f, effort_f, mask))

    def fit_stats(self, stats: AffineStats) -> AffineCalibration:
        """Fit from statistics merged elsewhere (e.g. computed per log on workers)."""
        self.fit_s_ = 0.0
        return self.solve(FitStats(stats))

    def solve(self, stats: FitStats) -> AffineCalibration:
        super().solve(stats)
        self.stats_ = stats.affine
        if self.warn_ill_conditioned:
            sol = solve(stats.affine)
            names = self.joint_names or getattr(self, "joint_names_", None)
            warn_ill_conditioned(names, stats.affine, sol.ill_conditioned, sol.a)
            labels = list(names or [f"#{i + 1}" for i in range(len(sol.a))])
            for line in self.held_.messages(labels):
                log.warning("%s", line)
        return self

    def predict(self, inputs: ModelInputs | FloatArray) -> FloatArray:
        """a⊙τ̂̃ + b: the twin's effort adjusted to the real robot (``inputs``: prepared
        samples, or the twin's effort τ̂̃ alone)."""
        if isinstance(inputs, ModelInputs):
            return super().predict(inputs)
        return super().predict(ModelInputs(sim_effort_f=np.asarray(inputs, dtype=np.float64)))


# ------------------------------------------------------------------ the file's model block


def _optional_column(
    coeff: Mapping[str, Any], names: Sequence[str], key: str, where: str
) -> FloatArray | None:
    """A per-joint coefficient that only some models have: all joints or none."""
    values = [coeff[n].get(key) for n in names]
    if all(v is None for v in values):
        return None
    if any(v is None for v in values):
        raise ValueError(f"coefficient {key!r} is missing for some joints")
    return finite_array(values, names, key, where)


def _speed_bins(model: Mapping[str, Any], where: str) -> tuple[float, ...] | None:
    """The depth statistic's speed bins (None: a model scored by the sum): rising, positive,
    finite edges."""
    statistic = model["statistic"]
    if statistic not in STATISTICS:
        raise CalibrationError(
            f"calibration field model.statistic is {statistic!r}, not one of "
            f"{', '.join(STATISTICS)}",
            where,
            "re-run `twincd fit`",
        )
    if statistic == "sum":
        return None
    edges = model["speed_bins"]
    if not isinstance(edges, list) or not edges:
        raise CalibrationError(
            "calibration field model.speed_bins is not a list of speeds",
            where,
            "re-run `twincd fit`",
        )
    out = tuple(finite_number(e, "model.speed_bins", where, positive=True) for e in edges)
    if any(b <= a for a, b in pairwise(out)):
        raise CalibrationError(
            "calibration field model.speed_bins does not rise", where, "re-run `twincd fit`"
        )
    return out


def _scale(
    coeff: Mapping[str, Any],
    names: Sequence[str],
    speed_bins: tuple[float, ...] | None,
    where: str,
) -> FloatArray | None:
    """The whitening scale: one number per joint (the sum), or one per speed bin (the depth
    statistic), all joints or none."""
    if speed_bins is None:
        return _optional_column(coeff, names, "scale", where)
    rows = [coeff[n].get("scale") for n in names]
    bins = len(speed_bins) + 1
    if any(not isinstance(r, list) or len(r) != bins for r in rows):
        raise CalibrationError(
            f"calibration field scale is not a list of {bins} numbers (one per speed bin) for "
            "every joint",
            where,
            "re-run `twincd fit`",
        )
    return np.array(
        [
            [finite_number(v, f"scale[{n}]", where) for v in r]
            for r, n in zip(rows, names, strict=True)
        ]
    )


def _theta(coeff: Mapping[str, Any], names: Sequence[str], where: str) -> FloatArray | None:
    """The identified models' per-joint regressor weights: all joints, of one length, or none."""
    rows = [coeff[n].get("theta") for n in names]
    if all(r is None for r in rows):
        return None
    if any(r is None for r in rows):
        raise ValueError("coefficient 'theta' is missing for some joints")
    lengths = {len(r) if isinstance(r, list) else -1 for r in rows}
    if len(lengths) != 1 or -1 in lengths:
        raise CalibrationError(
            "calibration field theta is not a list of numbers of one length per joint",
            where,
            "re-run `twincd fit`",
        )
    length = lengths.pop()
    if length == 0 or length % 10:
        raise CalibrationError(
            f"calibration field theta has {length} numbers per joint, not 10 per link",
            where,
            "re-run `twincd fit`",
        )
    return np.array(
        [
            [finite_number(v, f"theta[{n}]", where) for v in r]
            for r, n in zip(rows, names, strict=True)
        ],
        dtype=np.float64,
    )


def _require_coefficients(kind: str, extra: Mapping[str, FloatArray | None], where: str) -> None:
    cls, whitened = model_class(kind)
    needed = (
        (["c", "d", "epsilon"] if cls.needs_coulomb else [])
        + (["scale"] if whitened else [])
        + (["theta"] if cls.needs_regressor else [])
    )
    if extra.get("theta") is not None and not cls.needs_regressor:
        raise CalibrationError(
            f"the {kind} model has regressor weights (theta), which only identified models use",
            where,
            "re-run `twincd fit`",
        )
    missing = [k for k in needed if extra.get(k) is None]
    if missing:
        raise CalibrationError(
            f"the {kind} model lacks its coefficient(s) {', '.join(missing)}",
            where,
            "re-run `twincd fit`",
        )
    eps, scale = extra.get("epsilon"), extra.get("scale")
    if (eps is not None and not np.all(eps > 0)) or (scale is not None and not np.all(scale > 0)):
        raise CalibrationError("epsilon and scale must be positive", where, "re-run `twincd fit`")


def read_model(
    raw: Mapping[str, Any],
    names: Sequence[str],
    order: Sequence[int],
    where: str,
    r2: FloatArray | None = None,
    rmse: FloatArray | None = None,
) -> ResidualModel:
    """The fitted model of a calibration file's ``model`` block (``ResidualModel.to_dict``),
    every number validated; ``order`` the joints base first (the depth statistic's), ``r2``
    and ``rmse`` the fit's per joint. A ``CalibrationError`` for a block that is not one."""
    kind = raw.get("kind")
    if kind not in MODEL_KINDS:
        raise CalibrationError(
            f"unknown model kind {kind!r} (this twincd knows {', '.join(MODEL_KINDS)})",
            where,
            "re-run `twincd fit`",
        )
    coeff = raw["joints"]
    a = finite_array([coeff[n]["a"] for n in names], names, "a", where)
    b = finite_array([coeff[n]["b"] for n in names], names, "b", where)
    extra = {key: _optional_column(coeff, names, key, where) for key in ("c", "d", "epsilon")}
    speed_bins = _speed_bins(raw, where)
    extra["scale"] = _scale(coeff, names, speed_bins, where)
    extra["theta"] = _theta(coeff, names, where)
    _require_coefficients(str(kind), extra, where)
    model = make_model(str(kind), order, SPEED_BINS if speed_bins is None else speed_bins)
    return model.with_coefficients({"a": a, "b": b, **extra}, r2, rmse)
