"""Collision isolation: which link an event most likely touched (the seed paper's future work).

A force on link k makes torque only on the joints between the base and link k: the joints
beyond it feel nothing. So among the joints whose residual is significant during the event,
the deepest one in the kinematic tree bounds the touched link from below, and its child link
is named. A joint's evidence is its residual at the event's peak score, over the calibration's
per-joint noise scale (ones for a model with speed bins, whose residual is already over each
joint's noise at its speed), so joints of different noise levels are judged alike; it is
significant when it reaches ``kappa``. The value at the peak, rather than the largest magnitude
over the event (kept before), is taken where the push stands out most, and does not grow with
the event's length as the largest of many noisy samples does (a joint the push does not load
reaching κ by noise over a long event named a link too deep). The statistic (against the
largest magnitude, the RMS and the mean magnitude over the event, its early part, and the
projection on the event's common time profile), κ and ρ were chosen on synth development seeds
and the real arm's rotations (``studies/choose_isolation.py``).

A push whose line of action passes through a joint's axis makes no torque on that joint: it is
then named one link short, or not named. No rule on joint torques alone can tell those apart.

The rule knows when it does not know: a link is named only when the answer does not depend on
where exactly κ lies, i.e. the same link is named for every significance level in the band
[κ / ρ, κ × ρ] (``margin`` ρ ≥ 1): the deepest significant joint clears κ × ρ and every deeper
joint stays under κ / ρ. Otherwise the event's ``link`` is None and ``link_candidates`` lists
every link the rule names within the band: the one at κ first, then the deeper ones (a push
that reads one link short is the common miss), then the shallower ones.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from twincd.types import FloatArray

# κ and ρ: studies/choose_isolation.py on synth development seeds 2, 3 and 4 (303 found presses
# with identified-whitened, the default) keeps, of every statistic and setting, the one that names
# the most presses while right when named is ≥ 90 % on every seed and ≥ 93 % pooled (the ±3
# points one setting varies between seeds), and that names ≥ 70 % of the real arm's found
# pushes. The value at the score's peak, κ = 2.25, ρ = 1.3: 77.2 % named, 94.4 % right (95.9,
# 94.9, 92.7 % by seed), the real arm 125 of 161 named. The largest magnitude kept before
# (κ = 4, ρ = 1.3): 85.8 % named, 93.1 % right, but 89.9 % on seed 4; by the same rule
# (κ = 3.5): 76.6 %, 93.1 % (90.1 % on seed 4). The same setting is the best for identified
# (75.6 %, 94.8 %; 93.8 % on its worst seed) and better than before for friction-whitened (78 %
# named, 88 % right, against 86 % and 81 %); for the affine and friction models no statistic
# comes near the target: their residual during a push is mostly the twin's modelling error.
DEFAULT_KAPPA = 2.25
DEFAULT_MARGIN = 1.3


@dataclass(frozen=True)
class LinkIsolator:
    """Names the link of an event from each joint's residual at its peak score."""

    links: tuple[str, ...]  # each joint's child link, in the calibration's joint order
    depths: tuple[int, ...]  # each joint's depth in the kinematic tree
    scale: FloatArray  # each joint's noise scale (ones when the residual is already whitened)
    kappa: float = DEFAULT_KAPPA
    margin: float = DEFAULT_MARGIN

    def significance(self, at_peak: FloatArray) -> FloatArray:
        """Per joint: the residual's magnitude at the event's peak score over the joint's noise
        scale."""
        out: FloatArray = np.abs(np.asarray(at_peak, dtype=np.float64)) / np.maximum(
            self.scale, 1e-9
        )
        return out

    def named_at(self, z: FloatArray, level: float) -> str:
        """The child link of the deepest joint with significance ≥ ``level`` (the most
        significant joint's when none is)."""
        strong = np.flatnonzero(z >= level)
        if not len(strong):
            return self.links[int(np.argmax(z))]
        depth = np.asarray(self.depths)[strong]
        deepest = strong[depth == depth.max()]
        return self.links[int(deepest[np.argmax(z[deepest])])]

    def isolate(self, at_peak: FloatArray) -> tuple[str | None, tuple[str, ...]]:
        """(the link, or None when the evidence does not single one out; the candidates, most
        likely first), from each joint's residual at the event's peak score."""
        z = self.significance(at_peak)
        low, high = self.kappa / self.margin, self.kappa * self.margin
        # every level where the answer may change lies at a joint's significance
        levels = [low, *sorted(float(x) for x in z if low < x <= high), high]
        at_kappa = self.named_at(z, self.kappa)
        deeper_first = [self.named_at(z, level) for level in levels]
        candidates = tuple(dict.fromkeys([at_kappa, *deeper_first]))
        singled_out = len(candidates) == 1 and bool(np.any(z >= high))
        return (at_kappa if singled_out else None), candidates

    def link(self, at_peak: FloatArray) -> str | None:
        """The link when the evidence singles it out, else None."""
        return self.isolate(at_peak)[0]


def isolator_for(
    links: Sequence[str] | None,
    depths: Sequence[int] | None,
    scale: FloatArray | None,
    kappa: float = DEFAULT_KAPPA,
    margin: float = DEFAULT_MARGIN,
) -> LinkIsolator | None:
    """An isolator when the chain and the per-joint scale are known, else None."""
    if links is None or depths is None or scale is None:
        return None
    scale_ = np.asarray(scale, dtype=np.float64)
    return LinkIsolator(tuple(links), tuple(depths), scale_, kappa, margin)
