"""Shared fixtures. Append fixtures of your own below; keep each group's helpers together."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pytest

# ---------------------------------------------------------------- twin logs (fit/detect/evaluate)
# Tiny logs that carry their own /twincd/sim_effort, so no robot model is needed: the measured
# effort is GAINS ⊙ twin + OFFSET + friction + noise, plus sin² bumps (labelled) for collisions.

TWIN_JOINTS = ("j1", "j2", "j3")
GAINS = np.array([1.3, 0.8, 1.1])
OFFSET = np.array([0.2, -0.5, 0.05])
T0_NS = 1_700_000_000_000_000_000
# (start s, duration s, peak N·m) per bump
Bump = tuple[float, float, float]
DEFAULT_BUMPS: tuple[Bump, ...] = ((4.0, 0.8, 3.0), (11.0, 1.2, 2.5))


def twin_signals(t: np.ndarray, seed: int, dof: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(position, velocity, twin effort) as smooth sums of sines."""
    rng = np.random.default_rng(seed)
    amp = rng.uniform(0.3, 0.8, (2, dof))
    w = 2 * np.pi * rng.uniform(0.1, 0.4, (2, dof))
    ph = rng.uniform(0, 2 * np.pi, (2, dof))
    arg = w[None] * t[:, None, None] + ph[None]
    q = (amp[None] * np.sin(arg)).sum(1)
    qd = (amp[None] * w[None] * np.cos(arg)).sum(1)
    twin = 3.0 * np.sin(q) + 0.5 * np.cos(2 * q)  # varies well on every joint
    return q, qd, twin


def build_twin_log(
    path: Path,
    seed: int = 0,
    seconds: float = 16.0,
    rate_hz: float = 100.0,
    bumps: Sequence[Bump] = (),
    labels: bool = True,
    joints: Sequence[str] = TWIN_JOINTS,
    noise: float = 0.05,
    gains: np.ndarray | None = None,
    edit: Callable[[dict[str, np.ndarray]], None] | None = None,
    state_joints: Sequence[str] | None = None,
) -> Path:
    """Write a bare MCAP log with /joint_states, /twincd/sim_effort and /collision_flag.

    ``edit`` may change the arrays in place before they are written (faults: NaN, clock jumps):
    ``stamps`` (header stamps) and ``log_times`` (n,) int64, ``q``, ``qd``, ``effort``, ``twin``
    (n, dof). ``state_joints``: the names of /joint_states messages, in their order (default
    ``joints``): ``joints`` keep their data, any other name is an extra joint (a gripper, a
    linear axis) with signals of its own; /twincd/sim_effort keeps ``joints``."""
    from twincd.io.cdr import bool_cdr, joint_state_cdr
    from twincd.io.mcap import McapLogWriter

    dof = len(joints)
    n = round(seconds * rate_hz)
    t = np.arange(n) / rate_hz
    q, qd, twin = twin_signals(t, seed, dof)
    rng = np.random.default_rng(seed + 1000)
    g = GAINS[:dof] if gains is None else gains
    friction = 0.3 * np.tanh(qd / 0.05)  # unmodelled by the twin: residual with structure
    effort = g * twin + OFFSET[:dof] + friction + noise * rng.standard_normal((n, dof))
    flag = np.zeros(n, dtype=bool)
    for k, (start, duration, peak) in enumerate(bumps):
        inside = (t >= start) & (t < start + duration)
        shape = np.sin(np.pi * (t[inside] - start) / duration) ** 2
        direction = np.roll(np.array([1.0, -0.6, 0.4][:dof]), k)
        effort[inside] += peak * shape[:, None] * direction
        flag |= inside
    stamps = T0_NS + np.round(t * 1e9).astype(np.int64)
    log_times = stamps.copy()
    if edit is not None:
        edit(
            {
                "stamps": stamps,
                "log_times": log_times,
                "q": q,
                "qd": qd,
                "effort": effort,
                "twin": twin,
            }
        )
    with McapLogWriter(path) as out:
        js = out.add_topic("/joint_states", "sensor_msgs/msg/JointState")
        sim = out.add_topic("/twincd/sim_effort", "sensor_msgs/msg/JointState")
        names = list(joints if state_joints is None else state_joints)
        msgs = joint_state_cdr(stamps, names, *_layout(names, joints, t, q, qd, effort))
        sims = joint_state_cdr(stamps, joints, q, qd, twin)
        for log_time, m, s in zip(log_times, msgs, sims, strict=True):
            out.write(js, int(log_time), m)
            out.write(sim, int(log_time), s)
        if labels:
            lab = out.add_topic("/collision_flag", "std_msgs/msg/Bool")
            change = np.flatnonzero(np.diff(np.concatenate(([False], flag))) != 0)
            out.write(lab, int(log_times[0]) - 1, bool_cdr(False))
            for i in change:
                out.write(lab, int(log_times[i]), bool_cdr(bool(flag[i])))
    return path


def _layout(
    names: Sequence[str], joints: Sequence[str], t: np.ndarray, *arrays: np.ndarray
) -> list[np.ndarray]:
    """``arrays`` (n, len(joints)) as columns in ``names`` order; extra joints move slowly."""
    extra = 0.1 * np.sin(0.7 * t) + 0.02
    return [
        np.column_stack([a[:, list(joints).index(n)] if n in joints else extra for n in names])
        for a in arrays
    ]


@pytest.fixture
def twin_log() -> Callable[..., Path]:
    """``twin_log(path, seed=..., bumps=..., labels=...)``: build one tiny twin log."""
    return build_twin_log


@pytest.fixture(scope="session")
def twin_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """train/ (3 clean), val/ (2 clean), test/ (2 with labelled bumps) under one folder."""
    root = tmp_path_factory.mktemp("twin_dataset")
    for split, count, bumps in (("train", 3, ()), ("val", 2, ()), ("test", 2, DEFAULT_BUMPS)):
        (root / split).mkdir()
        for i in range(count):
            seed = {"train": 0, "val": 100, "test": 200}[split] + i
            build_twin_log(root / split / f"{split}_{i}.mcap", seed=seed, bumps=bumps)
    return root


# ---------------------------------------------------------------- reports


def _fit_and_threshold(dataset: Path, folder: Path, *fit_options: str) -> Path:
    """``twincd fit`` on ``dataset``/train with ``fit_options``, then ``twincd threshold`` on
    its val logs: the calibration file in ``folder``."""
    from support.clitools import run

    path = folder / "cal.json"
    assert run("fit", dataset / "train", "-o", path, "-q", *fit_options).exit_code == 0
    assert run("threshold", dataset / "val", "-c", path, "-q").exit_code == 0
    return path


@pytest.fixture(scope="session")
def twin_calibration(twin_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The paper's calibration (``--model affine``, fit on twin_dataset/train, threshold on
    val) shared by many tests (read-only: copy it before changing it)."""
    folder = tmp_path_factory.mktemp("twin_calibration")
    return _fit_and_threshold(twin_dataset, folder, "--model", "affine")


@pytest.fixture(scope="session")
def default_calibration(twin_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``twincd fit`` then ``twincd threshold`` at their defaults on twin_dataset (read-only:
    copy it before changing it)."""
    return _fit_and_threshold(twin_dataset, tmp_path_factory.mktemp("default_calibration"))


@pytest.fixture(scope="session")
def xarm_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small synthetic xArm 7 set (train 3 paths of 20–25 s, val 1 and test 1 of 10–12 s),
    twin from the robot model: what the identified models and the best model fit on. Less
    training motion (two 10-s paths) gave an identified model that does not fit the validation
    path (a residual 48× its noise on joint2), which ``threshold`` refuses."""
    from support.clitools import run

    root = tmp_path_factory.mktemp("xarm_dataset")
    for counts, seconds in ((("3", "0", "0"), ("20", "25")), (("0", "1", "1"), ("10", "12"))):
        args = ["--seed", "3", *sum(zip(("--train", "--val", "--test"), counts), ())]
        lengths = ("--min-duration", seconds[0], "--max-duration", seconds[1])
        result = run("synth", root, *args, *lengths, "-q")
        assert result.exit_code == 0, result.output
    return root
