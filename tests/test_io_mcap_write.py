"""The MCAP writer: lossless streaming copies, new channels in blocks, atomic outputs."""

from __future__ import annotations

import struct
import tracemalloc
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Channel, Chunk
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from support.builders import SUFFIX, TS, Bool, Message, String, joint_recording, write

import twincd
import twincd.io.mcap.messages as message_blocks
from twincd.errors import LogReadError
from twincd.io.cdr import joint_state_cdr
from twincd.io.mcap import (
    DEFAULT_QOS,
    QOS_KEY,
    AugmentedMcap,
    McapLogWriter,
    NewTopic,
    write_augmented,
)

T0 = 1_700_000_000_000_000_000
JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT64 = "std_msgs/msg/Float64"
BOOL = "std_msgs/msg/Bool"
STRING = "std_msgs/msg/String"
NAMES = [f"joint{i}" for i in range(1, 8)]

Record = tuple[str, str, int, int, int, bytes]  # topic, schema, log, publish, sequence, data


# ---------------------------------------------------------------- reading back


def mcap_messages(path: Path) -> list[Record]:
    """Every message through mcap's indexed reader, in log-time order, chunk CRCs checked."""
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        out = [
            (c.topic, s.name if s else "", m.log_time, m.publish_time, m.sequence, bytes(m.data))
            for s, c, m in reader.iter_messages(log_time_order=True)
        ]
    assert [r[2] for r in out] == sorted(r[2] for r in out)
    return out


def streamed_messages(path: Path) -> list[Record]:
    """Every message in file order through mcap's streaming reader, which checks the
    data-section CRC (and each chunk's) and needs every channel defined before use."""
    with open(path, "rb") as f:
        reader = NonSeekingReader(f, validate_crcs=True)
        return [
            (c.topic, s.name if s else "", m.log_time, m.publish_time, m.sequence, bytes(m.data))
            for s, c, m in reader.iter_messages(log_time_order=False)
        ]


def rosbags_messages(path: Path) -> list[tuple[str, int, bytes]]:
    with AnyReader([path]) as reader:
        out = [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]
        for c, _, raw in reader.messages():  # and every message decodes
            reader.deserialize(raw, c.msgtype)
    assert [r[1] for r in out] == sorted(r[1] for r in out)
    return out


def without(records: list[Any], topics: set[str]) -> list[Any]:
    return sorted(r for r in records if r[0] not in topics)


def check_output(path: Path) -> None:
    """A well-formed ros2 MCAP: CRCs everywhere, summary, every reader agrees."""
    data = path.read_bytes()
    summary_start, offsets_start, summary_crc = struct.unpack_from("<QQI", data, len(data) - 28)
    # DataEnd (13 bytes) right before the summary, with the CRC of everything before it
    opcode, _, data_crc = struct.unpack_from("<BQI", data, summary_start - 13)
    assert opcode == 0x0F
    assert data_crc != 0 and data_crc == zlib.crc32(data[: summary_start - 13])
    assert summary_crc == zlib.crc32(data[summary_start : len(data) - 8 - 4])
    assert offsets_start > summary_start
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        for channel in summary.channels.values():
            assert QOS_KEY in channel.metadata and channel.message_encoding == "cdr"
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        stats = summary.statistics
        assert stats.chunk_count == len(summary.chunk_indexes)
    indexed = mcap_messages(path)
    assert stats.message_count == len(indexed)
    counts: dict[str, int] = {}
    for r in indexed:
        counts[r[0]] = counts.get(r[0], 0) + 1
    assert {summary.channels[c].topic: n for c, n in stats.channel_message_counts.items() if n} == (
        counts
    )
    assert sorted(streamed_messages(path)) == sorted(indexed)
    assert sorted(rosbags_messages(path)) == sorted((r[0], r[2], r[5]) for r in indexed)
    with open(path, "rb") as f:  # mcap_ros2 decodes every message against its schema
        decoded = make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()
        assert sum(1 for _ in decoded) == len(indexed)


# ---------------------------------------------------------------- payloads built with numpy


def float64_payloads(values: np.ndarray) -> np.ndarray:
    out = np.zeros((len(values), 12), dtype=np.uint8)
    out[:, 1] = 1  # CDR little-endian encapsulation
    out[:, 4:] = np.asarray(values, dtype="<f8")[:, None].view(np.uint8)
    return out


def bool_payloads(values: np.ndarray) -> np.ndarray:
    out = np.zeros((len(values), 5), dtype=np.uint8)
    out[:, 1] = 1
    out[:, 4] = np.asarray(values, dtype=bool)
    return out


def string_payload(text: str) -> bytes:
    return bytes(TS.serialize_cdr(String(data=text), STRING))


def test_numpy_payloads_are_cdr():
    assert float64_payloads(np.array([2.5]))[0].tobytes() == bytes(
        TS.serialize_cdr(TS.types[FLOAT64](data=2.5), FLOAT64)
    )
    assert bool_payloads(np.array([True]))[0].tobytes() == bytes(
        TS.serialize_cdr(Bool(data=True), BOOL)
    )


# ---------------------------------------------------------------- inputs


def msgdef(msgtype: str) -> bytes:
    return TS.generate_msgdef(msgtype, ros_version=2)[0].encode()


def rich_mcap(path: Path, n: int = 400, qos: bool = True, chunked: bool = True) -> Path:
    """A bare MCAP written with mcap's own Writer: several chunks, publish times and
    sequences of their own, metadata and attachments, extra channel metadata."""
    rng = np.random.default_rng(3)
    msgs = joint_recording(n=n, effort=rng.normal(size=(n, 7)))
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=8192, compression=CompressionType.ZSTD, use_chunking=chunked)
        w.start(profile="ros2", library="test")
        meta = {QOS_KEY: DEFAULT_QOS} if qos else {}
        js = w.register_channel(
            "/joint_states",
            "cdr",
            w.register_schema(JOINT_STATE, "ros2msg", msgdef(JOINT_STATE)),
            {**meta, "extra": "kept"},
        )
        flag = w.register_channel(
            "/collision_flag", "cdr", w.register_schema(BOOL, "ros2msg", msgdef(BOOL)), meta
        )
        text = w.register_channel(
            "/rosout_text", "cdr", w.register_schema(STRING, "ros2msg", msgdef(STRING)), meta
        )
        for i, m in enumerate(msgs):
            data = bytes(TS.serialize_cdr(m.msg, JOINT_STATE))
            w.add_message(js, m.log_time, data, m.log_time - 1000 - i, sequence=7 * i + 3)
            if i % 50 == 0:
                w.add_message(
                    flag,
                    m.log_time + 1,
                    bytes(TS.serialize_cdr(Bool(data=i % 100 == 0), BOOL)),
                    m.log_time,
                    sequence=i,
                )
            if i % 130 == 0:
                w.add_message(text, m.log_time + 2, string_payload(f"hello {i}"), m.log_time + 2)
        w.add_metadata("rosbag2", {"serialized_bag_info": "x"})
        w.add_metadata("robot", {"model": "xarm7", "site": "lab 2"})
        w.add_attachment(T0, T0 + 5, "calib.yaml", "text/yaml", b"a: 1\n")
        w.add_attachment(0, T0 + 9, "blob.bin", "application/octet-stream", bytes(range(256)))
        w.finish()
    return path


def attachments(path: Path) -> list[tuple[str, str, int, int, bytes]]:
    with open(path, "rb") as f:
        return [
            (a.name, a.media_type, a.log_time, a.create_time, bytes(a.data))
            for a in make_reader(f).iter_attachments()
        ]


def metadata(path: Path) -> dict[str, dict[str, str]]:
    with open(path, "rb") as f:
        return {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}


def chunk_payloads(path: Path) -> list[bytes]:
    with open(path, "rb") as f:
        return [
            bytes(r.data) for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)
        ]


def add_three_channels(out: AugmentedMcap, log_time: np.ndarray) -> dict[str, list[Record]]:
    """Residual, score and flag channels, as detect writes them; the records expected back."""
    n = len(log_time)
    rng = np.random.default_rng(1)
    q = rng.normal(size=(n, 7))
    residual = np.stack(
        [np.frombuffer(b, np.uint8) for b in joint_state_cdr(log_time, NAMES, q, q, q)]
    )
    score, flag = float64_payloads(rng.normal(size=n)), bool_payloads(rng.random(n) > 0.9)
    expected: dict[str, list[Record]] = {}
    for topic, msgtype, payloads in (
        ("/twincd/residual", JOINT_STATE, residual),
        ("/twincd/score", FLOAT64, score),
        ("/twincd/collision", BOOL, flag),
    ):
        channel = out.add_channel(topic, msgtype)
        for start in range(0, n, 97):  # many small blocks
            block = slice(start, start + 97)
            out.write(channel, log_time[block], payloads[block])
        expected[topic] = [
            (topic, msgtype, int(t), int(t), i, payloads[i].tobytes())
            for i, t in enumerate(log_time)
        ]
    return expected


# ---------------------------------------------------------------- lossless copies


def test_mcap_copy_is_lossless_and_chunks_pass_through(tmp_path):
    src = rich_mcap(tmp_path / "in.mcap")
    out = tmp_path / "out.mcap"
    before = mcap_messages(src)
    log_time = np.array([r[2] for r in before if r[0] == "/joint_states"], dtype=np.int64)
    with AugmentedMcap(src, out) as aug:
        expected = add_three_channels(aug, log_time)
    after = mcap_messages(out)
    assert without(after, set(expected)) == sorted(before)  # topic, schema, times, seq, bytes
    for topic, records in expected.items():
        assert [r for r in after if r[0] == topic] == records
    check_output(out)
    # channel metadata as it was, the rosbag2 record dropped, the rest kept
    with open(src, "rb") as f, open(out, "rb") as g:
        old = {c.topic: c.metadata for c in make_reader(f).get_summary().channels.values()}
        new = {c.topic: c.metadata for c in make_reader(g).get_summary().channels.values()}
    assert {t: new[t] for t in old} == old and new["/joint_states"]["extra"] == "kept"
    marker = {"twincd": {"output": "detect", "version": twincd.__version__}}
    assert metadata(out) == {"robot": {"model": "xarm7", "site": "lab 2"}, **marker}
    assert attachments(out) == attachments(src) and len(attachments(src)) == 2
    # the input's compressed chunks are in the output as they were: no decompression
    assert set(chunk_payloads(src)) <= set(chunk_payloads(out))


@pytest.mark.parametrize("form", ["mcap", "rosbag2-mcap", "rosbag2-sqlite3"])
def test_storage_forms_copy_losslessly(tmp_path, form):
    msgs = joint_recording(n=120)
    msgs.append(Message("/collision_flag", BOOL, msgs[0].log_time + 7, Bool(data=True)))
    msgs.append(Message("/rosout_text", STRING, msgs[0].log_time + 9, String(data="hi")))
    msgs.sort(key=lambda m: m.log_time)
    src = write(tmp_path / f"in{SUFFIX[form]}", form, msgs)
    out = tmp_path / "out.mcap"
    log_time = np.array([m.log_time for m in msgs if m.topic == "/joint_states"])
    with AugmentedMcap(src, out) as aug:
        expected = add_three_channels(aug, log_time)
    assert without(rosbags_messages(out), set(expected)) == sorted(rosbags_messages(src))
    check_output(out)


@pytest.mark.parametrize("mode", ["message", "file"])
def test_compressed_rosbag2_is_decompressed(tmp_path, mode):
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

    msgs = joint_recording(n=50)
    src = tmp_path / "bag"
    writer = Writer2(src, version=8, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode[mode.upper()], CompressionFormat.ZSTD)
    with writer:
        conn = writer.add_connection("/joint_states", JOINT_STATE, typestore=TS)
        for m in msgs:
            writer.write(conn, m.log_time, TS.serialize_cdr(m.msg, m.msgtype))
    out = tmp_path / "out.mcap"
    with AugmentedMcap(src, out):
        pass
    # a bare MCAP has no place to say "zstd per message": its messages are plain CDR
    assert rosbags_messages(out) == [
        ("/joint_states", m.log_time, bytes(TS.serialize_cdr(m.msg, m.msgtype))) for m in msgs
    ]
    check_output(out)


def test_ros1_bags_are_converted(tmp_path):
    msgs = joint_recording(n=50)
    msgs.append(Message("/collision_flag", BOOL, msgs[0].log_time + 7, Bool(data=True)))
    src = write(tmp_path / "in.bag", "ros1", msgs)
    out = tmp_path / "out.mcap"
    with AugmentedMcap(src, out) as aug:
        add_three_channels(aug, np.array([m.log_time for m in msgs[:50]]))
    check_output(out)
    with open(out, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        decoded = list(reader.iter_decoded_messages(topics=["/joint_states"]))
    assert [m.message.log_time for m in decoded] == [m.log_time for m in msgs[:50]]
    for got, want in zip(decoded, msgs[:50]):
        np.testing.assert_array_equal(got.decoded_message.position, want.msg.position)
        assert list(got.decoded_message.name) == NAMES


def test_split_rosbag2_files_numbering_channels_differently(tmp_path):
    folder = tmp_path / "split"
    folder.mkdir()
    expected = []
    for k, topics in enumerate([("/a", "/b"), ("/b", "/c", "/a")]):
        with open(folder / f"split_{k}.mcap", "wb") as f:
            w = Writer(f, chunk_size=1024)
            w.start(profile="ros2", library="test")
            schema = w.register_schema(STRING, "ros2msg", msgdef(STRING))
            ids = {t: w.register_channel(t, "cdr", schema, {QOS_KEY: DEFAULT_QOS}) for t in topics}
            for i in range(60):
                topic = topics[i % len(topics)]
                t = T0 + 1000 * (100 * k + i)
                data = string_payload(f"{topic} {k} {i}")
                w.add_message(ids[topic], t, data, t + 1, sequence=i)
                expected.append((topic, STRING, t, t + 1, i, data))
            w.finish()
    out = tmp_path / "out.mcap"
    with AugmentedMcap(folder, out) as aug:
        aug.write(aug.add_channel("/new", STRING), np.array([T0]), [string_payload("x")])
    assert without(mcap_messages(out), {"/new"}) == sorted(expected)
    with open(out, "rb") as f:
        topics = [c.topic for c in make_reader(f).get_summary().channels.values()]
    assert sorted(topics) == ["/a", "/b", "/c", "/new"]  # one channel per topic
    check_output(out)


def without_summary(src: Path, dst: Path) -> Path:
    """``src`` with its summary section cut off (footer pointing at none)."""
    data = src.read_bytes()
    summary_start = struct.unpack_from("<Q", data, len(data) - 28)[0]
    footer = struct.pack("<BQQQI", 0x02, 20, 0, 0, 0)
    dst.write_bytes(data[:summary_start] + footer + data[:8])
    return dst


@pytest.mark.parametrize("kind", ["unchunked", "no-summary", "no-qos"])
def test_unusual_mcap_inputs(tmp_path, kind):
    src = rich_mcap(tmp_path / "rich.mcap", qos=kind != "no-qos", chunked=kind != "unchunked")
    if kind == "no-summary":
        src = without_summary(src, tmp_path / "bare.mcap")
    before = streamed_messages(src)
    out = tmp_path / "out.mcap"
    with AugmentedMcap(src, out) as aug:
        expected = add_three_channels(aug, np.array([T0, T0 + 5, T0 + 6]))
    assert without(mcap_messages(out), set(expected)) == sorted(before)
    check_output(out)  # every channel has QoS metadata now
    assert attachments(out)[0][0] == "calib.yaml"


# ---------------------------------------------------------------- new channels


def test_interleaved_writes_of_fixed_and_variable_payloads(tmp_path, monkeypatch):
    monkeypatch.setattr(message_blocks, "CHUNK_SIZE", 2048)  # many chunks, writes split across them
    src = rich_mcap(tmp_path / "in.mcap", n=50)
    before = mcap_messages(src)
    out = tmp_path / "out.mcap"
    rng = np.random.default_rng(5)
    n = 3000
    log_time = T0 + np.cumsum(rng.integers(1, 2_000_000, n))
    publish = log_time - rng.integers(0, 1000, n)
    score = float64_payloads(rng.normal(size=n))
    flag = bool_payloads(rng.random(n) > 0.5)
    texts = [string_payload("e" * int(k)) for k in rng.integers(0, 300, n)]
    with AugmentedMcap(src, out) as aug:
        channels = {
            "/twincd/score": aug.add_channel("/twincd/score", FLOAT64),
            "/twincd/collision": aug.add_channel("/twincd/collision", BOOL),
            "/twincd/event": aug.add_channel("/twincd/event", STRING),
        }
        done = dict.fromkeys(channels, 0)
        while min(done.values()) < n:
            topic = list(channels)[rng.integers(0, 3)]
            a = done[topic]
            b = min(n, a + int(rng.integers(0, 400)))  # empty writes too
            if topic == "/twincd/score":
                aug.write(channels[topic], log_time[a:b], score[a:b], publish[a:b])
            elif topic == "/twincd/collision":
                aug.write(channels[topic], log_time[a:b], flag[a:b])
            else:
                aug.write(channels[topic], log_time[a:b], texts[a:b])
            done[topic] = b
    after = streamed_messages(out)  # file order: each channel's messages in write order
    assert without(after, set(channels)) == sorted(before)
    got = {t: [r for r in after if r[0] == t] for t in channels}
    ts = log_time.tolist()
    assert got["/twincd/score"] == [
        ("/twincd/score", FLOAT64, ts[i], int(publish[i]), i, score[i].tobytes()) for i in range(n)
    ]
    assert got["/twincd/collision"] == [
        ("/twincd/collision", BOOL, ts[i], ts[i], i, flag[i].tobytes()) for i in range(n)
    ]
    assert got["/twincd/event"] == [
        ("/twincd/event", STRING, ts[i], ts[i], i, texts[i]) for i in range(n)
    ]
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    assert len(summary.chunk_indexes) > 50
    check_output(out)


def test_write_refuses_bad_input(tmp_path):
    src = rich_mcap(tmp_path / "in.mcap", n=10)
    with AugmentedMcap(src, tmp_path / "out.mcap") as aug:
        channel = aug.add_channel("/x", FLOAT64)
        with pytest.raises(ValueError, match="payloads"):
            aug.write(channel, np.array([T0, T0 + 1]), float64_payloads(np.zeros(3)))
        with pytest.raises(ValueError, match="add_channel"):
            aug.write(1, np.array([T0]), float64_payloads(np.zeros(1)))
        with pytest.raises(ValueError, match="negative"):
            aug.write(channel, np.array([-1]), float64_payloads(np.zeros(1)))
        with pytest.raises(ValueError, match="replace_topics"):
            aug.add_channel("/joint_states", JOINT_STATE)
    assert (tmp_path / "out.mcap").exists()


# ---------------------------------------------------------------- replacing channels


def interleaved_twin_log(path: Path, n: int = 300) -> Path:
    """A log simulated by an earlier twincd: sim messages in the same chunks as the joints."""
    msgs = joint_recording(n=n)
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=4096)
        w.start(profile="ros2", library="twincd 0.0")
        schema = w.register_schema(JOINT_STATE, "ros2msg", msgdef(JOINT_STATE))
        js = w.register_channel("/joint_states", "cdr", schema, {QOS_KEY: DEFAULT_QOS})
        sim = None
        for i, m in enumerate(msgs):
            data = bytes(TS.serialize_cdr(m.msg, JOINT_STATE))
            w.add_message(js, m.log_time, data, m.log_time, sequence=i)
            if sim is None:  # registered lazily, inside a chunk, as the old writer did
                sim = w.register_channel(
                    "/twincd/sim_effort", "cdr", schema, {QOS_KEY: DEFAULT_QOS}
                )
            w.add_message(sim, m.log_time, data[::-1], m.log_time, sequence=i)
        w.finish()
    return path


@pytest.mark.parametrize("layout", ["own-chunks", "interleaved"])
def test_replaced_topic_is_not_duplicated(tmp_path, layout, twin_log):
    if layout == "own-chunks":  # what this writer makes: sim in chunks of its own
        src = twin_log(tmp_path / "in.mcap", seconds=4.0)
    else:
        src = interleaved_twin_log(tmp_path / "in.mcap")
    before = mcap_messages(src)
    old_sim = [r for r in before if r[0] == "/twincd/sim_effort"]
    log_time = np.array([r[2] for r in old_sim], dtype=np.int64)
    new = np.zeros((len(log_time), 12), dtype=np.uint8)  # any fixed-size bytes will do
    new[:, 4:] = log_time[:, None].view(np.uint8)
    out = tmp_path / "out.mcap"
    with AugmentedMcap(src, out, replace_topics={"/twincd/sim_effort"}) as aug:
        channel = aug.add_channel("/twincd/sim_effort", JOINT_STATE)
        aug.write(channel, log_time[:100], new[:100])
        aug.write(channel, log_time[100:], new[100:])
    after = mcap_messages(out)
    assert without(after, {"/twincd/sim_effort"}) == without(before, {"/twincd/sim_effort"})
    sim = [r for r in after if r[0] == "/twincd/sim_effort"]
    assert [r[5] for r in sim] == [row.tobytes() for row in new]
    assert [r[4] for r in sim] == list(range(len(new)))
    for reader in (make_reader, NonSeekingReader):  # one sim channel, indexed or streamed
        with open(out, "rb") as f:
            topics = [c.topic for c in reader(f).get_summary().channels.values()]
        assert topics.count("/twincd/sim_effort") == 1
    with open(out, "rb") as f:
        stream_topics = [r.topic for r in StreamReader(f).records if isinstance(r, Channel)]
    assert set(stream_topics) == set(topics)
    if layout == "own-chunks":  # chunks without sim messages passed through untouched
        kept = [c for c in chunk_payloads(src) if c in set(chunk_payloads(out))]
        assert len(kept) >= 2


def test_in_place_rewrite(tmp_path):
    src = rich_mcap(tmp_path / "run.mcap", n=30)
    before = mcap_messages(src)
    for _ in range(2):
        with AugmentedMcap(src, src, replace_topics={"/twincd/score"}) as aug:
            channel = aug.add_channel("/twincd/score", FLOAT64)
            aug.write(channel, np.array([T0, T0 + 1]), float64_payloads(np.array([1.0, 2.0])))
    after = mcap_messages(src)
    assert without(after, {"/twincd/score"}) == sorted(before)
    assert sum(r[0] == "/twincd/score" for r in after) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap"]


# ---------------------------------------------------------------- atomic output


def test_an_error_inside_the_block_leaves_nothing(tmp_path):
    src = rich_mcap(tmp_path / "in.mcap", n=50)
    target = tmp_path / "out.mcap"
    with pytest.raises(RuntimeError, match="boom"), AugmentedMcap(src, target) as aug:
        channel = aug.add_channel("/x", FLOAT64)
        aug.write(channel, np.array([T0]), float64_payloads(np.zeros(1)))
        raise RuntimeError("boom")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.mcap"]


@pytest.mark.parametrize("damage", ["truncated", "garbage", "empty"])
def test_unreadable_sources_are_one_clear_error(tmp_path, damage):
    good = rich_mcap(tmp_path / "good.mcap").read_bytes()
    src = tmp_path / "bad.mcap"
    content = {
        "truncated": good[: len(good) // 2],
        "garbage": good[:8] + bytes(range(256)) * 8,
        "empty": b"",
    }[damage]
    src.write_bytes(content)
    with pytest.raises(LogReadError, match="cannot"), AugmentedMcap(src, tmp_path / "o.mcap"):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mcap", "good.mcap"]


# ---------------------------------------------------------------- the older entry points


def test_write_augmented_and_log_writer(tmp_path):
    src = tmp_path / "made.mcap"
    msgs = joint_recording(n=40)
    payloads = [bytes(TS.serialize_cdr(m.msg, JOINT_STATE)) for m in msgs]
    with McapLogWriter(src) as out:
        js = out.add_topic("/joint_states", JOINT_STATE)
        flag = out.add_topic("/collision_flag", BOOL)
        for m, data in zip(msgs[:20], payloads[:20]):
            out.write(js, m.log_time, data)
        out.write(flag, msgs[0].log_time, bool_payloads(np.array([True]))[0].tobytes())
        out.write_many(js, np.array([m.log_time for m in msgs[20:]]), payloads[20:])
    written = mcap_messages(src)
    assert [r[5] for r in written if r[0] == "/joint_states"] == payloads
    assert [r[4] for r in written if r[0] == "/joint_states"] == list(range(40))
    check_output(src)
    out_path = tmp_path / "aug.mcap"
    score = [
        (m.log_time, m.log_time + 3, float64_payloads(np.array([i]))[0].tobytes())
        for i, m in enumerate(msgs)
    ]
    write_augmented(src, out_path, [NewTopic("/twincd/score", FLOAT64, iter(score))])
    after = mcap_messages(out_path)
    assert without(after, {"/twincd/score"}) == sorted(written)
    assert [(r[2], r[3], r[5]) for r in after if r[0] == "/twincd/score"] == score
    check_output(out_path)


# ---------------------------------------------------------------- speed and memory


def legacy_copy(src: Path, dst: Path, new: list[tuple[str, str, np.ndarray]], log_time) -> None:
    """What write_augmented did before: mcap's Writer, message by message."""
    with open(dst, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="ros2", library="legacy")
        schemas: dict[Any, int] = {}
        channels: dict[str, int] = {}
        with open(src, "rb") as s:
            for schema, channel, m in make_reader(s).iter_messages(log_time_order=False):
                key = (schema.name, schema.encoding, schema.data)
                if key not in schemas:
                    schemas[key] = w.register_schema(*key)
                if channel.topic not in channels:
                    channels[channel.topic] = w.register_channel(
                        channel.topic, "cdr", schemas[key], dict(channel.metadata)
                    )
                w.add_message(
                    channels[channel.topic], m.log_time, m.data, m.publish_time, m.sequence
                )
        for topic, msgtype, payloads in new:
            schema_id = w.register_schema(msgtype, "ros2msg", msgdef(msgtype))
            channel_id = w.register_channel(topic, "cdr", schema_id, {QOS_KEY: DEFAULT_QOS})
            for i, (t, row) in enumerate(zip(log_time.tolist(), payloads)):
                w.add_message(channel_id, t, row.tobytes(), t, sequence=i)
        w.finish()


def long_log(path: Path, seconds: float, rate_hz: float = 1000.0) -> tuple[np.ndarray, list]:
    """A 7-joint JointState log as in benchmarks/bench_io.py; the three new channels' data."""
    n = int(seconds * rate_hz)
    t = np.arange(n) / rate_hz
    q = 0.5 * np.sin(2 * np.pi * 0.2 * t[:, None] + np.arange(7))
    qd = 0.5 * 2 * np.pi * 0.2 * np.cos(2 * np.pi * 0.2 * t[:, None] + np.arange(7))
    stamps = T0 + (t * 1e9).astype(np.int64)
    rows = np.stack(
        [np.frombuffer(b, np.uint8) for b in joint_state_cdr(stamps, NAMES, q, qd, 0 * q)]
    )
    with McapLogWriter(path) as out:
        out.write_many(out.add_topic("/joint_states", JOINT_STATE), stamps, rows)
    residual = np.stack(
        [np.frombuffer(b, np.uint8) for b in joint_state_cdr(stamps, NAMES, q, qd, q * qd)]
    )
    new = [
        ("/twincd/residual", JOINT_STATE, residual),
        ("/twincd/score", FLOAT64, float64_payloads(np.sin(t))),
        ("/twincd/collision", BOOL, bool_payloads(np.sin(t) > 0.9)),
    ]
    return stamps, new


def augmented_copy(src: Path, dst: Path, new: list, log_time: np.ndarray, block: int) -> None:
    with AugmentedMcap(src, dst) as out:
        channels = [out.add_channel(topic, msgtype) for topic, msgtype, _ in new]
        for start in range(0, len(log_time), block):
            for channel, (_, _, payloads) in zip(channels, new):
                out.write(channel, log_time[start : start + block], payloads[start : start + block])


def test_a_long_copy_holds_what_a_per_message_copy_holds(tmp_path):
    """The block-wise lossless copy and a plain per-message copy (mcap's Writer, one message at
    a time) hold the same messages; which is faster is benchmarks/bench_io.py's question."""
    src = tmp_path / "long.mcap"
    log_time, new = long_log(src, 60.0)
    legacy_copy(src, tmp_path / "legacy.mcap", new, log_time)
    augmented_copy(src, tmp_path / "new.mcap", new, log_time, 65536)
    counts = []
    for name in ("legacy.mcap", "new.mcap"):
        with open(tmp_path / name, "rb") as f:
            counts.append(make_reader(f).get_summary().statistics.channel_message_counts)
    assert counts[0] == counts[1] and sum(counts[1].values()) == 4 * len(log_time)


def test_memory_does_not_grow_with_log_length(tmp_path):
    peaks = []
    for seconds in (15.0, 60.0):
        src = tmp_path / f"log{seconds:g}.mcap"
        log_time, new = long_log(src, seconds)
        tracemalloc.start()
        augmented_copy(src, tmp_path / "out.mcap", new, log_time, 8192)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    # the inputs (held by the caller) are not counted; what the writer holds is bounded
    assert peaks[1] < 1.3 * peaks[0] + 2e6, peaks
    assert peaks[1] < 40e6, peaks


def test_the_data_section_crc_is_written(tmp_path):
    import struct
    import zlib

    src = rich_mcap(tmp_path / "in.mcap")
    out = tmp_path / "out.mcap"
    with AugmentedMcap(src, out) as aug:
        add_three_channels(aug, np.array([1, 2, 3], dtype=np.int64) + 1_700_000_000_000_000_000)
    data = out.read_bytes()
    at = 8
    while True:  # to the DataEnd record: its CRC covers every byte before it
        opcode, length = struct.unpack_from("<BQ", data, at)
        if opcode == 0x0F:
            break
        at += 9 + length
    (crc,) = struct.unpack_from("<I", data, at + 9)
    assert crc != 0 and crc == zlib.crc32(data[:at])
