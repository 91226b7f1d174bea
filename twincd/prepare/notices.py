"""What preparing a log says about it, and the logs it refuses: a stream's warnings (a sampling
rate other than the calibration's, ``judged_period``; velocity differentiated from position,
positions unwrapped, a log most of whose samples lie near a segment's end: ``warn_short``,
``edges_s``), ``said_already`` to silence them on a second pass, and the refusal of a log
without measured effort, with fewer than ``MIN_SAMPLES`` usable samples, or most of whose
intervals are gaps at the calibration's period (``refuse_gapped``).

``twincd.prepare.stream`` says them of a log read from disk, ``inspect`` and ``watch`` the same
of what they read, so every path says the same of a log.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING

import numpy as np

from twincd.errors import DataError
from twincd.signal.filters import LowPass
from twincd.types import FloatArray

if TYPE_CHECKING:
    from twincd.signal.unwrap import StreamingUnwrap

log = logging.getLogger("twincd")


# fewer usable samples than this: a log is refused, not scored (a few samples say nothing)
MIN_SAMPLES = 20
# a sample is near a segment's end (``warn_short``) where its filtered values carry this many
# times the noise of the segment's middle
SHORT_FACTOR = 1.5


@contextlib.contextmanager
def said_already() -> Iterator[None]:
    """Warnings off: a second pass over logs whose warnings the first pass gave (``threshold``
    counting its false alarms, ``fit`` cross-fitting)."""
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        log.setLevel(level)


def other_rate(source: str, own_s: float, calibrated_s: float | None) -> str | None:
    """What to say of a log or a live source sampled every ``own_s`` when the calibration was
    fitted at ``calibrated_s`` (more than 5 % apart; None: the same rate, or none recorded)."""
    if not calibrated_s or own_s <= 0 or abs(own_s / calibrated_s - 1) <= 0.05:
        return None
    return (
        f"{source} is sampled every {own_s * 1e3:.4g} ms, the calibration every "
        f"{calibrated_s * 1e3:.4g} ms; its filter and gap rule follow the calibration"
    )


def judged_period(source: str, own_s: float, calibrated_s: float | None) -> float:
    """The period a log sampled every ``own_s`` is judged at: the calibration's (said when the
    log's differs, ``other_rate``), else its own."""
    text = other_rate(source, own_s, calibrated_s)
    if text is not None:
        log.warning("%s", text)
    return calibrated_s or own_s


def gap_ns(period_s: float) -> float:
    """The interval over which two samples lie in different segments at ``period_s``."""
    from twincd.signal.stream import DEFAULT_GAP_FACTOR

    return DEFAULT_GAP_FACTOR * period_s * 1e9


def refuse_gapped(source: str, gapped: int, intervals: int, calibrated_s: float | None) -> None:
    """Refuse a log, or a live source, ``gapped`` of whose ``intervals`` (more than half) are
    gaps at the calibration's period (``gap_ns``): sampled that much slower than the
    calibration, its samples lie one or two to a segment, with nothing to filter them with."""
    from twincd.signal.stream import DEFAULT_GAP_FACTOR

    if calibrated_s and intervals and 2 * gapped > intervals:
        raise DataError(
            f"{gapped} of the {intervals} intervals between its samples are gaps, longer than "
            f"{DEFAULT_GAP_FACTOR:g} of the calibration's {calibrated_s * 1e3:.4g} ms periods: "
            "sampled this much slower than the calibration, it cannot be judged",
            source,
            "fit a calibration on logs recorded at this rate",
        )


def edges_s(lowpass: LowPass, period_s: float) -> float:
    """How far from a segment's ends the filter's start-up leaves its values noisier than the
    middle's by ``SHORT_FACTOR`` or more (at its start only, causal): a log of twice this (once,
    causal) is near an end throughout."""
    from twincd.signal.bands import slow_band
    from twincd.signal.edges import edge_profile

    profile = edge_profile(slow_band(lowpass), period_s)
    reach = max(_reach(profile.start), _reach(profile.end)) * period_s
    return reach * (1 if lowpass.causal else 2)


def _reach(factor: FloatArray) -> int:
    above = np.flatnonzero(factor >= SHORT_FACTOR)
    return int(above[-1]) + 1 if len(above) else 0


def warn_short(
    source: str, samples: int, near_ends: int, seconds: float, lowpass: LowPass, period_s: float
) -> None:
    """A log most of whose samples lie near a segment's end is judged with the noise the
    filter's start-up leaves there, less sensitively than a longer log: say so."""
    if samples and 2 * near_ends > samples:
        log.warning(
            "%s is short (%.3g s): %d of its %d samples lie within %.3g s of a segment's end, "
            "where this filter (%g Hz) leaves at least %g× the noise of a longer log's middle: "
            "collisions there are judged less sensitively",
            source,
            seconds,
            near_ends,
            samples,
            edges_s(lowpass, period_s) / (1 if lowpass.causal else 2),
            lowpass.cutoff_hz,
            SHORT_FACTOR,
        )


def warn_velocity_from_position(
    source: str, velocity: FloatArray, joint_names: Sequence[str]
) -> None:
    """The log lacks (finite) velocities: they are differentiated from position."""
    finite = np.asarray(np.isfinite(velocity).all(axis=0), dtype=bool)
    lacking = [n for i, n in enumerate(joint_names) if not finite[i]]
    log.warning(
        "%s: velocity missing on %s; differentiated from position where missing",
        source,
        ", ".join(lacking) if lacking else "some samples",
    )


def require_effort(has_effort: bool, source: str, topic: str, why: str | None = None) -> None:
    """A log without measured effort is refused by every command that compares it with the
    twin (and by ``inspect``, which says what those would do); ``why``: what the log has that
    cannot stand in (its DynamicJointState topic without an effort interface)."""
    if not has_effort:
        raise DataError(
            "the log has no measured effort" + (f", and {why}" if why else ""),
            f"{source}, {topic}",
            "record JointState.effort (or ros2_control's effort state interface); twincd "
            "compares it with the twin",
        )


def require_enough_samples(samples: int, source: str) -> None:
    """A log with fewer than ``MIN_SAMPLES`` usable samples is refused, never scored."""
    if samples < MIN_SAMPLES:
        raise DataError(
            f"log too short: {samples} usable sample(s), at least {MIN_SAMPLES} needed",
            source,
            "record at least a few seconds",
        )


def warn_unwrapped(source: str, unwrap: StreamingUnwrap | None, joints: Sequence[str]) -> None:
    """One warning for the joints whose positions wrapped (unwrapped before differentiating),
    one naming the steps that cannot be a wrap."""
    if unwrap is None or not len(unwrap.wraps):
        return
    wrapped = [f"{j} ({n})" for j, n in zip(joints, unwrap.wraps.tolist(), strict=True) if n]
    if wrapped:
        log.warning(
            "%s: positions wrap by a whole turn (2π) on %s; unwrapped before differentiating "
            "them into velocity",
            source,
            ", ".join(wrapped),
        )
    jumps = [
        f"{j} ({n}×, up to {big:.3g} rad, first at stamp {first})"
        for j, n, big, first in zip(
            joints,
            unwrap.jumps.tolist(),
            unwrap.largest_jump.tolist(),
            unwrap.first_jump_ns.tolist(),
            strict=True,
        )
        if n
    ]
    if jumps:
        log.warning(
            "%s: positions jump by more than π between two samples, and not by a whole turn: "
            "%s; no joint moves that fast, so the velocity differentiated there is wrong; check "
            "the log",
            source,
            "; ".join(jumps),
        )
