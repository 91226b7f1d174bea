"""``twincd.watch``: live collision detection on a source's joint states (``twincd watch``).

``watch(source, calibration, …)`` is an iterator of ``WatchEvent`` (an event, when it closes),
``WatchStatus`` (every ``status_every_s``), ``WatchNotice`` (the source went away or came
back; it is sampled at another rate than the calibration) and, last, one ``WatchSummary``. It
runs the calibration's causal chain (``twincd.detection.online.OnlineDetector``, used in
``twincd.live.detector`` only), so the events and flags are those of ``detect --causal`` on the
same messages. Samples are decoded, reordered and cut into segments as
``twincd.live.samples`` says. How the source's messages are read (topics, the joint map or
prefix, the robot's URDF) is the calibration's by default and may be given, as for every
command; its robot's dynamics are checked by content.

It ends at ``duration_s``, when ``stop`` is set, on KeyboardInterrupt (Ctrl-C, or SIGTERM raised
as one), or after ``idle_timeout_s`` without a message; the summary says which. Errors
(``SourceError``, exit 2): the source cannot be reached, does not advertise the JointState
topic (or carries another type on it), or gives no usable JointState within
``connect_timeout_s``.

Latency (``WatchStatus.latency_ms``, ``WatchSummary.latency_ms``): from the moment a message
was taken from the transport to the moment its score was computed, i.e. the reorder window's
hold (at most the window after its arrival, even when no newer sample comes), a coarse grid's
hold and the chain's time, over the samples scored as they came (not those scored only
because a segment or the session ended). The causal filter's own delay (how late a step shows
in the score, ``filter_delay_ms``) comes on top.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict, deque
from collections.abc import Generator, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from twincd.detection.events import Event
from twincd.errors import CalibrationError
from twincd.io.cdr import BOOL, JOINT_STATE, STRING
from twincd.live.connect import open_source
from twincd.live.detector import LiveDetector, Scored
from twincd.live.items import WatchEvent, WatchItem, WatchNotice, WatchStatus, WatchSummary
from twincd.live.samples import REORDER_WINDOW_NS, JointDecoder, Reorder, Sample, Segments
from twincd.live.source import Arrival, Connection, Source, SourceError, SourceLost, Wanted
from twincd.prepare.frames import Frame

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.io.options import LogOptions
    from twincd.live.record import SessionRecorder

__all__ = ["CONNECT_TIMEOUT_S", "watch"]

CONNECT_TIMEOUT_S = 10.0
_POLL_S = 0.05
# recent samples by stamp, for the session file: their scores may come a few pushes later (a
# coarse grid holds them), and events are recorded at the log time of their last sample
_KEEP_SAMPLES = 30_000
# samples of the first segment whose stamps tell the source's rate (a second at 100 Hz)
_RATE_SAMPLES = 100
# a source whose first intervals are all gaps at the calibration's period is refused after
# this many (``_Session._checked``): sampled over 5 × slower, nothing of it could be judged
_GAP_CHECK = 10


class _Latency:
    """Arrival → score latencies: the last interval's, and a bounded window for the summary."""

    def __init__(self) -> None:
        self.recent: list[float] = []
        self.window: deque[float] = deque(maxlen=100_000)
        self.max = 0.0

    def add(self, received_ns: Sequence[int], now_ns: int) -> None:
        ms = [(now_ns - r) * 1e-6 for r in received_ns]
        self.recent += ms
        self.window.extend(ms)
        if ms:
            self.max = max(self.max, max(ms))

    def interval(self) -> float:
        value = float(np.median(self.recent)) if self.recent else float("nan")
        self.recent = []
        return value

    def summary(self) -> dict[str, float]:
        if not self.window:
            return {}
        p50, p95, p99 = np.percentile(np.asarray(self.window), [50, 95, 99])
        return {
            "p50": round(float(p50), 3),
            "p95": round(float(p95), 3),
            "p99": round(float(p99), 3),
            "max": round(self.max, 3),
        }


def _load(calibration: Calibration | str | Path) -> Calibration:
    from twincd.calibration import Calibration

    cal = Calibration.given(calibration)
    if not cal.lowpass.causal:
        raise CalibrationError(
            "the calibration was fitted with the zero-phase filter, which needs the future of "
            "every sample; watching live needs a causal one",
            cal.source or "calibration",
            "fit and threshold a calibration with the causal filter",
            option="causal",
        )
    cal.require_threshold()
    return cal


class _Session:
    """The state of one watch: detector, reorder buffer, segments, recorder, counts."""

    def __init__(
        self,
        cal: Calibration,
        source_name: str,
        options: LogOptions,
        robot: str | None,
        reorder_ns: int,
        recorder: SessionRecorder | None,
    ) -> None:
        self.source_name = source_name
        self.detector = LiveDetector(cal, source_name, twin=recorder is not None, robot=robot)
        self.topic, self.label_topic = options.topic, options.label_topic
        # what a recorded session keeps of the other topics: labels and contact links, by type
        self.extra = {options.label_topic: BOOL, options.link_topic: STRING}
        self.sim_topic = options.sim_topic if self.detector.use_sim else None
        names = self.detector.joint_names
        self.decoder = JointDecoder(names, options.rename)
        self.sim_decoder = JointDecoder(names)
        self.sim: dict[int, np.ndarray] = {}
        self.reorder = Reorder(reorder_ns)
        self.segments = Segments()
        self.recorder = recorder
        self.threshold = float(cal.require_threshold().value)
        self.recent: OrderedDict[int, Sample] = OrderedDict()  # kept when recording
        self.latency = _Latency()
        self.received: deque[int] = deque()  # pushed samples not scored yet: their arrival
        self.first_stamps: list[int] = []  # the first segment's, for the rate (``rate_notice``)
        self.held: list[Sample] = []  # the first samples, while their intervals are all gaps
        self.rate_checked = False  # an interval within the calibration's gap rule has come
        self.rate_said = False
        self.events = 0
        self.collision = False
        self.last_score = float("nan")
        self.scored_in_interval = 0

    def wanted(self) -> list[Wanted]:
        wanted = [Wanted(self.topic, JOINT_STATE)]
        if self.sim_topic:
            wanted.append(Wanted(self.sim_topic, JOINT_STATE))
        wanted += [Wanted(topic, msgtype, required=False) for topic, msgtype in self.extra.items()]
        return wanted

    def take(self, arrivals: Sequence[Arrival]) -> tuple[int, list[Event]]:
        """Messages in; (usable samples, closed events) out."""
        usable = 0
        events: list[Event] = []
        for a in arrivals:
            if self.recorder is not None:
                msgtype = self.extra.get(a.topic, JOINT_STATE)
                self.recorder.message(a.topic, msgtype, a.log_time_ns, a.data)
            if a.topic == self.sim_topic:
                s = self.sim_decoder.decode(a.data, a.log_time_ns, a.received_ns)
                if s is not None:
                    self.sim[s.stamp_ns] = s.effort
                continue
            if a.topic != self.topic:
                continue
            sample = self.decoder.decode(a.data, a.log_time_ns, a.received_ns)
            if sample is None:
                continue
            usable += 1
            if self.segments.jumped(sample):
                events += self._push(self.reorder.drain())
                events += self._finish(restart=True)
                self.reorder.reset()
                self.sim = {k: v for k, v in self.sim.items() if k >= sample.stamp_ns}
            self.reorder.add(sample)
        complete = (lambda stamp: stamp in self.sim) if self.sim_topic else None
        events += self._push(self.reorder.ready(complete, time.monotonic_ns()))
        if self.recorder is not None:
            self.recorder.tick()
        return usable, events

    def _checked(self, samples: list[Sample]) -> list[Sample]:
        """``samples`` once the source's first intervals show that it can be judged: while
        every interval so far is a gap at the calibration's period they are held, and after
        ``_GAP_CHECK`` such intervals the source is refused as ``detect`` refuses such a log
        (``refuse_gapped``), before any of its samples is scored."""
        if self.rate_checked:
            return samples
        from twincd.prepare.notices import gap_ns, refuse_gapped

        self.held += samples
        period = self.detector.period_s
        steps = np.diff([s.stamp_ns for s in self.held])
        if not period or np.any(steps <= gap_ns(period)):
            self.rate_checked = True
            held, self.held = self.held, []
            return held
        if len(steps) >= _GAP_CHECK:
            refuse_gapped(self.source_name, len(steps), len(steps), period)
        return []

    def _push(self, samples: list[Sample]) -> list[Event]:
        samples = self._checked(samples)
        if not samples:
            return []
        joints = len(self.detector.joint_names)
        stamps = np.array([s.stamp_ns for s in samples], dtype=np.int64)
        pos = np.array([s.position for s in samples]).reshape(-1, joints)
        vel = np.array([s.velocity for s in samples]).reshape(-1, joints)
        eff = np.array([s.effort for s in samples]).reshape(-1, joints)
        sim = None
        if self.sim_topic:
            nan = np.full(joints, np.nan)
            sim = np.array([self.sim.pop(s.stamp_ns, nan) for s in samples]).reshape(-1, joints)
            last = int(stamps[-1])
            for k in [k for k in self.sim if k <= last]:
                del self.sim[k]
        if self.recorder is not None:
            for s in samples:
                self.recent[s.stamp_ns] = s
            while len(self.recent) > _KEEP_SAMPLES:
                self.recent.popitem(last=False)
        log_times = np.array([s.log_time_ns for s in samples], dtype=np.int64)
        if len(self.first_stamps) < _RATE_SAMPLES and self.segments.count == 1:
            self.first_stamps += stamps[: _RATE_SAMPLES - len(self.first_stamps)].tolist()
        self.received.extend(s.received_ns for s in samples)
        scored = self.detector.push(stamps, pos, vel, eff, sim, log_times)
        # the samples scored now (a coarse grid may hold the newest back): their latency
        arrived = [self.received.popleft() for _ in range(len(scored.stamp_ns))]
        self.latency.add(arrived, time.monotonic_ns())
        self._record(scored)
        return self._events(scored)

    def _finish(self, restart: bool) -> list[Event]:
        """The end of a segment (``restart``) or of the session: what the detector still
        holds is scored because the stream ended, not as it came: no latency is counted."""
        scored = self.detector.restart() if restart else self.detector.finish()
        self.received.clear()
        self._record(scored)
        return self._events(scored)

    def rate_notice(self, elapsed_s: float) -> WatchNotice | None:
        """Once the first samples are in: a notice when the source is sampled at another
        rate than the calibration (``twincd.prepare.notices.other_rate``, as ``detect`` says
        it of a log)."""
        if self.rate_said or len(self.first_stamps) < _RATE_SAMPLES:
            return None
        from twincd.prepare.notices import other_rate
        from twincd.signal import nominal_period

        self.rate_said = True
        own = nominal_period(np.sort(np.asarray(self.first_stamps, dtype=np.int64)))
        text = other_rate(self.source_name, own, self.detector.period_s)
        return None if text is None else WatchNotice("rate", text, elapsed_s)

    def _record(self, scored: Scored) -> None:
        n = len(scored.stamp_ns)
        if n:
            finite = scored.score[np.isfinite(scored.score)]
            if len(finite):
                self.last_score = float(finite[-1])
            self.scored_in_interval += n
        if self.recorder is None:
            return
        if scored.twin.n:
            self.recorder.twin(scored.twin)
        if not n:
            return
        # results are matched to the pushed samples by stamp (a detector may hold some back),
        # and a skipped sample has no score to write
        rows = [self.recent.get(int(t)) for t in scored.stamp_ns]
        ok = np.array([r is not None for r in rows], dtype=bool) & np.isfinite(scored.score)
        kept = [r for r, good in zip(rows, ok, strict=True) if good and r is not None]
        if not kept:
            return
        joints = len(self.detector.joint_names)
        frame = Frame(
            {
                "stamp_ns": scored.stamp_ns[ok],
                "log_time_ns": np.array([r.log_time_ns for r in kept], dtype=np.int64),
                "position": np.array([r.position for r in kept]).reshape(-1, joints),
                "velocity": np.array([r.velocity for r in kept]).reshape(-1, joints),
                "residual": scored.residual[ok],
                "score": scored.score[ok],
                "flag": scored.flag[ok],
            }
        )
        self.recorder.scored(frame)

    def _events(self, scored: Scored) -> list[Event]:
        events = scored.events
        if events:
            self.events += len(events)
            self.collision = True
            if self.recorder is not None:
                times = [self._log_time(e.end_ns) for e in events]
                self.recorder.events(events, times)
        return events

    def _log_time(self, stamp_ns: int) -> int:
        sample = self.recent.get(stamp_ns)
        return stamp_ns if sample is None else sample.log_time_ns

    def end(self) -> list[Event]:
        events = self._push(self.reorder.drain())
        events += self._finish(restart=False)
        return events


def watch(
    source: str | Source,
    calibration: Calibration | str | Path,
    *,
    topic: str | None = None,
    label_topic: str | None = None,
    link_topic: str | None = None,
    sim_topic: str | None = None,
    joint_map: Mapping[str, str] | None = None,
    joint_prefix: str | None = None,
    robot: str | None = None,
    record: str | Path | None = None,
    force: bool = False,
    duration_s: float | None = None,
    idle_timeout_s: float | None = None,
    connect_timeout_s: float = CONNECT_TIMEOUT_S,
    reorder_ns: int = REORDER_WINDOW_NS,
    status_every_s: float = 1.0,
    stop: threading.Event | None = None,
) -> Iterator[WatchItem]:
    """Watch ``source`` (``ws://HOST:PORT``, ``ros2``, or a ``Source``) with ``calibration``
    (see the module's docstring). ``topic``, ``label_topic``, ``link_topic``, ``sim_topic``,
    ``joint_map``, ``joint_prefix`` and ``robot`` (its URDF) default to the calibration's, as
    for every command; the label and link topics are subscribed to when they are published,
    for ``record``: the session MCAP (``-o``)."""
    from twincd.prepare.settings import SetupOptions

    cal = _load(calibration)
    # how the source's messages are read: the calibration's way unless given, as for every
    # command; the robot model found (beside the calibration, by its package) when not given
    setup = SetupOptions(
        topic=topic,
        label_topic=label_topic,
        link_topic=link_topic,
        sim_topic=sim_topic,
        joint_map=joint_map,
        joint_prefix=joint_prefix,
        robot=robot,
    ).resolve(cal)
    src = open_source(source, connect_timeout_s) if isinstance(source, str) else source
    recorder: SessionRecorder | None = None
    session = None
    try:
        if record is not None:
            from twincd.live.record import SessionRecorder

            recorder = SessionRecorder(Path(record), src.name, cal.joint_names, force)
        session = _Session(cal, src.name, setup.options, setup.robot, reorder_ns, recorder)
        yield from _run(
            src, session, duration_s, idle_timeout_s, connect_timeout_s, status_every_s, stop
        )
    except BaseException:
        if recorder is not None:
            recorder.abandon()
        raise
    finally:
        src.close()
    if recorder is not None:
        recorder.close()


def _run(
    src: Source,
    s: _Session,
    duration_s: float | None,
    idle_timeout_s: float | None,
    connect_timeout_s: float,
    status_every_s: float,
    stop: threading.Event | None,
) -> Iterator[WatchItem]:
    """The session on a source opened: its items until it ends, the events still open and
    the summary."""
    start = time.monotonic()
    src.start(s.wanted(), connect_timeout_s)
    deadline = start + connect_timeout_s
    ended = "stopped"
    error = ""
    connection = _Reconnects(src, start)
    try:
        yield from _first_samples(s, connection, deadline, connect_timeout_s, stop)
        ended = yield from _watching(
            s, connection, duration_s, idle_timeout_s, status_every_s, stop
        )
    except KeyboardInterrupt:
        ended = "interrupted"
    except SourceLost as exc:
        ended = "source lost"
        error = exc.message
    for e in s.end():
        yield WatchEvent(e, s.segments.count)
    yield _summary(s, ended, round(time.monotonic() - start, 3), error, connection.back)


def _first_samples(
    s: _Session,
    connection: _Reconnects,
    deadline: float,
    connect_timeout_s: float,
    stop: threading.Event | None,
) -> Iterator[WatchItem]:
    """Until the first usable JointState (or ``stop``): a ``SourceError`` when none came by
    ``deadline``."""
    src = connection.src
    samples = 0
    while samples == 0:
        left = deadline - time.monotonic()
        if left <= 0:
            c = s.decoder.counts
            seen = (
                f"{c.messages} message(s) arrived, none with all of the calibrated joints "
                f"({', '.join(s.detector.joint_names)})"
                if c.messages
                else "no message arrived"
            )
            raise SourceError(
                f"waited {connect_timeout_s:g} s for a usable JointState on {s.topic}: {seen}",
                src.name,
                "check that the robot publishes there, and its joint names",
                option="topic",
            )
        if stop is not None and stop.is_set():
            break
        got, events = s.take(src.receive(min(left, _POLL_S)))
        samples += got
        for e in events:
            yield WatchEvent(e, s.segments.count)
        yield from connection.notices()


def _watching(
    s: _Session,
    connection: _Reconnects,
    duration_s: float | None,
    idle_timeout_s: float | None,
    status_every_s: float,
    stop: threading.Event | None,
) -> Generator[WatchItem, None, str]:
    """The session after its first sample, until ``stop``, ``duration_s`` or ``idle_timeout_s``
    (from the start of the session): its events, notices and status; returns how it ended."""
    src, start = connection.src, connection.start
    last_message = time.monotonic()
    last_status = start
    while not (stop is not None and stop.is_set()):
        now = time.monotonic()
        if duration_s is not None and now - start >= duration_s:
            return "duration"
        if idle_timeout_s is not None and now - last_message >= idle_timeout_s:
            return "idle"
        arrivals = src.receive(_POLL_S)
        if arrivals:
            last_message = time.monotonic()
        _, events = s.take(arrivals)
        for e in events:
            yield WatchEvent(e, s.segments.count)
        yield from connection.notices()
        rate = s.rate_notice(round(time.monotonic() - start, 3))
        if rate is not None:
            yield rate
        if now - last_status >= status_every_s:
            yield _status(s, start, now - last_status)
            last_status = now
    return "stopped"


def _summary(s: _Session, ended: str, elapsed_s: float, error: str, back: int) -> WatchSummary:
    """The session's summary once it ``ended`` (after ``elapsed_s``; ``back``: the times the
    source came back)."""
    counts = s.detector
    dec = s.decoder.counts
    return WatchSummary(
        samples=counts.samples,
        events=s.events,
        collision=s.collision,
        ended=ended,
        elapsed_s=elapsed_s,
        segments=s.segments.count,
        late=s.reorder.late,
        duplicates=s.reorder.duplicates,
        unusable=dec.other_joints + dec.partial + dec.ragged + dec.undecodable,
        skipped=counts.skipped,
        judged=counts.judged,
        flagged=counts.flagged,
        latency_ms=s.latency.summary(),
        filter_delay_ms=round(s.detector.filter_delay_s * 1e3, 3),
        error=error,
        reconnects=back,
    )


class _Reconnects:
    """The source's connection notices (``Source.notices``) as ``WatchNotice`` items, and how
    often it came back."""

    def __init__(self, src: Source, start: float) -> None:
        self.src = src
        self.start = start
        self.back = 0
        self._gone_at: float | None = None

    def notices(self) -> Iterator[WatchNotice]:
        for change in self.src.notices():
            yield self._notice(change)

    def _notice(self, change: Connection) -> WatchNotice:
        elapsed = round(change.at - self.start, 3)
        name = self.src.name
        if not change.up:
            self._gone_at = change.at
            text = (
                f"{name}: the source went away ({change.reason}); waiting for it to come back "
                "(the samples it does not send are not judged)"
            )
            return WatchNotice("source gone", text, elapsed)
        self.back += 1
        away = None if self._gone_at is None else round(change.at - self._gone_at, 3)
        gone = "" if away is None else f" after {away:g} s"
        return WatchNotice("source back", f"{name}: the source is back{gone}", elapsed, away)


def _status(s: _Session, start: float, interval: float) -> WatchStatus:
    rate = s.scored_in_interval / interval if interval > 0 else 0.0
    s.scored_in_interval = 0
    return WatchStatus(
        elapsed_s=round(time.monotonic() - start, 3),
        samples=s.detector.samples,
        rate_hz=round(rate, 1),
        latency_ms=s.latency.interval(),
        score=s.last_score,
        threshold=s.threshold,
        events=s.events,
        segment=s.segments.count,
    )
