"""One reader, one answer: every command reads a log through the same path, so what one command
reads every command reads alike; ``inspect`` calls a log usable exactly when ``fit`` and
``detect`` accept it."""

from __future__ import annotations

import json
from pathlib import Path

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
