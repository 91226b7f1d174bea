"""Helpers for the chunked = whole tests of streaming signal stages."""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import numpy as np


def chunked(stage: Any, stamps: np.ndarray, values: np.ndarray, cuts: list[int]) -> np.ndarray:
    """Push in pieces split at ``cuts``, then finish; every output is C-ordered (a layout that
    followed the chunking would change reductions downstream)."""
    edges = [0, *sorted(c for c in set(cuts) if 0 < c < len(stamps)), len(stamps)]
    out = [stage.push(stamps[a:b], values[a:b]) for a, b in itertools.pairwise(edges)]
    out.append(stage.finish())
    assert all(o.flags.c_contiguous and o.shape[1:] == values.shape[1:] for o in out)
    return np.concatenate(out)


def split_points(n: int, how: str | int, rng: np.random.Generator) -> list[int]:
    """Where to cut ``n`` samples: nowhere, at random places, or every ``how`` samples."""
    if how == "whole":
        return []
    if how == "random":
        return sorted(rng.choice(np.arange(1, max(n, 2)), size=min(n - 1, 6), replace=False))
    return list(range(int(how), n, int(how)))


class Frames:
    """A sink of ``detect``: the frames it scores (empty ones left out), by column."""

    def __init__(self) -> None:
        self.frames: list[Any] = []

    def write(self, frame: Any, events: object) -> None:
        if frame.n:
            self.frames.append(frame)

    def column(self, name: str) -> np.ndarray:
        return np.concatenate([f[name] for f in self.frames])


def detect_frames(log: Path, cal: Any, setup: Any = None) -> tuple[Any, Frames]:
    """``detect_streamed`` of ``log`` (with the calibration's own setup by default): its
    summary and the frames it scored."""
    from twincd.detection import detect_streamed
    from twincd.prepare.setup import Setup

    frames = Frames()
    if setup is None:
        setup = Setup.from_calibration(cal)
    return detect_streamed(log, cal, setup, [frames]), frames


T0_NS = 1_700_000_000_000_000_000  # absolute header stamps, as in real logs


def jittered_stamps(
    rng: np.random.Generator, n: int, period_ns: int, gaps: int = 0, t0: int = T0_NS
) -> np.ndarray:
    """``n`` stamps from ``t0``: ±15 % jitter around ``period_ns``, plus ``gaps`` intervals
    of 6–40 periods."""
    dt = np.rint(period_ns * (1 + rng.uniform(-0.15, 0.15, n))).astype(np.int64)
    if gaps and n > 1:
        where = rng.choice(np.arange(1, n), size=min(gaps, n - 1), replace=False)
        dt[where] = rng.integers(6 * period_ns, 40 * period_ns, len(where))
    return t0 + np.cumsum(dt) - dt[0]


def random_walk(
    rng: np.random.Generator,
    n: int,
    channels: int,
    step: float,
    step_rate: float,
    offset: float = 0.0,
) -> np.ndarray:
    """A random walk plus ``step``s at a ``step_rate`` per sample, from ``offset``: a signal
    with all kinds of features; (n, channels), channels 0 → (n,)."""
    c = max(channels, 1)
    y = offset + np.cumsum(rng.standard_normal((n, c)), axis=0)
    y += step * (rng.uniform(size=(n, c)) < step_rate).cumsum(axis=0)
    return y[:, 0] if channels == 0 else y


def blocks(n: int, size: int) -> list[slice]:
    """``n`` samples in blocks of ``size`` (the last one shorter)."""
    return [slice(a, a + size) for a in range(0, n, size)]


def pushed(detector: Any, states: Any, slices: list[slice], sim_effort: Any = None) -> list[Any]:
    """What ``detector`` (an ``OnlineDetector``) gives for each block of the samples
    ``states`` (and the twin's effort ``sim_effort``) pushed in turn."""
    return [
        detector.push(
            states.stamp_ns[sl],
            states.position[sl],
            states.velocity[sl],
            states.effort[sl],
            None if sim_effort is None else sim_effort[sl],
        )
        for sl in slices
    ]


def write_detection(result: Any, source: Path, target: Path) -> None:
    """A whole-log detection (``twincd.detection.detect_log``'s ``LogDetection``) written to
    ``target`` through ``detect``'s streaming sinks (``open_sink``), as one frame."""
    from twincd.detection.outputs import open_sink
    from twincd.prepare.frames import Frame

    states = result.log.states
    frame = Frame(
        {
            "stamp_ns": states.stamp_ns,
            "log_time_ns": states.log_time_ns,
            "position": states.position,
            "velocity": states.velocity,
            "residual": result.residual,
            "score": result.scores,
            "flag": result.flags,
        }
    )
    with open_sink(source, target, result.log.joint_names) as sink:
        sink.write(frame, result.events)
