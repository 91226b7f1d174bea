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
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

DEFAULT_KAPPA = 3.0
# κ per calibration model where validation chose another: the identified models' residual is
# near the sensor noise, so its training RMS is small and a push's significance larger
# (studies/choose_models.py, 216 simulated presses on validation logs, with their default
# critically damped filter: 0.916 at κ = 3.25 against 0.912 at κ = 3; Butterworth: 0.926, 0.902)
KAPPA_BY_MODEL = {"identified": 3.25, "identified-whitened": 3.25}


def kappa_for(kind: str) -> float:
    """The significance factor κ of the isolation rule for a calibration model."""
    return KAPPA_BY_MODEL.get(kind, DEFAULT_KAPPA)


@dataclass(frozen=True)
class LinkIsolator:
    """Names the link of an event from its per-joint largest residual magnitude."""

    links: tuple[str, ...]  # each joint's child link, in the calibration's joint order
    depths: tuple[int, ...]  # each joint's depth in the kinematic tree
    scale: FloatArray  # each joint's residual RMS on collision-free training samples
    kappa: float = DEFAULT_KAPPA

    def significance(self, peak_abs: FloatArray) -> FloatArray:
        """Per joint: the event's largest residual magnitude over the joint's training RMS."""
        out: FloatArray = np.asarray(peak_abs, dtype=np.float64) / np.maximum(self.scale, 1e-9)
        return out

    def link(self, peak_abs: FloatArray) -> str:
        z = self.significance(peak_abs)
        strong = np.flatnonzero(z >= self.kappa)
        if not len(strong):
            return self.links[int(np.argmax(z))]
        depth = np.asarray(self.depths)[strong]
        deepest = strong[depth == depth.max()]
        return self.links[int(deepest[np.argmax(z[deepest])])]


def isolator_for(
    links: Sequence[str] | None,
    depths: Sequence[int] | None,
    scale: FloatArray | None,
    kappa: float = DEFAULT_KAPPA,
) -> LinkIsolator | None:
    """An isolator when the chain and the per-joint scale are known, else None."""
    if links is None or depths is None or scale is None:
        return None
    return LinkIsolator(tuple(links), tuple(depths), np.asarray(scale, dtype=np.float64), kappa)
