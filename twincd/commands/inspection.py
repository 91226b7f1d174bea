"""Look before running: what a log holds and what twincd will make of it, without the twin.

``inspect_log(path, ...)`` reads a log twice, as ``detect`` would (the same readers, the same
topic and joint rules), and returns an ``Inspection``: the topics and their types, the joint
sets the JointState topic carries (one per publisher layout), which log joints match the robot
model and which are ignored or locked, the sampling (rate, jitter, gaps, duration), per-joint
position and effort ranges against the model's limits, the labels, where the twin's effort
will come from, and every warning the reading and the signal checks give. Nothing is fitted,
simulated or written.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from twincd.defaults import DEFAULT_ROBOT
from twincd.errors import TwincdError
from twincd.io.options import LogOptions
from twincd.signal.bounds import DrivesOff, Dropped
from twincd.signal.moments import Moments
from twincd.types import FloatArray, IntArray

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.io.stream import SampleBlock, TopicReader
    from twincd.signal.bounds import SampleBounds
    from twincd.signal.unwrap import StreamingUnwrap
    from twincd.twin.robot import RobotModel

log = logging.getLogger("twincd")


@dataclass(frozen=True)
class TopicInfo:
    name: str
    type: str


@dataclass(frozen=True)
class JointSet:
    """The JointState messages of one layout (one publisher's name list)."""

    joints: tuple[str, ...]
    messages: int
    with_velocity: int
    with_effort: int
    zero_stamps: int  # header stamp left empty: the log time stands in


@dataclass(frozen=True)
class JointRange:
    """One joint's recorded range (NaN where nothing was read) against the model's limits."""

    name: str
    position_min: float
    position_max: float
    lower_limit: float | None
    upper_limit: float | None
    effort_min: float | None
    effort_max: float | None
    effort_std: float | None


@dataclass(frozen=True)
class Sampling:
    samples: int
    duration_s: float
    rate_hz: float
    jitter_ms: float  # standard deviation of the sampling interval
    gaps: int  # intervals longer than the gap rule's (segments restart after each)
    largest_gap_s: float


@dataclass
class Inspection:
    """What ``inspect_log`` found; ``problem`` is why the log is unusable (None: usable)."""

    path: str
    topics: list[TopicInfo] = field(default_factory=list)
    joint_topic: str | None = None
    joint_sets: list[JointSet] = field(default_factory=list)
    robot: str | None = None
    robot_is_default: bool = False  # no robot given (nor a calibration's): the default assumed
    matched: tuple[str, ...] = ()
    ignored: tuple[str, ...] = ()
    locked: tuple[str, ...] = ()
    sampling: Sampling | None = None
    joints: list[JointRange] = field(default_factory=list)
    label_messages: int = 0
    labelled_fraction: float | None = None
    link_labels: tuple[str, ...] = ()
    twin_source: str | None = None
    # samples dropped as absurd (twincd.signal.bounds), with their times and joints
    absurd: Dropped = field(default_factory=Dropped)
    # messages of a second publisher on the arm's joints (zeros between the live samples)
    other_publisher: int = 0
    # samples left out as drives off (every effort exactly 0), with their spans
    drives_off: DrivesOff = field(default_factory=DrivesOff)
    warnings: list[str] = field(default_factory=list)
    problem: str | None = None
    # the error behind ``problem`` (its traceback is what ``--debug`` shows); not in to_dict
    error: TwincdError | None = field(default=None, repr=False, compare=False)

    @property
    def usable(self) -> bool:
        return self.problem is None

    def to_dict(self) -> dict[str, Any]:
        doc = asdict(replace(self, error=None))
        del doc["error"]
        doc["usable"] = self.usable
        finite: dict[str, Any] = _finite(doc)
        return finite


def _finite(value: Any) -> Any:
    """JSON has no NaN: None in its place."""
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


@contextmanager
def _captured_warnings() -> Iterator[list[str]]:
    """The ``twincd`` logger's warnings held back (``twincd.executors.local.captured_warnings``) and
    nothing less said, whatever level the logger is set to: an inspection returns its warnings
    as data (the caller shows them with the log they belong to)."""
    from twincd.executors.local import captured_warnings

    level = log.level
    log.setLevel(logging.WARNING)
    try:
        with captured_warnings() as lines:
            yield lines
    finally:
        log.setLevel(level)


def inspect_log(
    path: str | Path,
    options: LogOptions | None = None,
    robot: str | None = None,
    calibration: Calibration | None = None,
    strict: bool = False,
    allow_urdf_change: bool = False,
) -> Inspection:
    """What ``path`` holds and what twincd will make of it (see the module's docstring).

    ``robot`` None: the calibration's robot, else the default one, unless the log carries its
    own twin effort (then no model is needed and none is loaded). Errors that make the log
    unusable are recorded in ``problem``; only an unreadable file raises."""
    options = options or (calibration.options if calibration is not None else LogOptions())
    found = Inspection(path=str(path))
    with _captured_warnings() as warnings:
        try:
            _inspect(Path(path), options, robot, calibration, strict, allow_urdf_change, found)
        except TwincdError as exc:
            if not found.topics:  # nothing could be read at all
                raise
            found.problem, found.error = exc.message, exc
        found.warnings = list(dict.fromkeys(warnings))
    return found


def _inspect(
    path: Path,
    options: LogOptions,
    robot: str | None,
    calibration: Calibration | None,
    strict: bool,
    allow_urdf_change: bool,
    found: Inspection,
) -> None:
    from twincd.io.named import require_named
    from twincd.io.stream import TopicReader, choose_topic

    with TopicReader(path, strict=strict) as reader:
        found.topics = [TopicInfo(n, t) for n, t in sorted(reader.topics.items())]
        require_named(options, reader.topics, str(path))
        found.joint_topic = choose_topic(reader.topics, options.topic, str(path))
        has_sim = options.sim_topic in reader.topics
        _read_topics(reader, found, options)
        if reader.damage is not None:
            log.warning("%s: %s", found.path, reader.damage)
        if not found.joint_sets:
            from twincd.errors import LogReadError

            what = f"topic {found.joint_topic} has no readable messages"
            raise LogReadError(what, found.path, "record joint states, or repair the log")
    in_log = tuple(dict.fromkeys(options.rename(n) for s in found.joint_sets for n in s.joints))
    model_name = robot or (calibration.robot_model() if calibration is not None else None)
    if model_name is None and not has_sim:
        model_name = DEFAULT_ROBOT
        found.robot_is_default = True
    found.twin_source = (
        f"the log's own {options.sim_topic}"
        if has_sim
        else f"inverse dynamics of {model_name} (simulated)"
    )
    model = None
    if model_name:
        model = _match_robot(model_name, in_log, calibration, found, has_sim, allow_urdf_change)
    joints = calibration.joint_names if calibration is not None else (found.matched or in_log)
    missing = [j for j in joints if j not in in_log]
    if missing:
        from twincd.errors import JointMismatchError

        raise JointMismatchError(
            f"the log lacks joint(s) {', '.join(missing)}",
            str(path),
            "use a calibration or robot model made for this robot, or a joint map",
        )
    usable, has_effort, why = _read_samples(
        path, options, tuple(joints), strict, model, calibration, found, has_sim
    )
    if found.sampling is not None:
        if calibration is not None and found.sampling.rate_hz > 0:
            from twincd.prepare.notices import judged_period, refuse_gapped

            judged_period(found.path, 1.0 / found.sampling.rate_hz, calibration.period_s)
            intervals = max(found.sampling.samples - 1, 0)
            refuse_gapped(found.path, found.sampling.gaps, intervals, calibration.period_s)
        _warn_if_too_short(found.path, found.sampling, calibration)
    # what fit and detect refuse, refused here alike (the same checks, the same words)
    from twincd.prepare.notices import require_effort, require_enough_samples

    require_effort(has_effort, found.path, found.joint_topic or options.topic, why)
    require_enough_samples(usable, found.path)


def _read_topics(reader: TopicReader, found: Inspection, options: LogOptions) -> None:
    """Joint sets of the JointState topic, and the labels, in one pass."""
    from twincd.io.stream import BoolBatch, JointStateBatch, StringBatch

    sets: dict[tuple[str, ...], list[int]] = {}
    labels = positive = 0
    links: dict[str, None] = {}
    wanted = [found.joint_topic or options.topic, options.label_topic, options.link_topic]
    for topic, batch in reader.batches(wanted):
        if topic == found.joint_topic and isinstance(batch, JointStateBatch):
            counts = sets.setdefault(batch.names, [0, 0, 0, 0])
            counts[0] += len(batch)
            counts[1] += len(batch) if batch.velocity.shape[1] else 0
            counts[2] += len(batch) if batch.effort.shape[1] else 0
            counts[3] += int(np.count_nonzero(batch.stamp_ns == 0))
        elif topic == options.label_topic and isinstance(batch, BoolBatch):
            labels += len(batch)
            positive += int(np.count_nonzero(batch.value))
        elif topic == options.link_topic and isinstance(batch, StringBatch):
            links.update(dict.fromkeys(v for v in batch.values if v))
    found.joint_sets = [
        JointSet(names, *counts) for names, counts in sorted(sets.items(), key=lambda kv: -kv[1][0])
    ]
    found.label_messages = labels
    found.link_labels = tuple(links)


def _match_robot(
    name: str,
    in_log: tuple[str, ...],
    calibration: Calibration | None,
    found: Inspection,
    has_own_twin: bool,
    allow_urdf_change: bool,
) -> RobotModel:
    """The model's joints against the log's: matched, ignored (log only), locked (model only)."""
    from twincd.twin.robot import load_robot

    full = load_robot(name)
    found.robot = full.name
    found.matched = tuple(j for j in full.joint_names if j in in_log)
    found.ignored = tuple(j for j in in_log if j not in full.joint_names)
    found.locked = tuple(j for j in full.joint_names if j not in in_log)
    if found.robot_is_default:  # as fit and detect: the default model only on its own joints
        from twincd.prepare.robots import require_default_robot

        require_default_robot(in_log, found.path)
    if calibration is not None and not has_own_twin:
        from twincd.prepare.robots import check_robot, robot_for

        twin = robot_for(name, calibration.joint_names)
        cal = calibration
        check_robot(twin, cal.dynamics_sha256, cal.urdf_sha256, allow_urdf_change, found.path)
    return load_robot(name, keep=in_log)  # the model detect will use (its warnings too)


class _Ranges:
    """Streaming per-joint ranges and sampling intervals (flat memory at any length)."""

    def __init__(self, width: int, period_s: float | None = None) -> None:
        from twincd.signal import DEFAULT_GAP_FACTOR

        self.gap_factor = DEFAULT_GAP_FACTOR
        self.samples = 0
        self.first: int | None = None
        self.last: int | None = None
        self.period_ns = 0.0  # the log's nominal one, from the first block
        # gaps by the calibration's period, else the log's own (as ``twincd.prepare.stream``)
        self.judged_ns = (period_s or 0.0) * 1e9
        self.steps = np.zeros(3)  # count, sum, sum of squares of the intervals (ns)
        self.gaps = 0
        self.largest_gap_ns = 0
        self.pos = np.full((2, width), np.nan)
        self.eff = np.full((2, width), np.nan)
        self.effort = Moments(0, np.zeros(width), np.zeros(width))  # each joint's own spread

    def add(self, stamp: IntArray, position: FloatArray, effort: FloatArray | None) -> None:
        from twincd.signal import nominal_period

        if not len(stamp):
            return
        if self.first is None:
            self.first = int(stamp[0])
            self.period_ns = nominal_period(stamp) * 1e9
        steps = np.diff(stamp if self.last is None else np.concatenate([[self.last], stamp]))
        steps = steps.astype(np.float64)
        self.steps += (len(steps), steps.sum(), (steps**2).sum())
        judged = self.judged_ns or self.period_ns
        gaps = steps[steps > self.gap_factor * judged] if judged else steps[:0]
        self.gaps += len(gaps)
        self.largest_gap_ns = max(self.largest_gap_ns, int(gaps.max()) if len(gaps) else 0)
        self.last = int(stamp[-1])
        self.samples += len(stamp)
        self.pos[0] = np.fmin(self.pos[0], position.min(axis=0))
        self.pos[1] = np.fmax(self.pos[1], position.max(axis=0))
        if effort is not None:
            effort = effort[np.isfinite(effort).all(axis=1)]
            if len(effort):
                self._add_effort(effort)

    def _add_effort(self, effort: FloatArray) -> None:
        self.eff[0] = np.fmin(self.eff[0], effort.min(axis=0))
        self.eff[1] = np.fmax(self.eff[1], effort.max(axis=0))
        mean = effort.mean(axis=0)
        self.effort += Moments(len(effort), mean, ((effort - mean) ** 2).sum(axis=0))

    def sampling(self) -> Sampling:
        assert self.first is not None and self.last is not None
        count, total, squares = self.steps
        mean = total / count if count else 0.0
        jitter = np.sqrt(max(squares / count - mean**2, 0.0)) if count else 0.0
        return Sampling(
            samples=self.samples,
            duration_s=(self.last - self.first) * 1e-9,
            rate_hz=1e9 / self.period_ns if self.period_ns > 0 else float("nan"),
            jitter_ms=float(jitter) * 1e-6,
            gaps=self.gaps,
            largest_gap_s=self.largest_gap_ns * 1e-9,
        )


def _read_samples(
    path: Path,
    options: LogOptions,
    joints: tuple[str, ...],
    strict: bool,
    model: RobotModel | None,
    calibration: Calibration | None,
    found: Inspection,
    has_sim: bool = False,
) -> tuple[int, bool, str | None]:
    """Ranges, sampling and the signal checks into ``found``; the samples fit and detect would
    use (finite position and effort, and the log's twin effort where it has one), and whether
    the log has measured effort (as the stream decides it)."""
    from twincd.io.stream import iter_blocks
    from twincd.prepare.robots import sample_bounds

    limits = model.position_limits if model is not None else {}
    # the joints as detect reads them: exactly the calibration's, else those of the robot
    # model (or the log) the log has, and what is ignored said as detect says it
    exact = calibration is not None
    known_from = "the robot model" if model is not None else "the topic"
    opened = iter_blocks(
        path,
        options,
        joints=joints if exact else None,
        strict=strict,
        known=None if exact else joints,
        known_from=known_from,
    )
    with opened as stream:
        has_effort, why = stream.has_effort, stream.no_effort_why
        found.joint_topic = stream.topic  # ros2_control's DynamicJointState may stand in
        joints = tuple(stream.joint_names)
        bounds = sample_bounds(model, joints)
        period = calibration.period_s if calibration is not None else None
        scan = _SignalScan(joints, limits, bounds, has_sim, period)
        for block in stream:
            scan.push(block)
        found.absurd = bounds.dropped
        found.drives_off = bounds.off
        found.other_publisher = stream.counts.other_publisher
        bounds.warn(found.path)
    acc = scan.ranges
    if acc.first is None:
        return scan.usable, has_effort, why
    found.sampling = acc.sampling()
    scan.warn(found.path)
    has_effort = int(acc.effort.n) > 0
    found.joints = _joint_ranges(acc, joints, limits, has_effort)
    return scan.usable, has_effort, why


class _SignalScan:
    """What a log's samples tell as they stream, less their absurd ones (``_within_bounds``):
    ranges and sampling (``_Ranges``), the signal checks, the joints without a logged velocity
    and what the derivative of their position would see, and the usable samples."""

    def __init__(
        self,
        joints: tuple[str, ...],
        limits: dict[str, tuple[float, float]],
        bounds: SampleBounds,
        has_sim: bool,
        period_s: float | None = None,
    ) -> None:
        from twincd.signal.checks import SignalChecks

        self.joints = joints
        self.bounds = bounds
        self.has_sim = has_sim
        self.ranges = _Ranges(len(joints), period_s)
        self.checks = SignalChecks(joints, limits)
        self.has_velocity = np.ones(len(joints), dtype=bool)
        self.from_position: bool | None = None  # decided on the first block, as detect does
        self.unwrap: StreamingUnwrap | None = None  # what the derivative of position would see
        self.usable = 0

    def push(self, block: SampleBlock) -> None:
        from twincd.signal import nominal_period
        from twincd.signal.unwrap import StreamingUnwrap

        if self.from_position is None:
            self.from_position = not bool(np.isfinite(block.velocity).all())
        block = _within_bounds(block, self.bounds, self.from_position, self.has_sim)
        if self.unwrap is None and len(block) > 1:
            self.unwrap = StreamingUnwrap(nominal_period(block.stamp_ns))
        if self.unwrap is not None:
            self.unwrap.push(block.stamp_ns, block.position)
        self.ranges.add(block.stamp_ns, block.position, block.effort)
        self.checks.push(block.position, block.effort)
        self.has_velocity &= np.isfinite(block.velocity).all(axis=0)
        if block.effort is not None:
            ok = np.isfinite(block.position).all(axis=1) & np.isfinite(block.effort).all(1)
            if self.has_sim and block.sim_effort is not None:
                ok &= np.isfinite(block.sim_effort).all(axis=1)
            self.usable += int(np.count_nonzero(ok))

    def warn(self, source: str) -> None:
        """The signal checks' warnings, those of velocity taken from position, and of a log
        in which no joint moves."""
        from twincd.prepare.notices import warn_unwrapped, warn_velocity_from_position

        self.checks.warn(source)
        if not self.has_velocity.all():
            velocity = np.where(self.has_velocity, 0.0, np.nan)[None]
            warn_velocity_from_position(source, velocity, self.joints)
            warn_unwrapped(source, self.unwrap, self.joints)
        _warn_if_at_rest(source, self.ranges.pos[1] - self.ranges.pos[0])


def _joint_ranges(
    acc: _Ranges,
    joints: tuple[str, ...],
    limits: dict[str, tuple[float, float]],
    has_effort: bool,
) -> list[JointRange]:
    """Each joint's position range against its limits, and its effort's (with ``has_effort``)."""
    std = np.sqrt(acc.effort.m2 / max(int(acc.effort.n), 1))
    return [
        JointRange(
            name=name,
            position_min=float(acc.pos[0, i]),
            position_max=float(acc.pos[1, i]),
            lower_limit=limits.get(name, (None, None))[0],
            upper_limit=limits.get(name, (None, None))[1],
            effort_min=float(acc.eff[0, i]) if has_effort else None,
            effort_max=float(acc.eff[1, i]) if has_effort else None,
            effort_std=float(std[i]) if has_effort else None,
        )
        for i, name in enumerate(joints)
    ]


def _within_bounds(
    block: SampleBlock, bounds: SampleBounds, from_position: bool, has_sim: bool
) -> SampleBlock:
    """The block less its absurd samples, judged among the finite ones as detect judges them
    (``twincd.signal.bounds``: a recorder glitch's values never reach the ranges or checks)."""
    values = {"position": block.position, "effort": block.effort}
    if not from_position:
        values["velocity"] = block.velocity
    if has_sim:
        values["sim_effort"] = block.sim_effort
    ok = np.ones(len(block), dtype=bool)
    for v in values.values():
        if v is not None:
            ok &= np.isfinite(v).all(axis=1)
    rows = np.flatnonzero(ok)
    keep = bounds.keep(
        block.stamp_ns[rows], **{c: v[rows] for c, v in values.items() if v is not None}
    )
    if keep.all():
        return block
    ok[:] = True
    ok[rows[~keep]] = False
    kept: dict[str, Any] = {}
    for f in fields(block):
        v = getattr(block, f.name)
        kept[f.name] = None if v is None else v[ok]
    return replace(block, **kept)


def _warn_if_at_rest(source: str, spans: FloatArray) -> None:
    """A log in which no joint moves: ``fit`` refuses such logs on their own
    (``twincd.calibration.excitation``); detect and threshold judge them."""
    from twincd.calibration.excitation import REST_POSITION

    if len(spans) and bool(np.all(np.nan_to_num(spans, nan=0.0) < REST_POSITION)):
        log.warning(
            "%s: the arm does not move (every joint's position spans less than %g rad): fit "
            "refuses logs in which no joint moves, since they determine nothing but an offset; "
            "fit on logs of the arm at work",
            source,
            REST_POSITION,
        )


def _warn_if_too_short(source: str, sampling: Sampling, calibration: Calibration | None) -> None:
    """What detect would say of a log near a segment's end throughout."""
    from twincd.prepare.notices import edges_s, warn_short
    from twincd.signal.filters import LowPass

    lowpass = calibration.lowpass if calibration is not None else LowPass()
    period_s = 1.0 / sampling.rate_hz if sampling.rate_hz > 0 else 0.0
    if period_s and sampling.duration_s < edges_s(lowpass, period_s):
        n = sampling.samples
        warn_short(source, n, n, sampling.duration_s, lowpass, period_s)
