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
from twincd.calibration.crossfit import Folds, crossfit_log
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
