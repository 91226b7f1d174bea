"""What a run set of ``twincd synth`` is drawn from: the plant's errors, the motion and the
presses (``SynthConfig``), and its seed, whose generators (``seeded_rng``) make every path a
pure function of (config, seed, split, index)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from twincd.defaults import SYNTH_SEGMENT_S
from twincd.errors import UsageError

SPLITS = ("train", "val", "test")


@dataclass(frozen=True)
class PlantConfig:
    """What the twin does not know; drawn once per run set."""

    mass_sigma: float = 0.08
    com_sigma_m: float = 0.004
    payload_kg: float = 0.25
    payload_offset_m: float = 0.06  # centre beyond the flange, along the flange normal
    payload_radius_m: float = 0.03
    payload_length_m: float = 0.06
    coulomb_nm: tuple[float, ...] = (1.2, 1.2, 0.8, 0.8, 0.4, 0.3, 0.12)
    viscous_nms: tuple[float, ...] = (0.8, 0.8, 0.5, 0.5, 0.3, 0.2, 0.05)
    friction_spread: float = 0.2  # each coefficient × U(1 − s, 1 + s)
    coulomb_velocity: float = 0.02  # rad/s in tanh(q̇ / v)
    gain_range: tuple[float, float] = (0.72, 0.88)
    offset_sigma_nm: float = 0.2
    effort_noise_nm: tuple[float, ...] = (0.35, 0.35, 0.25, 0.25, 0.12, 0.10, 0.03)
    velocity_noise: float = 0.002  # rad/s
    float32: bool = True  # the driver reports float32 values


@dataclass(frozen=True)
class MotionConfig:
    """Teaching-point paths around a home pose (paper Table I)."""

    rate_hz: float = 100.0
    duration_s: tuple[float, float] = (22.0, 35.0)
    mean_speed_deg_s: float = 30.0
    radius_m: float = 0.2  # the flange stays within this of its home position
    point_radius_m: float = 0.18  # teaching points keep this margin
    home: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0)
    spread_rad: tuple[float, ...] = (0.25, 0.2, 0.3, 0.25, 0.5, 0.35, 0.8)
    rest_s: float = 0.5
    # a longer path is joined from segments of at most this, each home → points → home
    segment_s: float = SYNTH_SEGMENT_S
    latency_ms: tuple[float, float] = (0.2, 1.0)


@dataclass(frozen=True)
class CollisionConfig:
    """Hand presses on the moving arm (paper Fig. 4)."""

    presses: tuple[int, int] = (5, 7)  # per path, inclusive
    links: tuple[str, ...] = ("link3", "link4", "link5", "link6")
    force_n: tuple[float, float] = (8.0, 35.0)
    duration_s: tuple[float, float] = (0.4, 1.6)
    lead_s: tuple[float, float] = (0.0, 0.15)  # switch on before contact
    lag_s: tuple[float, float] = (0.0, 0.10)  # switch off after contact
    miss_probability: float = 0.15  # label on, nothing touched
    surface_radius_m: float = 0.045
    margin_s: float = 1.0  # no press in the first/last second


@dataclass(frozen=True)
class SynthConfig:
    """A run set's configuration: its plant, its motion, the presses of its test paths."""

    plant: PlantConfig = field(default_factory=PlantConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    collision: CollisionConfig = field(default_factory=CollisionConfig)


def seeded_rng(seed: int, *key: int) -> np.random.Generator:
    """The generator of ``key`` in the run set ``seed``: the plant's is ``(0,)``, a path's
    ``(1 + its split's number, its index)``, a segment's that and its number."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), *key]))


def check_seed(seed: int) -> None:
    if seed < 0:
        raise UsageError(
            f"seed must be ≥ 0, got {seed}", "seed", "give a non-negative integer", option="seed"
        )


def check_durations(cfg: MotionConfig) -> None:
    """A path's duration range holds its rests and a second of motion; a segment two such."""
    if not 2 * cfg.rest_s + 1.0 <= cfg.duration_s[0] <= cfg.duration_s[1]:
        raise UsageError(
            f"bad path duration range {cfg.duration_s[0]}–{cfg.duration_s[1]} s",
            "MotionConfig.duration_s",
            f"give {2 * cfg.rest_s + 1.0:g} s ≤ min ≤ max",
            option="min_duration,max_duration",
        )
    if not cfg.segment_s >= 2 * (2 * cfg.rest_s + 1.0):
        raise UsageError(
            f"segment length {cfg.segment_s} s too short",
            "MotionConfig.segment_s",
            f"give {2 * (2 * cfg.rest_s + 1.0):g} s or more",
        )
