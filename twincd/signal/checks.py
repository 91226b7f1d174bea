"""Signals that cannot be right, named before anyone trusts an answer built on them.

``SignalChecks`` is fed a log's positions and efforts block by block (per-joint minima and
maxima only: flat memory however long the log) and, at the end, says in one line each:

- positions outside the robot model's joint limits, and whether they look like degrees logged
  as radians;
- an effort that is zero, or constant, on every sample of a joint (no effort recorded, a
  driver that fills a placeholder).

It needs positions, efforts and the model's limits only, never the twin or the filters, so a
log can be checked without running them.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from twincd.types import FloatArray

log = logging.getLogger("twincd")


# positions this far outside a limit (a share of the joint's range, at least LIMIT_FLOOR in the
# joint's unit) are implausible. URDF limits are often narrower than the arm's real range (a
# real Doosan M0609 logs joints 0.5 rad, 10 % of the range, past its URDF's ±2.617): only what
# no such approximation explains is named (degrees, a wrong joint map)
LIMIT_TOLERANCE = 0.25
LIMIT_FLOOR = 1e-3
# an effort whose spread is below this share of its size (or exactly 0) carries no measurement
CONSTANT_EFFORT = 1e-12


class SignalChecks:
    """Per-joint position and effort ranges of one log, accumulated per block.

    ``limits`` maps a joint name to its (lower, upper) position limits; a joint it lacks, or
    with an infinite limit, is not checked against limits.
    """

    def __init__(
        self, joint_names: Sequence[str], limits: Mapping[str, tuple[float, float]]
    ) -> None:
        self.joint_names = tuple(joint_names)
        bounds = [limits.get(n, (-math.inf, math.inf)) for n in self.joint_names]
        self.lower = np.array([b[0] for b in bounds], dtype=np.float64)
        self.upper = np.array([b[1] for b in bounds], dtype=np.float64)
        d = len(self.joint_names)
        self.q_min, self.q_max = np.full(d, np.inf), np.full(d, -np.inf)
        self.e_min, self.e_max = np.full(d, np.inf), np.full(d, -np.inf)
        self.samples = 0

    def push(self, position: FloatArray, effort: FloatArray | None) -> None:
        """One block's positions and efforts, (N, joints) in ``joint_names`` order."""
        if not len(position):
            return
        self.samples += len(position)
        self.q_min = np.fmin(self.q_min, np.fmin.reduce(position, axis=0))
        self.q_max = np.fmax(self.q_max, np.fmax.reduce(position, axis=0))
        if effort is not None:
            self.e_min = np.fmin(self.e_min, np.fmin.reduce(effort, axis=0))
            self.e_max = np.fmax(self.e_max, np.fmax.reduce(effort, axis=0))

    def outside_limits(self, scale: float = 1.0) -> NDArray[np.bool_]:
        """Joints whose positions (times ``scale``) leave their limits by more than the
        tolerance."""
        span = np.where(np.isfinite(self.upper - self.lower), self.upper - self.lower, 0.0)
        tol = np.maximum(LIMIT_FLOOR, LIMIT_TOLERANCE * span)
        lo, hi = self.q_min * scale, self.q_max * scale
        seen = np.isfinite(self.q_min)
        out: NDArray[np.bool_] = seen & ((lo < self.lower - tol) | (hi > self.upper + tol))
        return out

    def looks_like_degrees(self) -> bool:
        """Positions beyond a turn that fit the limits once read as degrees."""
        outside = self.outside_limits()
        if not outside.any():
            return False
        biggest = float(np.max(np.maximum(np.abs(self.q_min), np.abs(self.q_max))[outside]))
        return biggest > 2 * math.pi and not self.outside_limits(math.pi / 180).any()

    def limit_warning(self, source: str) -> str | None:
        outside = np.flatnonzero(self.outside_limits())
        if not len(outside):
            return None
        joints = "; ".join(
            f"{self.joint_names[i]} {self.q_min[i]:.4g} to {self.q_max[i]:.4g} "
            f"(limits {self.lower[i]:.4g} to {self.upper[i]:.4g})"
            for i in outside
        )
        why = (
            "positions look like degrees: record radians"
            if self.looks_like_degrees()
            else "check the robot model, the joint map and the position unit"
        )
        return f"{source}: positions outside the robot model's joint limits: {joints}; {why}"

    def effort_warning(self, source: str) -> str | None:
        seen = np.isfinite(self.e_min)
        size = np.maximum(np.abs(self.e_min), np.abs(self.e_max))
        flat = seen & (self.e_max - self.e_min <= CONSTANT_EFFORT * size)
        if not flat.any():
            return None
        zero = flat & (size == 0)
        parts = []
        if zero.any():
            parts.append("all zero on " + ", ".join(self._names(zero)))
        if (flat & ~zero).any():
            parts.append("constant on " + ", ".join(self._names(flat & ~zero)))
        return (
            f"{source}: the effort is {' and '.join(parts)}: no measurement to compare with the "
            "twin; check that the driver records effort"
        )

    def _names(self, mask: NDArray[np.bool_]) -> list[str]:
        return [self.joint_names[i] for i in np.flatnonzero(mask)]

    def warnings(self, source: str) -> list[str]:
        """What cannot be right in the samples pushed so far, one line each."""
        found = (self.limit_warning(source), self.effort_warning(source))
        return [w for w in found if w is not None]

    def warn(self, source: str) -> None:
        """Each of ``warnings(source)`` through the ``twincd`` logger."""
        for line in self.warnings(source):
            log.warning("%s", line)
