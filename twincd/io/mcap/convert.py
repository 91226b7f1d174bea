"""A log that is not plain MCAP copied into an MCAP output.

rosbag2 sqlite3 (with or without its metadata.yaml, or a bare .db3): read in bulk by the same
reader as every command's (``twincd.io.sqlite3``); raw CDR bytes pass through, each topic's QoS
as the database recorded it; publish time is the log time (sqlite3 keeps one). Through
rosbags: rosbag2 MCAP whose files or messages rosbag2 compressed (raw bytes pass through), and
ROS 1 bags (messages converted to ROS 2 CDR with rosbags' own converter, as the container
format forces; times are kept). Every channel gets a ``ros2msg`` schema and its recorded QoS
(the default where none).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from twincd.errors import LogReadError, TwincdError
from twincd.io.cdr import typestore
from twincd.io.mcap.channels import DEFAULT_QOS, QOS_KEY
from twincd.io.mcap.messages import BATCH
from twincd.io.mcap.output import McapOutput
from twincd.io.sources import open_reader

__all__ = ["copy_sqlite3", "copy_via_rosbags"]


def copy_sqlite3(
    files: Sequence[Path], source: Path, out: McapOutput, replaced: frozenset[str]
) -> None:
    """Every message of the rosbag2 sqlite3 storage ``files`` but those of ``replaced`` topics
    into ``out``, in bulk (the reader every command reads these files with)."""
    from twincd.io.sqlite3 import Sqlite3Storage, SqliteDamage

    try:
        storage = Sqlite3Storage(files)
    except SqliteDamage as exc:
        raise LogReadError(
            f"cannot copy log: {exc}".splitlines()[0], str(source), "check that it is complete"
        ) from exc
    try:
        channels: dict[str, int] = {}
        for topic, msgtype in storage.topics.items():
            if topic in replaced:
                continue
            try:
                msgdef, _ = typestore().generate_msgdef(msgtype, ros_version=2)
            except Exception:  # a custom type the store lacks: bytes still copy
                msgdef = ""
            schema_id = out.schema(msgtype, "ros2msg", msgdef.encode())
            meta = {QOS_KEY: storage.qos.get(topic) or DEFAULT_QOS}
            channels[topic] = out.channel(topic, schema_id, "cdr", meta)
            out.declare(channels[topic])
        for item in storage.read(list(channels)):
            if isinstance(item, int):
                continue
            topic, times, payloads = item
            # sequence 0: sqlite3 does not keep the publisher's
            zero = np.zeros(len(times), dtype=np.uint32)
            out.append(channels[topic], times, np.ascontiguousarray(payloads), None, zero)
    except SqliteDamage as exc:
        raise LogReadError(
            f"cannot copy log: {exc}".splitlines()[0], str(source), "check that it is complete"
        ) from exc
    finally:
        storage.close()


def copy_via_rosbags(source: Path, out: McapOutput, replaced: frozenset[str]) -> None:
    """Every message of ``source`` but those of ``replaced`` topics into ``out``, per message."""
    from rosbags.convert.converter import migrate_bytes
    from rosbags.rosbag2.metadata import dump_qos_v8

    reader = open_reader(source)
    try:
        channels: dict[int, int] = {}
        # ROS 1 messages become ROS 2 ones (Header loses `seq`) with rosbags' own converter,
        # for every type the ROS 2 store knows; others keep the bag's own definition
        to_ros2: dict[str, tuple[Any, str]] = {}
        for conn in reader.connections:
            if conn.topic in replaced:
                continue
            store = reader.typestore
            if not reader.is2 and conn.msgtype in typestore().fielddefs:
                store = typestore()
            to_ros2[conn.msgtype] = (store, conn.msgtype)
            try:
                msgdef, _ = store.generate_msgdef(conn.msgtype, ros_version=2)
            except Exception:  # a custom type an old bag did not describe: bytes still copy
                msgdef = ""
            schema_id = out.schema(conn.msgtype, "ros2msg", msgdef.encode())
            qos = getattr(conn.ext, QOS_KEY, None)
            meta = {QOS_KEY: dump_qos_v8(list(qos)) if qos else DEFAULT_QOS}
            channels[conn.id] = out.channel(conn.topic, schema_id, "cdr", meta)
            out.declare(channels[conn.id])
        wanted = [c for c in reader.connections if c.id in channels]
        cache: dict[str, object] = {}

        def convert(conn: Any, raw: Any) -> bytes:
            store, msgtype = to_ros2[conn.msgtype]
            return bytes(
                migrate_bytes(
                    reader.typestore,
                    store,
                    conn.msgtype,
                    msgtype,
                    cache,
                    raw,
                    src_is2=False,
                    dst_is2=True,
                )
            )

        pending: dict[int, tuple[list[int], list[Any]]] = {cid: ([], []) for cid in channels}

        def flush(conn_id: int) -> None:
            times, payloads = pending[conn_id]
            if times:
                pending[conn_id] = ([], [])
                # sequence 0: neither sqlite3 nor ROS 1 bags keep the publisher's
                zero = np.zeros(len(times), dtype=np.uint32)
                out.append(channels[conn_id], np.array(times, dtype=np.int64), payloads, None, zero)

        is2 = reader.is2
        for conn, log_time, raw in reader.messages(connections=wanted):
            times, payloads = pending[conn.id]
            times.append(log_time)
            payloads.append(raw if is2 else convert(conn, raw))
            if len(times) >= BATCH:
                flush(conn.id)
        for conn_id in pending:
            flush(conn_id)
    except TwincdError:
        raise
    except Exception as exc:  # the I/O edge
        raise LogReadError(
            f"cannot copy log: {exc}".splitlines()[0], str(source), "check that it is complete"
        ) from exc
    finally:
        reader.close()
