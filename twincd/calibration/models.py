"""Calibration models beyond the paper's affine map (DESIGN §4 ``model``), and their scores.

- ``affine``: τ̃ ≈ a⊙τ̂̃ + b, score ‖r‖² (the seed paper, eq. 3–5).
- ``friction``: per joint τ̃ ≈ a·τ̂̃ + b + c·LP[tanh(q̇/ε)] + d·q̇̃, the joint friction (Coulomb
  and viscous) that the twin does not model; LP is the low-pass filter of the efforts and q̇̃
  the velocity through it, so that the features lag and smooth as the efforts do. ε is picked
  per joint from ``EPSILON_GRID`` by the smallest training residual: statistics for every
  candidate are gathered in one pass, so the choice uses the training logs only and still
  merges exactly.
- ``…-whitened``: the same map, score Σ_j (r_j / s_j)² with s_j the joint's residual RMS on the
  collision-free training samples, so that one noisy joint does not drown a push on a quiet one.

Fitting is a pure per-log step (``FrictionStats.from_arrays``) and an exact merge (``+``, Chan
et al.'s pairwise update of means and centred cross-products), like ``AffineStats``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from twincd.errors import DataError

if TYPE_CHECKING:
    from twincd.calibration.affine import AffineStats
    from twincd.pipeline import PreparedLog

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

AFFINE = "affine"
MODEL_KINDS = ("affine", "affine-whitened", "friction", "friction-whitened")
# ε candidates (rad/s) of the Coulomb term tanh(q̇/ε): from a near step to a soft ramp
EPSILON_GRID: tuple[float, ...] = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2)
# a joint whose residual is almost zero on training data must not get an infinite weight
_MIN_SCALE = 1e-6


def uses_friction(kind: str) -> bool:
    return kind.startswith("friction")


def is_whitened(kind: str) -> bool:
    return kind.endswith("-whitened")


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
        f = np.asarray(coulomb_f, dtype=np.float64)
        y = np.asarray(effort_f, dtype=np.float64)
        if f.ndim != 3 or f.shape[1] != len(EPSILON_GRID):
            raise DataError(
                f"Coulomb features of shape {f.shape} do not match the ε grid",
                "friction fit",
                "prepare the logs with coulomb_eps=EPSILON_GRID",
            )
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

    def __add__(self, other: FrictionStats) -> FrictionStats:
        if self.n == 0:
            return other
        if other.n == 0:
            return self
        from twincd.calibration.affine import same_joints

        same_joints(self.mean.shape[1], other.mean.shape[1])
        n = self.n + other.n
        delta = other.mean - self.mean
        return FrictionStats(
            n,
            self.mean + delta * (other.n / n),
            self.cross
            + other.cross
            + np.einsum("eda,edb->edab", delta, delta) * (self.n * other.n / n),
        )


@dataclass(frozen=True)
class FrictionSolution:
    a: FloatArray
    b: FloatArray
    c: FloatArray
    d: FloatArray
    epsilon: FloatArray
    r2: FloatArray
    rmse: FloatArray


def solve_friction(stats: FrictionStats) -> FrictionSolution:
    """Least squares per joint and ε from merged statistics; per joint the ε of least error."""
    from twincd.calibration.affine import require_samples

    require_samples(stats.n, 5)
    cxx = stats.cross[..., :3, :3]  # (E, D, 3, 3)
    cxy = stats.cross[..., :3, 3]  # (E, D, 3)
    cyy = stats.cross[..., 3, 3]  # (E, D)
    # a column that does not vary (a joint at rest the whole time) must not make it singular
    ridge = 1e-9 * (np.trace(cxx, axis1=-2, axis2=-1)[..., None, None] + 1e-12) * np.eye(3)
    beta = np.linalg.solve(cxx + ridge, cxy[..., None])[..., 0]  # (E, D, 3)
    sse = np.maximum(cyy - np.einsum("eda,eda->ed", beta, cxy), 0.0)
    best = np.argmin(sse, axis=0)  # (D,)
    joints = np.arange(sse.shape[1])
    coef = beta[best, joints]  # (D, 3)
    mean = stats.mean[best, joints]  # (D, 4)
    b = mean[:, 3] - np.einsum("da,da->d", coef, mean[:, :3])
    err = sse[best, joints]
    total = cyy[best, joints]
    r2 = np.where(total > 0, 1.0 - err / np.where(total > 0, total, 1.0), 1.0)
    return FrictionSolution(
        a=coef[:, 0],
        b=b,
        c=coef[:, 1],
        d=coef[:, 2],
        epsilon=np.asarray(EPSILON_GRID)[best],
        r2=r2,
        rmse=np.sqrt(err / stats.n),
    )


@dataclass(frozen=True)
class ResidualModel:
    """What scoring needs of a calibration: the map from twin to measured effort and the score.

    ``c``, ``d``, ``epsilon`` are set for friction models; ``scale`` for whitened ones.
    """

    kind: str
    a: FloatArray
    b: FloatArray
    c: FloatArray | None = None
    d: FloatArray | None = None
    epsilon: FloatArray | None = None
    scale: FloatArray | None = None

    def predict(self, inputs: Mapping[str, Any]) -> FloatArray:
        """The twin's effort mapped to the real robot's, (N, D), from prepared samples
        (``sim_effort_f``; friction models also ``velocity_f``, ``coulomb_f`` and
        ``coulomb_eps``)."""
        out: FloatArray = self.a * np.asarray(inputs["sim_effort_f"], dtype=np.float64) + self.b
        if self.c is not None and self.d is not None and self.epsilon is not None:
            if inputs.get("coulomb_f") is None or inputs.get("velocity_f") is None:
                raise DataError(
                    f"the {self.kind} model needs the filtered velocity and Coulomb features",
                    "scoring",
                    "prepare logs with the calibration's settings (Setup.from_calibration)",
                )
            coulomb = coulomb_columns(inputs["coulomb_f"], inputs["coulomb_eps"], self.epsilon)
            out = out + self.c * coulomb + self.d * np.asarray(inputs["velocity_f"])
        return out

    def residual(self, inputs: Mapping[str, Any]) -> FloatArray:
        """τ̃ − f(τ̂̃, …), (N, D)."""
        out: FloatArray = np.asarray(inputs["effort_f"], np.float64) - self.predict(inputs)
        return out

    def score(self, residual: FloatArray) -> FloatArray:
        """Σ_j r_j² (affine, friction) or Σ_j (r_j/s_j)² (whitened), (N,)."""
        r = residual if self.scale is None else residual / np.maximum(self.scale, _MIN_SCALE)
        out: FloatArray = np.einsum("ij,ij->i", r, r)
        return out

    def scores(self, inputs: Mapping[str, Any]) -> FloatArray:
        return self.score(self.residual(inputs))


def model_inputs(log: PreparedLog) -> dict[str, Any]:
    """What ``ResidualModel`` reads, from a whole prepared log."""
    return {
        "effort_f": log.effort_f,
        "sim_effort_f": log.sim_effort_f,
        "velocity_f": log.velocity_f,
        "coulomb_f": log.coulomb_f,
        "coulomb_eps": log.coulomb_eps,
    }


@dataclass(frozen=True)
class ModelFit:
    """A fitted residual model with its per-joint R² and RMSE on the training samples."""

    model: ResidualModel
    r2: FloatArray
    rmse: FloatArray


def fit_model(kind: str, affine: AffineStats, friction: FrictionStats) -> ModelFit:
    """``kind`` fitted from merged statistics (both kinds of statistics come from one pass)."""
    from twincd.calibration.affine import solve

    if uses_friction(kind):
        fr = solve_friction(friction)
        scale = fr.rmse if is_whitened(kind) else None
        model = ResidualModel(kind, fr.a, fr.b, fr.c, fr.d, fr.epsilon, scale)
        return ModelFit(model, fr.r2, fr.rmse)
    sol = solve(affine)
    scale = sol.rmse if is_whitened(kind) else None
    return ModelFit(ResidualModel(kind, sol.a, sol.b, scale=scale), sol.r2, sol.rmse)
