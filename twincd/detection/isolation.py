"""Collision isolation: which link an event most likely touched (the seed paper's future work).

A force on link k makes torque only on the joints between the base and link k: the joints
beyond it feel nothing. So among the joints whose residual is significant during the event,
the deepest one in the kinematic tree bounds the touched link from below, and its child link
is named. A joint's residual is significant when its largest magnitude during the event exceeds
``kappa`` times its RMS on the collision-free training samples (the calibration's per-joint
scale), so joints of different noise levels are judged alike. The statistic (largest magnitude,
rather than the RMS over the event or the value at the score's peak) and ``kappa`` were chosen
on training and validation logs with simulated presses only (``studies/choose_models.py``).

A push whose line of action passes near a joint's axis (a push straight into a link behind a
roll joint) makes almost no torque on that joint: it is then named one link short. No rule on
joint torques alone can tell those apart.

The rule knows when it does not know: a link is named only when the answer does not depend on
where exactly κ lies, i.e. the same link is named for every significance level in the band
[κ / ρ, κ × ρ] (``margin`` ρ ≥ 1): the deepest significant joint clears κ × ρ and every deeper
joint stays under κ / ρ. Otherwise the event's ``link`` is None and ``link_candidates`` lists
every link the rule names within the band: the one at κ first, then the deeper ones (a push
that reads one link short is the common miss), then the shallower ones. ρ was chosen on synth
development seeds (``studies/choose_isolation.py``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from twincd.types import FloatArray

DEFAULT_KAPPA = 3.0
# κ per calibration model where validation chose another: the identified models' residual is
# near the sensor noise, so its training RMS is small and a push's significance larger
# (studies/choose_models.py, 216 simulated presses on validation logs, with their default
# critically damped filter: 0.916 at κ = 3.25 against 0.912 at κ = 3; Butterworth: 0.926, 0.902)
KAPPA_BY_MODEL = {"identified": 3.25, "identified-whitened": 3.25}


# ρ: a link is named only when every significance level in [κ / ρ, κ × ρ] names it; for the
# models without speed bins (studies/choose_isolation.py then, synth seed 2, identified-whitened
# with one flat scale per joint, 96 found presses: ρ = 1
# names all, 87.5 % right; 1.1: 94 % named, 90.0 % right; 1.2: 80 % named, 92.2 % right;
# 1.3: 72 %, 95.7 %; 1.5: 51 %, 95.9 %)
DEFAULT_MARGIN = 1.2


# κ for a model with speed bins, whose evidence is each joint's residual over its noise at its
# speed (``ResidualModel.whitened_residual``): studies/choose_isolation.py, ρ = 1.2. Synth seed 2
# (96 found presses): κ = 3.25 named 75 % (94.4 % right), 4: 91.7 % (94.3 %), 5: 96.9 %
# (92.5 %), 6: 92.7 % (91.0 %); the flat scale of before named 80 % (92.2 % right). Seeds 2 and
# 4 (196): κ = 3.25: 79.6 % (92.3 %), 4: 91.8 % (91.7 %), 5: 95.4 % (89.3 %).
KAPPA_BY_SPEED = 4.0


# ρ for a model with speed bins: studies/choose_isolation.py on synth seeds 2, 3 and 4 (303
# found presses), κ = 4: ρ = 1.2 names 92.1 % (91.8 % right; 94.3, 91.9 and 89.1 % by seed),
# 1.3: 85.8 % (93.1 %; 95.0, 94.5, 89.9 %), 1.4: 79.9 % (93.0 %). The study keeps the setting
# that names the most presses while its pooled right-when-named clears 90 % by the ±3 points
# that one setting varies between seeds: κ = 4, ρ = 1.3.
MARGIN_BY_SPEED = 1.3


def kappa_for(kind: str, statistic: str = "sum") -> float:
    """The significance factor κ of the isolation rule for a calibration model (``statistic``:
    the model's, "depth" for the models with speed bins)."""
    if statistic == "depth":
        return KAPPA_BY_SPEED
    return KAPPA_BY_MODEL.get(kind, DEFAULT_KAPPA)


def margin_for(statistic: str = "sum") -> float:
    """The isolation rule's margin ρ for a calibration model's ``statistic``."""
    return MARGIN_BY_SPEED if statistic == "depth" else DEFAULT_MARGIN


@dataclass(frozen=True)
class LinkIsolator:
    """Names the link of an event from its per-joint largest residual magnitude."""

    links: tuple[str, ...]  # each joint's child link, in the calibration's joint order
    depths: tuple[int, ...]  # each joint's depth in the kinematic tree
    scale: FloatArray  # each joint's residual RMS on collision-free training samples
    kappa: float = DEFAULT_KAPPA
    margin: float = DEFAULT_MARGIN

    def significance(self, peak_abs: FloatArray) -> FloatArray:
        """Per joint: the event's largest residual magnitude over the joint's training RMS."""
        out: FloatArray = np.asarray(peak_abs, dtype=np.float64) / np.maximum(self.scale, 1e-9)
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

    def isolate(self, peak_abs: FloatArray) -> tuple[str | None, tuple[str, ...]]:
        """(the link, or None when the evidence does not single one out; the candidates, most
        likely first)."""
        z = self.significance(peak_abs)
        low, high = self.kappa / self.margin, self.kappa * self.margin
        # every level where the answer may change lies at a joint's significance
        levels = [low, *sorted(float(x) for x in z if low < x <= high), high]
        at_kappa = self.named_at(z, self.kappa)
        deeper_first = [self.named_at(z, level) for level in levels]
        candidates = tuple(dict.fromkeys([at_kappa, *deeper_first]))
        singled_out = len(candidates) == 1 and bool(np.any(z >= high))
        return (at_kappa if singled_out else None), candidates

    def link(self, peak_abs: FloatArray) -> str | None:
        """The link when the evidence singles it out, else None."""
        return self.isolate(peak_abs)[0]


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
