"""``twincd simulate`` through typer's CliRunner: exit codes, stdout, stderr, files left behind."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.builders import Message, String, joint_recording, write
from support.clitools import assert_one_line_error, run


def files(folder: Path) -> set[str]:
    return {p.name for p in folder.rglob("*")}


def test_list_robots():
    result = run("simulate", "--list-robots")
    assert result.exit_code == 0
    names = result.stdout.split()
    assert {"xarm7", "panda", "ur5"} <= set(names)


def test_simulate_writes_default_output(tmp_path):
    src = write(tmp_path / "run.mcap", "mcap", joint_recording(n=30))
    result = run("simulate", src)
    assert result.exit_code == 0, result.output
    assert (tmp_path / "run.twin.mcap").is_file()
    assert "run.twin.mcap" in result.stdout and "30 samples" in result.stdout


def test_several_logs_into_a_folder(tmp_path):
    a = write(tmp_path / "a.mcap", "mcap", joint_recording(n=20))
    b = write(tmp_path / "b", "rosbag2-sqlite3", joint_recording(n=20))
    result = run("simulate", a, b, "-o", tmp_path / "out", "--quiet")
    assert result.exit_code == 0, result.output
    assert files(tmp_path / "out") == {"a.twin.mcap", "b.twin.mcap"}
    assert result.stderr == ""


def test_missing_joints_warn_once_on_stderr(tmp_path):
    names = [f"panda_joint{i}" for i in range(1, 8)]
    src = write(tmp_path / "p.mcap", "mcap", joint_recording(n=20, names=names))
    result = run("simulate", src, "--robot", "panda")
    assert result.exit_code == 0
    assert result.stderr.count("warning: locking") <= 1


BAD_BYTES = {
    "empty": b"",
    "random": np.random.default_rng(0).bytes(2048),
}


@pytest.mark.parametrize("kind", sorted(BAD_BYTES))
def test_unreadable_files(tmp_path, kind):
    src = tmp_path / "bad.mcap"
    src.write_bytes(BAD_BYTES[kind])
    result = run("simulate", src)
    assert_one_line_error(result)
    assert files(tmp_path) == {"bad.mcap"}
    assert src.read_bytes() == BAD_BYTES[kind]


def test_truncated_mcap(tmp_path):
    good = write(tmp_path / "good.mcap", "mcap", joint_recording(n=200))
    data = good.read_bytes()
    good.unlink()
    src = tmp_path / "cut.mcap"
    src.write_bytes(data[: len(data) // 2])
    assert_one_line_error(run("simulate", src, "--strict"), "damaged")
    assert files(tmp_path) == {"cut.mcap"}
    src.write_bytes(data[:60])  # inside the one chunk's header: nothing is readable
    assert_one_line_error(run("simulate", src))
    assert files(tmp_path) == {"cut.mcap"}


def test_missing_topic(tmp_path):
    src = write(
        tmp_path / "a.mcap", "mcap", [Message("/x", "std_msgs/msg/String", 1, String(data="x"))]
    )
    assert_one_line_error(run("simulate", src), match="JointState")


def test_no_matching_joints(tmp_path):
    src = write(
        tmp_path / "a.mcap", "mcap", joint_recording(n=10, names=[f"x{i}" for i in range(7)])
    )
    assert_one_line_error(run("simulate", src), match="no joint of the log")
    assert files(tmp_path) == {"a.mcap"}


def test_ragged_arrays_are_dropped_with_a_warning(tmp_path):
    msgs = joint_recording(n=40)
    msgs[4].msg.position = np.zeros(2)
    src = write(tmp_path / "a.mcap", "mcap", msgs)
    result = run("simulate", src)
    assert result.exit_code == 0, result.output
    assert "39 samples" in result.stdout
    assert "warning:" in result.stderr and "dropping 1 ragged message" in result.stderr


def test_unknown_robot_and_broken_urdf(tmp_path):
    src = write(tmp_path / "a.mcap", "mcap", joint_recording(n=10))
    unknown = run("simulate", src, "--robot", "nosuchbot")
    assert_one_line_error(unknown, match="unknown robot")
    assert_one_line_error(unknown, match="(option --robot)")  # the CLI names the flag
    urdf = tmp_path / "broken.urdf"
    urdf.write_text("<robot name='x'><joint")
    assert_one_line_error(run("simulate", src, "--robot", urdf), match="URDF")
    # valid XML, invalid URDF: urdfdom's own stderr lines must not leak through
    dangling = tmp_path / "dangling.urdf"
    dangling.write_text(
        '<robot name="x"><link name="a"/><joint name="j" type="revolute">'
        '<parent link="a"/><child link="missing"/></joint></robot>'
    )
    assert_one_line_error(run("simulate", src, "--robot", dangling), match="URDF")
    assert files(tmp_path) == {"a.mcap", "broken.urdf", "dangling.urdf"}


def test_unwritable_output(tmp_path):
    # a path below a regular file cannot be created, whoever runs the test (root included)
    src = write(tmp_path / "a.mcap", "mcap", joint_recording(n=10))
    blocker = tmp_path / "plain.txt"
    blocker.write_text("not a folder")
    result = run("simulate", src, "-o", blocker / "out.mcap")
    assert_one_line_error(result, match="cannot write")
    assert files(tmp_path) == {"a.mcap", "plain.txt"}


def test_output_in_a_missing_folder_is_an_error(tmp_path):
    src = write(tmp_path / "a.mcap", "mcap", joint_recording(n=10))
    assert_one_line_error(
        run("simulate", src, "-o", tmp_path / "no" / "such" / "out.mcap"), match="cannot write"
    )
    assert files(tmp_path) == {"a.mcap"}


def test_in_place_only_for_bare_mcap(tmp_path):
    bag = write(tmp_path / "bag", "rosbag2-sqlite3", joint_recording(n=10))
    assert_one_line_error(run("simulate", bag, "--in-place"), match="--in-place")


def test_debug_shows_the_traceback(tmp_path):
    result = run("simulate", tmp_path / "nope.mcap", "--debug")
    assert result.exit_code == 2
    assert "Traceback" in result.stderr


def test_no_logs_is_a_usage_error():
    assert_one_line_error(run("simulate"), match="no logs")


def test_native_urdf_errors_do_not_reach_the_real_stderr(tmp_path):
    # CliRunner sees only Python's sys.stderr; urdfdom writes to file descriptor 2 directly
    import subprocess
    import sys

    src = write(tmp_path / "a.mcap", "mcap", joint_recording(n=10))
    dangling = tmp_path / "dangling.urdf"
    dangling.write_text(
        '<robot name="x"><link name="a"/><joint name="j" type="revolute">'
        '<parent link="a"/><child link="missing"/></joint></robot>'
    )
    done = subprocess.run(
        [sys.executable, "-m", "twincd_cli.main", "simulate", str(src), "--robot", str(dangling)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("twincd: error: cannot load URDF"), lines


def test_simulating_a_folder_twice_does_not_stack_twins(tmp_path):
    write(tmp_path / "a.mcap", "mcap", joint_recording(n=20))
    assert run("simulate", tmp_path, "-q").exit_code == 0
    assert run("simulate", tmp_path, "-q").exit_code == 0
    assert files(tmp_path) == {"a.mcap", "a.twin.mcap"}
    # a twin file named on its own is not overwritten by accident
    assert_one_line_error(run("simulate", tmp_path / "a.twin.mcap"), match="overwrite")
