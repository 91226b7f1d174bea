"""What the logs' motion determines of a model (contract: Exit codes and streams, ``fit``).

A coefficient is learned from how its column varies across the fit's samples. Four ways it
cannot be (per joint):

- the arm does not move: every joint's position stays within ``REST_POSITION`` (std) of one
  pose, and every column is a constant plus noise. ``fit`` refuses (``check_motion``).
- a joint does not move (its position within ``REST_POSITION``): its friction is never engaged,
  and the Coulomb and viscous columns carry the velocity's noise only. Its ``c`` and ``d`` are
  held at 0.
- a column the others and the intercept reproduce (``conditioning``: its part not explained by
  them, at unit RMS, below ``1 / CONDITION_LIMIT``): the twin's effort at one level (one pose),
  a joint that turns one way only at one speed (tanh(q̇/ε) constant), a speed that never
  changes. Its coefficient trades against the offset ``b`` (or ``c`` against ``d``) on noise:
  ``a`` is held at 1 (the twin's effort as it is), ``c`` and ``d`` at 0, an inertial parameter's
  correction θ at 0.
- too few independent samples: the filtered signals of a fit carry 2·f_c values a second
  (``independent_samples``: a 2 s log at 100 Hz, its 0.63 s edges left out, holds 74 samples
  but about 2 independent ones after the 1.5 Hz filter), and each coefficient of a joint, its
  offset ``b`` among them, takes ``SAMPLES_PER_COEFFICIENT`` of them (``scarce``). Short of
  that the fit has about as many unknowns as values and fits their noise (a gain of −231 from
  2 s of a synthetic path, every column well conditioned against its few neighbours). Held
  first: the identified model's inertial correction θ, as a whole (its directions the motion
  spans, ``spanned``: θ stays at the URDF's), then ``d``, ``c``, then ``a``.

Held coefficients are fitted around (least squares of the others with them fixed, ``b`` always
free), recorded (``Calibration.held``) and said in one warning each, with the motion that would
determine them. On the real arm's logs and twincd's synthetic ones nothing is held: their
smallest share is 0.03 (the twin's effort of a shoulder joint on a synthetic path near home),
against 3·10⁻⁴ and below for an arm held in one pose (a synthetic copy held still, a real
Panda at rest); their joints' positions vary by 0.08 rad (std) and more, an arm at rest by
10⁻⁵ rad.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from twincd.errors import DataError
from twincd.signal.moments import Moments
from twincd.types import BoolArray, FloatArray, IntArray

# a joint whose position varies less than this (std over the clean samples, rad or m) does not
# move; encoders resolve far below it (a real arm at rest: 10⁻⁵ rad)
REST_POSITION = 0.01
# a coefficient's condition index (its column at unit RMS against the others and the intercept)
# above which the logs do not determine it
CONDITION_LIMIT = 1000.0
# a gain changed by this much must move the fit by more than its residual for a twin effort
# that stays at one level to determine it anyway (high-precision data)
GAIN_STEP = 0.1
# what a coefficient the motion does not determine is held at: the twin's effort as it is
# (gain 1), no friction (Coulomb c, viscous d)
PRIOR = {"a": 1.0, "c": 0.0, "d": 0.0}
# the friction models' columns judged here, in ``FrictionStats``'s order
GAIN, COULOMB, VISCOUS = 0, 1, 2
# independent samples each coefficient of a joint (its offset among them) takes: with fewer,
# a fit has about as many unknowns as values, and fits their noise
SAMPLES_PER_COEFFICIENT = 2.0


def independent_samples(n: float, cutoff_hz: float, period_s: float) -> float:
    """How many independent samples ``n`` samples low-passed at ``cutoff_hz`` hold: a filtered
    signal carries 2·f_c values a second (Nyquist), so n·min(1, 2·f_c·period)."""
    return n * min(1.0, 2.0 * cutoff_hz * period_s)


def affordable(independent: float | None) -> float:
    """How many coefficients per joint, its offset among them, ``independent`` samples
    determine (``SAMPLES_PER_COEFFICIENT`` each; None, not known: any number)."""
    return math.inf if independent is None else independent / SAMPLES_PER_COEFFICIENT


def spanned(cross: FloatArray, live: BoolArray) -> IntArray:
    """(D,) the number of directions the ``live`` (D, K) columns of centred cross-products
    ``cross`` (D, K, K) span within the condition limit: the eigenvalues of their correlation
    matrix above 1/``CONDITION_LIMIT``² of the largest (a set of columns the motion moves
    together counts once)."""
    out = np.zeros(len(cross), dtype=np.int64)
    for j in range(len(cross)):
        cols = np.flatnonzero(live[j])
        if not len(cols):
            continue
        block = cross[j][np.ix_(cols, cols)]
        unit = np.sqrt(np.maximum(np.diagonal(block), 1e-300))
        values = np.linalg.eigvalsh(block / np.outer(unit, unit))
        out[j] = int(np.count_nonzero(values > values[-1] / CONDITION_LIMIT**2))
    return out


def scarce(free: BoolArray, extra: IntArray | int, independent: float | None) -> BoolArray:
    """(..., 3) which of a, c, d (``free`` (..., 3): not held otherwise) to hold so that a
    joint's coefficients, its offset, the free ones among a, c, d and ``extra`` more (θ's
    directions), fit in what ``independent`` samples determine (``affordable``): d first,
    then c, then a (the friction the twin lacks before the gain on the twin's own effort)."""
    room = affordable(independent) - 1.0 - np.asarray(extra, dtype=np.float64)
    count = free.sum(axis=-1)
    held = np.zeros_like(free)
    for k in (VISCOUS, COULOMB, GAIN):
        drop = free[..., k] & (count > room)
        held[..., k] = drop
        count = count - drop
    return held


@dataclass(frozen=True)
class MotionStats:
    """Mergeable count, mean and centred sum of squares of each joint's position (Chan et al.'s
    update: exact in any order): how far each joint moved over the clean samples."""

    n: int
    mean: FloatArray  # (D,)
    m2: FloatArray  # (D,) Σ (q − q̄)²

    @classmethod
    def from_arrays(cls, position: FloatArray, mask: BoolArray | None = None) -> MotionStats:
        q = np.asarray(position, dtype=np.float64)
        if mask is not None:
            q = q[mask]
        if len(q) == 0:
            z = np.zeros(q.shape[1] if q.ndim == 2 else 0)
            return cls(0, z, z)
        mean = q.mean(axis=0)
        return cls(len(q), mean, ((q - mean) ** 2).sum(axis=0))

    def __add__(self, other: MotionStats) -> MotionStats:
        merged = Moments(self.n, self.mean, self.m2) + Moments(other.n, other.mean, other.m2)
        return MotionStats(int(merged.n), merged.mean, merged.m2)

    @property
    def spread(self) -> FloatArray:
        """Each joint's position standard deviation."""
        out: FloatArray = np.sqrt(self.m2 / max(self.n, 1))
        return out

    @property
    def resting(self) -> BoolArray:
        """The joints that do not move (``REST_POSITION``)."""
        out: BoolArray = self.spread < REST_POSITION
        return out


def check_motion(motion: MotionStats | None, names: Sequence[str] | None = None) -> None:
    """Refuse logs in which no joint moves: no coefficient but the offset can be learned."""
    if motion is None or motion.n == 0 or not bool(np.all(motion.resting)):
        return
    spread = motion.spread
    i = int(np.argmax(spread))
    joint = names[i] if names is not None and i < len(names) else f"#{i + 1}"
    raise DataError(
        f"the logs hold no motion: every joint's position varies by less than "
        f"{REST_POSITION:g} rad (std; most: {spread[i]:.2g} rad on {joint}), so the twin's "
        "effort and the friction never change and nothing but an offset can be fitted",
        "fit",
        "fit on collision-free logs of the arm moving through its work, each joint both ways "
        "at several speeds",
    )


def conditioning(n: int, mean: FloatArray, cross: FloatArray) -> FloatArray:
    """(..., K) for each of K columns the part of it (at unit RMS) that the other columns and
    the intercept do not reproduce, from their means (..., K) and centred cross-products
    (..., K, K) over ``n`` samples: 1 for a column orthogonal to the rest, 0 for one they
    reproduce exactly; its inverse is the column's condition index. A column that is all
    zeros gets 0."""
    k = mean.shape[-1]
    count = max(n, 1)
    moments = np.zeros((*mean.shape[:-1], k + 1, k + 1))
    moments[..., 0, 0] = 1.0
    moments[..., 0, 1:] = mean
    moments[..., 1:, 0] = mean
    moments[..., 1:, 1:] = cross / count + mean[..., :, None] * mean[..., None, :]
    rms = np.sqrt(np.maximum(np.diagonal(moments, axis1=-2, axis2=-1), 0.0))
    zero = rms <= 0.0
    unit = np.where(zero, 1.0, rms)
    scaled = moments / (unit[..., :, None] * unit[..., None, :])
    scaled = np.where(zero[..., :, None] | zero[..., None, :], 0.0, scaled)
    # a tiny ridge: columns the others reproduce exactly get a share near 0, not a pseudo-inverse
    eye = np.eye(k + 1)
    inverse = np.linalg.inv(scaled + 1e-12 * eye)
    share = 1.0 / np.sqrt(np.maximum(np.diagonal(inverse, axis1=-2, axis2=-1), 1e-300))
    out: FloatArray = np.where(zero, 0.0, share)[..., 1:]
    return out


def undetermined(share: FloatArray) -> BoolArray:
    """Shares (``conditioning``) whose condition index exceeds ``CONDITION_LIMIT``."""
    out: BoolArray = share < 1.0 / CONDITION_LIMIT
    return out


def gain_held(share: FloatArray, spread: FloatArray, rmse: FloatArray) -> BoolArray:
    """Where a gain on the twin's effort is not determined: the effort stays at one level (its
    ``share`` against the intercept: ``conditioning``) and a ``GAIN_STEP`` change of the gain
    moves the fit (its ``spread`` times the step) by less than the fit's ``rmse``."""
    out: BoolArray = undetermined(share) & (GAIN_STEP * spread < rmse)
    return out


def friction_held(
    n: int, mean: FloatArray, cross: FloatArray, resting: BoolArray | None, rmse: FloatArray
) -> BoolArray:
    """(..., D, 3) which of a, c, d the logs do not determine, from the means (..., D, 3) and
    centred cross-products (..., D, 3, 3) of the columns [τ̂̃, LP[tanh(q̇/ε)], q̇̃] and the
    fit's residual RMS (..., D) with all three free: ``a`` when the twin's effort stays at one
    level (``gain_held``: the affine model's rule), ``c`` and ``d`` when their columns are
    reproduced by the others or the joint does not move (``resting``, (D,))."""
    held = undetermined(conditioning(n, mean, cross))
    share = conditioning(n, mean[..., :1], cross[..., :1, :1])[..., 0]
    spread = np.sqrt(np.maximum(cross[..., 0, 0], 0.0) / max(n, 1))
    held[..., GAIN] = gain_held(share, spread, rmse)
    if resting is not None:
        held[..., COULOMB] |= resting
        held[..., VISCOUS] |= resting
    return held


def solve_held(
    cxx: FloatArray, cxy: FloatArray, held: BoolArray, prior: FloatArray, ridge: FloatArray
) -> FloatArray:
    """(..., K) least squares of centred normal equations ``cxx`` β = ``cxy`` (plus ``ridge``,
    (..., K, K)) with the coefficients where ``held`` fixed at ``prior`` (K,): the others fit
    what the held ones leave. With nothing held, exactly ``solve(cxx + ridge, cxy)``."""
    fixed = np.where(held, prior, 0.0)
    free = ~held
    both = free[..., :, None] & free[..., None, :]
    matrix = np.where(both, cxx + ridge, 0.0) + np.where(held[..., None], np.eye(len(prior)), 0.0)
    rhs = np.where(free, cxy - np.einsum("...ab,...b->...a", cxx, fixed), fixed)
    out: FloatArray = np.linalg.solve(matrix, rhs[..., None])[..., 0]
    return out


def squared_error(
    cyy: FloatArray, cxy: FloatArray, cxx: FloatArray, beta: FloatArray
) -> FloatArray:
    """Σ (y − ȳ − β·(x − x̄))² from centred cross-products, for any β."""
    fitted = np.einsum("...a,...ab,...b->...", beta, cxx, beta)
    out: FloatArray = np.maximum(cyy - 2.0 * np.einsum("...a,...a->...", beta, cxy) + fitted, 0.0)
    return out


@dataclass(frozen=True)
class Held:
    """Per joint, the coefficients the logs' motion did not determine (held at ``PRIOR``; the
    identified model's θ at the URDF's), and why: the joints that did not move (``resting``),
    each joint's twin-effort share against the intercept (``gain_share``, for the message),
    and (``scarce``, (D, 4): a, c, d, θ) those held because the logs hold too few
    ``independent`` samples for them (``excitation.scarce``)."""

    a: BoolArray
    c: BoolArray
    d: BoolArray
    resting: BoolArray
    gain_share: FloatArray
    theta: BoolArray | None = None
    scarce: BoolArray | None = None
    independent: float | None = None

    @property
    def any(self) -> bool:
        theta = self.theta is not None and bool(self.theta.any())
        return bool(self.a.any() or self.c.any() or self.d.any()) or theta

    def _masks(self) -> tuple[tuple[str, BoolArray], ...]:
        none = np.zeros_like(self.a)
        return (
            ("a", self.a),
            ("c", self.c),
            ("d", self.d),
            ("theta", none if self.theta is None else self.theta),
        )

    def per_joint(self, joint: int) -> tuple[str, ...]:
        """The held coefficients' names of one joint."""
        return tuple(key for key, mask in self._masks() if mask[joint])

    def messages(self, names: Sequence[str], model: str = "") -> list[str]:
        """One line per reason, naming the joints and the motion that would determine them
        (``model``: the kind fitted, which the lines name)."""
        out = []

        def listed(mask: BoolArray) -> str:
            return ", ".join(n for n, m in zip(names, mask, strict=True) if m)

        scarce = np.zeros((len(self.a), 4), dtype=bool) if self.scarce is None else self.scarce
        if scarce.any():
            out.append(self._scarce_message(scarce, listed, model))
        if (self.a & ~scarce[:, GAIN]).any():
            held_a = self.a & ~scarce[:, GAIN]
            worst = float(np.min(self.gain_share[held_a]))
            out.append(
                f"these logs do not determine a (the gain on the twin's effort) on "
                f"{listed(held_a)}: the twin's effort there stays at one level (it varies by "
                f"{100 * worst:.2g} % of its size or less), so a and the offset b cannot be told "
                "apart; a is held at 1 (the twin's effort as it is). Move the arm through "
                "poses and speeds that change the effort on these joints"
            )
        still = self.resting & ((self.c & ~scarce[:, COULOMB]) | (self.d & ~scarce[:, VISCOUS]))
        if still.any():
            verb = "does" if int(still.sum()) == 1 else "do"
            out.append(
                f"{listed(still)} {verb} not move in these logs (position std below "
                f"{REST_POSITION:g} rad): their friction c and d are not determined and are held "
                "at 0. Give logs where these joints move both ways at several speeds"
            )
        friction = (
            (
                self.c,
                "c (Coulomb friction)",
                "the joint turns one way only, or its speed never leaves the Coulomb step; c is "
                "held at 0. Give logs where it moves both ways, at speeds well beyond ε",
            ),
            (
                self.d,
                "d (viscous friction)",
                "its speed hardly varies apart from its direction; d is held at 0. Give logs "
                "where it moves at several speeds",
            ),
        )
        for (held, coefficient, why), column in zip(friction, (COULOMB, VISCOUS), strict=True):
            moving = held & ~self.resting & ~scarce[:, column]
            if moving.any():
                out.append(f"these logs do not determine {coefficient} on {listed(moving)}: {why}")
        return out

    def _scarce_message(
        self, scarce: BoolArray, listed: Callable[[BoolArray], str], model: str
    ) -> str:
        """The line for what too few independent samples left held (``scarce``)."""
        groups = (
            (3, "θ (the URDF's inertial parameters re-fitted)"),
            (VISCOUS, "d (viscous friction)"),
            (COULOMB, "c (Coulomb friction)"),
            (GAIN, "a (the gain on the twin's effort)"),
        )
        which = "; ".join(
            f"{what} on {listed(scarce[:, k])}" for k, what in groups if scarce[:, k].any()
        )
        samples = "few" if self.independent is None else f"about {self.independent:.3g}"
        fitted = f"the {model} model" if model else "the model"
        return (
            f"these logs hold {samples} independent samples (their clean samples once "
            f"low-passed: 2 a second per Hz of cut-off), too few for every coefficient of "
            f"{fitted} ({SAMPLES_PER_COEFFICIENT:g} each, the offset b among them); held at "
            f"their prior (the twin as it is: θ at the URDF's, c and d at 0, a at 1): {which}. "
            "Fit on longer logs of the arm moving (a minute or more)"
        )
