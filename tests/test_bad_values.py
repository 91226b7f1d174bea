"""Absurd values are data faults (contract: Inputs, bad samples): a recorder glitch's finite values
(an effort of 1e300 or float32's 3.4e38, positions of 253 rad with zero efforts) are dropped by one
causal bound, bridged, counted and named with their times — never exit 3, never ``inf`` in JSON,
never an event before the glitch, never a threshold they move. Logs are the shipped xArm 7 sample
logs written again by rosbags' writer and by twincd's, with glitches put in on the way."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from support.builders import rewrite
from support.clitools import run
from support.streaming import blocks, detect_frames, pushed

from twincd.calibration import Calibration

SAMPLES = Path(__file__).resolve().parent.parent / "sample_logs"
CALIBRATION = SAMPLES / "calibration.json"
CAUSAL = SAMPLES / "calibration.causal.json"
CLEAN = SAMPLES / "val" / "val_000.mcap"
PRESSES = SAMPLES / "test" / "test_000.mcap"
GLITCH_AT = 1000  # the message (10.00 s into a 100 Hz log) a glitch is put in


def glitched(
    src: Path, dst: Path, edits: dict[int, Callable[[Any], object]], writer: str = "rosbags"
) -> Path:
    """``src`` written again by ``writer`` with ``edits[i]`` applied to its i-th JointState
    (one that returns False leaves the message out)."""
    seen = [0]

    def edit(msg: Any) -> object:
        change = edits.get(seen[0])
        seen[0] += 1
        return None if change is None else change(msg)

    return rewrite(src, dst, edit, writer=writer)


def effort_of(value: float) -> Callable[[Any], None]:
    def edit(msg: Any) -> None:
        msg.effort = msg.effort.copy()
        msg.effort[1] = value

    return edit


def corrupt_row(msg: Any) -> None:
    """What a real UR10e's recorder left: 253 rad on three joints, every effort 0."""
    msg.position = msg.position.copy()
    msg.position[:3] = 253.0
    msg.effort = np.zeros_like(msg.effort)


def strict_json(text: str) -> Any:
    """JSON that holds no NaN or infinity (Python's json would read them)."""

    def refuse(word: str) -> None:
        raise AssertionError(f"{word} in JSON")

    return json.loads(text, parse_constant=refuse)


# ---------------------------------------------------------------- one glitch, every command


@pytest.mark.parametrize("writer", ["rosbags", "twincd"])
@pytest.mark.parametrize("value", [1e300, 3.4e38, -3.4e38])
def test_a_huge_effort_is_dropped_and_named(tmp_path: Path, value: float, writer: str) -> None:
    """1e300 made detect exit 3 (JSON refuses inf); 3.4e38 gave an 8.6 s event starting 2 s
    before it. Now: the clean log's answer, and the sample named with its time."""
    log = glitched(CLEAN, tmp_path / "glitch.mcap", {GLITCH_AT: effort_of(value)}, writer)
    result = run("detect", log, "-c", CALIBRATION, "--json")
    assert result.exit_code == 0, result.output
    doc = strict_json(result.stdout)
    assert doc["logs"][0]["events"] == []
    (line,) = [w for w in doc["warnings"] if "absurd" in w]
    assert "dropping 1 sample(s)" in line and "10.000 s" in line and "joint2" in line
    clean = strict_json(run("detect", CLEAN, "-c", CALIBRATION, "--json").stdout)["logs"][0]
    # bridged: one sample fewer, and no filter restarted at the hole (no edge span lost)
    assert doc["logs"][0]["samples"] == clean["samples"] - 1
    assert doc["logs"][0]["judged_samples"] == clean["judged_samples"] - 1
    found = run("inspect", log, "--json")
    assert found.exit_code == 0
    absurd = strict_json(found.stdout)["logs"][0]["absurd"]
    assert absurd == {"samples": 1, "times_s": [10.0], "joints": {"effort": ["joint2"]}}


def test_events_never_start_before_a_glitch(tmp_path: Path) -> None:
    """A glitch between the presses of a log (at 12 s; they are at 9.4–10.9 s and 14.9–15.2 s):
    the same events as without it."""
    log = glitched(PRESSES, tmp_path / "glitch.mcap", {1200: effort_of(3.4e38)})
    same = rewrite(PRESSES, tmp_path / "same.mcap")
    events = [
        strict_json(run("detect", p, "-c", CALIBRATION, "--json").stdout)["logs"][0]["events"]
        for p in (log, same)
    ]
    assert events[0] and len(events[0]) == len(events[1])
    result = run("evaluate", log, "-c", CALIBRATION, "--json", "--no-summary")
    assert result.exit_code == 0 and strict_json(result.stdout)["methods"]
    for got, want in zip(*events, strict=True):
        assert got == {**want, "peak_score": pytest.approx(want["peak_score"], rel=1e-9)}


def test_corrupt_rows_are_not_degrees(tmp_path: Path) -> None:
    """Two rows of 253 rad: fit names them, with their times, and never says "degrees"; a log
    really in degrees still does."""
    log = glitched(CLEAN, tmp_path / "rows.mcap", {GLITCH_AT: corrupt_row, 1500: corrupt_row})
    result = run("fit", log, "-o", tmp_path / "cal.json")
    assert result.exit_code == 0, result.output
    assert "degrees" not in result.stderr
    assert "dropping 2 sample(s) with absurd values at 10.000, 15.000 s" in result.stderr
    assert "positions far outside the joint limits on joint1, joint2, joint3" in result.stderr
    found = strict_json(run("inspect", log, "--json").stdout)["logs"][0]
    assert found["absurd"]["samples"] == 2 and found["usable"]
    assert (
        found["sampling"]["samples"]
        == strict_json(run("inspect", CLEAN, "--json").stdout)["logs"][0]["sampling"]["samples"] - 2
    )
    text = run("inspect", log).stdout
    assert "absurd samples: 2 dropped, at 10.000, 15.000 s" in text

    def degrees(msg: Any) -> None:
        msg.position = np.degrees(msg.position)

    result = run("fit", rewrite(CLEAN, tmp_path / "deg.mcap", degrees), "-o", tmp_path / "d.json")
    assert "look like degrees" in result.stderr


def test_corrupt_rows_do_not_move_a_threshold(tmp_path: Path) -> None:
    """A threshold from logs with corrupt rows is within 5 % of the one from the same logs
    with those rows removed (the glitch once doubled a real arm's)."""
    bad, cut = tmp_path / "bad", tmp_path / "cut"
    bad.mkdir()
    cut.mkdir()
    rows = {GLITCH_AT: corrupt_row, 1200: effort_of(3.4e38), 1500: corrupt_row}
    for log in sorted((SAMPLES / "val").glob("*.mcap")):
        edits = rows if log.name == "val_000.mcap" else {}
        glitched(log, bad / log.name, edits)
        glitched(log, cut / log.name, dict.fromkeys(edits, lambda msg: False))
    values = []
    for folder in (bad, cut):
        cal = shutil.copy(CALIBRATION, tmp_path / f"{folder.name}.json")
        result = run("threshold", folder, "-c", cal, "--json")
        assert result.exit_code == 0, result.output
        strict_json(result.stdout)
        values.append(Calibration.load(cal).threshold.value)  # type: ignore[union-attr]
    assert abs(values[0] / values[1] - 1) < 0.05, values


def start_garbage(msg: Any, shift: tuple[float, ...]) -> None:
    """What a real UR10e's recorder published between its first real rows: another state,
    every value within the limits (joints 1.5 rad away), efforts of 250 N·m."""
    msg.position = msg.position + np.resize(np.array(shift), len(msg.position))
    msg.effort = np.full_like(msg.effort, 250.0)


def test_rows_jumping_within_the_limits_are_dropped(tmp_path: Path) -> None:
    """A recorder's start-up rows, within every limit but 1.5 rad from the real ones and back
    (a real UR10e log's first 0.2 s, once its only false alarm): dropped and named as jumps;
    the events, at the defaults and at --causal, are the clean log's."""
    shifts = [(1.5, -1.5, 0.0), (0.0, 1.5, -1.5), (-1.5, 0.0, 1.5)]
    edits = {
        i: (lambda m, s=shifts[k % 3]: start_garbage(m, s))
        for k, i in enumerate((1, 3, 4, 6, 9, 10, 14))
    }
    log = glitched(PRESSES, tmp_path / "start.mcap", edits)
    same = rewrite(PRESSES, tmp_path / "same.mcap")
    for cal in (CALIBRATION, CAUSAL):
        docs = [strict_json(run("detect", p, "-c", cal, "--json").stdout) for p in (log, same)]
        (line,) = [w for w in docs[0]["warnings"] if "absurd" in w]
        assert "dropping 7 sample(s)" in line and "positions jumping faster than" in line
        spans = [[(e["start_ns"], e["end_ns"]) for e in d["logs"][0]["events"]] for d in docs]
        assert spans[0] and spans[0] == spans[1]
    absurd = strict_json(run("inspect", log, "--json").stdout)["logs"][0]["absurd"]
    assert absurd["samples"] == 7 and absurd["times_s"][0] == pytest.approx(0.01)
    assert set(absurd["joints"]) == {"jump"}


def test_a_stream_that_starts_with_a_glitch_is_kept_from_the_run_after_it() -> None:
    """The first sample, with nothing before it, is kept on the bounds alone; when it was a
    glitch within the limits, the samples after it are dropped as jumps only until ``STEP_RUN``
    of them move consistently, and kept from there, in any chunking; real motion at twice a
    joint's velocity limit, or a continuous joint's wrap, is never a jump."""
    from twincd.signal.bounds import STEP_RUN, SampleBounds

    n = 200
    stamps = np.arange(n, dtype=np.int64) * 10_000_000
    t = stamps * 1e-9
    q = np.stack([0.3 * np.sin(t), 2.0 * t - 2.0, np.unwrap(4.0 * t) % (2 * np.pi) - np.pi], 1)
    q[0, 0] += 1.5  # the glitch
    limits = {"a": (-3.0, 3.0), "b": (-3.0, 3.0)}  # c: continuous
    speeds = {"a": 1.0, "b": 1.0, "c": 1.0}  # b moves at twice its limit

    def keep(edges: list[int]) -> np.ndarray:
        bounds = SampleBounds("abc", limits, speeds, {})
        parts = [slice(a, b) for a, b in zip([0, *edges], [*edges, n], strict=True)]
        return np.concatenate([bounds.keep(stamps[p], position=q[p]) for p in parts])

    whole = keep([])
    assert whole[0] and not whole[1:STEP_RUN].any() and whole[STEP_RUN:].all()
    for edges in ([1], [2, 3], [4, 5, 6], list(range(1, 20))):
        np.testing.assert_array_equal(keep(edges), whole)


# ---------------------------------------------------------------- batch = causal = live


def test_live_drops_what_detect_causal_drops(tmp_path: Path) -> None:
    """The bound is causal: OnlineDetector, pushed the glitched log in any blocks, gives the
    flags and events of detect --causal on it."""
    from twincd.detection.online import OnlineDetector
    from twincd.prepare.setup import read_log

    log = glitched(
        PRESSES,
        tmp_path / "glitch.mcap",
        {GLITCH_AT: effort_of(3.4e38), 1300: corrupt_row, 1301: corrupt_row},
    )
    cal = Calibration.load(CAUSAL)
    summary, frames = detect_frames(log, cal)
    states = read_log(log)
    for size in (1, 7, 4096):
        det = OnlineDetector(cal)
        outs = [*pushed(det, states, blocks(len(states), size)), det.flush()]
        flag = np.concatenate([o.flag for o in outs])
        score = np.concatenate([o.score for o in outs])
        assert np.isnan(score[[GLITCH_AT, 1300, 1301]]).all()
        kept = ~np.isnan(score)
        np.testing.assert_array_equal(flag[kept], frames.column("flag"))
        events = [e for o in outs for e in o.events]
        assert [(e.start_ns, e.end_ns) for e in events] == [
            (e.start_ns, e.end_ns) for e in summary.events
        ]


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 1000),
    cuts=st.lists(st.integers(1, 299), max_size=6),
    glitches=st.lists(st.integers(0, 299), max_size=8),
    degrees=st.booleans(),
    jumps=st.lists(st.tuples(st.integers(0, 299), st.integers(1, 8)), max_size=4),
)
def test_the_bound_is_the_same_in_any_chunking(
    seed: int, cuts: list[int], glitches: list[int], degrees: bool, jumps: list[tuple[int, int]]
) -> None:
    from twincd.signal.bounds import EFFORT_BOUND, SampleBounds

    rng = np.random.default_rng(seed)
    n = 300
    stamps = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 10_000_000
    q = np.cumsum(rng.normal(0, 0.01, (n, 3)), axis=0)
    effort = rng.normal(0, 5, (n, 3))
    if degrees:
        q = np.degrees(q) + 100.0  # far outside the limits, but continuous: no glitch
    for g in glitches:
        q[g, rng.integers(3)] = 253.0 if rng.random() < 0.5 else q[g, 0]
        effort[g, rng.integers(3)] *= 1e30 if rng.random() < 0.5 else 1.0
    for start, length in jumps:  # rows of another state within the limits (or a re-anchoring run)
        q[start : start + length, rng.integers(3)] += 1.5
    limits = {n: (-3.0, 3.0) for n in "abc"}

    def keep(edges: list[int]) -> np.ndarray:
        bounds = SampleBounds("abc", limits, {}, {n: 50.0 for n in "abc"})
        parts = [slice(a, b) for a, b in zip([0, *edges], [*edges, n], strict=True)]
        return np.concatenate(
            [bounds.keep(stamps[p], position=q[p], effort=effort[p]) for p in parts]
        )

    whole = keep([])
    np.testing.assert_array_equal(keep(sorted(set(cuts))), whole)
    huge = np.abs(effort).max(axis=1) > 50.0 * EFFORT_BOUND
    assert not whole[huge].any()
    if degrees and not glitches:
        assert whole[1:].all()  # only the first sample, with nothing before it, is judged alone


def test_the_largest_synth_press_survives_the_bound() -> None:
    """Every sample of synth's hardest presses (35 N) is kept, far inside the bound."""
    from twincd.prepare.robots import robot_for, sample_bounds
    from twincd.signal.bounds import EFFORT_BOUND
    from twincd.synth.config import SynthConfig
    from twincd.synth.simulate import simulate_path

    base = SynthConfig()
    strongest = replace(base, collision=replace(base.collision, force_n=(35.0, 35.0)))
    robot = robot_for("xarm7", tuple(f"joint{i}" for i in range(1, 8)))
    for index in range(3):
        run_ = simulate_path(strongest, 0, "test", index, collisions=True)
        assert run_.presses
        bounds = sample_bounds(robot, run_.joint_names)
        kept = bounds.keep(
            run_.stamp_ns, position=run_.position, velocity=run_.velocity, effort=run_.effort
        )
        assert kept.all()
        limits = np.array([robot.effort_limits[n] for n in run_.joint_names])
        # each joint's largest effort is under a tenth of its bound
        assert (np.abs(run_.effort).max(axis=0) < 0.1 * EFFORT_BOUND * limits).all()
