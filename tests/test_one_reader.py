"""One reader, one answer: every command reads a log through the same path, so what one command
reads every command reads alike; ``inspect`` calls a log usable exactly when ``fit`` and
``detect`` accept it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import DEFAULT_BUMPS, build_twin_log
from support.builders import QOS_WITHOUT_DEADLINE, rewrite_mcap
from support.clitools import run


def _summary(result) -> dict:  # type: ignore[no-untyped-def]
    assert result.exit_code in (0, 1), result.output
    return json.loads(result.stdout)


@pytest.mark.parametrize("writer", ["mcap", "rosbags"])
def test_qos_without_deadline_reads_in_every_command(tmp_path: Path, writer: str) -> None:
    """Channel QoS without ``deadline``/``lifespan`` (rosbags' own reader refuses it): fit,
    threshold, detect, evaluate and inspect read the log and answer as on the same messages
    with full QoS."""
    plain, odd = tmp_path / "plain", tmp_path / "odd"
    for folder in (plain, odd):
        folder.mkdir()
    for name, seed, bumps in (("train", 0, ()), ("val", 100, ()), ("test", 200, DEFAULT_BUMPS)):
        source = build_twin_log(tmp_path / f"{name}.mcap", seed=seed, bumps=bumps)
        rewrite_mcap(source, plain / f"{name}.mcap", writer=writer)
        rewrite_mcap(source, odd / f"{name}.mcap", qos=QOS_WITHOUT_DEADLINE)
    answers = []
    for folder in (plain, odd):
        cal = folder / "cal.json"
        assert run("fit", folder / "train.mcap", "-o", cal, "-q").exit_code == 0
        assert run("threshold", folder / "val.mcap", "-c", cal, "-q").exit_code == 0
        evaluated = _summary(run("evaluate", folder / "test.mcap", "-c", cal, "--json", "-q"))
        detected = _summary(run("detect", folder / "test.mcap", "-c", cal, "--json", "-q"))
        inspected = run("inspect", folder / "test.mcap", "--json", "-q")
        assert inspected.exit_code == 0, inspected.output
        (found,) = json.loads(inspected.stdout)["logs"]
        answers.append(
            (
                json.loads(cal.read_text())["threshold"]["value"],
                {k: v for k, v in evaluated["methods"][0].items() if not k.endswith("_s")},
                [(e["start_ns"], e["end_ns"]) for e in detected["logs"][0]["events"]],
                found["sampling"]["samples"],
                found["usable"],
            )
        )
    assert answers[0] == answers[1]


# ---------------------------------------------------------------- inspect = fit and detect


def _variant(path: Path, kind: str) -> Path:
    from support.builders import XARM, joint_recording, write_by

    rng = np.random.default_rng(5)
    names = XARM[:6] if kind == "six-joints" else XARM
    effort = rng.normal(size=(1000, len(names)))
    if kind == "nan-effort":  # 15 usable samples left
        effort[15:] = np.nan
    msgs = joint_recording(n=1000, names=names, effort=None if kind == "no-effort" else effort)
    return write_by("twincd" if kind == "good" else "rosbags", path, msgs)


@pytest.fixture(scope="module")
def xarm_cal(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("xarm_cal")
    log = _variant(root / "good.mcap", "good")
    cal = root / "cal.json"
    assert run("fit", log, "-o", cal, "-q", "--model", "affine").exit_code == 0
    assert run("threshold", log, "-c", cal, "-q", "-k", "4").exit_code == 0
    return cal


@pytest.mark.parametrize("kind", ["good", "no-effort", "nan-effort", "six-joints"])
def test_inspect_says_usable_exactly_when_fit_and_detect_accept(tmp_path, xarm_cal, kind):
    log = _variant(tmp_path / f"{kind}.mcap", kind)
    inspected = run("inspect", log)
    fitted = run("fit", log, "-o", tmp_path / "c.json", "-q", "--model", "affine")
    detected = run("detect", log, "-c", xarm_cal, "-q")
    usable = inspected.exit_code == 0
    assert usable == (fitted.exit_code == 0), (kind, inspected.stdout, fitted.stderr)
    assert usable == (detected.exit_code in (0, 1)), (kind, inspected.stdout, detected.stderr)
    assert usable == (kind == "good")
    if not usable:  # the same reason, in the same words
        why = inspected.stderr.strip().removeprefix("twincd: error: ").split(" (")[0]
        assert why in fitted.stderr, (why, fitted.stderr)
