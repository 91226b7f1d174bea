"""A log that is not plain MCAP copied into an MCAP output through rosbags.

rosbag2 sqlite3 (and rosbag2 MCAP whose files or messages rosbag2 compressed): raw CDR bytes
pass through; publish time is the log time (sqlite3 keeps one). ROS 1 bags: messages are
converted to ROS 2 CDR with rosbags' own converter (the container format forces it); times are
kept. Every channel gets a ``ros2msg`` schema and its recorded QoS (the default where none).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from twincd.errors import LogReadError, TwincdError
from twincd.io.cdr import typestore
from twincd.io.mcap.channels import DEFAULT_QOS, QOS_KEY
from twincd.io.mcap.messages import BATCH
from twincd.io.mcap.output import McapOutput
from twincd.io.sources import open_reader

__all__ = ["copy_via_rosbags"]


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
