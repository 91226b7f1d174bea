"""A log's ends never raise an event by themselves (contract: "Filter edges"), at any rate.

Clean xArm 7 logs at 50 Hz to 1 kHz, moving from their first sample to their last, are fitted
and thresholded at the defaults (the identified, whitened model and its critically damped
1.5 Hz filter; ``--causal`` for the causal one) and a fresh clean log is judged: zero-phase
(``detect``), causal (``detect`` with the causal calibration) and live (``OnlineDetector``). No
sample may be flagged, no event raised, ``detect`` must exit 0, and what is left out at each
segment's ends is the filter's settling time at that rate, computed here from scipy's step
response of the recorded filter. The 1 kHz log has a gap in the middle of its motion, so two
segments start and end there.

The plant is the twin itself (sinusoids as in benchmarks/bench_long.py, effort = gain ·
RNEA + offset + noise, reported velocity with noise): the model fits it exactly, so whatever the
score does at a log's ends is the edges' doing, not a misfit. (With the previous rule — half a
cut-off period left out, zero-phase only, and the extension pivoted on the end sample — these
logs were flagged at the end at 1 kHz, and causal at every segment's start at every rate.)
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from scipy import signal
from support.builders import XARM
from support.clitools import run
from support.streaming import pushed

from twincd.calibration import Calibration
from twincd.detection import OnlineDetector
from twincd.prepare.setup import Setup

RATES = (50, 100, 200, 500, 1000)
SECONDS = 20.0
GAP_RATE = 1000  # its fresh log loses 0.2 s mid-motion: a gap, two segments
T0_NS = 1_700_000_000_000_000_000
HOME = np.array([0.0, -0.3, 0.0, 1.0, 0.0, 1.3, 0.0])
GAIN = np.array([1.1, 0.9, 1.05, 0.85, 1.2, 0.95, 1.0])
OFFSET = np.array([0.3, -0.2, 0.1, 0.0, -0.1, 0.05, 0.02])
NOISE = np.array([0.35, 0.35, 0.25, 0.25, 0.12, 0.10, 0.03])  # N·m, as twincd.synth's plant
VELOCITY_NOISE = 0.002  # rad/s


def twin_plant_log(path: Path, rate: int, seed: int, gap_at_s: float | None = None) -> Path:
    """A clean log of ``SECONDS`` at ``rate`` moving throughout: each joint home + five sines of
    0.1–0.5 Hz (peak ≈ 40 °/s: enough for the identified model to tell its parameters apart),
    effort from the robot model's own inverse dynamics; with ``gap_at_s``, 0.2 s of samples from
    there on are missing."""
    from twincd.io.cdr import joint_state_cdr
    from twincd.io.mcap import McapLogWriter
    from twincd.twin.dynamics import inverse_dynamics
    from twincd.twin.robot import load_robot

    rng = np.random.default_rng([rate, seed])
    freq = rng.uniform(0.1, 0.5, (7, 5))
    amp = np.radians(40.0) / (2 * np.pi * freq.sum(axis=1, keepdims=True))
    phase = rng.uniform(0.0, 2 * np.pi, (7, 5))
    t = np.arange(round(SECONDS * rate) + 1) / rate
    if gap_at_s is not None:
        t = t[(t < gap_at_s) | (t >= gap_at_s + 0.2)]
    arg = 2 * np.pi * freq[None] * t[:, None, None] + phase[None]
    q = HOME + (amp * np.sin(arg)).sum(axis=2)
    v = (amp * 2 * np.pi * freq * np.cos(arg)).sum(axis=2)
    a = -(amp * (2 * np.pi * freq) ** 2 * np.sin(arg)).sum(axis=2)
    tau = inverse_dynamics(load_robot("xarm7"), q, v, a)
    effort = GAIN * tau + OFFSET + NOISE * rng.standard_normal(q.shape)
    v_reported = v + VELOCITY_NOISE * rng.standard_normal(q.shape)
    stamps = T0_NS + seed * 10**11 + np.round(t * 1e9).astype(np.int64)
    with McapLogWriter(path) as out:
        topic = out.add_topic("/joint_states", "sensor_msgs/msg/JointState")
        for stamp, msg in zip(stamps, joint_state_cdr(stamps, XARM, q, v_reported, effort)):
            out.write(topic, int(stamp) + 300_000, msg)
    return path


@dataclass(frozen=True)
class RateSet:
    rate: int
    root: Path
    fresh: Path
    segments: int


def settling(calibration: Calibration, rate: int) -> int:
    """Samples until the recorded filter's step response stays within 1e-3 of 1 (scipy)."""
    sos = calibration.lowpass.sos(float(rate))
    step = signal.sosfilt(sos, np.ones(40 * rate))
    return int(np.flatnonzero(np.abs(step - 1.0) > 1e-3)[-1]) + 1


@pytest.fixture(scope="module", params=RATES, ids=[f"{r}Hz" for r in RATES])
def rate_set(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> RateSet:
    rate = int(request.param)
    root = tmp_path_factory.mktemp(f"edges_{rate}hz")
    for split, seeds in (("train", (0, 1, 2)), ("val", (50,))):
        (root / split).mkdir()
        for seed in seeds:
            twin_plant_log(root / split / f"{seed}.mcap", rate, seed)
    gap = 9.0 if rate == GAP_RATE else None
    fresh = twin_plant_log(root / "fresh.mcap", rate, 101, gap)  # never fitted nor thresholded on
    return RateSet(rate, root, fresh, 1 if gap is None else 2)


def calibrate(rates: RateSet, *options: str) -> Path:
    cal = rates.root / f"cal{''.join(options)}.json"
    fitted = run("fit", rates.root / "train", "-o", cal, *options)
    assert fitted.exit_code == 0, fitted.output
    thresholded = run("threshold", rates.root / "val", "-c", cal)
    assert thresholded.exit_code == 0, thresholded.output
    return cal


def detect(rates: RateSet, cal: Path) -> dict[str, object]:
    result = run("detect", rates.fresh, "-c", cal, "--json")
    assert result.exit_code == 0, result.stdout  # no collision: exit 0
    (entry,) = json.loads(result.stdout)["logs"]
    assert entry["events"] == [] and entry["collision_samples"] == 0
    out: dict[str, object] = entry
    return out


def test_zero_phase_ends_never_flag(rate_set: RateSet) -> None:
    cal_path = calibrate(rate_set)
    cal = Calibration.load(cal_path)
    assert not cal.lowpass.causal and cal.model.kind == "identified-whitened"
    entry = detect(rate_set, cal_path)
    # every sample is judged, the segments' ends with their own noise
    assert entry["judged_samples"] == entry["samples"]


def test_causal_and_live_starts_never_flag(rate_set: RateSet) -> None:
    cal_path = calibrate(rate_set, "--causal")
    cal = Calibration.load(cal_path)
    assert cal.lowpass.causal
    entry = detect(rate_set, cal_path)
    assert entry["judged_samples"] == entry["samples"]
    # live: the same samples pushed in blocks of any size; nothing flagged, nothing raised
    states_ = Setup.from_calibration(cal).prepare(rate_set.fresh).states
    live = OnlineDetector(cal)
    rng = np.random.default_rng(rate_set.rate)
    slices, at = [], 0
    while at < len(states_):
        size = int(rng.integers(1, 400))
        slices.append(slice(at, at + size))
        at += size
    outs = pushed(live, states_, slices)
    events = [event for out in outs for event in out.events] + live.close()
    assert not np.concatenate([out.flag for out in outs]).any() and events == []
    assert live.counts.judged == entry["judged_samples"]


@pytest.mark.parametrize("options", [(), ("--model", "affine")], ids=["default", "paper"])
def test_a_3_s_segment_is_judged_throughout_and_its_ends_raise_nothing(
    tmp_path: Path, options: tuple[str, ...]
) -> None:
    """Real datasets come as segments of a few seconds: a 3 s log at 100 Hz is judged on all
    its samples (at least 90 % asked), with the paper's 1 Hz Butterworth filter as with the
    default one, and its ends raise nothing."""
    root = tmp_path / "segments"
    for split, seeds in (("train", (0, 1, 2)), ("val", (50,))):
        (root / split).mkdir(parents=True)
        for seed in seeds:
            twin_plant_log(root / split / f"{seed}.mcap", 100, seed)
    rates = RateSet(100, root, root / "fresh.mcap", 1)
    cal = calibrate(rates, *options)
    for seed in (101, 102, 103):
        segment = twin_plant_log(root / f"segment{seed}.mcap", 100, seed)
        short = root / f"short{seed}.mcap"
        _cut(segment, short, 3.0)
        result = run("detect", short, "-c", cal, "--json")
        assert result.exit_code == 0, result.stdout
        (entry,) = json.loads(result.stdout)["logs"]
        assert entry["events"] == [] and entry["samples"] == 301
        assert entry["judged_samples"] >= 0.9 * entry["samples"]


def _cut(source: Path, target: Path, seconds: float) -> None:
    """The first ``seconds`` of a log's joint states, as a log of its own."""
    from twincd.io.cdr import joint_state_cdr
    from twincd.io.mcap import McapLogWriter
    from twincd.prepare.setup import read_log

    states = read_log(source)
    keep = states.t_s <= seconds + 1e-9
    with McapLogWriter(target) as out:
        topic = out.add_topic("/joint_states", "sensor_msgs/msg/JointState")
        stamps = states.stamp_ns[keep]
        messages = joint_state_cdr(
            stamps, states.joint_names, states.position[keep], states.velocity[keep],
            states.effort[keep],
        )  # fmt: skip
        for stamp, msg in zip(stamps, messages, strict=True):
            out.write(topic, int(stamp) + 300_000, msg)
