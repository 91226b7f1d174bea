"""Copies of ``twincd synth`` paths that a user could get wrong: the arm held still (some joints
or all of them, with the friction a held joint keeps in its stiction band), or its effort in
another scale. The effort of a held copy comes from the synthetic plant itself (its rigid-body
dynamics, friction, gain, offset and noise), so only the motion differs; written with twincd's
own MCAP writer or as a rosbag2 sqlite3 folder through rosbags' writer.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from twincd.synth.config import SynthConfig
from twincd.synth.plant import make_plant
from twincd.synth.simulate import SynthRun, simulate_path
from twincd.synth.write import write_mcap, write_rosbag2
from twincd.twin.dynamics import inverse_dynamics

SEED = 3


def config(seconds: float = 12.0, longest: float | None = None) -> SynthConfig:
    base = SynthConfig()
    longest = seconds + 2.0 if longest is None else longest
    return replace(base, motion=replace(base.motion, duration_s=(seconds, longest)))


def path(
    split: str, index: int, seconds: float = 12.0, seed: int = SEED, longest: float | None = None
) -> SynthRun:
    """One collision-free path of the run set ``seed`` (as ``twincd synth`` writes it), of
    ``seconds`` to ``longest`` (default: 2 s more) seconds."""
    return simulate_path(config(seconds, longest), seed, split, index, collisions=False)


def held(run: SynthRun, joints: Sequence[int] | None = None, seed: int = SEED) -> SynthRun:
    """``run`` with ``joints`` (all: None) held at their first position: the plant's effort of
    that motion, a held joint's friction anywhere in its stiction band (a constant within
    ±0.8 of its Coulomb level) and the velocity the driver reports (noise)."""
    cfg = config()
    plant = make_plant(cfg.plant, seed)
    n, dof = run.position.shape
    still = np.zeros(dof, dtype=bool)
    still[list(range(dof)) if joints is None else list(joints)] = True
    rng = np.random.default_rng(seed + 17)
    position = np.where(still, run.position[:1], run.position)
    velocity = np.where(still, 0.0, run.true_velocity)
    acceleration = np.where(still, 0.0, run.acceleration)
    rigid = inverse_dynamics(plant.true, position, velocity, acceleration)
    stiction = plant.coulomb * rng.uniform(-0.8, 0.8, dof)
    friction = np.where(still, stiction, plant.friction(velocity))
    noise = rng.normal(size=(n, dof)) * plant.noise
    effort = (rigid + friction) / plant.gain + plant.offset + noise
    reported = velocity + rng.normal(0.0, plant.velocity_noise, (n, dof))
    return replace(run, position=position, velocity=reported, effort=effort)


def scaled(run: SynthRun, factor: float) -> SynthRun:
    """``run`` with its effort in another scale (a unit, a gear ratio, a current)."""
    return replace(run, effort=run.effort * factor)


def write(run: SynthRun, target: Path, form: str = "mcap") -> Path:
    """``run`` as a bare MCAP (twincd's writer) or a rosbag2 sqlite3 folder (rosbags')."""
    if form == "mcap":
        return write_mcap(run, target.with_suffix(".mcap"))
    if form == "rosbag2-sqlite3":
        return write_rosbag2(run, target)
    raise ValueError(form)
