"""Topic batches (twincd.io.stream.topics): every log form gives the same arrays, in bounded
batches, in log-time order, with an honest watermark; damaged MCAP files are read up to the
damage."""

from __future__ import annotations

import tempfile
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.writer import CompressionType, IndexType, Writer
from support.builders import (
    FORMS,
    SUFFIX,
    TS,
    XARM,
    Bool,
    Message,
    String,
    joint_recording,
    joint_state,
    write,
    write_humble_sqlite3,
)

from twincd.errors import LogReadError, TopicError
from twincd.io.stream import BoolBatch, JointStateBatch, StringBatch, TopicReader

TOPICS = ("/joint_states", "/collision_flag", "/chatter")


def write_mcap(
    path: Path,
    msgs: Sequence[Message],
    chunk_size: int = 1024 * 1024,
    compression: CompressionType = CompressionType.ZSTD,
    index_types: IndexType = IndexType.ALL,
    chunked: bool = True,
    summary: bool = True,
) -> Path:
    """A bare ros2 MCAP written with mcap's own Writer (file order = ``msgs`` order)."""
    with open(path, "wb") as f:
        writer = Writer(
            f,
            chunk_size=chunk_size,
            compression=compression,
            index_types=index_types,
            use_chunking=chunked,
            repeat_channels=summary,
            repeat_schemas=summary,
            use_statistics=summary,
            use_summary_offsets=summary,
        )
        writer.start(profile="ros2", library="tests")
        channels: dict[str, int] = {}
        for m in msgs:
            if m.topic not in channels:
                msgdef, _ = TS.generate_msgdef(m.msgtype, ros_version=2)
                sid = writer.register_schema(m.msgtype, "ros2msg", msgdef.encode())
                meta = {"offered_qos_profiles": ""}
                channels[m.topic] = writer.register_channel(m.topic, "cdr", sid, meta)
            data = bytes(TS.serialize_cdr(m.msg, m.msgtype))
            writer.add_message(channels[m.topic], m.log_time, data, m.log_time)
        writer.finish()
    return path


def recording(n: int = 300, seed: int = 1) -> list[Message]:
    rng = np.random.default_rng(seed)
    msgs = joint_recording(n=n, effort=rng.normal(size=(n, 7)))
    t0 = msgs[0].log_time
    extra = [
        Message("/collision_flag", "std_msgs/msg/Bool", t0 + k * 330_000_000, Bool(data=k % 2 == 0))
        for k in range(8)
    ]
    extra.append(Message("/chatter", "std_msgs/msg/String", t0 + 1, String(data="hello")))
    return sorted(msgs + extra, key=lambda m: m.log_time)


def read_all(path: Path, topics: Sequence[str] = TOPICS, **kwargs):
    """Per topic, every batch's arrays concatenated, plus the reader (closed)."""
    parts: dict[str, list] = defaultdict(list)
    with TopicReader(path, **kwargs) as reader:
        for topic, batch in reader.batches(topics):
            parts[topic].append(batch)
    out = {}
    for topic, batches in parts.items():
        first = batches[0]
        if isinstance(first, JointStateBatch):
            assert {b.names for b in batches} == {first.names}
            out[topic] = {
                f: np.concatenate([getattr(b, f) for b in batches])
                for f in ("log_time_ns", "stamp_ns", "position", "velocity", "effort")
            }
        elif isinstance(first, BoolBatch):
            out[topic] = {f: np.concatenate([b.log_time_ns for b in batches]) for f in ["t"]}
            out[topic]["value"] = np.concatenate([b.value for b in batches])
        else:
            assert isinstance(first, StringBatch)
            out[topic] = {"t": np.concatenate([b.log_time_ns for b in batches])}
            out[topic]["values"] = np.array([v for b in batches for v in b.values])
    return out, reader


def assert_same(a, b):
    assert a.keys() == b.keys()
    for topic in a:
        assert a[topic].keys() == b[topic].keys()
        for field in a[topic]:
            np.testing.assert_array_equal(a[topic][field], b[topic][field], err_msg=field)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    path = write_mcap(tmp_path_factory.mktemp("ref") / "ref.mcap", recording())
    arrays, reader = read_all(path)
    return arrays, reader


def test_reference_is_what_was_written(reference):
    arrays, reader = reference
    msgs = recording()
    js = [m for m in msgs if m.topic == "/joint_states"]
    np.testing.assert_array_equal(arrays["/joint_states"]["log_time_ns"], [m.log_time for m in js])
    np.testing.assert_array_equal(arrays["/joint_states"]["position"], [m.msg.position for m in js])
    np.testing.assert_array_equal(arrays["/joint_states"]["effort"], [m.msg.effort for m in js])
    assert arrays["/collision_flag"]["value"].tolist() == [k % 2 == 0 for k in range(8)]
    assert arrays["/chatter"]["values"].tolist() == ["hello"]
    assert reader.topics["/joint_states"] == "sensor_msgs/msg/JointState"
    # JointState and Bool on the fast path; String through rosbags
    assert (reader.stats.fast, reader.stats.fallback) == (308, 1)
    assert reader.damage is None


@pytest.mark.parametrize("form", FORMS)
def test_every_form_gives_the_same_batches(tmp_path, reference, form):
    path = write(tmp_path / f"log{SUFFIX[form]}", form, recording())
    arrays, reader = read_all(path)
    assert_same(arrays, reference[0])
    if form == "ros1":
        assert reader.stats.fast == 0  # rosbags' path, and counted as such
    else:
        assert (reader.stats.fast, reader.stats.fallback) == (308, 1)


def test_humble_sqlite3_without_definitions(tmp_path, reference):
    arrays, reader = read_all(write_humble_sqlite3(tmp_path / "bag", recording()))
    assert_same(arrays, reference[0])
    assert reader.stats.fast == 308


@pytest.mark.parametrize(
    "kind",
    [
        "lz4",
        "uncompressed",
        "small-chunks",
        "no-chunk-index",
        "no-index",
        "no-summary",
        "unchunked",
    ],
)
def test_mcap_variants(tmp_path, reference, kind):
    options = {
        "lz4": {"compression": CompressionType.LZ4},
        "uncompressed": {"compression": CompressionType.NONE},
        "small-chunks": {"chunk_size": 2000},
        "no-chunk-index": {"chunk_size": 2000, "index_types": IndexType.MESSAGE},
        "no-index": {"chunk_size": 2000, "index_types": IndexType.NONE},
        "no-summary": {"chunk_size": 2000, "index_types": IndexType.NONE, "summary": False},
        "unchunked": {"chunked": False, "index_types": IndexType.NONE},
    }[kind]
    arrays, reader = read_all(write_mcap(tmp_path / "a.mcap", recording(), **options))
    assert_same(arrays, reference[0])
    assert reader.stats.fast == 308 and reader.damage is None


def test_batches_are_bounded_ordered_and_watermarked(tmp_path):
    msgs = recording(n=2000)
    path = write_mcap(tmp_path / "a.mcap", msgs, chunk_size=3000)
    per_chunk = 12  # messages of ~250 bytes in a 3000-byte chunk, at most
    seen = []
    with TopicReader(path, batch_size=100) as reader:
        for _, batch in reader.batches(TOPICS):
            assert len(batch) <= 100 + per_chunk
            seen.append((reader.watermark_ns, batch.log_time_ns))
    # the watermark never lies: nothing yielded after it is older than it
    for i, (mark, _) in enumerate(seen):
        for _, later in seen[i:]:
            assert later.min() >= mark
    times = np.concatenate([t for _, t in seen])
    assert len(times) == len(msgs)
    assert len(seen) > 10
    assert reader.watermark_ns == 2**63 - 1  # all read


def test_interleaved_name_layouts(tmp_path):
    # a gripper publishing its own joint on the same topic: two batches per flush
    msgs = []
    for m in joint_recording(n=30):
        msgs.append(Message(m.topic, m.msgtype, m.log_time, joint_state(m.log_time, ["g"], [1.0])))
        msgs.append(m)
    arrays = defaultdict(list)
    with TopicReader(write_mcap(tmp_path / "a.mcap", msgs)) as reader:
        for _, batch in reader.batches(["/joint_states"]):
            arrays[batch.names].append(batch.log_time_ns)
    assert set(arrays) == {("g",), XARM}
    assert sum(len(t) for v in arrays.values() for t in v) == 60


def test_unknown_topics_are_skipped_and_odd_types_refused(tmp_path):
    msgs = [
        *recording(),
        Message("/f", "std_msgs/msg/Float64", 5, TS.types["std_msgs/msg/Float64"](data=1.0)),
    ]
    path = write_mcap(tmp_path / "a.mcap", msgs)
    with TopicReader(path) as reader:
        assert list(reader.batches(["/nope"])) == []
        with pytest.raises(TopicError, match="does not read"):
            list(reader.batches(["/f"]))


def cut(path: Path, fraction: float) -> Path:
    data = path.read_bytes()
    out = path.with_name("cut.mcap")
    out.write_bytes(data[: int(len(data) * fraction)])
    return out


def test_truncated_mcap(tmp_path):
    msgs = recording(n=2000)
    path = cut(write_mcap(tmp_path / "a.mcap", msgs, chunk_size=4000), 0.6)
    with pytest.raises(LogReadError, match="damaged") as err:
        TopicReader(path)
    assert "\n" not in str(err.value)
    arrays, reader = read_all(path, strict=False)
    n = len(arrays["/joint_states"]["log_time_ns"])
    assert 1000 < n < 1300  # the intact chunks, all of them
    full, _ = read_all(write_mcap(tmp_path / "b.mcap", msgs))
    for field, values in arrays["/joint_states"].items():
        np.testing.assert_array_equal(values, full["/joint_states"][field][:n])
    assert reader.damage is not None and "\n" not in reader.damage
    assert "mcap recover" in reader.damage and f"read {reader.messages} message" in reader.damage


def test_corrupt_chunk_with_intact_summary(tmp_path):
    path = write_mcap(tmp_path / "a.mcap", recording(n=2000), chunk_size=4000)
    data = bytearray(path.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 64] = bytes(64)  # zeros inside a compressed chunk
    path.write_bytes(bytes(data))
    with pytest.raises(LogReadError, match="damaged"):
        read_all(path)
    arrays, reader = read_all(path, strict=False)
    assert 0 < len(arrays["/joint_states"]["log_time_ns"]) < 2000
    assert reader.damage is not None and "byte" in reader.damage


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (b"", "empty file"),
        (b"\x89MCAP0\r\n" + bytes(range(256)) * 4, "damaged"),
        (b"x" * 99, "not an MCAP"),
    ],
)
def test_unreadable_mcap_files(tmp_path, content, match):
    path = tmp_path / "bad.mcap"
    path.write_bytes(content)
    with pytest.raises(LogReadError, match=match):
        TopicReader(path)


@pytest.fixture(scope="module")
def small_mcap(tmp_path_factory) -> bytes:
    folder = tmp_path_factory.mktemp("fuzz")
    return write_mcap(folder / "a.mcap", recording(n=200), chunk_size=3000).read_bytes()


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_damaged_files_fail_with_one_clear_error(small_mcap, data):
    raw = bytearray(small_mcap)
    if data.draw(st.booleans(), label="cut"):
        raw = raw[: data.draw(st.integers(0, len(raw) - 1), label="length")]
    else:
        for _ in range(data.draw(st.integers(1, 8), label="flips")):
            at = data.draw(st.integers(0, len(raw) - 1), label="at")
            raw[at] = data.draw(st.integers(0, 255), label="byte")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "d.mcap"
        path.write_bytes(bytes(raw))
        for strict in (True, False):
            try:
                with TopicReader(path, strict=strict) as reader:
                    for _ in reader.batches(TOPICS):
                        pass
            except (LogReadError, TopicError) as exc:
                assert "\n" not in str(exc)
