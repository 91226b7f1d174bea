"""Robot models: names, URDF paths, reduced models for joints a log lacks."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from twincd.errors import JointMismatchError, RobotModelError
from twincd.twin.robot import list_robots, load_robot, resolve_urdf


def test_example_robot_data_names():
    robots = list_robots()
    for name in ("xarm7", "panda", "ur5", "ur3", "ur10", "kinova", "z1"):
        assert name in robots and robots[name].is_file()


def test_unknown_robot_suggests_names():
    with pytest.raises(RobotModelError, match=r"unknown robot 'xarm'.*xarm7") as raised:
        resolve_urdf("xarm")
    assert raised.value.option == "robot" and "--" not in raised.value.message


def test_broken_urdf_is_a_clear_error(tmp_path):
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot><link name=")
    with pytest.raises(RobotModelError, match="cannot load URDF"):
        load_robot(str(bad))
    with pytest.raises(RobotModelError, match="not found"):
        load_robot(str(tmp_path / "missing.urdf"))


def test_missing_joints_are_locked_with_one_warning(caplog):
    with caplog.at_level(logging.WARNING, logger="twincd"):
        robot = load_robot("panda", keep=[f"panda_joint{i}" for i in range(1, 7)])
    assert robot.dof == 6
    assert robot.locked == ("panda_joint7", "panda_finger_joint1", "panda_finger_joint2")
    assert caplog.text.count("locking") == 1 and "finger" not in caplog.text


def test_gripper_joints_are_never_driven_even_when_logged(caplog):
    arm = [f"panda_joint{i}" for i in range(1, 8)]
    with caplog.at_level(logging.WARNING, logger="twincd"):
        robot = load_robot("panda", keep=[*arm, "panda_finger_joint1", "panda_finger_joint2"])
        whole = load_robot("panda")
    assert robot.joint_names == whole.joint_names == tuple(arm)
    assert robot.locked == ("panda_finger_joint1", "panda_finger_joint2")
    assert caplog.text == ""  # the arm's twin: nothing to warn about


def test_no_shared_joint_is_a_mismatch():
    with pytest.raises(JointMismatchError, match="no joint of the log"):
        load_robot("xarm7", keep=["shoulder_pan_joint"])


def test_unbounded_joints_use_cos_sin():
    robot = load_robot("kinova")
    assert robot.model.nq > robot.dof
    angles = np.linspace(-3, 3, robot.dof)[None, :]
    q = robot.configuration(angles)[0]
    assert q.shape == (robot.model.nq,)
    # Pinocchio's own difference from neutral recovers the angles
    np.testing.assert_allclose(
        robot.joint_values(pin.difference(robot.model, pin.neutral(robot.model), q)[None])[0],
        angles[0],
        atol=1e-12,
    )


XACRO = """<?xml version="1.0"?>
<robot name="arm" xmlns:xacro="http://www.ros.org/wiki/xacro">
  <xacro:property name="l" value="0.3"/>
  <xacro:macro name="link" params="n"><link name="${n}"/></xacro:macro>
  <xacro:link n="base"/>
</robot>
"""


@pytest.mark.parametrize("name", ["model.urdf.xacro", "model.xacro", "model.urdf"])
def test_a_xacro_file_is_named_with_what_to_run(tmp_path, name):
    """A xacro file (even one called .urdf) was "does not contain a valid URDF model"."""
    from support.clitools import assert_one_line_error, run

    path = tmp_path / name
    path.write_text(XACRO)
    with pytest.raises(RobotModelError, match="xacro file, not a URDF") as raised:
        load_robot(str(path))
    assert f"xacro {name} > model.urdf" in raised.value.hint
    result = run(
        "inspect", Path(__file__).parent.parent / "sample_logs/val/val_000.mcap", "--robot", path
    )
    assert_one_line_error(result, "xacro file")


def test_the_dynamics_hash_is_what_the_twin_uses_not_the_file(tmp_path):
    """A robot is identified by what inverse dynamics computes with: the same file at another
    path, or with a comment added, hashes alike; a heavier link, another robot or another
    set of joints (a reduced model) does not."""
    from support.robots import xarm_urdf

    shipped = load_robot("xarm7")
    moved = load_robot(str(xarm_urdf(tmp_path / "a" / "arm.urdf")))
    commented = load_robot(str(xarm_urdf(tmp_path / "b" / "arm.urdf", comment=True)))
    heavier = load_robot(str(xarm_urdf(tmp_path / "c" / "arm.urdf", heavier=True)))
    assert moved.dynamics_sha256 == shipped.dynamics_sha256 == commented.dynamics_sha256
    assert commented.urdf_sha256 != shipped.urdf_sha256  # the file's bytes differ
    assert heavier.dynamics_sha256 != shipped.dynamics_sha256
    assert load_robot("panda").dynamics_sha256 != shipped.dynamics_sha256
    reduced = load_robot("xarm7", keep=[f"joint{i}" for i in range(1, 7)])
    assert reduced.dynamics_sha256 != shipped.dynamics_sha256


def test_a_package_uri_names_a_urdf_in_a_package(tmp_path, monkeypatch):
    from support.robots import xarm_urdf

    from twincd.twin.robot import package_uri

    shipped = resolve_urdf("xarm7")
    assert package_uri(shipped) == "package://xarm_description/urdf/xarm7.urdf"
    assert resolve_urdf("package://xarm_description/urdf/xarm7.urdf") == shipped
    ament = tmp_path / "install"
    urdf = xarm_urdf(ament / "share" / "arm_description" / "urdf" / "arm.urdf")
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(ament))
    assert package_uri(urdf) == "package://arm_description/urdf/arm.urdf"
    assert resolve_urdf("package://arm_description/urdf/arm.urdf") == urdf
    assert package_uri(tmp_path / "loose.urdf") is None
    with pytest.raises(RobotModelError, match="not found in any installed package"):
        resolve_urdf("package://arm_description/urdf/missing.urdf")
