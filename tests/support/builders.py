"""Build tiny logs in every form twincd reads, with rosbags' writers (independent of twincd's).

A recording is a list of ``Message(topic, msgtype, log_time_ns, msg)``; ``write(path, form, msgs)``
stores it as a bare MCAP, a rosbag2 MCAP or sqlite3 folder, or a ROS 1 bag.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

TS = get_typestore(Stores.LATEST)
# ros2_control's control_msgs, which rosbags' stores lack: registered from its .msg text
TS.register(
    {
        **get_types_from_msg("string[] interface_names\nfloat64[] values\n",
                             "control_msgs/msg/InterfaceValue"),
        **get_types_from_msg(
            "std_msgs/Header header\nstring[] joint_names\n"
            "control_msgs/InterfaceValue[] interface_values\n",
            "control_msgs/msg/DynamicJointState",
        ),
    }
)  # fmt: skip
TS1 = get_typestore(Stores.ROS1_NOETIC)
JointState = TS.types["sensor_msgs/msg/JointState"]
Header = TS.types["std_msgs/msg/Header"]
Time = TS.types["builtin_interfaces/msg/Time"]
Bool = TS.types["std_msgs/msg/Bool"]
String = TS.types["std_msgs/msg/String"]

FORMS = ("mcap", "rosbag2-mcap", "rosbag2-sqlite3", "ros1")
SUFFIX = {"mcap": ".mcap", "rosbag2-mcap": "", "rosbag2-sqlite3": "", "ros1": ".bag"}
XARM = tuple(f"joint{i}" for i in range(1, 8))


@dataclass
class Message:
    topic: str
    msgtype: str
    log_time: int
    msg: Any


def header(stamp_ns: int) -> Any:
    return Header(
        stamp=Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000), frame_id=""
    )


def joint_state(stamp_ns: int, names: Sequence[str], pos: Any, vel: Any = (), eff: Any = ()) -> Any:
    return JointState(
        header=header(stamp_ns),
        name=list(names),
        position=np.asarray(pos, dtype=np.float64),
        velocity=np.asarray(vel, dtype=np.float64),
        effort=np.asarray(eff, dtype=np.float64),
    )


def _write_rosbag2(path: Path, plugin: StoragePlugin, msgs: Sequence[Message]) -> None:
    with Writer2(path, version=8, storage_plugin=plugin) as writer:
        conns: dict[str, Any] = {}
        for m in msgs:
            if m.topic not in conns:
                conns[m.topic] = writer.add_connection(m.topic, m.msgtype, typestore=TS)
            writer.write(conns[m.topic], m.log_time, TS.serialize_cdr(m.msg, m.msgtype))


def write(path: Path, form: str, msgs: Sequence[Message]) -> Path:
    """Store ``msgs`` at ``path`` in ``form``; returns the path to hand to twincd."""
    if form == "rosbag2-mcap":
        _write_rosbag2(path, StoragePlugin.MCAP, msgs)
    elif form == "rosbag2-sqlite3":
        _write_rosbag2(path, StoragePlugin.SQLITE3, msgs)
    elif form == "mcap":
        folder = path.with_name(path.name + ".bagdir")
        _write_rosbag2(folder, StoragePlugin.MCAP, msgs)
        shutil.move(next(folder.glob("*.mcap")), path)
        shutil.rmtree(folder)
    elif form == "ros1":
        with Writer1(path) as writer:
            conns1: dict[str, Any] = {}
            for m in msgs:
                if m.topic not in conns1:
                    conns1[m.topic] = writer.add_connection(m.topic, m.msgtype, typestore=TS1)
                data = TS1.serialize_ros1(to_ros1(m.msg), m.msgtype)
                writer.write(conns1[m.topic], m.log_time, data)
    else:
        raise ValueError(form)
    return path


def to_ros1(msg: Any) -> Any:
    """The same message as a ROS 1 (Noetic) object: headers gain their ``seq``."""
    import dataclasses

    cls = TS1.types[msg.__msgtype__]
    values = {}
    for f in dataclasses.fields(cls):
        value = getattr(msg, f.name, 0)
        values[f.name] = to_ros1(value) if hasattr(value, "__msgtype__") else value
    return cls(**values)


def trajectory(
    t_s: np.ndarray, dof: int = 7, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A smooth analytic joint trajectory: sums of sines; exact q, q̇, q̈ at any times."""
    rng = np.random.default_rng(seed)
    amp = rng.uniform(0.2, 0.6, (3, dof))
    freq = rng.uniform(0.1, 0.5, (3, dof))
    phase = rng.uniform(0, 2 * np.pi, (3, dof))
    w = 2 * np.pi * freq
    arg = w[None] * t_s[:, None, None] + phase[None]
    q = (amp[None] * np.sin(arg)).sum(1)
    qd = (amp[None] * w[None] * np.cos(arg)).sum(1)
    qdd = -(amp[None] * w[None] ** 2 * np.sin(arg)).sum(1)
    return q, qd, qdd


def joint_recording(
    n: int = 400,
    period_ns: int = 10_000_000,
    t0_ns: int = 1_700_000_000_000_000_000,
    names: Sequence[str] = XARM,
    effort: np.ndarray | None = None,
    with_velocity: bool = True,
    topic: str = "/joint_states",
    seed: int = 0,
) -> list[Message]:
    """A clean recording: header stamp = log time, a regular period, optional effort rows."""
    t_s = np.arange(n) * period_ns * 1e-9
    q, qd, _ = trajectory(t_s, len(names), seed)
    msgs = []
    for i in range(n):
        stamp = t0_ns + i * period_ns
        eff = effort[i] if effort is not None else ()
        msgs.append(
            Message(
                topic,
                "sensor_msgs/msg/JointState",
                stamp,
                joint_state(stamp, names, q[i], qd[i] if with_velocity else (), eff),
            )
        )
    return msgs


def jittered_xarm_log(
    path: Path,
    seconds: float = 12.0,
    rate_hz: float = 250.0,
    gaps: Sequence[tuple[float, float]] = ((5.0, 5.3),),
    velocity_noise: float = 0.0,
) -> Path:
    """An xArm 7 MCAP log of slow sines with ±15 % stamp jitter, no samples inside ``gaps``
    ((start, end) s: dropouts, which exercise derivative gaps), noisy effort and
    ``velocity_noise`` (std, rad/s) on the velocity."""
    rng = np.random.default_rng(5)
    n = int(seconds * rate_hz)
    t = np.arange(n) / rate_hz + rng.uniform(-0.15, 0.15, n) / rate_hz
    for start, end in gaps:
        t = t[(t < start) | (t > end)]
    w = np.linspace(0.3, 0.9, 7)
    q = 0.4 * np.sin(w * t[:, None])
    qd = 0.4 * w * np.cos(w * t[:, None])
    if velocity_noise:
        qd = qd + velocity_noise * rng.standard_normal(q.shape)
    effort = 5 * np.sin(q) + 0.05 * rng.standard_normal(q.shape)
    stamps = 1_700_000_000_000_000_000 + np.round(t * 1e9).astype(np.int64)
    msgs = [
        Message(
            "/joint_states",
            "sensor_msgs/msg/JointState",
            int(s) + 200_000,
            joint_state(int(s), XARM, q[i], qd[i], effort[i]),
        )
        for i, s in enumerate(stamps)
    ]
    return write(path, "mcap", msgs)


def write_humble_sqlite3(path: Path, msgs: Sequence[Message]) -> Path:
    """A rosbag2 sqlite3 bag as ROS 2 Humble writes it: metadata version 5, no message
    definitions stored (readers must bring their own types)."""
    import sqlite3

    write(path, "rosbag2-sqlite3", msgs)
    db = next(path.glob("*.db3"))
    con = sqlite3.connect(db)
    con.executescript(
        """
        CREATE TABLE topics_old(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
            serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
        INSERT INTO topics_old SELECT id, name, type, serialization_format, offered_qos_profiles
            FROM topics;
        DROP TABLE topics; ALTER TABLE topics_old RENAME TO topics;
        DROP TABLE message_definitions; DROP TABLE metadata; DROP TABLE schema;
        """
    )
    con.commit()
    con.close()
    meta = path / "metadata.yaml"
    text = meta.read_text().replace("version: 8", "version: 5")
    dropped = ("type_description_hash", "RIHS01", "ros_distro")
    lines = [ln for ln in text.splitlines() if not any(d in ln for d in dropped)]
    meta.write_text("\n".join(lines) + "\n")
    return path


# QoS as some recorders write it: no deadline nor lifespan (rosbags' reader needs both)
QOS_WITHOUT_DEADLINE = (
    "- history: 1\n  depth: 10\n  reliability: 1\n  durability: 2\n  liveliness: 1\n"
    "  avoid_ros_namespace_conventions: false"
)


def rewrite_mcap(source: Path, target: Path, writer: str = "mcap", qos: str | None = None) -> Path:
    """The messages of the MCAP ``source`` written again to ``target``: with mcap's own writer
    (``writer="mcap"``; every channel's ``offered_qos_profiles`` replaced by ``qos`` when given)
    or with rosbags' (``writer="rosbags"``, its bare-MCAP form; ``qos`` not supported)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer as McapWriter

    with open(source, "rb") as f:
        reader = make_reader(f)
        items = [(s.name, c.topic, m.log_time, m.publish_time, m.data, c.metadata)
                 for s, c, m in reader.iter_messages(log_time_order=False)]  # fmt: skip
    if writer == "rosbags":
        assert qos is None
        msgs = [Message(t, name, when, TS.deserialize_cdr(data, name))
                for name, t, when, _, data, _ in items]  # fmt: skip
        return write(target, "mcap", msgs)
    with open(target, "wb") as f:
        out = McapWriter(f)
        out.start(profile="ros2", library="test")
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for name, topic, when, published, data, meta in items:
            if name not in schemas:
                text = TS.generate_msgdef(name, ros_version=2)[0]
                schemas[name] = out.register_schema(name, "ros2msg", text.encode())
            if topic not in channels:
                meta = dict(meta)
                if qos is not None:
                    meta["offered_qos_profiles"] = qos
                channels[topic] = out.register_channel(topic, "cdr", schemas[name], meta)
            out.add_message(channels[topic], when, data, published)
        out.finish()
    return target


def write_with_twincd(path: Path, msgs: Sequence[Message]) -> Path:
    """``msgs`` as a bare MCAP written by twincd's own writer (``McapLogWriter``)."""
    from twincd.io.mcap import McapLogWriter

    with McapLogWriter(path) as out:
        channels: dict[str, int] = {}
        for m in msgs:
            if m.topic not in channels:
                channels[m.topic] = out.add_topic(m.topic, m.msgtype)
            out.write(channels[m.topic], m.log_time, TS.serialize_cdr(m.msg, m.msgtype))
    return path


def write_by(writer: str, path: Path, msgs: Sequence[Message]) -> Path:
    """A bare MCAP of ``msgs`` by ``writer``: ``"rosbags"`` or ``"twincd"``."""
    return write(path, "mcap", msgs) if writer == "rosbags" else write_with_twincd(path, msgs)


def messages_of(src: Path) -> list[Message]:
    """Every message of the log ``src``, decoded by rosbags, in log order."""
    from rosbags.highlevel import AnyReader

    with AnyReader([src], default_typestore=TS) as reader:
        return [
            Message(conn.topic, conn.msgtype, log_time, reader.deserialize(raw, conn.msgtype))
            for conn, log_time, raw in reader.messages()
        ]


def rewrite(
    src: Path,
    dst: Path,
    edit: Callable[[Any], object] = lambda m: None,
    form: str = "mcap",
    writer: str = "rosbags",
) -> Path:
    """``src`` written again, by rosbags' writer in ``form`` or (``writer="twincd"``) as a bare
    MCAP by twincd's; ``edit`` changes each JointState message in place, in log order (one for
    which it returns False is left out)."""
    msgs = [
        m
        for m in messages_of(src)
        if m.msgtype != "sensor_msgs/msg/JointState" or edit(m.msg) is not False
    ]
    return write(dst, form, msgs) if writer == "rosbags" else write_with_twincd(dst, msgs)
