"""The .db3 files of a rosbag2 sqlite3 folder read in bulk: SQL in timestamp order, payloads as
numpy arrays.

rosbags reads these files message by message; here ``fetchmany`` hands over thousands of rows
at once and the payloads of equal length become one (n, L) array for the numpy decoders.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from twincd.types import ByteArray, IntArray

__all__ = ["FETCH", "Sqlite3Storage", "SqliteDamage"]

FETCH = 16384  # rows per fetchmany


class SqliteDamage(Exception):
    """A database that cannot be read (any further)."""


class Sqlite3Storage:
    """The .db3 files of one rosbag2 folder, opened read-only."""

    def __init__(self, paths: Sequence[Path]) -> None:
        self.paths = [Path(p) for p in paths]
        self._cons: list[sqlite3.Connection] = []
        self._ids: list[dict[int, str]] = []
        self.topics: dict[str, str] = {}  # topic -> msgtype (CDR topics only)
        self.qos: dict[str, str] = {}  # topic -> offered_qos_profiles as recorded (when kept)
        try:
            for p in self.paths:
                # the reader may run on a prefetch thread; only one thread uses it at a time
                uri = f"{p.resolve().as_uri()}?mode=ro"
                con = sqlite3.connect(uri, uri=True, check_same_thread=False)
                self._cons.append(con)
                ids: dict[int, str] = {}
                for tid, name, msgtype, fmt in con.execute(
                    "SELECT id, name, type, serialization_format FROM topics"
                ):
                    if fmt == "cdr":
                        self.topics.setdefault(str(name), str(msgtype))
                        ids[int(tid)] = str(name)
                self._ids.append(ids)
                self._read_qos(con)
        except sqlite3.Error as exc:
            self.close()
            raise SqliteDamage(str(exc)) from exc

    def _read_qos(self, con: sqlite3.Connection) -> None:
        """Each topic's recorded QoS (rosbag2 keeps it in the topics table since Foxy)."""
        columns = {str(row[1]) for row in con.execute("PRAGMA table_info(topics)")}
        if "offered_qos_profiles" not in columns:
            return
        for name, qos in con.execute("SELECT name, offered_qos_profiles FROM topics"):
            if qos:
                self.qos.setdefault(str(name), str(qos))

    def close(self) -> None:
        for con in self._cons:
            con.close()

    def read(
        self, topics: Sequence[str], fetch: int = FETCH
    ) -> Iterator[tuple[str, IntArray, ByteArray] | int]:
        """``(topic, log times, (n, L) payloads)`` groups in timestamp order, each fetch
        followed by its last timestamp (every earlier message has then been yielded)."""
        for con, ids in zip(self._cons, self._ids):
            wanted = {tid: t for tid, t in ids.items() if t in topics and self.topics[t]}
            if not wanted:
                continue
            marks = ",".join("?" * len(wanted))
            try:
                cur = con.execute(
                    "SELECT topic_id, timestamp, data FROM messages "
                    f"WHERE topic_id IN ({marks}) ORDER BY timestamp, id",
                    list(wanted),
                )
                while rows := cur.fetchmany(fetch):
                    yield from _groups(rows, wanted)
                    yield int(rows[-1][1])
            except sqlite3.Error as exc:
                raise SqliteDamage(str(exc)) from exc


def _groups(
    rows: list[tuple[int, int, bytes]], wanted: dict[int, str]
) -> Iterator[tuple[str, IntArray, ByteArray]]:
    n = len(rows)
    topic_id = np.fromiter((r[0] for r in rows), np.int64, n)
    log_time = np.fromiter((r[1] for r in rows), np.int64, n)
    data = [r[2] for r in rows]
    size = np.fromiter(map(len, data), np.int64, n)
    blob = np.frombuffer(b"".join(data), np.uint8)
    start = np.cumsum(size) - size
    for tid, width in np.unique(np.stack([topic_id, size], 1), axis=0).tolist():
        sel = np.flatnonzero((topic_id == tid) & (size == width))
        if width == 0:
            payloads = np.zeros((len(sel), 0), np.uint8)
        else:
            payloads = np.lib.stride_tricks.sliding_window_view(blob, width)[start[sel]]
        yield wanted[tid], log_time[sel], payloads
