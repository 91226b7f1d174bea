"""A short log in ONE chunk (rosbags' MCAP writer, or any writer that never closed its chunk),
cut short: the whole records inside the cut chunk are read, uncompressed or as a zstd or lz4
stream, with one warning; ``--strict`` refuses it; ``detect -o`` copies what was read.

Hypothesis profiles as in test_faults.py: ``ci`` (the default, a few dozen cases) and ``local``.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from conftest import build_twin_log
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.writer import CompressionType
from support.builders import TS, Message, joint_recording, write
from support.clitools import assert_one_line_error, run
from test_io_topics import write_mcap

from twincd.errors import LogReadError
from twincd.io.options import LogOptions
from twincd.io.stream import iter_blocks

settings.register_profile(
    "ci", max_examples=30, deadline=None, suppress_health_check=list(HealthCheck)
)
settings.register_profile(
    "local", max_examples=1000, deadline=None, suppress_health_check=list(HealthCheck)
)
CUTS = settings.get_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
N = 3000  # ≈ 0.8 MB of records: one chunk, several zstd and lz4 blocks
# a cut loses the records after the last whole block: a zstd block (128 kB) is ≈ 16 % of them
LOST_AT_MOST = 0.25


def _rosbags(path: Path, msgs: list[Message]) -> Path:
    return write(path.with_suffix(".mcap"), "mcap", msgs)


def _rosbag2(path: Path, msgs: list[Message]) -> Path:
    return write(path, "rosbag2-mcap", msgs)


def _twincd(path: Path, msgs: list[Message]) -> Path:
    from twincd.io.mcap import McapLogWriter

    out = path.with_suffix(".mcap")
    with McapLogWriter(out) as writer:
        channel = writer.add_topic("/joint_states", "sensor_msgs/msg/JointState")
        for m in msgs:
            writer.write(channel, m.log_time, bytes(TS.serialize_cdr(m.msg, m.msgtype)))
    return out


def _mcap(compression: CompressionType) -> Callable[[Path, list[Message]], Path]:
    def build(path: Path, msgs: list[Message]) -> Path:
        return write_mcap(path.with_suffix(".mcap"), msgs, 1 << 26, compression)

    return build


FORMS: dict[str, Callable[[Path, list[Message]], Path]] = {
    "rosbags": _rosbags,  # uncompressed
    "rosbag2-folder": _rosbag2,  # uncompressed
    "twincd-zstd": _twincd,
    "mcap-zstd": _mcap(CompressionType.ZSTD),
    "mcap-lz4": _mcap(CompressionType.LZ4),
}


def storage_file(log: Path) -> Path:
    return log if log.is_file() else next(log.glob("*.mcap"))


def chunks(path: Path) -> int:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return len(summary.chunk_indexes)


class OneChunkLogs(dict[str, tuple[Path, bytes, dict[str, np.ndarray]]]):
    """Per form: the log, its storage file's bytes, and the samples of a complete read."""

    def __repr__(self) -> str:  # hypothesis prints the arguments of a failing case
        return f"OneChunkLogs({sorted(self)})"


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> OneChunkLogs:
    root = tmp_path_factory.mktemp("one_chunk")
    msgs = joint_recording(n=N)
    out = OneChunkLogs()
    for form, build in FORMS.items():
        log = build(root / form, msgs)
        assert chunks(storage_file(log)) == 1, form
        out[form] = (log, storage_file(log).read_bytes(), samples(log, strict=True)[0])
    return out


def samples(log: Path, strict: bool) -> tuple[dict[str, np.ndarray], str | None]:
    with iter_blocks(log, LogOptions(), strict=strict) as stream:
        blocks = list(stream)
    got = {
        f: np.concatenate([getattr(b, f) for b in blocks])
        for f in ("stamp_ns", "log_time_ns", "position", "velocity")
    }
    return got, stream.damage


def cut_copy(log: Path, data: bytes, fraction: float, into: Path) -> Path:
    """A copy of ``log`` whose storage file keeps the first ``fraction`` of its bytes."""
    target = into / log.name
    if log.is_dir():
        shutil.copytree(log, target)
    (storage_file(target) if log.is_dir() else target).write_bytes(
        data[: int(fraction * len(data))]
    )
    return target


def read_cut(log: Path, caplog: pytest.LogCaptureFixture) -> dict[str, np.ndarray]:
    """The samples of a cut log: read with one warning that says it is damaged."""
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="twincd"):
        got, damage = samples(log, strict=False)
    assert damage is not None and "damaged" in damage
    warned = [r.getMessage() for r in caplog.records if "damaged" in r.getMessage()]
    assert len(warned) == 1 and f"read {len(got['stamp_ns'])} message" in warned[0]
    return got


@pytest.mark.parametrize("form", FORMS)
@CUTS
@given(fractions=st.tuples(st.floats(0.1, 0.99), st.floats(0.1, 0.99)))
def test_a_cut_chunk_gives_a_growing_prefix_of_the_samples(
    logs, form, fractions, tmp_path_factory, caplog
):
    log, data, full = logs[form]
    counts = []
    for fraction in sorted(fractions):
        cut = cut_copy(log, data, fraction, tmp_path_factory.mktemp("cut"))
        try:
            got = read_cut(cut, caplog)
        except LogReadError as exc:  # nothing whole before the cut (a first zstd or lz4 block)
            assert "damaged" in str(exc) and fraction < LOST_AT_MOST
            counts.append(0)
            continue
        n = len(got["stamp_ns"])
        for field, values in got.items():
            np.testing.assert_array_equal(values, full[field][:n], err_msg=field)
        assert n >= (fraction - LOST_AT_MOST) * N
        counts.append(n)
        with pytest.raises(LogReadError, match="damaged"):
            samples(cut, strict=True)
    assert counts == sorted(counts)


@pytest.mark.parametrize("form", FORMS)
def test_sixty_percent_of_the_file_gives_most_samples(logs, form, tmp_path, caplog):
    log, data, _ = logs[form]
    got = read_cut(cut_copy(log, data, 0.6, tmp_path), caplog)
    # uncompressed: what the bytes hold; compressed: up to the last whole zstd or lz4 block
    assert len(got["stamp_ns"]) > 0.5 * N, len(got["stamp_ns"])


@pytest.mark.parametrize("form", ["rosbags", "rosbag2-folder"])
def test_strict_refuses_a_cut_chunk(logs, form, tmp_path):
    log, data, _ = logs[form]
    cut = cut_copy(log, data, 0.6, tmp_path)
    assert_one_line_error(run("simulate", cut, "-o", tmp_path / "out.mcap", "--strict"), "damaged")
    assert not (tmp_path / "out.mcap").exists()


# ---------------------------------------------------------------- the lossless copy


@pytest.fixture(scope="module")
def one_chunk_twin(tmp_path_factory, twin_calibration) -> dict[str, Path]:
    """A calibration, and a twin log (joint states, twin effort, labels) rewritten by rosbags'
    writer: every message in one uncompressed chunk."""
    from rosbags.highlevel import AnyReader

    root = tmp_path_factory.mktemp("one_chunk_twin")
    cal = twin_calibration
    source = build_twin_log(root / "twin.mcap", seed=310, seconds=6.0)
    with AnyReader([source]) as reader:
        msgs = [
            Message(c.topic, c.msgtype, t, reader.deserialize(raw, c.msgtype))
            for c, t, raw in reader.messages()
        ]
    log = write(root / "one_chunk.mcap", "mcap", sorted(msgs, key=lambda m: m.log_time))
    assert chunks(log) == 1
    return {"cal": cal, "log": log}


def messages_by_topic(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    """(log time, bytes) per topic, through rosbags' AnyReader; mcap's reader must agree."""
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    out: dict[str, list[tuple[int, bytes]]] = {}
    with AnyReader([path]) as reader:
        for c, t, raw in reader.messages():
            out.setdefault(c.topic, []).append((t, bytes(raw)))
    with open(path, "rb") as f:
        counts = Counter(ch.topic for _, ch, _ in make_reader(f).iter_messages())
    assert counts == Counter({topic: len(v) for topic, v in out.items()})
    return out


@pytest.mark.parametrize("fraction", [0.35, 0.6, 0.9])
def test_detect_output_of_a_cut_chunk_holds_what_was_read(one_chunk_twin, tmp_path, fraction):
    log = one_chunk_twin["log"]
    data = log.read_bytes()
    cut = cut_copy(log, data, fraction, tmp_path)
    out = tmp_path / "out.mcap"
    result = run("detect", cut, "-c", one_chunk_twin["cal"], "-o", out, "--json")
    assert result.exit_code in (0, 1), result.output
    doc = json.loads(result.stdout)
    assert [w for w in doc["warnings"] if "damaged" in w] != []
    samples_read = doc["logs"][0]["samples"]
    full = messages_by_topic(log)
    copied = messages_by_topic(out)
    n = len(copied["/joint_states"])
    assert samples_read <= n < len(full["/joint_states"])
    assert n > fraction * len(full["/joint_states"]) - 50
    # the input's messages before the cut, unchanged, and the new channels for every sample
    for topic in ("/joint_states", "/twincd/sim_effort"):
        assert copied[topic] == full[topic][: len(copied[topic])]
    assert len(copied["/twincd/score"]) == samples_read


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("fraction", [0.3, 0.7])
def test_the_copy_of_a_cut_chunk_has_the_messages_read(logs, form, fraction, tmp_path, caplog):
    from twincd.io.mcap import AugmentedMcap

    log, data, _ = logs[form]
    cut = cut_copy(log, data, fraction, tmp_path)
    n = len(read_cut(cut, caplog)["stamp_ns"])
    out = tmp_path / "out.mcap"
    with AugmentedMcap(cut, out, partial=True):
        pass
    full = messages_by_topic(storage_file(log))["/joint_states"]
    assert messages_by_topic(out)["/joint_states"] == full[:n]
    with pytest.raises(LogReadError, match="cannot copy"):
        AugmentedMcap(cut, tmp_path / "strict.mcap").__enter__()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([cut.name, "out.mcap"])


def test_a_cut_sqlite3_bag_is_refused_in_one_line(tmp_path):
    bag = write(tmp_path / "bag", "rosbag2-sqlite3", joint_recording(n=400))
    db = next(bag.glob("*.db3"))
    data = db.read_bytes()
    db.write_bytes(data[: len(data) * 6 // 10])
    assert_one_line_error(run("simulate", bag, "-o", tmp_path / "out.mcap"), "malformed")
    assert not (tmp_path / "out.mcap").exists()
