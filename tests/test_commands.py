"""The library does what the CLI does (contract: The library does what the CLI does): each
command's function at its defaults gives what the command gives (the same calibration file but
for when it was written and how long it took, the same flags and events, the same metrics), and
returns its warnings as data without touching the user's logging set-up."""

from __future__ import annotations

import json
import logging
import pickle
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support.arms import messages_of, retopic, two_arm_bag
from support.builders import XARM, joint_recording, write
from support.clitools import run

import twincd
from twincd.commands import LogsFailed
from twincd.io.options import LogOptions, parse_joint_map

# what may differ between two runs: when a calibration was written, how long work took
CHANGING = {"created", "seconds", "train_s", "test_s", "train_s_std", "test_s_std"}


def _stable(doc: Any) -> Any:
    if isinstance(doc, dict):
        return {k: _stable(v) for k, v in doc.items() if k not in CHANGING}
    if isinstance(doc, list):
        return [_stable(v) for v in doc]
    return doc


def _json(path: Path) -> Any:
    return _stable(json.loads(path.read_text()))


@pytest.fixture
def cli_calibration(default_calibration: Path) -> Path:
    """``twincd fit`` then ``twincd threshold`` at their defaults."""
    return default_calibration


def test_fit_calibration_at_its_defaults_is_twincd_fit(twin_dataset: Path, tmp_path: Path) -> None:
    """The default filter is the fit command's (critical at 1.5 Hz for the best model), not the
    reading settings' Butterworth at 1 Hz."""
    cli = tmp_path / "cli.json"
    assert run("fit", twin_dataset / "train", "-o", cli, "-q").exit_code == 0
    done = twincd.fit_calibration([twin_dataset / "train"], output=tmp_path / "lib.json")
    assert _json(tmp_path / "lib.json") == _json(cli)
    assert json.loads(cli.read_text())["filter"]["kind"] == "critical"
    assert done.calibration.lowpass.kind == "critical" and done.calibration.lowpass.cutoff_hz == 1.5
    assert done.failures == () and done.exit_code == 0


def test_threshold_calibration_at_its_defaults_is_twincd_threshold(
    twin_dataset: Path, tmp_path: Path
) -> None:
    cli, lib = tmp_path / "cli.json", tmp_path / "lib.json"
    assert run("fit", twin_dataset / "train", "-o", cli, "-q").exit_code == 0
    shutil.copy(cli, lib)
    shown = run("threshold", twin_dataset / "val", "-c", cli, "--json")
    assert shown.exit_code == 0, shown.output
    done = twincd.threshold_calibration([twin_dataset / "val"], lib, output=lib)
    assert _json(lib) == _json(cli)
    assert done.written == lib and done.calibration.require_threshold().false_alarms is not None
    assert done.to_dict() == {**_answer(json.loads(shown.stdout)), "calibration": str(lib)}


def _on_the_test_logs(command: str, dataset: Path, cal: Path, exit_code: int) -> dict[str, Any]:
    """``twincd COMMAND`` on the test logs at its defaults: its ``--json`` document, once its
    exit code is checked."""
    shown = run(command, dataset / "test", "-c", cal, "--json", "--no-summary")
    assert shown.exit_code == exit_code, shown.output
    doc: dict[str, Any] = json.loads(shown.stdout)
    return doc


def _answer(doc: dict[str, Any]) -> dict[str, Any]:
    """A ``--json`` document but for its errors and warnings (not in a run's ``to_dict``)."""
    return {k: v for k, v in doc.items() if k not in ("errors", "warnings")}


def test_detect_files_at_its_defaults_is_twincd_detect(
    twin_dataset: Path, cli_calibration: Path
) -> None:
    doc = _on_the_test_logs("detect", twin_dataset, cli_calibration, 1)
    done = twincd.detect_files([twin_dataset / "test"], cli_calibration, step_summary=False)
    assert done.to_dict() == _answer(doc)
    assert done.collision and done.exit_code == 1
    assert list(done.warnings) == doc["warnings"]


def test_detect_file_is_twincd_detect_on_one_log(
    twin_dataset: Path, cli_calibration: Path, tmp_path: Path
) -> None:
    log = twin_dataset / "test" / "test_0.mcap"
    cli_out, lib_out = tmp_path / "cli.csv", tmp_path / "lib.csv"
    shown = run("detect", log, "-c", cli_calibration, "--json", "-o", cli_out, "--no-summary")
    summary = twincd.detect_file(log, cli_calibration, output=lib_out, step_summary=False)
    assert [summary.to_dict()] == json.loads(shown.stdout)["logs"]
    assert summary.events  # the log has labelled bumps
    assert lib_out.read_text() == cli_out.read_text()  # the same flags, sample by sample


def test_detect_file_refuses_a_setting_that_contradicts_the_calibration(
    twin_dataset: Path, cli_calibration: Path
) -> None:
    with pytest.raises(twincd.TwincdError, match="contradicts the calibration"):
        twincd.detect_file(twin_dataset / "test" / "test_0.mcap", cli_calibration, causal=True)


def test_a_calibration_is_one_or_its_file_else_a_usage_error(
    twin_dataset: Path, cli_calibration: Path
) -> None:
    log = twin_dataset / "test" / "test_0.mcap"
    loaded = twincd.Calibration.load(cli_calibration)
    by_path = twincd.detect_file(log, cli_calibration).to_dict()
    assert twincd.detect_file(log, loaded).to_dict() == by_path
    for wrong in (None, 3, {"schema": "twincd.calibration/2"}):
        with pytest.raises(twincd.TwincdError, match="a Calibration or the path of its file"):
            twincd.detect_files([log], wrong)  # type: ignore[arg-type]
        with pytest.raises(twincd.TwincdError, match="a Calibration or the path of its file"):
            twincd.threshold_calibration([log], wrong)  # type: ignore[arg-type]


def test_evaluate_logs_at_its_defaults_is_twincd_evaluate(
    twin_dataset: Path, cli_calibration: Path
) -> None:
    doc = _on_the_test_logs("evaluate", twin_dataset, cli_calibration, 0)
    done = twincd.evaluate_logs([twin_dataset / "test"], cli_calibration, step_summary=False)
    assert _stable(done.to_dict()) == _stable(_answer(doc))
    assert done.evaluation.methods[0].f1_at_threshold is not None and done.exit_code == 0


def test_evaluate_logs_misses_a_gate_as_the_cli_does(
    twin_dataset: Path, cli_calibration: Path
) -> None:
    gated = run("evaluate", twin_dataset / "test", "-c", cli_calibration, "--min-auc", "1.01")
    done = twincd.evaluate_logs(
        [twin_dataset / "test"], cli_calibration, min_auc=1.01, step_summary=False
    )
    assert gated.exit_code == done.exit_code == 1
    assert done.missed and any("gate missed" in w for w in done.warnings)


def test_simulate_logs_at_its_defaults_is_twincd_simulate(tmp_path: Path) -> None:
    a = write(tmp_path / "a.mcap", "mcap", joint_recording(n=30))
    b = write(tmp_path / "b.mcap", "mcap", joint_recording(n=30))
    assert run("simulate", a, "-o", tmp_path / "a.cli.mcap", "-q").exit_code == 0
    done = twincd.simulate_logs([b])
    assert [r.output for r in done.outputs] == [tmp_path / "b.twin.mcap"]
    cli, lib = (twincd.read_log(p) for p in (tmp_path / "a.cli.mcap", tmp_path / "b.twin.mcap"))
    assert cli.sim_effort is not None and lib.sim_effort is not None
    np.testing.assert_array_equal(lib.sim_effort, cli.sim_effort)


def test_simulate_logs_refuses_a_filter(tmp_path: Path) -> None:
    a = write(tmp_path / "a.mcap", "mcap", joint_recording(n=30))
    with pytest.raises(twincd.TwincdError, match="unfiltered") as raised:
        twincd.simulate_logs([a], cutoff_hz=2.0)
    assert raised.value.option == "cutoff_hz"


def test_simulate_logs_refuses_a_filter_setting_whatever_its_value(tmp_path: Path) -> None:
    """``causal=False`` (the zero-phase filter) is a filter setting too: refused, not ignored."""
    a = write(tmp_path / "a.mcap", "mcap", joint_recording(n=30))
    with pytest.raises(twincd.TwincdError, match="unfiltered") as raised:
        twincd.simulate_logs([a], causal=False)
    assert raised.value.option == "causal"
    assert not (tmp_path / "a.twin.mcap").exists()


def test_threshold_calibration_gives_a_log_that_failed_counting(
    twin_dataset: Path, default_calibration: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A log that fails in the second pass (the false alarms counted at the threshold) is a
    failure of the run, as one that fails scoring is (exit 2, --json's errors)."""
    from twincd.detection import files
    from twincd.errors import DataError

    logs = sorted((twin_dataset / "val").glob("*.mcap"))
    bad = logs[0]
    tally = files.tally_false_alarms

    def failing(path: Any, *args: Any) -> Any:
        if Path(path) == bad:
            raise DataError("cannot count", str(path), "")
        return tally(path, *args)

    monkeypatch.setattr(files, "tally_false_alarms", failing)
    done = twincd.threshold_calibration(
        logs, default_calibration, keep_going=True, on_failure=lambda _f: None, jobs=1
    )
    assert [f.path for f in done.failures] == [bad] and done.exit_code == 2


def test_inspect_logs_at_its_defaults_is_twincd_inspect(twin_dataset: Path) -> None:
    log = twin_dataset / "train" / "train_0.mcap"
    shown = run("inspect", log, "--json")
    done = twincd.inspect_logs([log])
    assert shown.exit_code == done.exit_code == 0
    assert done.to_dict() == json.loads(shown.stdout)


def test_warnings_are_data_and_the_users_handlers_stay(
    twin_dataset: Path, cli_calibration: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A test log given twice is used once, with one warning: in ``warnings`` and on the
    user's own handlers, which the command leaves in place."""
    logger = logging.getLogger("twincd")
    handlers, filters = list(logger.handlers), list(logger.filters)
    log = twin_dataset / "test" / "test_0.mcap"
    with caplog.at_level(logging.WARNING, logger="twincd"):
        done = twincd.detect_files([log, log], cli_calibration, step_summary=False)
    assert len(done.logs) == 1
    assert done.warnings and any("twice" in w or "once" in w for w in done.warnings)
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == list(
        done.warnings
    )
    assert logger.handlers == handlers and logger.filters == filters


def test_keep_going_gives_the_failures_and_every_log_failing_is_an_error(
    twin_dataset: Path, cli_calibration: Path, tmp_path: Path
) -> None:
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"not a log")
    good = twin_dataset / "test" / "test_0.mcap"
    seen: list[Any] = []
    done = twincd.detect_files(
        [good, broken], cli_calibration, keep_going=True, on_failure=seen.append, step_summary=False
    )
    assert [f.path for f in done.failures] == [broken] == [f.path for f in seen]
    assert [s.source for s in done.logs] == [str(good)] and done.exit_code == 2
    with pytest.raises(LogsFailed) as raised:
        twincd.detect_files([broken], cli_calibration, keep_going=True, step_summary=False)
    assert raised.value.exit_code == 2 and len(raised.value.failures) == 1
    again = pickle.loads(pickle.dumps(raised.value))  # it may cross a process boundary
    assert again.exit_code == 2 and again.message == raised.value.message


# ---------------------------------------------------------------- reading options by name

LEFT_TOPIC = "/left/joint_states"
LEFT_FLAGS = ("--topic", LEFT_TOPIC, "--joint-prefix", "left_")


@pytest.fixture(scope="module")
def two_arms(twin_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[Path]]:
    """twin_dataset's logs as the left arms of two-arm bags (``left_j1``…), labels on
    ``/collision``."""
    root = tmp_path_factory.mktemp("two_arms")
    relabel = {"/collision_flag": "/collision"}
    out: dict[str, list[Path]] = {}
    for split in ("train", "val", "test"):
        logs = sorted((twin_dataset / split).glob("*.mcap"))
        out[split] = [
            two_arm_bag(root / f"{split}_{i}", log, logs[0], topics=relabel)
            for i, log in enumerate(logs)
        ]
    return out


def test_fit_and_threshold_read_one_arm_as_the_library_does(two_arms, tmp_path):
    cli, lib = tmp_path / "cli.json", tmp_path / "lib.json"
    assert run("fit", *two_arms["train"], *LEFT_FLAGS, "-o", cli, "-q").exit_code == 0
    twincd.fit_calibration(two_arms["train"], output=lib, topic=LEFT_TOPIC, joint_prefix="left_")
    assert _json(lib) == _json(cli)
    assert json.loads(cli.read_text())["log_options"]["joint_prefix"] == "left_"
    shown = run("threshold", *two_arms["val"], "-c", cli, *LEFT_FLAGS, "--json")
    assert shown.exit_code == 0, shown.output
    done = twincd.threshold_calibration(
        two_arms["val"], lib, output=lib, topic=LEFT_TOPIC, joint_prefix="left_"
    )
    assert _json(lib) == _json(cli)
    assert done.to_dict() == {**_answer(json.loads(shown.stdout)), "calibration": str(lib)}


def test_detect_and_evaluate_read_one_arm_as_the_library_does(two_arms, cli_calibration):
    """The calibration was fitted on the unprefixed arm, its labels on /collision_flag: the
    options given read the bag, by the CLI's flags or the library's keywords alike."""
    log = two_arms["test"][0]
    by_map = ",".join(f"left_j{i}=j{i}" for i in range(1, 4))
    as_mapped = ("--topic", LEFT_TOPIC, "--joint-map", by_map)
    for flags, summary in (
        (
            LEFT_FLAGS,
            twincd.detect_file(
                log, cli_calibration, step_summary=False, topic=LEFT_TOPIC, joint_prefix="left_"
            ),
        ),
        (
            as_mapped,
            twincd.detect_file(
                log,
                cli_calibration,
                step_summary=False,
                topic=LEFT_TOPIC,
                joint_map=parse_joint_map(by_map),
            ),
        ),
    ):
        shown = run("detect", log, "-c", cli_calibration, *flags, "--json", "--no-summary")
        assert shown.exit_code == 1, shown.output
        assert [summary.to_dict()] == json.loads(shown.stdout)["logs"] and summary.events
    labels = ("--label-topic", "/collision")
    shown = run(
        "evaluate",
        *two_arms["test"],
        "-c",
        cli_calibration,
        *LEFT_FLAGS,
        *labels,
        "--json",
        "--no-summary",
    )
    assert shown.exit_code == 0, shown.output
    done = twincd.evaluate_logs(
        two_arms["test"],
        cli_calibration,
        label_topic="/collision",
        step_summary=False,
        topic=LEFT_TOPIC,
        joint_prefix="left_",
    )
    assert _stable(done.to_dict()) == _stable(_answer(json.loads(shown.stdout)))
    assert done.evaluation.positives > 0


def test_inspect_reads_links_and_one_arm_as_the_library_does(xarm_dataset, tmp_path):
    """``--link-topic`` and ``--joint-prefix`` on inspect: the contact links of a log that
    carries them on another topic, the joints of one arm."""
    log = xarm_dataset / "test" / "test_000.mcap"
    touched = write(
        tmp_path / "touched",
        "rosbag2-mcap",
        retopic(messages_of(log), {"/collision_link": "/touched"}),
    )
    shown = run("inspect", touched, "--link-topic", "/touched", "--json")
    done = twincd.inspect_logs([touched], link_topic="/touched")
    assert shown.exit_code == done.exit_code == 0, shown.output
    assert done.to_dict() == json.loads(shown.stdout) and done.logs[0].link_labels
    bag = two_arm_bag(tmp_path / "bag", log, xarm_dataset / "val" / "val_000.mcap")
    shown = run("inspect", bag, *LEFT_FLAGS, "--json")
    done = twincd.inspect_logs([bag], topic=LEFT_TOPIC, joint_prefix="left_")
    assert shown.exit_code == done.exit_code == 0, shown.output
    assert done.to_dict() == json.loads(shown.stdout) and done.logs[0].matched == XARM


def test_simulate_reads_one_arm_as_the_library_does(tmp_path):
    names = [f"left_{n}" for n in XARM]
    recording = joint_recording(n=60, names=names, topic="/left/joint_states")
    a = write(tmp_path / "a.mcap", "mcap", recording)
    b = write(tmp_path / "b.mcap", "mcap", recording)
    assert run("simulate", a, *LEFT_FLAGS, "-o", tmp_path / "a.cli.mcap", "-q").exit_code == 0
    twincd.simulate_logs([b], topic=LEFT_TOPIC, joint_prefix="left_")
    left = LogOptions(topic=LEFT_TOPIC, joint_prefix="left_")
    outputs = (tmp_path / "a.cli.mcap", tmp_path / "b.twin.mcap")
    cli, lib = (twincd.read_log(p, left) for p in outputs)
    assert cli.sim_effort is not None and lib.sim_effort is not None
    np.testing.assert_array_equal(lib.sim_effort, cli.sim_effort)
