"""Exit codes CI can trust, and outputs never lost: 1 only for a finding (a collision, a missed
gate), 2 for errors of use, input or output (a full disk too), 3 for a defect; one line on
stderr, no traceback without --debug, no temporary left, inputs unchanged; a closed stdout
ends quietly; two logs never write one output; --force never overwrites an input."""

from __future__ import annotations

import errno
import hashlib
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from conftest import build_twin_log
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.builders import joint_recording, write
from support.clitools import assert_one_line_error, run

from twincd.errors import DataError, InternalError, OutputError

settings.register_profile(
    "ci", max_examples=30, deadline=None, suppress_health_check=list(HealthCheck)
)
settings.register_profile(
    "local", max_examples=300, deadline=None, suppress_health_check=list(HealthCheck)
)
FAULTS = settings.get_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
PROGRAM = [sys.executable, "-c", "from twincd_cli.main import main; main()"]


@pytest.fixture(scope="module")
def world(tmp_path_factory, twin_dataset, twin_calibration) -> dict[str, Path]:
    """Read-only inputs of every command: twin logs, a calibration, an xArm 7 recording."""
    root = tmp_path_factory.mktemp("exits")
    cal = twin_calibration
    xarm = write(root / "xarm.mcap", "mcap", joint_recording(n=60))
    return {"data": twin_dataset, "cal": cal, "xarm": xarm}


def digests(paths: list[Path]) -> dict[Path, str]:
    files = [f for p in paths for f in ([p] if p.is_file() else sorted(p.rglob("*")))]
    return {f: hashlib.sha256(f.read_bytes()).hexdigest() for f in files if f.is_file()}


# ------------------------------------------------------------------ injected faults


# (command, arguments in folder OUT, the inputs it reads)
def commands(world: dict[str, Path], out: Path) -> dict[str, tuple[list[Any], list[Path]]]:
    data, cal = world["data"], world["cal"]
    test = data / "test" / "test_0.mcap"
    return {
        "simulate": (["simulate", world["xarm"], "-o", out / "x.twin.mcap"], [world["xarm"]]),
        "fit": (["fit", data / "train", "-o", out / "c.json", "--report", out / "f.md"], [data]),
        "threshold": (["threshold", data / "val", "-c", cal, "-o", out / "t.json"], [data, cal]),
        "detect": (
            [
                *("detect", test, "-c", cal, "-o", out / "d.mcap", "--report", out / "d.md"),
                *("--junit", out / "d.xml", "--no-summary"),
            ],
            [test, cal],
        ),
        "evaluate": (
            [
                *("evaluate", data / "test", "-c", cal, "--report", out / "e.md"),
                *("--junit", out / "e.xml", "--min-f1", "0.0", "--no-summary"),
            ],
            [data, cal],
        ),
        "inspect": (["inspect", test, "-c", cal, "--json"], [test, cal]),
        "synth": (
            [
                *("synth", out / "s", "--train", "1", "--val", "0", "--test", "0"),
                *("--min-duration", "2", "--max-duration", "2", "--no-rosbag2-copy"),
            ],
            [],
        ),
    }


# where a fault is injected: (module, attribute); "reader" and "writer" errors of the
# operating system are errors of input and output (exit 2), anywhere else a defect (3)
POINTS = {
    "reader": ("twincd.io.stream.backends", "McapFile"),
    "twin": ("twincd.twin.dynamics", "inverse_dynamics"),
    "synth twin": ("twincd.synth.simulate", "inverse_dynamics"),
    "filter": ("twincd.signal.filters.LowPass", "sos"),
    "writer": ("twincd.io.atomic._OutputFile", "put"),
    "report": ("twincd.reports", "calibration_settings"),
    "fit report": ("twincd.reports.documents", "fit_markdown"),
    "evaluation": ("twincd.reports.documents", "evaluation_markdown"),
}
# the points each command passes through (a point that stops being reached fails the test)
REACHED = {
    "simulate": ("reader", "twin", "writer"),
    "fit": ("reader", "filter", "writer", "fit report"),
    "threshold": ("reader", "filter", "writer"),
    "detect": ("reader", "filter", "writer", "report"),
    "evaluate": ("reader", "filter", "writer", "evaluation"),
    "inspect": ("reader",),
    "synth": ("synth twin", "writer"),
}
FAULT_TYPES: dict[str, Callable[[], BaseException]] = {
    "ENOSPC": lambda: OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)),
    "EIO": lambda: OSError(errno.EIO, os.strerror(errno.EIO)),
    "RuntimeError": lambda: RuntimeError("injected\nover two lines"),
    "ValueError": lambda: ValueError("injected"),
    "MemoryError": MemoryError,
    "KeyError": lambda: KeyError("injected"),
    "TwincdError": lambda: DataError("injected fault", "here", "do something"),
}


# a file write raises only these (an MCAP copy reads and writes in one loop, and tells a
# damaged input by the KeyError, ValueError... its reader raises: not drawn at the writer)
WRITE_FAULTS = ("EIO", "ENOSPC", "MemoryError", "TwincdError")


def faults_at(point: str) -> list[str]:
    return list(WRITE_FAULTS) if point == "writer" else sorted(FAULT_TYPES)


def expected_code(point: str, fault: str) -> int:
    os_error = fault in ("ENOSPC", "EIO")
    if fault == "TwincdError" or (os_error and point in ("reader", "writer")):
        return 2
    return 3


def inject(monkeypatch: pytest.MonkeyPatch, point: str, fault: str, after: int) -> list[int]:
    """Replace the point with one that works ``after`` times, then raises; the calls seen."""
    import importlib

    module_name, attribute = POINTS[point]
    try:
        owner: Any = importlib.import_module(module_name)
    except ImportError:
        parent, _, cls = module_name.rpartition(".")
        owner = getattr(importlib.import_module(parent), cls)
    original = getattr(owner, attribute)
    calls = [0]

    def faulty(*args: Any, **kwargs: Any) -> Any:
        calls[0] += 1
        if calls[0] > after:
            raise FAULT_TYPES[fault]()
        return original(*args, **kwargs)

    monkeypatch.setattr(owner, attribute, faulty)
    return calls


CASES = [(command, point) for command, points in REACHED.items() for point in points]


@FAULTS
@given(
    case=st.sampled_from(CASES).flatmap(
        lambda c: st.tuples(st.just(c[0]), st.just(c[1]), st.sampled_from(faults_at(c[1])))
    ),
    after=st.integers(0, 3),
    debug=st.booleans(),
)
def test_a_fault_anywhere_is_exit_2_or_3_never_1(world, tmp_path_factory, case, after, debug):
    command, point, fault = case
    out = tmp_path_factory.mktemp("fault")
    args, inputs = commands(world, out)[command]
    before = digests(inputs)
    with pytest.MonkeyPatch.context() as monkeypatch:
        calls = inject(monkeypatch, point, fault, after)
        result = run(*args, "-q", *(["--debug"] if debug else []))
    assert calls[0] > 0, f"{command} no longer reaches {point}"
    left = sorted(p.name for p in out.rglob("*") if p.is_file())
    assert not [name for name in left if ".twincd-" in name], left  # no temporary
    assert digests(inputs) == before
    if calls[0] <= after:  # the fault never fired: a normal run
        assert result.exit_code in (0, 1) if command == "detect" else result.exit_code == 0
        return
    code = expected_code(point, fault)
    assert result.exit_code == code, (result.exit_code, result.output)
    kind = "internal error" if code == 3 else "error"
    lines = [line for line in result.stderr.splitlines() if line.startswith("twincd: ")]
    assert len(lines) == 1 and lines[0].startswith(f"twincd: {kind}: "), result.stderr
    assert " — " in lines[0]
    if code == 3:
        assert lines[0].endswith("re-run with --debug and report it")
    assert ("Traceback" in result.stderr) == debug
    if not debug:
        assert len(result.stderr.splitlines()) == 1
    assert left == [], left  # every output of a failed run is gone


def test_every_fault_point_of_a_command_is_reached(world, tmp_path, monkeypatch):
    """The strategy above draws only pairs that fire; this names a pair that stopped firing."""
    for command, points in REACHED.items():
        for point in points:
            out = tmp_path / f"{command}-{point}".replace(" ", "_")
            out.mkdir()
            args, _ = commands(world, out)[command]
            with pytest.MonkeyPatch.context() as patch:
                calls = inject(patch, point, "RuntimeError", 0)
                result = run(*args, "-q")
            assert calls[0] >= 1 and result.exit_code == 3, (command, point, result.output)


def test_internal_error_line_and_debug_traceback(world, monkeypatch):
    test = world["data"] / "test" / "test_0.mcap"
    inject(monkeypatch, "filter", "KeyError", 0)
    result = run("detect", test, "-c", world["cal"])
    assert result.exit_code == 3
    assert result.stderr == (
        "twincd: internal error: KeyError: 'injected' — re-run with --debug and report it\n"
    )
    result = run("detect", test, "-c", world["cal"], "--debug")
    assert result.exit_code == 3 and "Traceback" in result.stderr and "faulty" in result.stderr


def test_internal_error_survives_a_process_boundary():
    import pickle

    error = InternalError.from_exception(ValueError("bad"), "run.mcap")
    again = pickle.loads(pickle.dumps(error))
    assert again.exit_code == 3 and again.message == error.message and "ValueError" in again.details


def test_keep_going_reports_a_defect_per_log_and_exits_3(world, tmp_path, monkeypatch):
    """--keep-going: a log whose work hits a defect is one internal-error line; the other logs
    are answered; exit 3 (a defect outranks the input errors of exit 2). In this process (a
    pool's workers would not inherit the injected fault; a worker's defect crosses back as an
    InternalError, whose pickling the test above checks)."""
    jobs = "1"
    good = shutil.copy(world["data"] / "test" / "test_0.mcap", tmp_path / "a_good.mcap")
    bad = build_twin_log(tmp_path / "b_bad.mcap", seed=5, seconds=4.0)
    original = __import__("twincd.detection.files", fromlist=["detect_streamed"]).detect_streamed

    def detect_streamed(path: Path, *args: Any, **kwargs: Any) -> Any:
        if Path(path).name == "b_bad.mcap":
            raise ZeroDivisionError("injected")
        return original(path, *args, **kwargs)

    monkeypatch.setattr("twincd.detection.files.detect_streamed", detect_streamed)
    result = run("detect", good, bad, "-c", world["cal"], "--json", "--keep-going", "-j", jobs)
    assert result.exit_code == 3, result.output
    assert result.stderr.splitlines() == [
        f"twincd: internal error: ZeroDivisionError: injected ({bad}) "
        "— re-run with --debug and report it"
    ]
    import json

    doc = json.loads(result.stdout)
    assert [lg["path"] for lg in doc["logs"]] == [str(good)] and doc["collision"]
    assert [e["path"] for e in doc["errors"]] == [str(bad)]
    # without --keep-going the defect stops the run: exit 3, not 1 for the other log's finding
    result = run("detect", good, bad, "-c", world["cal"], "-j", jobs)
    assert result.exit_code == 3 and result.stderr.startswith("twincd: internal error: ")


# ------------------------------------------------------------------ a closed stdout


@pytest.mark.parametrize(("split", "code"), [("train", 0), ("test", 1)])
def test_a_closed_stdout_ends_quietly_with_the_run_s_own_code(world, tmp_path, split, code):
    """``twincd detect … | head -1``: the reader is gone before twincd writes; exit 1 only for
    the finding, no message, no traceback."""
    logs = sorted((world["data"] / split).glob("*.mcap"))
    argv = [*PROGRAM, "detect", *map(str, logs), "-c", str(world["cal"])]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # the reader leaves before anything is written
    err = proc.stderr.read()
    assert proc.wait(timeout=120) == code, err
    assert err == b""


def test_a_closed_stdout_after_one_line(world, tmp_path):
    """Reading one line, then closing: many logs, so that twincd writes after the close."""
    logs = []
    for i in range(100):
        logs.append(shutil.copy(world["data"] / "train" / "train_0.mcap", tmp_path / f"l{i}.mcap"))
    argv = [*PROGRAM, "detect", *map(str, logs), "-c", str(world["cal"])]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, bufsize=0)
    assert proc.stdout is not None and proc.stderr is not None
    import fcntl

    fcntl.fcntl(proc.stdout.fileno(), getattr(fcntl, "F_SETPIPE_SZ", 1031), 4096)  # one page
    assert b"no collision" in proc.stdout.readline()
    proc.stdout.close()
    err = proc.stderr.read()
    assert proc.wait(timeout=120) == 0, err
    assert err == b""


def test_help_into_a_closed_pipe(tmp_path):
    proc = subprocess.Popen([*PROGRAM, "detect", "--help"], stdout=subprocess.PIPE)
    assert proc.stdout is not None
    proc.stdout.close()
    assert proc.wait(timeout=60) == 0


# ------------------------------------------------------------------ full disks, devices


NO_DEV_FULL = pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full")


@NO_DEV_FULL
def test_dev_full_is_refused_before_any_work(world, tmp_path):
    full = Path("/dev/full")
    data, cal = world["data"], world["cal"]
    test = data / "test" / "test_0.mcap"
    for args in (
        ("detect", test, "-c", cal, "-o", full),
        ("detect", test, test.with_name("test_1.mcap"), "-c", cal, "-o", full),
        ("detect", test, "-c", cal, "--report", tmp_path / "r.md", "--junit", full),
        ("fit", data / "train", "-o", full),
        ("threshold", data / "val", "-c", cal, "-o", full),
        ("simulate", world["xarm"], "-o", full),
        ("evaluate", data / "test", "-c", cal, "--junit", full),
    ):
        assert_one_line_error(run(*args), "device")
    assert full.is_char_device()


@NO_DEV_FULL
def test_stdout_on_a_full_device_is_exit_2(world):
    test = world["data"] / "test" / "test_0.mcap"
    with open("/dev/full", "w") as full:
        proc = subprocess.run(
            [*PROGRAM, "detect", str(test), "-c", str(world["cal"])],
            stdout=full,
            stderr=subprocess.PIPE,
            timeout=120,
        )
    assert proc.returncode == 2
    assert proc.stderr.decode().splitlines() == [
        "twincd: error: cannot write standard output: No space left on device (stdout) "
        "— redirect it to a file on a disk with space"
    ]


def test_a_file_size_limit_is_a_full_disk_in_a_real_process(world, tmp_path):
    """RLIMIT_FSIZE makes the kernel refuse writes past the limit (EFBIG): a real write error
    in a real process, not a monkeypatch."""
    import resource
    import signal

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))

    test = world["data"] / "test" / "test_0.mcap"
    for out in (tmp_path / "d.mcap", tmp_path / "d.csv"):
        argv = [*PROGRAM, "detect", str(test), "-c", str(world["cal"]), "-o", str(out)]
        proc = subprocess.run(argv, capture_output=True, preexec_fn=limit, timeout=120)
        assert proc.returncode == 2, proc.stderr
        assert proc.stderr.decode().splitlines() == [
            "twincd: error: cannot write output: File too large "
            f"({out}) — free space on the disk, or write elsewhere"
        ]
        assert list(tmp_path.iterdir()) == []


def test_atomic_output_maps_a_write_error_and_removes_the_temporary(tmp_path, monkeypatch):
    import io

    from twincd.io.atomic import _OutputFile, atomic_output

    def full(self: Any, data: Any) -> int:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(_OutputFile, "put", full)
    target = tmp_path / "x.txt"
    with (
        pytest.raises(OutputError, match="free space on the disk") as caught,
        atomic_output(target) as stream,
    ):
        text = io.TextIOWrapper(stream, encoding="utf-8")
        text.write("a" * 100_000)  # through two layers of buffers
        text.flush()
    assert caught.value.where == str(target)
    assert list(tmp_path.iterdir()) == []
    # an error of the block that is not the output's passes unchanged
    monkeypatch.undo()
    with pytest.raises(ValueError), atomic_output(target):
        raise ValueError("not the disk")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ outputs never lost


def same_name_logs(root: Path, source: Path) -> list[Path]:
    logs = []
    for folder in ("d1", "d2"):
        (root / folder).mkdir()
        logs.append(Path(shutil.copy(source, root / folder / "run.mcap")))
    return logs


def test_two_logs_of_one_name_write_two_outputs_whatever_the_order(world, tmp_path):
    logs = same_name_logs(tmp_path, world["data"] / "train" / "train_0.mcap")
    names = []
    for order in (logs, logs[::-1]):
        out = tmp_path / "out"
        result = run("detect", *order, "-c", world["cal"], "-o", out, "-q")
        assert result.exit_code == 0, result.output
        names.append(sorted(p.name for p in out.iterdir()))
        shutil.rmtree(out)
    assert names[0] == names[1] == ["d1_run.detect.mcap", "d2_run.detect.mcap"]


def test_simulate_of_two_logs_of_one_name(world, tmp_path):
    logs = same_name_logs(tmp_path, world["xarm"])
    result = run("simulate", *logs, "-o", tmp_path / "out", "-q")
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "d1_run.twin.mcap",
        "d2_run.twin.mcap",
    ]


def test_distinct_targets():
    from twincd.detection.outputs import distinct_targets
    from twincd.errors import UsageError

    def name(p: Path) -> Path:
        return p.with_name(p.stem + ".x")

    paths = [Path("/a/d1/run.mcap"), Path("/b/d1/run.mcap"), Path("/a/d2/other.mcap")]
    got = distinct_targets(paths, name, Path("/out"))
    assert [t.name for t in got] == ["a_d1_run.x", "b_d1_run.x", "other.x"]
    assert distinct_targets(paths[::-1], name, Path("/out")) == got[::-1]
    # beside the logs: a folder and a file of one name in one folder cannot be told apart
    with pytest.raises(UsageError, match="two logs would write one output"):
        distinct_targets([Path("/a/run.mcap"), Path("/a/run.bag")], name)


@pytest.mark.parametrize("option", ["--report", "--junit", "-o"])
def test_force_never_overwrites_an_input(world, tmp_path, option):
    # a log under a name the option accepts (-o: .mcap, .csv, .jsonl; reports: .md, .html)
    name = "run.csv" if option == "-o" else "run.md"
    log = Path(shutil.copy(world["data"] / "train" / "train_0.mcap", tmp_path / name))
    cal = Path(shutil.copy(world["cal"], tmp_path / "cal.json"))
    before = digests([log, cal])
    for target in (log, cal) if option == "--junit" else (log,):
        args = ["detect", log, "-c", cal, option, target]
        for force in ((), ("--force",)):
            result = run(*args, *force)
            assert_one_line_error(result, "would overwrite an input of this run")
            assert "--force" not in result.stderr  # it would not help
    assert digests([log, cal]) == before


def test_an_input_inside_a_rosbag2_folder_is_an_input(world, tmp_path):
    bag = write(tmp_path / "bag", "rosbag2-sqlite3", joint_recording(n=40))
    inside = next(p for p in bag.iterdir() if p.suffix == ".db3")
    before = digests([bag])
    result = run("detect", bag, "-c", world["cal"], "--junit", inside, "--force")
    assert_one_line_error(result, "would overwrite an input of this run")
    from twincd.io.atomic import is_input

    assert is_input(inside, [bag]) and not is_input(tmp_path / "x.twin.mcap", [bag])
    assert digests([bag]) == before


# ------------------------------------------------------------------ reports without matplotlib


@pytest.mark.parametrize("missing", ["matplotlib", "matplotlib.pyplot"])
def test_html_report_without_the_plot_extra_is_refused_before_any_work(
    world, tmp_path, monkeypatch, missing
):
    data, cal = world["data"], world["cal"]
    monkeypatch.setitem(sys.modules, missing, None)
    report, junit = tmp_path / "r.html", tmp_path / "j.xml"
    for args in (
        ("fit", data / "train", "-o", tmp_path / "c.json"),
        ("detect", data / "test", "-c", cal, "--junit", junit),
        ("evaluate", data / "test", "-c", cal, "--junit", junit),
    ):
        result = run(*args, "--report", report)
        assert_one_line_error(result, "twincd[plot]")
        assert result.stdout == ""  # refused before any work: no result printed
        assert list(tmp_path.iterdir()) == []
