"""Which logs the arguments stand for (contract: Inputs): each log once however often it is given,
and rosbag2 bags whose metadata.yaml is missing (a recorder killed before writing it) read from
their storage files, split parts in order as one log."""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import DEFAULT_BUMPS, build_twin_log
from support.builders import Message, joint_recording, write, write_by
from support.clitools import run

from twincd.io.logs import expand_logs
from twincd.prepare.setup import read_log


def _recording(n: int = 300) -> list[Message]:
    rng = np.random.default_rng(4)
    return joint_recording(n=n, effort=rng.normal(size=(n, 7)))


def _same(a: Path, b: Path) -> None:
    x, y = read_log(a), read_log(b)
    assert x.joint_names == y.joint_names
    for name in ("stamp_ns", "log_time_ns", "position", "velocity", "effort"):
        np.testing.assert_array_equal(getattr(x, name), getattr(y, name))


def _repeat_warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if "more than once" in r.getMessage()]


# ---------------------------------------------------------------- the same log given twice


def test_a_log_given_twice_is_one_log_with_one_warning(tmp_path, caplog):
    logs = tmp_path / "logs"
    logs.mkdir()
    a = write(logs / "a.mcap", "mcap", _recording(40))
    b = write(logs / "b", "rosbag2-sqlite3", _recording(40))
    (tmp_path / "link.mcap").symlink_to(a)
    given = [a, logs / "." / "a.mcap", tmp_path / "link.mcap", logs, b, b / "b.db3"]
    with caplog.at_level(logging.WARNING, logger="twincd"):
        found = expand_logs(given)
    assert found == [a, b]
    (line,) = _repeat_warnings(caplog)
    assert line.startswith("5 log(s) given more than once") and "link.mcap" in line


def test_a_bag_s_own_file_given_first_gives_way_to_the_bag(tmp_path, caplog):
    from twincd.io.logs import unique_logs

    bag = write(tmp_path / "bag", "rosbag2-mcap", _recording(40))
    with caplog.at_level(logging.WARNING, logger="twincd"):
        assert unique_logs([bag / "bag.mcap", bag]) == [bag]
    assert len(_repeat_warnings(caplog)) == 1


def test_separate_logs_are_left_alone(tmp_path, caplog):
    a = write(tmp_path / "a.mcap", "mcap", _recording(40))
    b = write(tmp_path / "b.mcap", "mcap", _recording(40))
    with caplog.at_level(logging.WARNING, logger="twincd"):
        assert expand_logs([b, a]) == [b, a]
    assert not _repeat_warnings(caplog)


def test_fit_counts_a_repeated_log_once(twin_dataset, tmp_path):
    once, twice = tmp_path / "once.json", tmp_path / "twice.json"
    log = twin_dataset / "train" / "train_0.mcap"
    assert run("fit", log, "-o", once, "-q", "--model", "affine").exit_code == 0
    result = run("fit", log, log, twin_dataset / "train" / ".." / "train" / "train_0.mcap",
                 "-o", twice, "--model", "affine")  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "given more than once" in result.stderr and "1 log(s)" in result.stderr
    a, b = json.loads(once.read_text()), json.loads(twice.read_text())
    assert b["fit"]["logs"] == a["fit"]["logs"] and b["fit"]["samples"] == a["fit"]["samples"]
    assert b["model"] == a["model"]


def test_evaluate_counts_a_repeated_test_log_once(twin_calibration, twin_dataset):
    test = twin_dataset / "test" / "test_0.mcap"
    once = run("evaluate", test, "-c", twin_calibration, "--json", "-q")
    twice = run("evaluate", test, twin_dataset / "test", "-c", twin_calibration, "--json")
    assert once.exit_code == twice.exit_code == 0, twice.output
    a, b = json.loads(once.stdout), json.loads(twice.stdout)
    assert b["logs"]["test"] == [str(test), str(twin_dataset / "test" / "test_1.mcap")]
    assert any("given more than once" in w for w in b["warnings"])
    solo = run("evaluate", test, test, "-c", twin_calibration, "--json", "-q")
    c = json.loads(solo.stdout)
    assert (c["samples"], c["positives"]) == (a["samples"], a["positives"])
    assert c["methods"][0]["events_total"] == a["methods"][0]["events_total"]
    assert c["methods"][0]["events_detected"] == a["methods"][0]["events_detected"]


def test_evaluate_sets_are_each_counted_once(twin_dataset):
    train, val = twin_dataset / "train", twin_dataset / "val"
    test = twin_dataset / "test" / "test_0.mcap"
    args = ["--methods", "affine-whitened", "--json", "-q"]
    once = run("evaluate", test, "--train", train, "--val", val, *args)
    twice = run("evaluate", test, "--train", train, "--train", train / "train_1.mcap",
                "--val", val, "--val", val, *args)  # fmt: skip
    assert once.exit_code == twice.exit_code == 0, twice.output
    a, b = json.loads(once.stdout), json.loads(twice.stdout)
    assert a["logs"] == b["logs"]
    assert a["methods"][0]["threshold"] == b["methods"][0]["threshold"]


# ---------------------------------------------------------------- bags without metadata.yaml


def _headless_sqlite3(folder: Path, recording: list[Message], parts: int = 1) -> Path:
    """A rosbag2 sqlite3 bag as a killed recorder leaves it: ``NAME_0.db3`` … and no
    metadata.yaml (rosbags' writer, one bag per part, moved together)."""
    folder.mkdir()
    bounds = np.linspace(0, len(recording), parts + 1).astype(int)
    for i in range(parts):
        part = write(folder.parent / f"{folder.name}.part{i}", "rosbag2-sqlite3",
                     recording[bounds[i] : bounds[i + 1]])  # fmt: skip
        shutil.move(next(part.glob("*.db3")), folder / f"{folder.name}_{i}.db3")
        shutil.rmtree(part)
    return folder


def _headless_mcap(folder: Path, recording: list[Message], parts: int, writer: str) -> Path:
    """A split rosbag2 MCAP bag without its metadata.yaml, parts ``NAME_i.mcap`` written with
    rosbags' writer or twincd's own."""
    folder.mkdir()
    bounds = np.linspace(0, len(recording), parts + 1).astype(int)
    for i in range(parts):
        write_by(writer, folder / f"{folder.name}_{i}.mcap", recording[bounds[i] : bounds[i + 1]])
    return folder


def test_a_killed_sqlite3_recorder_s_bag_reads_with_one_warning(tmp_path, caplog):
    recording = _recording()
    whole = write(tmp_path / "whole", "rosbag2-sqlite3", recording)
    bag = _headless_sqlite3(tmp_path / "rosbag2_2024_05_01-10_00_00", recording)
    assert expand_logs([bag]) == [bag] == expand_logs([tmp_path / "rosbag2_2024_05_01-10_00_00"])
    with caplog.at_level(logging.WARNING, logger="twincd"):
        _same(bag, whole)
    lines = [r.getMessage() for r in caplog.records if "metadata.yaml" in r.getMessage()]
    assert len(lines) == 1 and "reindex" in lines[0] and "contradict" not in lines[0]
    # the .db3 itself is a log too
    _same(bag / f"{bag.name}_0.db3", whole)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap-rosbags", "mcap-twincd"])
def test_split_parts_without_metadata_are_one_log_in_order(tmp_path, caplog, storage):
    recording = _recording(400)
    whole = write(tmp_path / "whole.mcap", "mcap", recording)
    logs = tmp_path / "logs"
    logs.mkdir()
    if storage == "sqlite3":
        bag = _headless_sqlite3(logs / "run", recording, parts=3)
    else:
        bag = _headless_mcap(logs / "run", recording, 3, storage.split("-")[1])
    assert expand_logs([logs]) == [bag]
    with caplog.at_level(logging.WARNING, logger="twincd"):
        _same(bag, whole)
    (line,) = [r.getMessage() for r in caplog.records if "metadata.yaml" in r.getMessage()]
    assert "3" in line and "in order" in line


def test_separate_recordings_named_like_parts_stay_separate(tmp_path):
    """``train/train_0.mcap``, ``train/train_1.mcap`` that start together are two logs."""
    folder = tmp_path / "train"
    folder.mkdir()
    build_twin_log(folder / "train_0.mcap", seed=0, seconds=4)
    build_twin_log(folder / "train_1.mcap", seed=1, seconds=4)
    assert expand_logs([folder]) == [folder / "train_0.mcap", folder / "train_1.mcap"]


def test_commands_run_on_a_killed_recorder_s_sqlite3_bag(tmp_path, twin_calibration):
    """fit, detect (and its lossless MCAP copy), inspect and evaluate read the headless bag as
    they read the bag with its metadata."""
    from rosbags.highlevel import AnyReader

    source = build_twin_log(tmp_path / "src.mcap", seed=200, bumps=DEFAULT_BUMPS)
    with AnyReader([source]) as reader:
        recording = [Message(c.topic, c.msgtype, t, reader.deserialize(raw, c.msgtype))
                     for c, t, raw in reader.messages()]  # fmt: skip
    whole = write(tmp_path / "whole", "rosbag2-sqlite3", recording)
    bag = _headless_sqlite3(tmp_path / "bag", recording)
    answers = []
    for log in (whole, bag):
        out = tmp_path / f"{log.name}.detect.mcap"
        detected = run("detect", log, "-c", twin_calibration, "--json", "-o", out)
        assert detected.exit_code == 1, detected.output
        evaluated = run("evaluate", log, "-c", twin_calibration, "--json", "-q")
        assert evaluated.exit_code == 0, evaluated.output
        assert run("inspect", log, "-q").exit_code == 0
        with AnyReader([out]) as reader:
            copied = sum(1 for c, _, _ in reader.messages() if not c.topic.startswith("/twincd/"))
        events = json.loads(detected.stdout)["logs"][0]["events"]
        answers.append((events, json.loads(evaluated.stdout)["methods"][0]["auc"], copied))
    assert answers[0] == answers[1]
    assert answers[0][2] == sum(1 for m in recording if not m.topic.startswith("/twincd/"))
