"""The block JointState encoder gives exactly rosbags' bytes, on its fast path."""

from __future__ import annotations

import numpy as np
import pytest

from twincd.io import cdr as messages
from twincd.io.cdr import joint_state_cdr, typestore


@pytest.mark.parametrize(
    "names",
    [
        [],
        ["x"],
        ["joint1", "joint2"],
        [f"joint{i}" for i in range(1, 8)],
        ["a", "bb", "ccc", "dddd"],
    ],
)
def test_every_row_matches_rosbags(names, monkeypatch):
    monkeypatch.setattr(messages, "_BLOCK", 16)  # several blocks on a small input
    rng = np.random.default_rng(len(names))
    n = 40
    stamps = 1_700_000_000_000_000_000 + rng.integers(0, 10**12, n)
    values = [rng.normal(size=(n, len(names))) for _ in range(3)]
    values[0][3] = np.nan
    messages.STATS.reset()
    fast = list(joint_state_cdr(stamps, names, *values))
    assert len(fast) == n
    # every row came from the numpy template, none from rosbags (a broken fast path fails here)
    assert (messages.STATS.fast, messages.STATS.fallback) == (n, 0)
    for i in range(n):
        msg = typestore().deserialize_cdr(fast[i], "sensor_msgs/msg/JointState")
        assert list(msg.name) == names
        assert msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec == stamps[i]
        ref = messages._joint_state_rosbags(int(stamps[i]), names, *(v[i] for v in values))
        assert fast[i] == ref


def test_no_rows_no_messages():
    assert list(joint_state_cdr(np.zeros(0, np.int64), ["a"], *(np.zeros((0, 1)),) * 3)) == []
