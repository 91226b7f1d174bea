"""Fault injection (issue 10): on damaged or odd input, twincd either answers (exit 0/1, one
JSON document) or exits 2 with one ``twincd: error:`` line; never a traceback, never a
changed input, never a leftover file. Also the reproductions of each reported fault.

Hypothesis profiles: ``ci`` (the default, a few hundred cases in all) and ``local``
(``HYPOTHESIS_PROFILE=local``, thousands); the cases each property ran are counted, and
checked at the end against what the profile promised.
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import TWIN_JOINTS, build_twin_log
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.clitools import assert_one_line_error, run

from twincd.calibration import Calibration

settings.register_profile(
    "ci", max_examples=40, deadline=None, suppress_health_check=list(HealthCheck)
)
settings.register_profile(
    "local", max_examples=2500, deadline=None, suppress_health_check=list(HealthCheck)
)
PROFILE = os.environ.get("HYPOTHESIS_PROFILE", "ci")
FAULTS = settings.get_profile(PROFILE)
# cases run, per test (the name pytest gives the test running now)
CASES: dict[str, int] = {}

MCAP_MAGIC = b"\x89MCAP0\r\n"


@pytest.fixture(scope="module")
def world(tmp_path_factory, twin_calibration) -> dict[str, Any]:
    """A calibration with threshold, and a clean 4 s log (with labels, its own twin effort)."""
    root = tmp_path_factory.mktemp("faults")
    cal = twin_calibration
    clean = build_twin_log(root / "clean.mcap", seed=300, seconds=4.0)
    return {"cal": cal, "clean": clean}


def record_boundaries(data: bytes) -> tuple[list[int], int]:
    """Offsets where each top-level MCAP record starts (after the magic), and the end; and the
    end of the data section (after its DataEnd record: cut later, no message is lost)."""
    at, found, data_end = len(MCAP_MAGIC), [], len(data)
    while at + 9 <= len(data):
        found.append(at)
        opcode, length = struct.unpack_from("<BQ", data, at)
        at += 9 + length
        if opcode == 0x0F:  # DataEnd
            data_end = at
        if opcode == 0x02:  # footer
            break
    return [*found, len(data)], data_end


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def check_run(folder: Path, log: Path, cal: Path, *extra: Any, output: bool = True) -> Any:
    """``detect`` on ``log`` (with ``-o`` into ``folder``): an answer or one clean error line;
    the input unchanged; nothing left over but the output of a successful run."""
    test = os.environ.get("PYTEST_CURRENT_TEST", "").split("::")[-1].split(" ")[0]
    CASES[test] = CASES.get(test, 0) + 1
    before = digest(log)
    out = folder / "out.mcap"
    args = ["detect", log, "-c", cal, "--json", *extra] + (["-o", out] if output else [])
    result = run(*args)
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    assert "Traceback" not in result.output
    assert result.exit_code in (0, 1, 2), result.exit_code
    if result.exit_code == 2:
        assert_one_line_error(result)
        assert not out.exists()
    else:
        doc = json.loads(result.stdout)
        assert doc["logs"][0]["samples"] > 0 and not doc["errors"]
        if output:
            assert out.is_file()
            out.unlink()
    assert digest(log) == before
    assert sorted(p.name for p in folder.iterdir()) == [log.name]  # no temporary left
    return result


# ------------------------------------------------------------------ truncation


def test_truncation_at_every_record_boundary(world, tmp_path):
    data = world["clean"].read_bytes()
    cuts, data_end = record_boundaries(data)
    assert len(cuts) > 10
    log = tmp_path / "cut.mcap"
    for cut in cuts[:-1]:
        log.write_bytes(data[:cut])
        result = check_run(tmp_path, log, world["cal"])
        lost = cut < data_end  # a cut in the summary loses no message: nothing to say
        if result.exit_code != 2:  # read up to the damage: said once, with the way to repair
            damaged = [w for w in json.loads(result.stdout)["warnings"] if "damaged" in w]
            assert len(damaged) == int(lost)
            assert not lost or "mcap recover" in damaged[0]
        strict = check_run(tmp_path, log, world["cal"], "--strict", output=False)
        assert strict.exit_code == (2 if lost else result.exit_code)


@FAULTS
@given(fraction=st.floats(0.0, 1.0, exclude_max=True))
def test_truncation_at_random_offsets(world, tmp_path_factory, fraction):
    folder = tmp_path_factory.mktemp("cut")
    data = world["clean"].read_bytes()
    log = folder / "cut.mcap"
    log.write_bytes(data[: int(fraction * len(data))])
    check_run(folder, log, world["cal"])


# ------------------------------------------------------------------ flipped bytes


@FAULTS
@given(
    flips=st.lists(
        st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.integers(1, 255)),
        min_size=1,
        max_size=8,
    )
)
def test_flipped_bytes(world, tmp_path_factory, flips):
    folder = tmp_path_factory.mktemp("flip")
    data = bytearray(world["clean"].read_bytes())
    for where, mask in flips:
        data[int(where * len(data))] ^= mask
    log = folder / "flip.mcap"
    log.write_bytes(bytes(data))
    check_run(folder, log, world["cal"])


# ------------------------------------------------------------------ random CDR payloads


@FAULTS
@given(
    bad=st.dictionaries(st.integers(0, 399), st.binary(min_size=0, max_size=200), max_size=40),
)
def test_random_cdr_payloads(world, tmp_path_factory, bad):
    from twincd.io.cdr import joint_state_cdr
    from twincd.io.mcap import McapLogWriter

    folder = tmp_path_factory.mktemp("cdr")
    log = folder / "cdr.mcap"
    n = 400
    t = np.arange(n) * 0.01
    q = np.column_stack([np.sin(t + k) for k in range(3)])
    stamps = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 10_000_000
    msgs = list(joint_state_cdr(stamps, ("j1", "j2", "j3"), q, np.cos(q), 2 * q))
    sims = list(joint_state_cdr(stamps, ("j1", "j2", "j3"), q, np.cos(q), q))
    with McapLogWriter(log) as out:
        js = out.add_topic("/joint_states", "sensor_msgs/msg/JointState")
        sim = out.add_topic("/twincd/sim_effort", "sensor_msgs/msg/JointState")
        for i in range(n):
            out.write(js, int(stamps[i]), bad.get(i, msgs[i]))
            out.write(sim, int(stamps[i]), sims[i])
    check_run(folder, log, world["cal"])


# ------------------------------------------------------------------ NaN / inf


@FAULTS
@given(
    spots=st.lists(
        st.tuples(
            st.sampled_from(["q", "qd", "effort", "twin"]),
            st.integers(0, 399),
            st.integers(0, 2),
            st.sampled_from([np.nan, np.inf, -np.inf]),
        ),
        min_size=1,
        max_size=6,
    )
)
def test_nan_and_inf_at_random_places_drop_samples_not_the_log(world, tmp_path_factory, spots):
    folder = tmp_path_factory.mktemp("nan")

    def poison(arrays: dict[str, np.ndarray]) -> None:
        for name, row, col, value in spots:
            arrays[name][row, col] = value

    log = build_twin_log(folder / "nan.mcap", seed=301, seconds=4.0, edit=poison)
    result = check_run(folder, log, world["cal"])
    # a clean log with a few bad samples: still answered, and collision-free
    assert result.exit_code == 0, result.output
    rows = {row for _, row, _, _ in spots}
    doc = json.loads(result.stdout)
    assert doc["logs"][0]["samples"] >= 400 - len(rows)


# ------------------------------------------------------------------ clocks


@FAULTS
@given(
    jumps=st.lists(
        st.tuples(st.integers(1, 399), st.integers(-20_000, 20_000)), min_size=1, max_size=4
    ),
    shuffle=st.integers(0, 30),
    seed=st.integers(0, 1000),
)
def test_non_monotonic_and_jumping_clocks(world, tmp_path_factory, jumps, shuffle, seed):
    folder = tmp_path_factory.mktemp("clock")
    rng = np.random.default_rng(seed)

    def skew(arrays: dict[str, np.ndarray]) -> None:
        stamps = arrays["stamps"]
        for at, ms in jumps:
            stamps[at:] += ms * 1_000_000  # the header clock jumps (either way)
        for _ in range(shuffle):  # neighbours swapped: reordering
            i = int(rng.integers(0, len(stamps) - 1))
            stamps[[i, i + 1]] = stamps[[i + 1, i]]

    log = build_twin_log(folder / "clock.mcap", seed=302, seconds=4.0, edit=skew)
    result = check_run(folder, log, world["cal"])
    offset = np.zeros(400)  # where the header clock stands against the log time, ms
    for at, ms in jumps:
        offset[at:] += ms
    # back by more than 5 s (+ the swaps' 10 ms) from where it stood: a jump, not reordering
    jumped = float((np.maximum.accumulate(offset)[:-1] - offset[1:]).max()) > 5_020
    if result.exit_code != 2 and jumped:
        assert any("clock jumps back" in w for w in json.loads(result.stdout)["warnings"])


# ------------------------------------------------------------------ real drivers' shapes

EXTRA_JOINTS = ("drive_joint", "rail", "panda_finger_joint1")


@FAULTS
@given(
    extra=st.lists(
        st.tuples(st.sampled_from(EXTRA_JOINTS), st.integers(0, 3)),
        max_size=3,
        unique_by=lambda x: x[0],
    ),
    order=st.permutations(TWIN_JOINTS),
    effort=st.sampled_from(["as is", "zero", "flipped", "degrees"]),
    cut=st.one_of(st.none(), st.floats(0.3, 1.0, exclude_max=True)),
)
def test_real_shapes_with_damage(world, tmp_path_factory, extra, order, effort, cut):
    """Joint sets as real drivers publish them (extra joints anywhere, any order), signals that
    cannot be right, and a cut file: an answer or one line, never a crash; with the arm's data
    untouched and the file whole, the answer of the clean log, with the extra joints named."""
    folder = tmp_path_factory.mktemp("shape")
    names = list(order)
    for name, at in extra:
        names.insert(min(at, len(names)), name)

    def change(arrays: dict[str, np.ndarray]) -> None:
        if effort == "zero":
            arrays["effort"][:] = 0.0
        elif effort == "flipped":
            arrays["effort"] *= -1.0
        elif effort == "degrees":
            arrays["q"] *= 180.0 / np.pi

    log = build_twin_log(
        folder / "shape.mcap", seed=300, seconds=4.0, state_joints=names, edit=change
    )
    if cut is not None:
        data = log.read_bytes()
        log.write_bytes(data[: int(cut * len(data))])
    result = check_run(folder, log, world["cal"])
    if cut is None and effort == "as is":
        clean = json.loads(run("detect", world["clean"], "-c", world["cal"], "--json").stdout)
        doc = json.loads(result.stdout)
        assert doc["collision"] == clean["collision"]
        assert doc["logs"][0]["samples"] == clean["logs"][0]["samples"]
        assert doc["logs"][0]["events"] == clean["logs"][0]["events"]
        if extra:
            assert any(all(n in w for n, _ in extra) for w in doc["warnings"]), doc["warnings"]


PROPERTIES = (
    "test_truncation_at_random_offsets",
    "test_flipped_bytes",
    "test_random_cdr_payloads",
    "test_nan_and_inf_at_random_places_drop_samples_not_the_log",
    "test_non_monotonic_and_jumping_clocks",
    "test_real_shapes_with_damage",
)


def test_each_property_ran_the_cases_its_profile_promised():
    """Every property above that ran (all of them, unless deselected) ran the profile's
    number of cases: none stopped early or was silently cut short."""
    ran = {name: CASES[name] for name in PROPERTIES if name in CASES}
    for name, count in ran.items():
        assert count >= FAULTS.max_examples, (name, count, PROFILE)


# ------------------------------------------------------------------ reported faults


def test_nan_or_inf_in_the_calibration_is_an_error_not_no_collision(world, tmp_path):
    doc = json.loads(world["cal"].read_text())
    for field, value in (("a", float("nan")), ("b", float("inf"))):
        bad = json.loads(json.dumps(doc))
        bad["model"]["joints"]["j1"][field] = value
        path = tmp_path / f"{field}.json"
        path.write_text(json.dumps(bad))
        assert_one_line_error(run("detect", world["clean"], "-c", path), f"{field}[j1]")
        assert_one_line_error(run("threshold", world["clean"], "-c", path), f"{field}[j1]")
    bad = json.loads(json.dumps(doc))
    bad["threshold"]["mu"] = float("nan")
    (tmp_path / "mu.json").write_text(json.dumps(bad))
    assert_one_line_error(run("detect", world["clean"], "-c", tmp_path / "mu.json"), "mu")


def test_a_calibration_for_fewer_joints_is_refused(world, tmp_path):
    doc = json.loads(world["cal"].read_text())
    doc["robot"]["joint_names"] = ["j1", "j2"]
    del doc["model"]["joints"]["j3"]
    del doc["fit"]["joints"]["j3"]
    path = tmp_path / "two.json"
    path.write_text(json.dumps(doc))
    assert_one_line_error(run("detect", world["clean"], "-c", path), "j3 that the calibration")


def test_short_logs_are_refused(world, tmp_path):
    for seconds in (0.03, 0.1):  # 3 and 10 samples
        log = build_twin_log(tmp_path / f"s{seconds}.mcap", seed=1, seconds=seconds)
        assert_one_line_error(run("detect", log, "-c", world["cal"]), "log too short")
        assert_one_line_error(run("fit", log, "-o", tmp_path / "c.json"), "log too short")


def test_a_log_mostly_near_its_ends_is_judged_and_said_to_be_short(world, tmp_path):
    # 1.5 × the stretch near the ends where the filter leaves ≥ 1.5× the middle's noise: every
    # sample judged, most of them less sensitively, and said so
    from twincd.prepare.notices import edges_s

    near = edges_s(Calibration.load(world["cal"]).lowpass, 0.01)
    log = build_twin_log(tmp_path / "short.mcap", seed=1, seconds=1.5 * near)
    result = run("detect", log, "-c", world["cal"], "--json")
    assert result.exit_code == 0 and "judged less sensitively" in result.stderr
    assert any("of a segment's end" in w for w in json.loads(result.stdout)["warnings"])
    (entry,) = json.loads(result.stdout)["logs"]
    assert entry["too_short"] is False and entry["judged_samples"] == entry["samples"]


def test_a_clock_jumping_back_is_reported_not_merged(world, tmp_path):
    def back(arrays: dict[str, np.ndarray]) -> None:
        arrays["stamps"][800:] -= 10_000_000_000

    log = build_twin_log(tmp_path / "back.mcap", seed=2, edit=back)
    result = run("detect", log, "-c", world["cal"], "--json")
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc["logs"][0]["samples"] == 800
    assert [w for w in doc["warnings"] if "clock jumps back 1 time(s) (by up to 10 s)" in w]


def test_one_bad_effort_value_drops_a_sample(world, tmp_path):
    def nan(arrays: dict[str, np.ndarray]) -> None:
        arrays["effort"][0, 1] = np.nan
        arrays["effort"][200, 0] = np.inf

    log = build_twin_log(tmp_path / "nan.mcap", seed=3, edit=nan)
    for causal in ((), ("--causal",)):
        result = run("fit", log, "-o", tmp_path / "c.json", "--force", *causal)
        assert result.exit_code == 0, result.output
        assert "dropped 2 sample(s) with NaN or infinite values" in result.stderr


def test_fit_warnings(tmp_path):
    against = build_twin_log(tmp_path / "neg.mcap", gains=np.array([-1.3, 0.8, 1.1]))
    result = run("fit", against, "-o", tmp_path / "neg.json")
    assert result.exit_code == 0
    assert "friction-whitened model's gain on the twin's effort is negative on j1" in result.stderr
    flat = build_twin_log(tmp_path / "flat.mcap", gains=np.zeros(3), noise=1.0, labels=False)
    # the paper's map explains nothing of an effort the twin does not drive (the R² warned of is
    # the fitted model's: a friction model may still explain such an effort)
    result = run("fit", flat, "-o", tmp_path / "flat.json", "--model", "affine")
    assert result.exit_code == 0
    assert "R² below 0.1 on every joint" in result.stderr
    assert "have no collision labels" in result.stderr


def test_joint_map_that_merges_joints_is_an_error(world, tmp_path):
    result = run("fit", world["clean"], "--joint-map", "j1=j2", "-o", tmp_path / "c.json")
    assert_one_line_error(result, "log joints j1 and j2 are both j2")
    assert "--joint-map" in result.stderr


def test_log_time_above_2_63_is_a_clean_error(tmp_path):
    from mcap.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    from twincd.io.cdr import joint_state_cdr
    from twincd.io.mcap import DEFAULT_QOS, QOS_KEY

    msgdef, _ = get_typestore(Stores.ROS2_HUMBLE).generate_msgdef("sensor_msgs/msg/JointState")
    q = np.linspace(0, 1, 50)[:, None]
    payloads = joint_state_cdr(np.zeros(50, dtype=np.int64), ("joint1",), q, q, q)
    path = tmp_path / "late.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2")
        schema = writer.register_schema("sensor_msgs/msg/JointState", "ros2msg", msgdef.encode())
        channel = writer.register_channel("/joint_states", "cdr", schema, {QOS_KEY: DEFAULT_QOS})
        for i, data in enumerate(payloads):
            t = 2**63 + 5 + i * 10_000_000
            writer.add_message(channel, log_time=t, data=data, publish_time=t)
        writer.finish()
    assert_one_line_error(run("simulate", path, "-o", tmp_path / "o.mcap"), "above 2^63 ns")


def test_keep_going_reports_each_failure_and_exits_2(world, tmp_path):
    # long enough that most of it is judged: no "short" warning beside the one error line
    good = build_twin_log(tmp_path / "a_good.mcap", seed=300, seconds=8.0)
    (tmp_path / "b_bad.mcap").write_bytes(MCAP_MAGIC + b"garbage")
    bad = tmp_path / "b_bad.mcap"
    result = run("detect", good, bad, "-c", world["cal"], "--json")
    assert_one_line_error(result, "b_bad.mcap")  # without: the first bad log stops the run
    out = tmp_path / "out"
    for jobs in ("1", "2"):
        result = run(
            "detect", good, bad, "-c", world["cal"], "--json", "--keep-going", "-j", jobs, "-o", out
        )
        assert result.exit_code == 2
        lines = result.stderr.strip().splitlines()
        errors = [ln for ln in lines if ln.startswith("twincd: error: ")]
        assert len(errors) == 1 and "b_bad" in errors[0]
        # the good log's output is kept, and said
        assert [ln for ln in lines if ln not in errors] == [
            f"twincd: wrote {out / 'a_good.detect.mcap'} (800 samples)"
        ]
        doc = json.loads(result.stdout)
        assert [lg["path"] for lg in doc["logs"]] == [str(good)]
        assert [e["path"] for e in doc["errors"]] == [str(bad)] and doc["errors"][0]["error"]
        assert sorted(p.name for p in out.iterdir()) == ["a_good.detect.mcap"]
    result = run("fit", good, bad, "-o", tmp_path / "c.json", "--keep-going")
    assert result.exit_code == 2 and (tmp_path / "c.json").is_file()


def test_evaluate_keeps_going_past_a_bad_test_log(world, twin_dataset, tmp_path):
    bad = tmp_path / "b_bad.mcap"
    bad.write_bytes(MCAP_MAGIC + b"garbage")
    test = sorted((twin_dataset / "test").iterdir())
    result = run("evaluate", *test, bad, "-c", world["cal"], "--json")
    assert_one_line_error(result, "b_bad.mcap")
    result = run("evaluate", *test, bad, "-c", world["cal"], "--json", "--keep-going")
    assert result.exit_code == 2  # every other log evaluated, the failure still fails the run
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("twincd: error: ") and "b_bad" in lines[0]
    doc = json.loads(result.stdout)
    assert [e["path"] for e in doc["errors"]] == [str(bad)]
    assert doc["methods"][0]["f1_best"] > 0 and doc["samples"] > 0


def test_help_shows_no_bool_metavar():
    for command in ("detect", "fit", "threshold", "evaluate", "simulate", "synth"):
        result = run(command, "--help")
        assert result.exit_code == 0 and "<bool>" not in result.stdout, command


def test_tables_are_not_cut_when_stdout_is_not_a_terminal(world, twin_dataset):
    result = run("evaluate", twin_dataset / "test", "-c", world["cal"], "--methods", "all")
    assert result.exit_code == 0, result.output
    header = next(line for line in result.stdout.splitlines() if "method" in line)
    assert "recall" in header and "test s" in header
    from twincd_cli.common import stdout

    assert not stdout.is_terminal and stdout.width >= 200  # no 80-column default in CI logs


def test_short_logs_are_refused_by_causal_detection_too(twin_dataset, tmp_path):
    cal = tmp_path / "causal.json"
    assert run("fit", twin_dataset / "train", "-o", cal, "--causal", "-q").exit_code == 0
    assert run("threshold", twin_dataset / "val", "-c", cal, "-q").exit_code == 0
    log = build_twin_log(tmp_path / "s.mcap", seed=1, seconds=0.05)
    assert_one_line_error(run("detect", log, "-c", cal), "log too short")


def test_quiet_keeps_warnings_in_json_only(world, tmp_path):
    def back(arrays: dict[str, np.ndarray]) -> None:
        arrays["stamps"][800:] -= 10_000_000_000

    log = build_twin_log(tmp_path / "back.mcap", seed=2, edit=back)
    result = run("detect", log, "-c", world["cal"], "--json", "-q")
    assert result.exit_code == 0 and result.stderr == ""
    assert any("clock jumps back" in w for w in json.loads(result.stdout)["warnings"])


def test_on_a_terminal_messages_never_share_a_line_with_the_progress_bar(twin_dataset, tmp_path):
    """stderr on a pseudo-terminal (progress bars on), logs on a pool: every message starts a
    line of its own once the bar's control sequences are taken out (workers' warnings come
    back with their results; printed by the workers, they broke into the bar's line)."""
    import pty
    import re
    import subprocess
    import sys

    def back(arrays: dict[str, np.ndarray]) -> None:
        arrays["stamps"][800:] -= 10_000_000_000

    logs = [twin_dataset / "train" / f"train_{i}.mcap" for i in range(3)]
    logs.append(build_twin_log(tmp_path / "back.mcap", seed=2, edit=back))
    main, child = pty.openpty()
    argv = [sys.executable, "-c", "from twincd_cli.main import main; main()", "fit"]
    proc = subprocess.Popen(
        [*argv, *map(str, logs), "-o", str(tmp_path / "c.json"), "-j", "2"],
        stdout=subprocess.DEVNULL,
        stderr=child,
        env={**os.environ, "TERM": "xterm", "COLUMNS": "100"},
    )
    os.close(child)
    chunks = []
    while True:
        try:
            data = os.read(main, 4096)
        except OSError:
            break
        if not data:
            break
        chunks.append(data)
    assert proc.wait(timeout=120) == 0
    text = b"".join(chunks).decode(errors="replace")
    plain = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", text).replace("\r", "\n")
    lines = [line for line in plain.splitlines() if "twincd:" in line]
    assert any("clock jumps back" in line for line in lines)
    assert all(line.startswith("twincd:") for line in lines), lines
