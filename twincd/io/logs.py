"""Log I/O: find logs, read joint states, labels and simulated effort into arrays (DESIGN §1).

Every log form goes through rosbags' AnyReader (rosbag2 sqlite3 or MCAP folders, bare ``.mcap``
files, ROS 1 ``.bag``), reading only the topics asked for. A log becomes one ``JointStates``:
plain per-log arrays, no global state, so per-log work stays pure and can run anywhere.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from twincd.errors import JointMismatchError, LogReadError, TopicError, UsageError
from twincd.io.cdr import TYPESTORE
from twincd.signal.derivatives import differentiate

log = logging.getLogger("twincd")

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

JOINT_STATE = "sensor_msgs/msg/JointState"
BOOL = "std_msgs/msg/Bool"
DEFAULT_TOPIC = "/joint_states"
DEFAULT_LABEL_TOPIC = "/collision_flag"
DEFAULT_SIM_TOPIC = "/twincd/sim_effort"
OWN_PREFIX = "/twincd/"
TWIN_SUFFIX = ".twin.mcap"  # what `simulate` writes beside a log


@dataclass(frozen=True)
class LogOptions:
    """How to read joint states from a log; recorded in the calibration by ``fit``."""

    topic: str = DEFAULT_TOPIC
    label_topic: str = DEFAULT_LABEL_TOPIC
    sim_topic: str = DEFAULT_SIM_TOPIC
    joint_map: Mapping[str, str] | None = None


def parse_joint_map(text: str | None) -> dict[str, str]:
    """``old=new,old2=new2`` to a dict; empty or None gives {}."""
    if not text:
        return {}
    mapping: dict[str, str] = {}
    for item in text.split(","):
        old, sep, new = item.partition("=")
        if not sep or not old.strip() or not new.strip():
            raise UsageError(
                f"bad joint map entry {item!r}", "--joint-map", "write it as old=new,old2=new2"
            )
        mapping[old.strip()] = new.strip()
    return mapping


@dataclass(frozen=True)
class JointStates:
    """One log's joint states as arrays, sorted by time, one row per sample.

    ``stamp_ns`` is the header stamp (the log time where the stamp is zero); ``log_time_ns`` is
    when the recorder got the message. Columns follow ``joint_names``.
    """

    source: str
    topic: str
    joint_names: tuple[str, ...]
    stamp_ns: IntArray
    log_time_ns: IntArray
    position: FloatArray
    velocity: FloatArray
    effort: FloatArray | None
    velocity_from_position: bool = False
    labels: BoolArray | None = None
    sim_effort: FloatArray | None = None

    def __len__(self) -> int:
        return len(self.stamp_ns)

    @property
    def t_s(self) -> FloatArray:
        """Seconds since the first stamp (subtracted in integer ns to keep precision)."""
        seconds: FloatArray = (self.stamp_ns - self.stamp_ns[0]).astype(np.float64) * 1e-9
        return seconds

    def select(self, names: Sequence[str]) -> JointStates:
        """The same log restricted to ``names``, in that order."""
        missing = [n for n in names if n not in self.joint_names]
        if missing:
            raise JointMismatchError(
                f"joints {', '.join(missing)} are not in the log",
                self.source,
                "check --robot, --topic and --joint-map",
            )
        cols = [self.joint_names.index(n) for n in names]

        def pick(a: FloatArray | None) -> FloatArray | None:
            return None if a is None else a[:, cols]

        return replace(
            self,
            joint_names=tuple(names),
            position=self.position[:, cols],
            velocity=self.velocity[:, cols],
            effort=pick(self.effort),
            sim_effort=pick(self.sim_effort),
        )


# ---------------------------------------------------------------- finding logs


def _is_rosbag2_dir(path: Path) -> bool:
    return path.is_dir() and (path / "metadata.yaml").is_file()


def expand_logs(paths: Iterable[str | Path]) -> list[Path]:
    """Every log the arguments stand for: files, rosbag2 folders, and folders of logs."""
    found: list[Path] = []
    for raw in paths:
        path = Path(raw)
        if not path.exists():
            raise LogReadError("no such file or folder", str(path), "check the path")
        if path.is_file() or _is_rosbag2_dir(path):
            found.append(path)
            continue
        below = _without_twin_copies(sorted(_logs_below(path)))
        if not below:
            raise LogReadError(
                "no logs in folder", str(path), "give .mcap, .bag or rosbag2 folders"
            )
        found.extend(below)
    return found


def _logs_below(folder: Path) -> Iterator[Path]:
    for sub in folder.iterdir():
        if _is_rosbag2_dir(sub):
            yield sub  # the folder stands for its storage files
        elif sub.is_dir():
            yield from _logs_below(sub)
        elif sub.suffix in (".mcap", ".bag"):
            yield sub


def _without_twin_copies(paths: list[Path]) -> list[Path]:
    """Drop ``x.twin.mcap`` files (``simulate`` outputs) whose source log ``x`` is also here,
    so a folder does not count the same run twice; name a twin file to use it."""
    names = {p.name for p in paths}
    kept = []
    for p in paths:
        stem = p.name.removesuffix(TWIN_SUFFIX)
        if p.name.endswith(TWIN_SUFFIX) and {stem, f"{stem}.mcap", f"{stem}.bag"} & names:
            log.info("skipping %s: the simulate output of a log in the same folder", p)
            continue
        kept.append(p)
    return kept


# ---------------------------------------------------------------- reading


def open_reader(path: Path) -> Any:
    """An opened rosbags AnyReader, or one clear LogReadError."""
    from rosbags.highlevel import AnyReader

    if path.is_file() and path.stat().st_size == 0:
        raise LogReadError("empty file", str(path), "record the log again or remove it")
    if path.is_file() and path.suffix == ".db3":
        raise LogReadError(
            "a bare .db3 file is not a log", str(path), "give the rosbag2 folder that holds it"
        )
    try:
        # Humble-era rosbag2 bags store no message definitions: bring the standard ones
        reader = AnyReader([path], default_typestore=TYPESTORE)
        reader.open()
    except Exception as exc:  # the I/O edge: every reader failure becomes one line
        raise LogReadError(
            f"cannot read log: {_first_line(exc)}",
            str(path),
            "check that it is a rosbag2 folder, an MCAP file or a ROS 1 bag and not truncated",
        ) from exc
    return reader


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def choose_topic(reader: Any, wanted: str, source: str) -> str:
    """The JointState topic to read (DESIGN §1: fall back to the only JointState topic)."""
    topics = {c.topic: c.msgtype for c in reader.connections}
    if wanted in topics:
        if topics[wanted] != JOINT_STATE:
            raise TopicError(
                f"topic {wanted} is {topics[wanted]}, not {JOINT_STATE}", source, "pick --topic"
            )
        return wanted
    candidates = sorted(
        t for t, m in topics.items() if m == JOINT_STATE and not t.startswith(OWN_PREFIX)
    )
    if len(candidates) == 1:
        log.warning(
            "topic %s not in %s; using its only JointState topic %s", wanted, source, candidates[0]
        )
        return str(candidates[0])
    if not candidates:
        raise TopicError(
            f"no {JOINT_STATE} topic (wanted {wanted})",
            source,
            "record joint states or pick --topic",
        )
    raise TopicError(
        f"topic {wanted} not found and several JointState topics exist: {', '.join(candidates)}",
        source,
        "pick one with --topic",
    )


@dataclass
class _Rows:
    """Values gathered while reading one JointState topic, as the messages hold them.

    Per message only references are kept (rosbags already decodes arrays to numpy); the
    (N, joints) matrices are assembled once per name layout at the end (``matrix``).
    """

    stamp: list[int]
    log_time: list[int]
    layout: list[int]  # index into ``columns`` per message
    position: list[FloatArray]
    velocity: list[FloatArray]
    effort: list[FloatArray]
    columns: list[NDArray[np.intp]]  # per layout: the union column of each message name

    def matrix(self, field: str, width: int) -> FloatArray:
        """(N, width) values of ``field``; NaN where a message lacks a joint or the array."""
        values: list[FloatArray] = getattr(self, field)
        out = np.full((len(values), width), np.nan)
        layout = np.asarray(self.layout)
        filled = np.fromiter((len(v) > 0 for v in values), dtype=bool, count=len(values))
        for k, cols in enumerate(self.columns):
            rows = np.flatnonzero((layout == k) & filled)
            if len(rows):
                out[rows[:, None], cols[None, :]] = np.stack([values[i] for i in rows])
        return out


def _iter_messages(
    reader: Any, connections: list[Any], source: str
) -> Iterator[tuple[Any, int, Any]]:
    try:
        for conn, log_time, raw in reader.messages(connections=connections):
            yield conn, log_time, reader.deserialize(raw, conn.msgtype)
    except LogReadError:
        raise
    except (Exception, struct.error) as exc:  # damaged storage surfaces mid-iteration
        raise LogReadError(
            f"log is damaged: {_first_line(exc)}", source, "re-record it or cut the damaged part"
        ) from exc


def _read_joint_topic(
    reader: Any, topic: str, source: str, joint_map: Mapping[str, str]
) -> tuple[tuple[str, ...], _Rows]:
    conns = [c for c in reader.connections if c.topic == topic]
    names: list[str] = []
    column: dict[str, int] = {}
    rows = _Rows([], [], [], [], [], [], [])
    layout_of: dict[tuple[str, ...], int] = {}
    where = f"{source}, {topic}"
    for _conn, log_time, msg in _iter_messages(reader, conns, source):
        key = tuple(msg.name)
        k = layout_of.get(key)
        if k is None:
            for n in key:
                mapped = joint_map.get(n, n)
                if mapped not in column:
                    column[mapped] = len(names)
                    names.append(mapped)
            k = layout_of[key] = len(rows.columns)
            rows.columns.append(np.array([column[joint_map.get(n, n)] for n in key], np.intp))
        n = len(key)
        pos, vel, eff = msg.position, msg.velocity, msg.effort
        if len(pos) != n or len(vel) not in (0, n) or len(eff) not in (0, n):
            raise LogReadError(
                f"ragged JointState: {n} names but {len(pos)} position, {len(vel)} velocity "
                f"and {len(eff)} effort values",
                f"{where} at log time {log_time}",
                "fix the publisher; every filled array must match `name`",
            )
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        rows.stamp.append(stamp if stamp != 0 else log_time)
        rows.log_time.append(log_time)
        rows.layout.append(k)
        rows.position.append(pos)
        rows.velocity.append(vel)
        rows.effort.append(eff)
    return tuple(names), rows


def _zero_order_hold(event_ns: IntArray, event_values: BoolArray, sample_ns: IntArray) -> BoolArray:
    """Each sample takes the value of the latest event at or before it (False before any)."""
    order = np.argsort(event_ns, kind="stable")
    event_ns, event_values = event_ns[order], event_values[order]
    idx = np.searchsorted(event_ns, sample_ns, side="right") - 1
    held = np.zeros(len(sample_ns), dtype=bool)
    ok = idx >= 0
    held[ok] = event_values[idx[ok]]
    return held


def read_log(path: str | Path, options: LogOptions | None = None) -> JointStates:
    """Read one log's joint states, labels and (if present) simulated effort."""
    options = options or LogOptions()
    path = Path(path)
    source = str(path)
    joint_map = dict(options.joint_map or {})
    reader = open_reader(path)
    try:
        topic = choose_topic(reader, options.topic, source)
        names, rows = _read_joint_topic(reader, topic, source, joint_map)
        if not rows.stamp:
            raise LogReadError(f"topic {topic} has no messages", source, "record joint states")
        width = len(names)
        stamp = np.asarray(rows.stamp, dtype=np.int64)
        log_time = np.asarray(rows.log_time, dtype=np.int64)
        position = rows.matrix("position", width)
        # samples missing a joint (another publisher on the topic) cannot be used; they go
        # before duplicate stamps are resolved, so they never displace a complete sample
        complete = np.isfinite(position).all(axis=1)
        if not complete.all():
            log.warning(
                "%s: dropping %d sample(s) that do not carry every joint",
                source,
                int((~complete).sum()),
            )
        candidates = np.flatnonzero(complete)
        order = candidates[np.argsort(stamp[candidates], kind="stable")]
        keep = np.ones(len(order), dtype=bool)
        keep[1:] = np.diff(stamp[order]) != 0  # exact duplicate stamps: keep the first
        sel = order[keep]
        stamp, log_time, position = stamp[sel], log_time[sel], position[sel]
        velocity = rows.matrix("velocity", width)[sel]
        effort = rows.matrix("effort", width)[sel]
        if len(stamp) == 0:
            raise LogReadError("no sample carries every joint", source, "pick --topic")
        t_s = (stamp - stamp[0]).astype(np.float64) * 1e-9
        from_position = not np.isfinite(velocity).all()
        if from_position:
            velocity = np.where(np.isfinite(velocity), velocity, differentiate(t_s, position))
        has_effort = bool(np.isfinite(effort).all())
        labels = _read_labels(reader, options.label_topic, log_time, source)
        sim = _read_sim_effort(reader, options.sim_topic, names, stamp, source, joint_map)
    finally:
        reader.close()
    return JointStates(
        source=source,
        topic=topic,
        joint_names=names,
        stamp_ns=stamp,
        log_time_ns=log_time,
        position=position,
        velocity=velocity,
        effort=effort if has_effort else None,
        velocity_from_position=from_position,
        labels=labels,
        sim_effort=sim,
    )


def _read_labels(reader: Any, topic: str, log_time: IntArray, source: str) -> BoolArray | None:
    conns = [c for c in reader.connections if c.topic == topic]
    if not conns:
        return None
    if conns[0].msgtype != BOOL:
        raise TopicError(
            f"label topic {topic} is {conns[0].msgtype}, not {BOOL}", source, "pick --label-topic"
        )
    times: list[int] = []
    values: list[bool] = []
    for _c, t, msg in _iter_messages(reader, conns, source):
        times.append(t)
        values.append(bool(msg.data))
    # labels are held onto the joint states' log times: both come from the recorder's clock
    return _zero_order_hold(np.asarray(times, np.int64), np.asarray(values, bool), log_time)


def _read_sim_effort(
    reader: Any,
    topic: str,
    names: tuple[str, ...],
    stamp: IntArray,
    source: str,
    joint_map: Mapping[str, str],
) -> FloatArray | None:
    conns = [c for c in reader.connections if c.topic == topic and c.msgtype == JOINT_STATE]
    if not conns:
        return None
    sim = np.full((len(stamp), len(names)), np.nan)
    column = {n: i for i, n in enumerate(names)}
    for _c, t, msg in _iter_messages(reader, conns, source):
        s = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec or t
        row = int(np.searchsorted(stamp, s))
        if row >= len(stamp) or stamp[row] != s:
            continue
        for n, e in zip(msg.name, msg.effort):
            col = column.get(joint_map.get(n, n))
            if col is not None:
                sim[row, col] = e
    return sim
