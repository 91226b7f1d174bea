"""twincd.prepare.stream: one chain of stages for whole, chunked and live processing.

Properties: any block size gives the whole-log answer (causal: identical; zero-phase: within
1e-9 of each signal's range), and the live detector fed in any chunking equals batch detection
with the same causal calibration.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support.builders import Message, jittered_xarm_log, write
from support.streaming import blocks, detect_frames, pushed

from twincd.commands import fit_calibration, threshold_calibration
from twincd.detection import OnlineDetector
from twincd.prepare.chain import warmup_samples
from twincd.prepare.setup import Setup
from twincd.signal.filters import LowPass

CAUSAL = LowPass(cutoff_hz=3.0, causal=True)


def _close(a: np.ndarray, b: np.ndarray, rel: float) -> None:
    scale = np.ptp(b, axis=0) + 1e-12
    assert np.all(np.abs(a - b) <= rel * scale), np.max(np.abs(a - b) / scale)


@pytest.mark.parametrize("lowpass", [LowPass(), CAUSAL], ids=["zero-phase", "causal"])
@pytest.mark.parametrize("block", [1, 7, 1000])
def test_block_size_does_not_change_the_answer(
    tmp_path: Path, lowpass: LowPass, block: int
) -> None:
    log = jittered_xarm_log(tmp_path / "run.mcap")
    whole = Setup(robot="xarm7", lowpass=lowpass, block_size=1 << 20).prepare(log)
    parts = Setup(robot="xarm7", lowpass=lowpass, block_size=block).prepare(log)
    np.testing.assert_array_equal(parts.states.stamp_ns, whole.states.stamp_ns)
    np.testing.assert_array_equal(parts.sim_effort, whole.sim_effort)  # derivative + RNEA
    rel = 0.0 if lowpass.causal else 1e-9
    _close(parts.effort_f, whole.effort_f, rel)
    _close(parts.sim_effort_f, whole.sim_effort_f, rel)


@pytest.fixture(scope="module", params=["affine", "friction-whitened"])
def causal_calibration(twin_dataset: Path, request):  # type: ignore[no-untyped-def]
    # every calibration model runs live: the friction model's Coulomb features stream too
    train = sorted((twin_dataset / "train").glob("*.mcap"))
    cal = fit_calibration(
        train,
        model=request.param,
        cutoff_hz=CAUSAL.cutoff_hz,
        causal=True,
        filter_kind=CAUSAL.kind,
    ).calibration
    val = sorted((twin_dataset / "val").glob("*.mcap"))
    return threshold_calibration(val, cal, k_sigma=3.0).calibration


@pytest.mark.parametrize("chunk", [1, 7, 1000, None])
def test_online_detector_equals_batch_causal_detection(
    twin_dataset: Path,
    causal_calibration,
    chunk: int | None,  # type: ignore[no-untyped-def]
) -> None:
    cal = causal_calibration
    log = twin_dataset / "test" / "test_0.mcap"
    setup = Setup.from_calibration(cal)
    batch, frames = detect_frames(log, cal, setup)
    assert batch.events, "the test log has labelled bumps: the detector should find them"
    prepared = replace(setup, lowpass=cal.lowpass).prepare(log)
    states = prepared.states
    n = len(states)
    det = OnlineDetector(cal)
    size = n if chunk is None else chunk
    slices = blocks(n, size)
    outs = pushed(det, states, slices, prepared.sim_effort)
    # each push gives its samples, but for a segment's first ones, which wait for the causal
    # derivative's window (the filter starts on the sample after them): in order, none lost
    released = np.concatenate([o.stamp_ns for o in outs])
    warmup = warmup_samples(True, False)
    assert len(released) >= n - warmup
    np.testing.assert_array_equal(released, states.stamp_ns[: len(released)])
    for sl, out in zip(slices, outs, strict=True):
        assert sl.stop <= warmup or out.stamp_ns[-1] == states.stamp_ns[sl][-1]
    outs.append(det.flush())
    events = [event for out in outs for event in out.events] + det.close()
    np.testing.assert_array_equal(np.concatenate([o.score for o in outs]), frames.column("score"))
    np.testing.assert_array_equal(np.concatenate([o.flag for o in outs]), frames.column("flag"))
    assert events == batch.events
    assert 0 < det.latency_s < 0.2


def test_online_detector_refuses_a_zero_phase_calibration(
    twin_dataset: Path,
    causal_calibration,  # type: ignore[no-untyped-def]
) -> None:
    from twincd.errors import CalibrationError

    zero_phase = replace(causal_calibration, lowpass=LowPass())
    with pytest.raises(CalibrationError, match="zero-phase"):
        OnlineDetector(zero_phase)


def test_online_detector_skips_bad_samples_without_poisoning_its_state(
    causal_calibration,  # type: ignore[no-untyped-def]
) -> None:
    det = OnlineDetector(causal_calibration)
    n, d = 50, len(causal_calibration.joint_names)
    stamps = 1_000_000_000 + np.arange(n, dtype=np.int64) * 10_000_000
    rng = np.random.default_rng(0)
    pos, vel, eff, sim = (rng.normal(size=(n, d)) * 0.1 for _ in range(4))
    eff[10] = np.nan
    stamps[20] = stamps[19]  # not after the previous one
    out = det.push(stamps, pos, vel, eff, sim)
    assert np.isnan(out.score[[10, 20]]).all() and not out.flag[[10, 20]].any()
    assert np.isfinite(np.delete(out.score, [10, 20])).all()
    assert det.skipped == 2


@pytest.mark.parametrize("form", ["rosbag2-sqlite3", "rosbag2-mcap", "ros1"])
def test_every_storage_form_streams_like_bare_mcap(tmp_path: Path, form: str) -> None:
    # the reader runs on a prefetch thread: every backend must work from there
    from support.builders import FORMS, SUFFIX

    assert form in FORMS
    # longer than what opening reads ahead (a batch and the reorder window), so the prefetch
    # thread reads too
    bare = jittered_xarm_log(tmp_path / "run.mcap", seconds=40.0, rate_hz=1000.0)
    from rosbags.highlevel import AnyReader

    with AnyReader([bare]) as reader:
        msgs = [
            Message(c.topic, c.msgtype, t, reader.deserialize(raw, c.msgtype))
            for c, t, raw in reader.messages()
        ]
    other = write(tmp_path / f"run_{form}{SUFFIX[form]}", form, msgs)
    setup = Setup(robot="xarm7", block_size=500)
    a, b = setup.prepare(bare), setup.prepare(other)
    np.testing.assert_array_equal(a.states.stamp_ns, b.states.stamp_ns)
    np.testing.assert_array_equal(a.effort_f, b.effort_f)


# ------------------------------------------------------------------ joint order


def test_joint_order_comes_from_names_not_from_the_first_log(twin_log, tmp_path: Path) -> None:
    """Logs that carry their own twin effort and no robot model: whatever order their messages
    list the joints in, and whichever log comes first, the columns are in one order."""
    from twincd.calibration import fit_log, merge_fits
    from twincd.prepare.setup import read_log

    a = twin_log(tmp_path / "a.mcap", seed=1, joints=("j1", "j2", "j3"))
    b = twin_log(tmp_path / "b.mcap", seed=2, joints=("j3", "j1", "j2"))
    setup = Setup()
    prepared = setup.prepare(b)
    raw = read_log(b)
    assert prepared.joint_names == ("j1", "j2", "j3")
    for i, name in enumerate(prepared.joint_names):  # each column follows its name
        np.testing.assert_array_equal(
            prepared.effort[:, i], raw.effort[:, raw.joint_names.index(name)]
        )
    parts = [fit_log(p, setup) for p in (a, b)]
    one, other = merge_fits(parts, setup, "affine"), merge_fits(parts[::-1], setup, "affine")
    assert one.joint_names == other.joint_names == ("j1", "j2", "j3")
    np.testing.assert_array_equal(one.model.a_, other.model.a_)
    np.testing.assert_array_equal(one.model.b_, other.model.b_)


def test_joint_order_puts_the_model_first_then_names_naturally() -> None:
    from types import SimpleNamespace

    from twincd.prepare.joints import joint_order

    names = ["joint10", "grip", "joint2", "joint1"]
    assert joint_order(names, None) == ("grip", "joint1", "joint2", "joint10")
    model: Any = SimpleNamespace(joint_names=("joint2", "joint1", "joint3"))
    assert joint_order(names, model) == ("joint2", "joint1", "grip", "joint10")


def test_logs_with_other_joints_are_refused_together(tmp_path: Path) -> None:
    from types import SimpleNamespace

    from twincd.errors import JointMismatchError
    from twincd.prepare.joints import agreed_joints

    logs: list[Any] = [
        SimpleNamespace(source="b", joint_names=("j1", "j2")),
        SimpleNamespace(source="a", joint_names=("j1", "j2")),
    ]
    assert agreed_joints(logs) == ("j1", "j2")
    logs.append(SimpleNamespace(source="c", joint_names=("j1", "k2")))
    with pytest.raises(JointMismatchError, match="different joints"):
        agreed_joints(logs)


# ------------------------------------------------------------------ one chain


@pytest.mark.parametrize("lowpass", [LowPass(), CAUSAL], ids=["zero-phase", "causal"])
def test_the_chain_follows_joint_names_whatever_the_columns(lowpass: LowPass) -> None:
    """``build_chain`` on frames whose columns are shuffled and carry a joint the twin does not
    use gives, joint by joint, what it gives on frames in the twin's order."""
    from twincd.prepare.chain import JointLayout, build_chain
    from twincd.prepare.frames import Frame
    from twincd.signal.features import ModelFeatures

    rng = np.random.default_rng(3)
    n, joints = 400, ("a", "b", "c")
    stamps = 1_000_000_000 + np.arange(n, dtype=np.int64) * 10_000_000
    arrays = {k: rng.normal(size=(n, 3)) for k in ("position", "velocity", "effort", "sim_effort")}
    features = ModelFeatures(coulomb_eps=(0.01,))

    def run(columns: tuple[str, ...], output: tuple[str, ...]) -> Frame:
        picked = [joints.index(c) if c in joints else 0 for c in columns]
        frame = Frame({"stamp_ns": stamps, **{k: v[:, picked] for k, v in arrays.items()}})
        layout = JointLayout(columns, joints, output)
        built = build_chain(
            lowpass, features, layout=layout, period_s=0.01, twin=None, fill_velocity=False
        )
        assert built.joint_names == output
        return Frame.concat([built.chain.push(frame), built.chain.finish()])

    plain = run(joints, joints)
    shuffled = run(("c", "extra", "a", "b"), ("b", "c", "a"))
    for k in ("effort_f", "sim_effort_f", "velocity_f"):
        np.testing.assert_array_equal(shuffled[k], plain[k][:, [1, 2, 0]])
    np.testing.assert_array_equal(shuffled["coulomb_f"], plain["coulomb_f"][:, :, [1, 2, 0]])
    # each segment's start is judged with the noise its filtering leaves there, and so is its end
    # when zero-phase (a causal filter's end is like its middle)
    factor = plain["edge_factor"][:, 0]
    np.testing.assert_array_equal(shuffled["edge_factor"], plain["edge_factor"])
    assert factor[0] > 1.5 and np.all(factor >= 1.0) and np.all(factor[n // 3 : -n // 3] == 1.0)
    assert bool(factor[-1] > 1.5) is not lowpass.causal  # a NumPy bool is never a Python one
    assert bool(factor[-1] == 1.0) is lowpass.causal
