"""Positions that wrap at ±π (continuous joints) are unwrapped before they are differentiated
(contract: Inputs): a log whose velocity is not logged answers the same whether a joint's
position is reported in (−π, π] or continuously; a jump that cannot be a wrap is named."""

from __future__ import annotations

import json
import logging
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from support.builders import Message, write_by
from support.clitools import run
from support.streaming import chunked, split_points

PERIOD_NS = 10_000_000


def _wrap(x: np.ndarray) -> np.ndarray:
    """Into (−π, π], as drivers report continuous joints."""
    return np.pi - np.mod(np.pi - x, 2 * np.pi)


def _turning(n: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * PERIOD_NS
    s = t * 1e-9
    q = np.column_stack([3.0 * s, 0.4 * np.sin(s), np.pi - 0.2 + 0.5 * np.sin(2 * s)])
    return t, q


@pytest.mark.parametrize("how", ["whole", "random", 1, 7, 500])
def test_unwrapped_in_any_chunking_equals_the_continuous_position(how):
    from twincd.signal.unwrap import StreamingUnwrap, unwrap_positions

    t, q = _turning()
    wrapped = _wrap(q)
    assert np.abs(np.diff(wrapped, axis=0)).max() > 6  # it does wrap
    stage = StreamingUnwrap(PERIOD_NS * 1e-9)
    out = chunked(stage, t, wrapped, split_points(len(t), how, np.random.default_rng(0)))
    turns = (out - q) / (2 * np.pi)  # the same signal, up to whole turns per joint
    np.testing.assert_allclose(turns, np.round(turns[:1]).repeat(len(t), 0), atol=1e-9)
    np.testing.assert_array_equal(out, unwrap_positions(t, wrapped))
    assert stage.wraps.tolist()[1] == 0 and min(stage.wraps[0], stage.wraps[2]) > 0
    assert stage.jumps.sum() == 0


def test_a_jump_that_cannot_be_a_wrap_is_counted_not_unwrapped():
    from twincd.signal.unwrap import StreamingUnwrap

    t, q = _turning(500)
    q[300:, 1] += 2.0  # 2 rad in 10 ms: a glitch, not a turn
    stage = StreamingUnwrap(PERIOD_NS * 1e-9)
    out = chunked(stage, t, q, [123, 301])
    np.testing.assert_array_equal(out[:, 1], q[:, 1])
    assert stage.jumps.tolist() == [0, 0, 0]  # 2 rad < π: not a candidate at all
    q[300:, 1] += 2.0  # now 4 rad
    stage = StreamingUnwrap(PERIOD_NS * 1e-9)
    out = chunked(stage, t, q, [123, 301])
    np.testing.assert_array_equal(out[:, 1], q[:, 1])
    assert stage.jumps.tolist() == [0, 1, 0] and stage.first_jump_ns[1] == t[300]
    assert stage.largest_jump[1] == pytest.approx(4.0, abs=0.01)


def test_the_count_restarts_after_a_gap():
    from twincd.signal.unwrap import StreamingUnwrap

    t, q = _turning(600)
    t[300:] += 10 * PERIOD_NS  # a gap: a new segment
    stage = StreamingUnwrap(PERIOD_NS * 1e-9)
    out = chunked(stage, t, _wrap(q), [])
    np.testing.assert_array_equal(out[300], _wrap(q)[300])  # a segment starts as logged


# ---------------------------------------------------------------- the xArm's wrist through ±π


def _rewritten(source: Path, target: Path, writer: str, wrap: bool) -> Path:
    """``source`` with joint7 turned by π + 0.4 (so that it passes π), velocity left out, its
    position wrapped into (−π, π] or kept continuous."""
    from rosbags.highlevel import AnyReader

    msgs = []
    with AnyReader([source]) as reader:
        for c, t, raw in reader.messages():
            msg = reader.deserialize(raw, c.msgtype)
            if c.topic == "/joint_states":
                q = np.array(msg.position, dtype=np.float64)
                i = list(msg.name).index("joint7")
                q[i] += math.pi + 0.4
                if wrap:
                    q[i] = _wrap(q[i])
                msg = replace(msg, position=q, velocity=np.zeros(0))
            msgs.append(Message(c.topic, c.msgtype, t, msg))
    return write_by(writer, target, msgs)


def _answers(root: Path) -> tuple[object, ...]:
    cal = root / "cal.json"
    fitted = run("fit", root / "train", "-o", cal)
    assert fitted.exit_code == 0, fitted.output
    assert run("threshold", root / "val", "-c", cal, "-q").exit_code == 0
    detected = run("detect", root / "test", "-c", cal, "--json")
    assert detected.exit_code in (0, 1), detected.output
    evaluated = run("evaluate", root / "test", "-c", cal, "--json", "-q")
    assert evaluated.exit_code == 0, evaluated.output
    row = json.loads(evaluated.stdout)["methods"][0]
    events = [
        (e["start_ns"], e["end_ns"]) for e in json.loads(detected.stdout)["logs"][0]["events"]
    ]
    figures = {k: v for k, v in row.items() if isinstance(v, float) and "_s" not in k}
    warned = [w for w in json.loads(detected.stdout)["warnings"] if "flagged" in w]
    return fitted.stderr, events, figures, warned


@pytest.mark.parametrize("writer", ["rosbags", "twincd"])
def test_a_wrapped_wrist_answers_as_a_continuous_one(xarm_dataset, tmp_path, writer):
    roots = {}
    for wrap in (False, True):
        root = roots[wrap] = tmp_path / ("wrapped" if wrap else "continuous")
        for split in ("train", "val", "test"):
            (root / split).mkdir(parents=True)
            for log in sorted((xarm_dataset / split).glob("*.mcap")):
                _rewritten(log, root / split / log.name, writer, wrap)
    cont_fit, cont_events, cont_figures, cont_warned = _answers(roots[False])
    wrap_fit, events, figures, warned = _answers(roots[True])
    # the same answer, up to the last bits of q − 2πk against q
    assert (events, warned) == (cont_events, cont_warned)
    assert figures == pytest.approx(cont_figures, rel=1e-6)
    # and fit says the same, but for the wraps it unwrapped
    said = [ln.replace("/wrapped/", "/continuous/") for ln in wrap_fit.splitlines()]
    wraps = [ln for ln in said if "whole turn (2π)" in ln]
    trained = len(list((roots[True] / "train").glob("*.mcap")))
    assert len(wraps) == trained and all("on joint7" in ln for ln in wraps)
    assert [ln for ln in said if ln not in wraps] == cont_fit.splitlines()


def test_streamed_in_any_block_size_equals_whole(xarm_dataset, tmp_path, caplog):
    from twincd import SetupOptions

    log = _rewritten(xarm_dataset / "test" / "test_000.mcap", tmp_path / "w.mcap", "twincd", True)
    setup = SetupOptions(robot="xarm7").resolve()
    with caplog.at_level(logging.WARNING, logger="twincd"):
        whole = setup.prepare(log)
    small = replace(setup, block_size=37).prepare(log)
    np.testing.assert_array_equal(whole.states.velocity, small.states.velocity)
    # the twin's effort after the filter differs in the last bits with the block size anyway
    np.testing.assert_allclose(whole.sim_effort_f, small.sim_effort_f, rtol=0, atol=1e-9)
    assert np.abs(whole.states.velocity[:, 6]).max() < 5  # no 2π spike in the derivative
    said = [r.getMessage() for r in caplog.records if "whole turn" in r.getMessage()]
    assert len(said) == 2 and all("on joint7" in m for m in said)  # once per read


def test_inspect_says_so_too(xarm_dataset, tmp_path):
    log = _rewritten(xarm_dataset / "test" / "test_000.mcap", tmp_path / "w.mcap", "rosbags", True)
    result = run("inspect", log, "--json")
    assert result.exit_code == 0, result.output
    (found,) = json.loads(result.stdout)["logs"]
    assert any("whole turn (2π) on joint7" in w for w in found["warnings"])
