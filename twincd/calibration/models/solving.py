"""Least squares of the friction and identified maps from merged statistics, per joint and ε,
coefficients the logs' motion does not determine held at their prior."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from twincd.calibration.affine import r_squared, require_samples
from twincd.calibration.excitation import (
    COULOMB,
    GAIN,
    PRIOR,
    VISCOUS,
    affordable,
    conditioning,
    friction_held,
    scarce,
    solve_held,
    spanned,
    squared_error,
    undetermined,
)
from twincd.calibration.models.constants import EPSILON_GRID, IDENTIFIED_RIDGE
from twincd.calibration.models.statistics import FrictionStats, IdentifiedStats
from twincd.types import BoolArray, FloatArray


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
    # (D, 4) which of a, c, d, θ were held because the logs hold too few independent samples
    scarce: BoolArray | None = None


def _friction_prior() -> FloatArray:
    return np.array([PRIOR["a"], PRIOR["c"], PRIOR["d"]])


def solve_friction(
    stats: FrictionStats, resting: BoolArray | None = None, independent: float | None = None
) -> FrictionSolution:
    """Least squares per joint and ε from merged statistics; per joint the ε of least error.
    Coefficients the logs do not determine (``excitation.friction_held``; ``resting``: the
    joints that do not move; ``excitation.scarce``: more than the ``independent`` samples
    determine) are held at their prior and the others fitted around them."""
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
    few = scarce(~held, 0, independent)
    held |= few
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
        scarce=_with_theta(few[best, joints]),
    )


def _with_theta(few: BoolArray, theta: BoolArray | None = None) -> BoolArray:
    """(D, 4) the a, c, d (``few``, (D, 3)) and θ (``theta``, (D,); none) held for want of
    samples."""
    held_theta = np.zeros(len(few), dtype=bool) if theta is None else theta
    return np.concatenate([few, held_theta[:, None]], axis=1)


@dataclass(frozen=True)
class IdentifiedSolution:
    friction: FrictionSolution
    theta: FloatArray  # (D, P): per joint, the regressor's weights
    # (D,) joints whose θ the logs' motion does not determine: held at 0 (the URDF's)
    theta_held: BoolArray | None = None


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
    stats: IdentifiedStats, resting: BoolArray | None = None, independent: float | None = None
) -> IdentifiedSolution:
    """Ridge least squares per joint and ε on standardised columns; per joint the ε of least
    training error (as ``solve_friction``). Coefficients the logs do not determine are held at
    their prior (a, c, d as ``solve_friction`` judges them on the same columns; a correction θ
    of an inertial parameter whose regressor column stays at one level, at 0; every θ of a
    joint, at the URDF's, and then d, c, a, where the ``independent`` samples are too few for
    them, ``excitation.scarce``)."""
    require_samples(stats.n, 5)
    p, e = stats.params, len(EPSILON_GRID)
    diagonal = np.diagonal(stats.cross, axis1=1, axis2=2)
    # the regressor's columns the intercept reproduces (zero columns excepted: never live)
    share = conditioning(stats.n, stats.mean[:, :, None], diagonal[:, :, None, None])[:, :, 0]
    flat = undetermined(share) & (diagonal > 0)
    # θ as a whole, where the logs do not hold samples for it and the other coefficients
    live = ~flat[:, 1 : p + 1] & (diagonal[:, 1 : p + 1] > 0)
    directions = spanned(stats.cross[:, 1 : p + 1, 1 : p + 1], live)  # (D,)
    theta_held = affordable(independent) < 4 + directions  # b, a, c, d and θ's directions
    flat[:, 1 : p + 1] |= theta_held[:, None]
    sse = []
    betas = []
    helds = []
    fews = []
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
        few = scarce(~held, np.where(theta_held, 0, directions), independent)
        held |= few
        fews.append(few)
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
        scarce=_with_theta(np.array(fews)[best, joints], theta_held),
    )
    return IdentifiedSolution(friction, coef[:, 1 : p + 1], theta_held)
