"""Contact-link ground truth (twincd/io/links.py): String messages held onto sample times."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from twincd.errors import LogReadError
from twincd.io.links import LinkMessages, read_links


def test_links_are_held_like_labels():
    msgs = np.array([30, 10, 50], dtype=np.int64)  # out of order on purpose
    held = LinkMessages.of(msgs, ["link4", "", ""]).hold(np.array([5, 10, 29, 30, 49, 50, 99]))
    assert held == ("", "", "", "link4", "link4", "", "")


def test_read_links_from_a_log(tmp_path: Path, twin_log) -> None:  # type: ignore[no-untyped-def]
    from twincd.io.cdr import serialize, typestore
    from twincd.io.mcap import McapLogWriter

    path = tmp_path / "links.mcap"
    string = typestore().types["std_msgs/msg/String"]
    with McapLogWriter(path) as out:
        ch = out.add_topic("/collision_link", "std_msgs/msg/String")
        for when, link in ((100, ""), (200, "link5"), (300, "")):
            out.write(ch, when, serialize(string(data=link), "std_msgs/msg/String"))
        other = out.add_topic("/other", "std_msgs/msg/Bool")
        out.write(other, 100, b"\x00\x01\x00\x00\x01")
    times = np.array([150, 250, 350], dtype=np.int64)
    assert read_links(path, "/collision_link", times) == ("", "link5", "")
    assert read_links(path, "/nothing", times) is None
    with pytest.raises(LogReadError, match="not std_msgs/msg/String"):
        read_links(path, "/other", times)
