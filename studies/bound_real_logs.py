"""What the bound on absurd samples (``twincd.signal.bounds``) drops on real recordings: every
labelled push of the real Doosan M0609 must survive it, and only recorder glitches may go.

For each real log it reads the samples as every command does, applies the bound with the arm's
URDF limits, and prints the samples dropped (with their times), and for the Doosan's labelled
pushes how many survive and how close their largest effort came to the bound. The recordings are
not part of the repository; they are read from ``../shared/data/`` beside it when present, and
the script says so when absent.

    python studies/bound_real_logs.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

DATA = Path(__file__).parents[1] / ".." / "shared" / "data"
ARMS = (
    ("doosan_m0609/logs/doosan_dev_0*", "doosan_m0609/m0609.urdf"),
    ("ur10e_clean/logs/ur-*", "ur10e_clean/ur10e.urdf"),
    ("panda_excitation/panda_excite_gaz2019", "panda"),
    ("real_panda_at_rest/joint_states.bag", "panda"),
)


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, end) index pairs of the runs of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(np.int8), [0]))))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def main() -> int:
    if not DATA.is_dir():
        print(f"{DATA.resolve()} is absent: nothing to study")
        return 0
    from twincd.prepare.robots import robot_for, sample_bounds
    from twincd.prepare.setup import read_log
    from twincd.signal.bounds import EFFORT_BOUND

    pushes = survived = 0
    closest = 0.0
    for pattern, model in ARMS:
        urdf = model if model == "panda" else str(DATA / model)
        for log in sorted(DATA.glob(pattern)):
            states = read_log(log)
            robot = robot_for(urdf, states.joint_names)
            states = states.select(robot.joint_names)
            bounds = sample_bounds(robot, robot.joint_names)
            assert states.effort is not None
            keep = bounds.keep(
                states.stamp_ns,
                position=states.position,
                velocity=None if states.velocity_from_position else states.velocity,
                effort=states.effort,
            )
            line = f"{log.name}: {len(keep)} samples, {int((~keep).sum())} dropped"
            if bounds.dropped.samples:
                line += f" at {bounds.dropped.times_s} s ({bounds.dropped.joints})"
            if states.labels is not None:
                limits = np.array([robot.effort_limits[n] for n in robot.joint_names])
                spans = runs(states.labels)
                kept = [bool(keep[a:b].all()) for a, b in spans]
                ratio = max(
                    float((np.abs(states.effort[a:b]) / (EFFORT_BOUND * limits)).max())
                    for a, b in spans
                )
                pushes += len(spans)
                survived += sum(kept)
                closest = max(closest, ratio)
                line += f"; labelled pushes {sum(kept)}/{len(spans)} whole, largest effort "
                line += f"{ratio:.1%} of the bound"
            print(line)
    print(
        f"Doosan: {survived} of {pushes} labelled pushes keep every sample; their largest "
        f"effort reaches {closest:.1%} of the bound"
    )
    return 0 if survived == pushes else 1


if __name__ == "__main__":
    sys.exit(main())
