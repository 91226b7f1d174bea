"""The numpy CDR decoders and bulk encoders give exactly rosbags' values and bytes, and take
their fast path (``cdr.STATS`` counts it: a silently broken fast path fails these tests)."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from twincd.io import cdr
from twincd.io.cdr import (
    BOOL,
    FLOAT64,
    JOINT_STATE,
    CdrStats,
    bool_block,
    decode_bools,
    decode_joint_states,
    float64_block,
    header,
    joint_state_block,
    typestore,
)

JointState = typestore().types[JOINT_STATE]
Bool = typestore().types[BOOL]


def message(stamp_ns, names, pos, vel=(), eff=(), frame_id=""):
    return JointState(
        header=header(stamp_ns, frame_id),
        name=list(names),
        position=np.asarray(pos, dtype=np.float64),
        velocity=np.asarray(vel, dtype=np.float64),
        effort=np.asarray(eff, dtype=np.float64),
    )


def decode_all(msgs, little_endian=True):
    """Serialise with rosbags, decode in groups of equal length; (decoded per message, stats)."""
    datas = [
        bytes(typestore().serialize_cdr(m, JOINT_STATE, little_endian=little_endian)) for m in msgs
    ]
    by_length = defaultdict(list)
    for i, d in enumerate(datas):
        by_length[len(d)].append(i)
    stats = CdrStats()
    decoded = [None] * len(msgs)
    for idx in by_length.values():
        payloads = np.stack([np.frombuffer(datas[i], np.uint8) for i in idx])
        for g in decode_joint_states(payloads, stats):
            for j, r in enumerate(g.rows):
                decoded[idx[r]] = (
                    g.names,
                    g.stamp_ns[j],
                    g.position[j],
                    g.velocity[j],
                    g.effort[j],
                )
    return decoded, stats


def assert_same(msgs, decoded):
    for m, (names, stamp, pos, vel, eff) in zip(msgs, decoded):
        ref = typestore().deserialize_cdr(typestore().serialize_cdr(m, JOINT_STATE), JOINT_STATE)
        assert names == tuple(ref.name)
        assert stamp == ref.header.stamp.sec * 1_000_000_000 + ref.header.stamp.nanosec
        for got, want in ((pos, ref.position), (vel, ref.velocity), (eff, ref.effort)):
            np.testing.assert_array_equal(got, want)
            assert got.tobytes() == want.tobytes()  # bit-identical, NaN payloads included


def mixed_messages(n=300, seed=0):
    rng = np.random.default_rng(seed)
    msgs = []
    for i in range(n):
        k = int(rng.integers(0, 9))
        names = [f"j{'x' * int(rng.integers(0, 4))}{j}" for j in range(k)]
        vel = rng.normal(size=k) if rng.random() < 0.5 else ()
        eff = rng.normal(size=k) if rng.random() < 0.5 else ()
        frame = "f" * int(rng.integers(0, 9))
        pos = rng.normal(size=k)
        if k and i % 17 == 0:
            pos[0] = np.nan
        msgs.append(message(int(rng.integers(0, 2**60)), names, pos, vel, eff, frame))
    return msgs


@pytest.mark.parametrize("little_endian", [True, False], ids=["little", "big"])
def test_decoder_equals_rosbags_on_mixed_layouts(little_endian):
    msgs = mixed_messages()
    decoded, stats = decode_all(msgs, little_endian)
    assert_same(msgs, decoded)
    assert stats.fast == len(msgs) and stats.fallback == 0


def test_rosbags_writes_big_endian():
    data = bytes(
        typestore().serialize_cdr(message(1, ["a"], [1.0]), JOINT_STATE, little_endian=False)
    )
    assert data[:2] == b"\x00\x00"


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.integers(0, 2**31 - 1),
            st.integers(0, 999_999_999),
            st.text("abcdefgh_", max_size=7),
            st.integers(0, 5),
            st.booleans(),
            st.booleans(),
        ),
        min_size=1,
        max_size=20,
    ),
    st.booleans(),
)
def test_decoder_property(spec, little_endian):
    rng = np.random.default_rng(len(spec))
    msgs = []
    for sec, nanosec, frame, k, has_vel, has_eff in spec:
        names = [f"n{frame}{j}" for j in range(k)]
        msgs.append(
            message(
                sec * 1_000_000_000 + nanosec,
                names,
                rng.normal(size=k),
                rng.normal(size=k) if has_vel else (),
                rng.normal(size=k) if has_eff else (),
                frame,
            )
        )
    decoded, stats = decode_all(msgs, little_endian)
    assert_same(msgs, decoded)
    assert stats.fast == len(msgs)


def test_ragged_messages_keep_their_widths():
    msgs = [message(i, ["a", "b", "c"], [1.0, 2.0], [], [3.0] * 4) for i in range(5)]
    decoded, stats = decode_all(msgs)
    assert_same(msgs, decoded)
    assert stats.fast == 5


def test_frame_id_text_does_not_split_layouts():
    # a counter in frame_id (same length) keeps every row on one layout
    msgs = [message(i, ["a", "b"], [i, -i], frame_id=f"cam{i % 10}") for i in range(40)]
    payloads = np.stack(
        [np.frombuffer(typestore().serialize_cdr(m, JOINT_STATE), np.uint8) for m in msgs]
    )
    stats = CdrStats()
    (group,) = decode_joint_states(payloads, stats)
    np.testing.assert_array_equal(group.position[:, 1], -np.arange(40))
    assert stats.fast == 40


def test_same_length_different_names_split_into_groups():
    msgs = [message(i, ["ab", "c"] if i % 2 else ["c", "ab"], [i, -i]) for i in range(10)]
    payloads = np.stack(
        [np.frombuffer(typestore().serialize_cdr(m, JOINT_STATE), np.uint8) for m in msgs]
    )
    groups = decode_joint_states(payloads)
    assert [g.names for g in groups] == [("c", "ab"), ("ab", "c")]
    np.testing.assert_array_equal(groups[1].rows, [1, 3, 5, 7, 9])
    np.testing.assert_array_equal(groups[1].position[:, 0], [1, 3, 5, 7, 9])


def test_padding_bytes_do_not_matter():
    msgs = [message(i, ["a"], [float(i)], [], [], frame_id="xy") for i in range(4)]
    payloads = np.stack(
        [np.frombuffer(typestore().serialize_cdr(m, JOINT_STATE), np.uint8) for m in msgs]
    ).copy()
    payloads[2, 19] = 0xAB  # the byte after frame_id "xy\0" aligns the name count: padding
    stats = CdrStats()
    (group,) = decode_joint_states(payloads, stats)
    np.testing.assert_array_equal(group.position[:, 0], [0, 1, 2, 3])
    assert stats.fast == 4


def test_rows_the_parser_refuses_go_to_rosbags(monkeypatch):
    msgs = mixed_messages(60, seed=3)
    real = cdr._parse_layout
    calls = []

    def refuse_every_other(row):
        calls.append(1)
        return None if len(calls) % 2 else real(row)

    monkeypatch.setattr(cdr, "_parse_layout", refuse_every_other)
    decoded, stats = decode_all(msgs)
    assert_same(msgs, decoded)
    assert stats.fallback > 0 and stats.fast + stats.fallback == len(msgs)


def test_corrupt_payloads_are_an_error_not_a_guess():
    good = bytes(typestore().serialize_cdr(message(5, ["ab"], [1.5]), JOINT_STATE))
    odd = bytearray(good)
    odd[16] = ord("x")  # frame_id "" loses its NUL: neither parser accepts it
    payloads = np.stack([np.frombuffer(good, np.uint8), np.frombuffer(bytes(odd), np.uint8)])
    with pytest.raises(Exception, match="terminator"):
        decode_joint_states(payloads)


def test_module_stats_count_too():
    cdr.STATS.reset()
    payloads = joint_state_block([1, 2, 3], ["a"], [[1.0], [2.0], [3.0]], None, None)
    decode_joint_states(payloads)
    assert cdr.STATS.fast == 6 and cdr.STATS.fallback == 0


def test_bools():
    values = np.array([True, False, True, True, False])
    payloads = np.stack(
        [
            np.frombuffer(typestore().serialize_cdr(Bool(data=bool(v)), BOOL), np.uint8)
            for v in values
        ]
    )
    stats = CdrStats()
    np.testing.assert_array_equal(decode_bools(payloads, stats), values)
    assert stats.fast == 5
    odd = payloads.copy()
    odd[1, 4] = 2  # not a CDR bool rosbags would write; rosbags reads it as True
    np.testing.assert_array_equal(decode_bools(odd, stats), [1, 1, 1, 1, 0])
    assert stats.fallback == 1
    big = np.frombuffer(
        typestore().serialize_cdr(Bool(data=True), BOOL, little_endian=False), np.uint8
    )
    assert decode_bools(big[None, :]).tolist() == [True]


# ---------------------------------------------------------------- encoders


@pytest.mark.parametrize(
    ("names", "widths"),
    [
        ([], (0, 0, 0)),
        (["x"], (1, 1, 1)),
        ([f"joint{i}" for i in range(1, 8)], (7, 7, 7)),
        (["a", "bb", "ccc"], (3, 0, 3)),
        (["a", "bb", "ccc"], (3, 3, 0)),
        (["a", "bb"], (2, 0, 0)),
    ],
)
def test_joint_state_block_is_rosbags_bytes_on_the_fast_path(names, widths):
    rng = np.random.default_rng(len(names))
    n = 25
    stamps = 1_700_000_000_000_000_000 + rng.integers(0, 10**12, n)
    values = [rng.normal(size=(n, w)) for w in widths]
    stats = CdrStats()
    block = joint_state_block(stamps, names, *values, stats=stats)
    assert stats.fast == n and stats.fallback == 0  # fails if the template path broke
    for i in range(n):
        ref = typestore().serialize_cdr(
            message(int(stamps[i]), names, *(v[i] for v in values)), JOINT_STATE
        )
        assert block[i].tobytes() == bytes(ref)


def test_joint_state_block_falls_back_and_says_so(monkeypatch):
    # a wrong layout (as if the template logic broke) must be caught by the first-row check
    monkeypatch.setattr(cdr, "_joint_state_layout", lambda names, counts: (7, [4, 4, 4]))
    stats = CdrStats()
    block = joint_state_block([5, 6], ["a"], [[1.0], [2.0]], None, None, stats=stats)
    assert stats.fallback == 2 and stats.fast == 0
    ref = typestore().serialize_cdr(message(6, ["a"], [2.0]), JOINT_STATE)
    assert block[1].tobytes() == bytes(ref)


def test_scalar_blocks_are_rosbags_bytes():
    Float64 = typestore().types[FLOAT64]
    values = np.array([0.0, -1.5, np.nan, np.inf, 1e300])
    stats = CdrStats()
    block = float64_block(values, stats)
    assert block.shape == (5, 12) and stats.fast == 5
    for v, row in zip(values, block):
        assert row.tobytes() == bytes(typestore().serialize_cdr(Float64(data=float(v)), FLOAT64))
    flags = np.array([True, False, True])
    block = bool_block(flags, stats)
    assert block.shape == (3, 5) and stats.fast == 8
    for v, row in zip(flags, block):
        assert row.tobytes() == bytes(typestore().serialize_cdr(Bool(data=bool(v)), BOOL))
    assert float64_block([]).shape == (0, 12) and bool_block([]).shape == (0, 5)
