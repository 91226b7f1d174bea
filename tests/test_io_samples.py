"""Time-ordered sample blocks (twincd.io.stream.samples): any block size, any arrival order
within the reorder window and any batch size give the same samples; drops are counted; labels
and the twin's effort are joined correctly while streaming; memory stays flat."""

from __future__ import annotations

import tempfile
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.builders import SUFFIX, XARM, Bool, Message, joint_recording, joint_state, write
from test_io_topics import cut, write_mcap

from twincd.errors import JointMismatchError, LogReadError
from twincd.io.options import LogOptions
from twincd.io.sources import open_reader
from twincd.io.stream import LogStream, SampleBlock, iter_blocks
from twincd.prepare.setup import read_log

OPTIONS = LogOptions()
FIELDS = ("stamp_ns", "log_time_ns", "position", "velocity", "effort", "labels", "sim_effort")
T0 = 1_700_000_000_000_000_000
PERIOD = 10_000_000


def collect(path: Path, **kwargs) -> tuple[dict[str, np.ndarray | None], LogStream]:
    options = kwargs.pop("options", OPTIONS)
    with LogStream(path, options, **kwargs) as stream:
        blocks = list(stream)
    for b in blocks:
        assert isinstance(b, SampleBlock) and 0 < len(b) <= stream.block_size
    out: dict[str, np.ndarray | None] = {}
    for f in FIELDS:
        parts = [getattr(b, f) for b in blocks]
        out[f] = None if parts[0] is None else np.concatenate(parts)
    assert np.all(np.diff(out["stamp_ns"]) > 0)
    return out, stream


def assert_same(a, b, fields=FIELDS):
    for f in fields:
        if a[f] is None or b[f] is None:
            assert a[f] is None and b[f] is None, f
        else:
            np.testing.assert_array_equal(a[f], b[f], err_msg=f)


def labelled(n: int = 400, flips: int = 9, effort: bool = True) -> list[Message]:
    rng = np.random.default_rng(0)
    msgs = joint_recording(n=n, effort=rng.normal(size=(n, 7)) if effort else None)
    for k in range(flips):
        when = T0 + int(rng.integers(-5, n + 5)) * PERIOD + int(rng.integers(-2, 3))
        msgs.append(Message("/collision_flag", "std_msgs/msg/Bool", when, Bool(data=k % 2 == 0)))
    return sorted(msgs, key=lambda m: m.log_time)


def expected_labels(msgs: list[Message], log_times: np.ndarray) -> np.ndarray:
    flags = [(m.log_time, m.msg.data) for m in msgs if m.topic == "/collision_flag"]
    out = np.zeros(len(log_times), dtype=bool)
    for i, t in enumerate(log_times):
        before = [v for w, v in flags if w <= t]
        out[i] = before[-1] if before else False
    return out


@pytest.fixture(scope="module")
def labelled_log(tmp_path_factory) -> tuple[Path, list[Message]]:
    msgs = labelled()
    return write_mcap(tmp_path_factory.mktemp("lab") / "a.mcap", msgs, chunk_size=3000), msgs


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    block=st.one_of(st.sampled_from([1, 7, 1000, 10**6]), st.integers(1, 500)),
    batch=st.sampled_from([8, 50, 65536]),
    reorder=st.sampled_from([0, 3, 100, 10_000]),
)
def test_any_block_batch_and_reorder_size_gives_the_same_samples(
    labelled_log, block, batch, reorder
):
    path, msgs = labelled_log
    whole = read_log(path)
    got, stream = collect(path, block_size=block, batch_size=batch, reorder=reorder)
    ref = {f: getattr(whole, f) for f in FIELDS}
    ref["velocity"] = got["velocity"]  # read_log may differentiate; blocks carry the messages'
    assert_same(got, ref)
    np.testing.assert_array_equal(got["labels"], expected_labels(msgs, got["log_time_ns"]))
    assert stream.counts.samples == 400 and stream.counts.late == 0
    assert stream.stats.fast == 409 and stream.stats.fallback == 0


def jittered(n: int, window: int, seed: int) -> tuple[list[Message], list[Message]]:
    """(sorted, shuffled): the same samples; in the shuffled log the header stamps arrive out
    of order (each at most ``window`` places from its own), the log time still increasing."""
    rng = np.random.default_rng(seed)
    clean = joint_recording(n=n, effort=rng.normal(size=(n, 7)))
    order = np.argsort(np.arange(n) + rng.uniform(0, window, n), kind="stable")
    shuffled = []
    for i, k in enumerate(order):
        m = clean[k]
        shuffled.append(Message(m.topic, m.msgtype, T0 + i * PERIOD + 3_000_000, m.msg))
    return clean, shuffled


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 10**6),
    window=st.integers(1, 40),
    block=st.sampled_from([1, 7, 64, 10**6]),
    batch=st.sampled_from([5, 64, 65536]),
)
def test_shuffled_within_the_window_equals_sorted(seed, window, block, batch):
    clean, shuffled = jittered(300, window, seed)
    with tempfile.TemporaryDirectory() as tmp:
        ref, _ = collect(write_mcap(Path(tmp) / "c.mcap", clean), block_size=block)
        path = write_mcap(Path(tmp) / "s.mcap", shuffled, chunk_size=2000)
        got, stream = collect(path, block_size=block, batch_size=batch, reorder=2 * window)
    assert_same(got, ref, ("stamp_ns", "position", "velocity", "effort"))
    assert stream.counts.late == 0 and stream.counts.duplicates == 0
    # each sample keeps its own log time
    arrival = {
        m.msg.header.stamp.sec * 10**9 + m.msg.header.stamp.nanosec: m.log_time for m in shuffled
    }
    assert got["log_time_ns"].tolist() == [arrival[s] for s in got["stamp_ns"].tolist()]


def test_a_log_that_fits_the_buffer_is_sorted_whole(tmp_path):
    _, shuffled = jittered(200, 200, seed=5)
    clean, _ = jittered(200, 1, seed=5)
    ref, _ = collect(write_mcap(tmp_path / "c.mcap", clean))
    got, _ = collect(write_mcap(tmp_path / "s.mcap", shuffled), reorder=200)
    assert_same(got, ref, ("stamp_ns", "position", "effort"))


def test_late_and_duplicate_samples_are_dropped_and_counted(tmp_path):
    msgs = joint_recording(n=100)
    t_end = msgs[-1].log_time
    late = joint_state(msgs[3].log_time + 1, XARM, np.full(7, 42.0))  # stamp long emitted
    dup_emitted = joint_state(msgs[5].log_time, XARM, np.full(7, 43.0))  # late, too
    dup_pending = joint_state(msgs[98].log_time, XARM, np.full(7, 44.0))
    msgs += [
        Message("/joint_states", msgs[0].msgtype, t_end + 1, late),
        Message("/joint_states", msgs[0].msgtype, t_end + 2, dup_emitted),
        Message("/joint_states", msgs[0].msgtype, t_end + 3, dup_pending),
    ]
    got, stream = collect(write_mcap(tmp_path / "a.mcap", msgs), reorder=10)
    c = stream.counts
    assert (c.read, c.samples, c.late, c.duplicates, c.incomplete) == (103, 100, 2, 1, 0)
    assert not np.isin([42.0, 43.0, 44.0], got["position"]).any()
    # with the whole log in the buffer the late sample is simply sorted in
    got, stream = collect(write_mcap(tmp_path / "b.mcap", msgs), reorder=1000)
    assert (stream.counts.samples, stream.counts.late, stream.counts.duplicates) == (101, 0, 2)
    assert 42.0 in got["position"]


def test_duplicates_keep_the_earliest_log_time(tmp_path):
    msgs = joint_recording(n=20)
    first = Message(msgs[0].topic, msgs[0].msgtype, msgs[7].log_time - 3, msgs[7].msg)
    msgs[7] = Message(
        msgs[7].topic,
        msgs[7].msgtype,
        msgs[7].log_time,
        joint_state(msgs[7].log_time, XARM, np.full(7, 9.0)),
    )
    msgs.append(first)  # written last, but recorded earlier
    got, stream = collect(write_mcap(tmp_path / "a.mcap", msgs))
    assert stream.counts.duplicates == 1
    assert 9.0 not in got["position"]


def test_incomplete_samples_and_joint_selection(tmp_path):
    msgs = []
    for m in joint_recording(n=30):
        msgs.append(
            Message(m.topic, m.msgtype, m.log_time, joint_state(m.log_time, ["grip"], [0.5]))
        )
        order = [6, 0, 5, 1, 4, 2, 3]
        names = [XARM[k] for k in order]
        msgs.append(
            Message(
                m.topic,
                m.msgtype,
                m.log_time + 1,
                joint_state(m.log_time + 1, names, m.msg.position[order]),
            )
        )
    path = write_mcap(tmp_path / "a.mcap", msgs)
    got, stream = collect(path, joints=("joint3", "joint1"))
    assert stream.joint_names == ("joint3", "joint1")
    # the "grip" messages are another publisher's: ignored and counted, not incomplete
    assert (stream.counts.samples, stream.counts.foreign, stream.counts.incomplete) == (30, 30, 0)
    ref = [m.msg.position[[2, 0]] for m in joint_recording(n=30)]
    np.testing.assert_array_equal(got["position"], ref)
    assert np.isnan(got["velocity"]).all() and got["effort"] is None
    # no joints given: those of the layout that names the most, in its order
    with iter_blocks(path, OPTIONS) as stream:
        assert stream.joint_names == tuple(XARM[k] for k in [6, 0, 5, 1, 4, 2, 3])
    with pytest.raises(JointMismatchError, match="joint9"):
        iter_blocks(path, OPTIONS, joints=("joint1", "joint9"))


def test_joint_map_renames_columns(tmp_path):
    msgs = joint_recording(n=10, names=[f"arm_{n}" for n in XARM])
    options = LogOptions(joint_map={f"arm_{n}": n for n in XARM})
    got, stream = collect(write_mcap(tmp_path / "a.mcap", msgs), options=options, joints=XARM[::-1])
    assert stream.joint_names == XARM[::-1]
    np.testing.assert_array_equal(got["position"], [m.msg.position[::-1] for m in msgs])


def test_labels_read_in_a_later_chunk_still_label_earlier_samples(tmp_path):
    msgs = labelled(n=600, flips=15)
    joints = [m for m in msgs if m.topic == "/joint_states"]
    flags = [m for m in msgs if m.topic == "/collision_flag"]
    # every label written after all joint states: their chunks come last in the file
    path = write_mcap(tmp_path / "a.mcap", joints + flags, chunk_size=2000)
    for batch in (10, 65536):
        got, _ = collect(path, batch_size=batch, reorder=0, block_size=33)
        np.testing.assert_array_equal(got["labels"], expected_labels(msgs, got["log_time_ns"]))


@pytest.mark.parametrize("form", ["ros1", "rosbag2-sqlite3"])
def test_labels_stream_on_every_form(tmp_path, form):
    msgs = labelled(n=600, flips=15)
    path = write(tmp_path / f"log{SUFFIX[form]}", form, msgs)
    with LogStream(path, OPTIONS, block_size=10, reorder=0, batch_size=50) as stream:
        blocks = iter(stream)
        first = next(blocks)
        assert stream.counts.read < 300  # emitted while reading: the watermark moves
        rest = list(blocks)
    log_times = np.concatenate([first.log_time_ns, *[b.log_time_ns for b in rest]])
    labels = np.concatenate([first.labels, *[b.labels for b in rest]])
    np.testing.assert_array_equal(labels, expected_labels(msgs, log_times))


def sim_log(tmp_path: Path) -> tuple[Path, np.ndarray]:
    msgs = joint_recording(n=120, effort=np.ones((120, 7)))
    twin = np.arange(120 * 7, dtype=float).reshape(120, 7)
    expected = np.full((120, 7), np.nan)
    out = list(msgs)
    for i, m in enumerate(msgs):
        if i % 10 == 3:
            continue  # no twin effort for this sample
        names = list(XARM[::-1]) if i % 2 else list(XARM[:4])  # reversed, or partial
        cols = [XARM.index(n) for n in names]
        sim = joint_state(m.log_time, names, twin[i, cols], (), twin[i, cols])
        out.append(Message("/twincd/sim_effort", m.msgtype, m.log_time, sim))
        expected[i, cols] = twin[i, cols]
    out.append(
        Message(
            "/twincd/sim_effort",
            msgs[0].msgtype,
            msgs[-1].log_time,
            joint_state(1, ["joint1"], [0.0], (), [5.0]),
        )
    )
    return write_mcap(
        tmp_path / "sim.mcap", sorted(out, key=lambda m: m.log_time), chunk_size=2500
    ), expected


@pytest.mark.parametrize(
    ("block", "batch", "reorder"), [(1, 5, 0), (17, 64, 7), (10**6, 65536, 10_000)]
)
def test_sim_effort_joined_by_stamp(tmp_path, block, batch, reorder):
    path, expected = sim_log(tmp_path)
    got, stream = collect(path, block_size=block, batch_size=batch, reorder=reorder)
    np.testing.assert_array_equal(got["sim_effort"], expected)
    assert stream.has_sim and not stream.has_labels and got["labels"] is None


def test_effort_is_there_when_most_first_messages_carry_it(tmp_path):
    msgs = joint_recording(n=10)
    msgs[5].msg.effort = np.ones(7)
    got, _ = collect(write_mcap(tmp_path / "a.mcap", msgs))
    assert got["effort"] is None
    for lacking in (5, 0):  # one empty effort, also the very first, is one bad sample
        msgs = joint_recording(n=10, effort=np.ones((10, 7)))
        msgs[lacking].msg.effort = np.zeros(0)
        got, _ = collect(write_mcap(tmp_path / "b.mcap", msgs))
        effort = got["effort"]
        assert np.isnan(effort[lacking]).all()
        assert np.isfinite(np.delete(effort, lacking, 0)).all()


def test_ragged_messages_are_dropped_counted_and_reported(tmp_path, caplog):
    msgs = joint_recording(n=10)
    msgs[4].msg.velocity = np.zeros(3)
    with LogStream(write_mcap(tmp_path / "a.mcap", msgs), OPTIONS) as stream:
        got = list(stream)
        assert stream.counts.ragged == 1 and sum(len(b) for b in got) == 9
    assert "dropping 1 ragged message" in caplog.text


def test_truncated_mcap_strict_and_not(tmp_path):
    msgs = labelled(n=3000, flips=30)
    full = write_mcap(tmp_path / "a.mcap", msgs, chunk_size=5000)
    path = cut(full, 0.5)
    with pytest.raises(LogReadError, match="damaged"):
        iter_blocks(path, OPTIONS)
    got, stream = collect(path, strict=False, block_size=100)
    ref, _ = collect(full)
    n = len(got["stamp_ns"])
    assert 1000 < n < 1600
    # the intact part, as a complete read has it (labels too: they were read up to there)
    for f in ("stamp_ns", "position", "effort", "labels"):
        np.testing.assert_array_equal(got[f], ref[f][:n], err_msg=f)
    assert stream.damage is not None and "mcap recover" in stream.damage


def test_a_topic_without_messages(tmp_path):
    from mcap.writer import Writer

    from twincd.io.cdr import JOINT_STATE, bool_cdr, typestore

    path = tmp_path / "a.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library="tests")
        ids = {}
        for msgtype in (JOINT_STATE, "std_msgs/msg/Bool"):
            msgdef, _ = typestore().generate_msgdef(msgtype, ros_version=2)
            schema = writer.register_schema(msgtype, "ros2msg", msgdef.encode())
            topic = "/joint_states" if msgtype == JOINT_STATE else "/collision_flag"
            ids[msgtype] = writer.register_channel(topic, "cdr", schema, {})
        writer.add_message(ids["std_msgs/msg/Bool"], 5, bool_cdr(True), 5)
        writer.finish()
    with pytest.raises(LogReadError, match="no messages"):
        iter_blocks(path, OPTIONS)


# ---------------------------------------------------------------- speed and memory


def long_log(path: Path, seconds: float, rate_hz: float = 1000.0) -> int:
    """A 7-joint JointState log at ``rate_hz`` (cf. benchmarks/bench_io.py), written fast."""
    from mcap.writer import Writer

    from twincd.io.cdr import JOINT_STATE, joint_state_block, typestore

    n = int(seconds * rate_hz)
    names = [f"joint{i}" for i in range(1, 8)]
    msgdef, _ = typestore().generate_msgdef(JOINT_STATE, ros_version=2)
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library="tests")
        schema = writer.register_schema(JOINT_STATE, "ros2msg", msgdef.encode())
        channel = writer.register_channel(
            "/joint_states", "cdr", schema, {"offered_qos_profiles": ""}
        )
        for b0 in range(0, n, 20_000):
            t = np.arange(b0, min(n, b0 + 20_000)) / rate_hz
            q = 0.5 * np.sin(2 * np.pi * 0.2 * t[:, None] + np.arange(7))
            stamps = T0 + (t * 1e9).astype(np.int64)
            for stamp, row in zip(stamps.tolist(), joint_state_block(stamps, names, q, q, q)):
                writer.add_message(channel, stamp, row.tobytes(), stamp)
        writer.finish()
    return n


def read_fast(path: Path, **kwargs) -> int:
    n = 0
    with LogStream(path, OPTIONS, **kwargs) as stream:
        for block in stream:
            n += len(block)
    assert stream.stats.fast == n
    return n


def test_a_long_log_reads_every_sample_rosbags_reads(tmp_path):
    """A minute at 1 kHz through the fast path gives every message rosbags decodes (which is
    faster is benchmarks/bench_io.py's question)."""
    path = tmp_path / "minute.mcap"
    n = long_log(path, 60.0)
    reader = open_reader(path)
    decoded = sum(1 for _ in reader.messages())
    reader.close()
    assert read_fast(path) == n == decoded


def test_memory_does_not_grow_with_the_log(tmp_path):
    peaks = []
    for seconds in (20.0, 80.0):
        path = tmp_path / f"{seconds:g}.mcap"
        long_log(path, seconds)
        tracemalloc.start()
        read_fast(path, batch_size=4096, block_size=4096, reorder=2000)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert peaks[1] < 1.3 * peaks[0], peaks
