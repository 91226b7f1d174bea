"""fit's second pass (``twincd.calibration.crossfit``): what it keeps of a log scored by a model
fitted without it does not depend on how the log is cut into blocks."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import build_twin_log
from support.clitools import run

from twincd.calibration import Calibration
from twincd.calibration.crossfit import (
    FAST_TAIL_QUANTILE,
    CrossScored,
    Folds,
    band_noise,
    crossfit_log,
)
from twincd.prepare.setup import Setup


@pytest.mark.parametrize("blocks", [5000, 777, 64])
def test_the_rows_kept_are_the_same_in_any_blocks(tmp_path: Path, blocks: int) -> None:
    """At 1 kHz one row in ten is kept; which ones follows the rows read, not the rows kept
    so far (which made the kept rows depend on the block size)."""
    log = build_twin_log(tmp_path / "fast.mcap", seconds=12.0, rate_hz=1000.0)
    cal_path = tmp_path / "cal.json"
    assert run("fit", log, "-o", cal_path).exit_code == 0
    cal = Calibration.load(cal_path)
    setup = replace(Setup.from_calibration(cal), fast_hz=cal.fast_hz)
    folds = Folds.of_logs([str(log)])
    models = [cal.model] * 5

    def kept(block_size: int) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        got = crossfit_log(
            log, replace(setup, block_size=block_size), models, folds, cal.score.jump
        )
        return got.stamp_ns, got.residual

    whole_stamps, whole = kept(16384)
    stamps, residual = kept(blocks)
    assert len(whole_stamps) < 12_001 // 5  # thinned
    assert np.array_equal(stamps, whole_stamps)
    for a, b in zip(residual, whole, strict=True):
        np.testing.assert_array_equal(a, b)


def _scored(source: str, residual: np.ndarray, velocity: np.ndarray) -> CrossScored:
    n = len(residual)
    return CrossScored(
        source=source,
        residual=(np.zeros_like(residual, dtype=np.float32), residual.astype(np.float32)),
        velocity=velocity.astype(np.float32),
        fit=np.ones(n, dtype=bool),
        clean=np.ones(n, dtype=bool),
        edge_factor=np.ones((n, 2), dtype=np.float32),
        fast_off=None,
        stamp_ns=np.arange(n, dtype=np.int64) * 10_000_000,
        period_s=0.01,
    )


def test_a_joint_whose_fast_residual_bursts_is_judged_on_its_tail() -> None:
    """The fast band's noise at a speed is the residual's RMS or, if heavier, its tail's (the
    99.9th percentile over a normal's), per speed bin: a joint that bursts at rest (1 % of its
    rest samples at 8–16 σ) then crosses 3.29 of its scales there no more often than a Gaussian
    joint does, where by its RMS it crossed them five times as often or more; its Gaussian
    moving samples and the Gaussian joint keep their RMS within a few %."""
    from scipy import stats

    rng = np.random.default_rng(3)
    n = 80_000
    moving = np.arange(n) % 2 == 1  # every other sample in the fastest speed bin
    quiet = rng.standard_normal(n)
    bursty = rng.standard_normal(n)
    spikes = ~moving & (rng.random(n) < 0.01)
    size = rng.uniform(8.0, 16.0, spikes.sum())
    bursty[spikes] = size * np.sign(rng.standard_normal(spikes.sum()))
    residual = np.column_stack([quiet, bursty])
    velocity = np.where(moving, 1.0, 0.0)[:, None] * np.ones((1, 2))
    parts = [_scored("a", residual[: n // 2], velocity[: n // 2]),
             _scored("b", residual[n // 2 :], velocity[n // 2 :])]  # fmt: skip
    bins = [0.003, 0.01, 0.03, 0.1, 0.3]
    rms, _ = band_noise(parts, 1, bins)
    scale, overall = band_noise(parts, 1, bins, tail=FAST_TAIL_QUANTILE)
    at_rest = residual[~moving]
    np.testing.assert_allclose(rms[:, 0], np.sqrt((at_rest**2).mean(axis=0)), rtol=1e-5)
    assert abs(scale[0, 0] / rms[0, 0] - 1.0) < 0.05
    assert scale[1, 0] > 2.0 * rms[1, 0]  # the bursts are judged on their tail
    assert abs(scale[1, 5] / rms[1, 5] - 1.0) < 0.05  # its Gaussian motion keeps its RMS
    z = float(stats.norm.ppf(0.5 + FAST_TAIL_QUANTILE / 2))
    crossing = np.abs(at_rest) > z * scale[:, 0]
    by_rms = np.abs(at_rest) > z * rms[:, 0]
    assert crossing[:, 1].mean() <= 1.5e-3 and by_rms[:, 1].mean() > 5e-3
    # a bin with too few samples takes the joint's overall scale, tail included
    np.testing.assert_allclose(scale[:, 3], overall)
    # the parts' order does not matter (but for the sums' rounding)
    again, _ = band_noise(parts[::-1], 1, bins, tail=FAST_TAIL_QUANTILE)
    np.testing.assert_allclose(again, scale, rtol=1e-12)
