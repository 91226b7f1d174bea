"""One score per sample from the residual of every band (the calibration file's ``score``).

The calibration's model scores its residual in the calibration's own filter band, the **slow**
band (``ResidualModel.score``: the depth statistic of each joint's residual over its noise at its
speed, or a sum of squares). A calibration fitted for contacts of every length also judges the
**fast** band, the residual between the slow cut-off and a faster one
(``twincd.signal.bands``): a hand strike of 0.1–0.7 s that the slow filter flattens stands out
there. Its noise is its own:

- each joint's residual RMS per bin of its speed, as for the slow band, or where larger its
  tail's (``FAST_TAIL_QUANTILE``: a joint whose fast residual bursts is judged on its bursts),
  measured on the fit's logs each scored by a model fitted without it
  (``twincd.calibration.crossfit``);
- never below ``FAST_FLOOR`` × the joint's slow-band noise: a joint at rest while the others move
  slips in its stiction band by a fraction of a newton-metre, bursts that no speed bin holds
  enough of to measure, yet a few times the fast band's noise of a resting joint;
- not judged around a **jump** of the logged velocity, a one-period change above
  ``JUMP_FACTOR`` × the joint's typical one (``jump``): a robot that stops dead in one period
  draws a one-sample current impulse of up to hundreds of N·m that the twin, differentiating
  the logged motion, cannot reproduce (``twincd.prepare.chain``'s ``fast_off``).

Both bands' scores are z of the depth statistic. Each band gets its share of the false-alarm
budget (``twincd.calibration.threshold``: its own threshold x_b over its clean median μ_b,
``levels``), and the score is the slow band's z or the fast band's carried onto the slow band's
scale, whichever is higher: s = max(z₀, μ₀ + (z₁ − μ₁)·(x₀ − μ₀)/(x₁ − μ₁)). So s reaches the
slow band's threshold x₀ exactly when one band reaches its own, and every figure on the score
(the μ + iσ sweep, AUC, peaks, hysteresis) reads one scale. Before a threshold is set the bands
are combined as they are (s = max z_b).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from twincd.calibration.models.constants import MIN_SCALE
from twincd.calibration.models.statistics import speed_bin
from twincd.calibration.models.whitening import depth_score
from twincd.signal.bands import Band
from twincd.types import BoolArray, FloatArray

if TYPE_CHECKING:
    from twincd.calibration.models import ResidualModel

__all__ = ["FAST_FLOOR", "JUMP_FACTOR", "BandLevel", "FastBand", "Score"]

# the fast band's noise scale is never below this share of the joint's slow-band noise
FAST_FLOOR = 0.5
# a one-period velocity change above this many times the joint's typical one is a jump
JUMP_FACTOR = 20.0


@dataclass(frozen=True)
class FastBand:
    """The fast band and its noise: (D, B) each joint's residual RMS per speed bin (the model's
    ``speed_bins``), and (D,) the floor no scale goes below."""

    band: Band
    scale: FloatArray
    floor: FloatArray

    def whitened(
        self, residual: FloatArray, velocity: FloatArray, speed_bins: Sequence[float]
    ) -> FloatArray:
        """(N, D) the fast band's residual over its noise at each joint's speed."""
        bins = speed_bin(np.asarray(velocity, dtype=np.float64), speed_bins)
        joints = np.arange(residual.shape[1])
        noise = np.maximum(np.maximum(self.scale, self.floor[:, None]), MIN_SCALE)
        out: FloatArray = residual / noise[joints[None, :], bins]
        return out

    def to_dict(self, joint_names: Sequence[str]) -> dict[str, Any]:
        return {
            **self.band.to_dict(),
            "joints": {
                n: {"scale": self.scale[i].tolist(), "floor": float(self.floor[i])}
                for i, n in enumerate(joint_names)
            },
        }


@dataclass(frozen=True)
class BandLevel:
    """A band's share of the threshold: its clean median (depth) or mean, and its own
    threshold."""

    mu: float
    value: float

    def to_dict(self) -> dict[str, float]:
        return {"mu": self.mu, "value": self.value}


@dataclass(frozen=True)
class Score:
    """How the residuals of every band become one score (see the module's docstring).

    ``fast``: the fast band and its noise (None: the model's own band only, as the paper's model
    and files written before the bands score). ``jump``: (D,) the one-period velocity change
    above which a joint jumps (None: no jump is looked for). ``levels``: the slow and the fast
    band's, once a threshold was set on both."""

    fast: FastBand | None = None
    jump: FloatArray | None = None
    levels: tuple[BandLevel, ...] = ()

    @property
    def bands(self) -> int:
        """How many bands are judged (1 or 2)."""
        return 1 if self.fast is None else 2

    def band_scores(
        self,
        model: ResidualModel,
        residual: FloatArray,
        velocity: FloatArray | None,
        fast_residual: FloatArray | None = None,
        edge_factor: FloatArray | None = None,
        fast_off: FloatArray | BoolArray | None = None,
    ) -> tuple[list[FloatArray], list[FloatArray]]:
        """Each band's score and the evidence events weigh joints by (``ResidualModel.weigh``):
        the slow band's from the model, the fast band's (when there is one) of its own, each
        sample over its edge factor in the band (``edge_factor``, (N, bands)) and the fast
        band's at −∞ where it is not judged (``fast_off``: around a jump)."""
        from twincd.signal.edges import edge_scaled

        scores, evidence = model.weigh(edge_scaled(residual, edge_factor, 0), velocity)
        if self.fast is None:
            return [scores], [evidence]
        if fast_residual is None or velocity is None:
            from twincd.errors import DataError

            raise DataError(
                "this calibration judges the fast band too",
                "scoring",
                "pass the fast band's residual and the joint velocities",
            )
        judged = edge_scaled(fast_residual, edge_factor, 1)
        whitened = self.fast.whitened(judged, velocity, model.speed_bins)
        order = None if model.order is None else np.asarray(model.order, dtype=np.intp)
        fast = depth_score(whitened, order)
        if fast_off is not None:
            fast = np.where(np.asarray(fast_off, dtype=bool).reshape(-1), -np.inf, fast)
        return [scores, fast], [evidence, whitened]

    def carried(self, band: int, z: Any) -> Any:
        """Band ``band``'s score ``z`` on the slow band's scale (as is before ``levels``)."""
        if band == 0 or len(self.levels) <= band:
            return z
        slow, level = self.levels[0], self.levels[band]
        return slow.mu + (z - level.mu) * self._gain(band)

    def band_level(self, band: int, x: float) -> float:
        """The score of band ``band`` that ``carried`` puts at ``x`` on the slow band's scale."""
        if band == 0 or len(self.levels) <= band:
            return x
        return self.levels[band].mu + (x - self.levels[0].mu) / self._gain(band)

    def _gain(self, band: int) -> float:
        slow, level = self.levels[0], self.levels[band]
        return (slow.value - slow.mu) / max(level.value - level.mu, 1e-12)

    def combine(self, scores: Sequence[FloatArray]) -> FloatArray:
        """One score from the bands' (the fast band's on the slow band's scale, ``levels``)."""
        if len(scores) == 1:
            return scores[0]
        carried = [self.carried(b, z) for b, z in enumerate(scores)]
        out: FloatArray = np.max(np.stack(carried), axis=0)
        return out

    def weigh(
        self, scores: Sequence[FloatArray], evidence: Sequence[FloatArray]
    ) -> tuple[FloatArray, FloatArray]:
        """(N,) the score and (N, D) the evidence of the band that gave it, per sample, from the
        bands' scores and evidence (``band_scores``)."""
        combined = self.combine(scores)
        if len(scores) == 1:
            return combined, evidence[0]
        fast_won = combined > scores[0]
        chosen: FloatArray = np.where(fast_won[:, None], evidence[1], evidence[0])
        return combined, chosen

    # ------------------------------------------------------------------ the file

    def to_dict(self, joint_names: Sequence[str]) -> dict[str, Any]:
        """The file's ``score`` block (empty bands: the model's own band only)."""
        out: dict[str, Any] = {"bands": 1 if self.fast is None else 2}
        if self.fast is not None:
            out["fast"] = self.fast.to_dict(joint_names)
        if self.jump is not None:
            out["jump"] = {
                "factor": JUMP_FACTOR,
                "joints": {n: float(self.jump[i]) for i, n in enumerate(joint_names)},
            }
        if self.levels:
            out["levels"] = [level.to_dict() for level in self.levels]
        return out


def read_score(d: Any, names: Sequence[str], where: str) -> Score:
    """The ``score`` block of a calibration file (None or absent: the model's own band only, as
    every file written before the bands), each number validated (a ``CalibrationError``
    naming the field)."""
    from twincd.calibration.values import finite_array, finite_number
    from twincd.errors import CalibrationError

    if d is None:
        return Score()
    if not isinstance(d, dict):
        raise CalibrationError("calibration field score is not an object", where, "re-run fit")
    fast = None
    if d.get("fast") is not None:
        block = d["fast"]
        joints = block["joints"]
        missing = [n for n in names if n not in joints]
        if missing:
            raise CalibrationError(
                f"calibration field score.fast.joints lacks {', '.join(missing)}",
                where,
                "re-run `twincd fit` to write a new one",
            )
        scale = np.array(
            [
                finite_array(
                    joints[n]["scale"],
                    [str(i) for i in range(len(joints[n]["scale"]))],
                    f"score.fast.joints.{n}.scale",
                    where,
                )
                for n in names
            ]
        )
        if scale.ndim != 2 or np.any(scale < 0):
            raise CalibrationError(
                "calibration field score.fast.joints.*.scale is not one non-negative list of "
                "the same length per joint",
                where,
                "re-run `twincd fit` to write a new one",
            )
        floor = finite_array(
            [joints[n]["floor"] for n in names], names, "score.fast.joints.*.floor", where
        )
        fast = FastBand(Band.from_dict(block), scale, np.maximum(floor, 0.0))
    jump = None
    if d.get("jump") is not None:
        per = d["jump"]["joints"]
        jump = finite_array([per.get(n) for n in names], names, "score.jump.joints", where)
    levels = tuple(
        BandLevel(
            finite_number(level["mu"], f"score.levels[{i}].mu", where),
            finite_number(level["value"], f"score.levels[{i}].value", where),
        )
        for i, level in enumerate(d.get("levels") or ())
    )
    bands = 1 if fast is None else 2
    if levels and len(levels) != bands:
        raise CalibrationError(
            f"calibration field score.levels has {len(levels)} level(s) for {bands} band(s)",
            where,
            "set the threshold again (`twincd threshold`)",
        )
    return Score(fast, jump, levels)
