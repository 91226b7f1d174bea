"""Helpers for tests of calibration files, and a threshold from logs prepared in memory (a second
way to the threshold that ``twincd threshold`` streams, for tests that hold their logs)."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np
import pytest

from twincd.calibration import Calibration, clean_mask
from twincd.calibration.models import model_inputs
from twincd.calibration.threshold import BandCounter, LogScores, NoiseRatio, threshold_from_parts
from twincd.errors import CalibrationError
from twincd.prepare.prepared import PreparedLog
from twincd.signal.edges import edge_scaled


@contextlib.contextmanager
def refused(doc: dict[str, Any], match: str | None = None) -> Iterator[dict[str, Any]]:
    """A copy of the calibration document ``doc`` to break in the block; loading it
    (``Calibration.from_dict``) must then fail with a ``CalibrationError`` matching ``match``."""
    broken: dict[str, Any] = json.loads(json.dumps(doc))
    yield broken
    with pytest.raises(CalibrationError, match=match):
        Calibration.from_dict(broken)


def threshold_prepared_logs(
    logs: Iterable[PreparedLog],
    calibration: Calibration,
    k_sigma: float | None = None,
    false_alarms_per_hour: float | None = None,
) -> Calibration:
    """The threshold from logs already prepared in memory (a fit's filtered inputs, or prepared
    for the calibration's model), by the rules of ``threshold_from_parts``."""
    parts = []
    model, score = calibration.model, calibration.score
    for lg in logs:
        velocity = lg.states.velocity
        residual = lg.residual if lg.residual is not None else model.residual(model_inputs(lg))
        bands, _ = score.band_scores(
            model, residual, velocity, lg.residual_fast, lg.edge_factor, lg.fast_off
        )
        period = lg.period_s or float(np.median(np.diff(lg.states.stamp_ns))) * 1e-9
        counter = BandCounter(period, score.bands)
        counter.push(lg.states.stamp_ns, bands, score.combine(bands), lg.labels)
        judged = edge_scaled(residual, lg.edge_factor)
        noise = NoiseRatio.from_residual(model.in_noise_units(judged, velocity), clean_mask(lg))
        stats = counter.finish()
        parts.append(LogScores(lg.source, stats, len(lg), noise, counter.combined))
    # evaluate's thresholds: logs the calibration does not fit are said, and judged all the same
    return threshold_from_parts(parts, calibration, k_sigma, false_alarms_per_hour, refuse=False)
