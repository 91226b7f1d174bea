"""Live detection (contract: Live detection): samples pushed one at a time or in blocks of any size.

The detector runs the calibration's causal chain, built by ``twincd.prepare.chain.build_chain`` as
for a log on disk — causal Savitzky–Golay derivative (the window ends at the newest sample), RNEA,
causal low-pass filter — and the same scoring and event stages as batch detection, so
pushing a log in any chunking gives the scores, flags and events of ``twincd detect`` with that
(causal) calibration. Every stage keeps bounded state: a few samples of derivative context, the
filter's second-order sections, one open event.

Start-up: the first samples of the stream, and of every stretch after a gap (an interval over 5
periods), are judged like the others, with the noise the filter's start at rest on one sample
leaves there (``twincd.signal.edges``: 3.7× the settled noise at the first sample of the
critically damped 3 Hz filter of ``fit --causal``, within 0.1 % of it after 0.3 s);
``counts.judged`` counts the samples that were judged.

Latency: on logs sampled at up to a few hundred hertz no stage holds a sample back, so each
push returns a score for every sample it carried, but at a segment's start: its first samples
wait for the causal derivative's window (8 samples), which the filter starts after
(``OnlineDetector.start_hold_s``). Sampled far faster than the filter keeps
(``twincd.prepare.grid``: 1 kHz), the twin and the filter run on a coarse grid, and a sample waits
for its grid cell to end: a push returns the samples whose cells have ended (the held ones of
earlier pushes first), each sample at most ``OnlineDetector.hold_s`` (one grid period, ≈ 5 ms
at 1 kHz under 3 Hz) late; ``flush`` scores the held ones when a stream ends. What delays a
detection is the causal low-pass filter itself: a step in effort shows in the score after
its group delay, ``OnlineDetector.latency_s`` (≈ 75 ms for the default 3 Hz, order-2
filter). An event is reported when it closes: once its score has stayed below the release
level for longer than the merge gap (``EventRules``, defaults 50 % of the way from μ to the
threshold and 300 ms), so ``out.events`` comes that long after a push ends; the flag of each
sample (score ≥ threshold) comes with its score.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from twincd.defaults import DEFAULT_ROBOT
from twincd.detection.detect import FlagCount, ScoringStage
from twincd.detection.events import Event, EventRules
from twincd.errors import CalibrationError, DataError, JointMismatchError
from twincd.prepare.chain import BuiltChain, JointLayout, build_chain
from twincd.prepare.frames import Frame
from twincd.prepare.robots import check_robot, robot_for, sample_bounds
from twincd.types import BoolArray, FloatArray, IntArray

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.twin.robot import RobotModel


@dataclass(frozen=True)
class OnlineResult:
    """The results of one push, one row per sample it released: every pushed sample, in the
    order pushed, unless a coarse grid holds the newest ones back (``OnlineDetector.hold_s``):
    they come first in a later push's result, or in ``flush``'s."""

    score: FloatArray  # (N,); NaN for a sample that was skipped (non-finite, or not newer)
    flag: BoolArray  # (N,)
    residual: FloatArray  # (N, joints)
    events: list[Event]  # events that closed with this push
    stamp_ns: IntArray | None = None  # (N,) the stamps of these rows, as pushed
    # the twin's effort of the rows that went down the chain (skipped ones left out): a frame of
    # ``stamp_ns``, ``position``, ``velocity`` (differentiated where the pushes had none) and
    # ``sim_effort``, when the chain twins each sample (None: the pushes carry the log's own
    # twin effort, or the twin runs on a coarse grid's cells)
    twin: Frame | None = None


class OnlineDetector:
    """Causal collision detection on live samples with a causal calibration.

    ``push(stamp_ns, position, velocity, effort)`` takes arrays of shape (N,) and (N, joints)
    (joints in the calibration's order; ``velocity`` may be None: it is then differentiated
    from position), returns an ``OnlineResult``; ``close()`` ends an open event. Samples with a
    non-finite value, an absurd one (``twincd.signal.bounds``: the rule batch detection applies,
    from the same limits; said in one warning when the stream ends) or a stamp not after the
    previous one are skipped (score NaN, flag False) and counted in ``skipped``.

    ``period_s`` overrides the calibration's sampling period (needed for calibration files that
    do not record it). ``sim_effort=True`` expects the twin's effort in every push (a log with
    its own ``/twincd/sim_effort``) instead of computing it with the robot model.

    ``robot``: the robot model (an example-robot-data name, a ``package://`` URI or a URDF
    path) when not the calibration's (``Calibration.robot_model``: the recorded one, found
    where it is, beside the calibration file or by its package). Its dynamics must be those
    the calibration was fitted with (``twincd.prepare.robots.check_robot``): other ones are
    refused unless ``allow_urdf_change`` (then said once). ``source`` names the stream in
    messages (default: the calibration). ``rules``: how flags become events (default:
    ``EventRules()``, as ``detect``).
    """

    def __init__(
        self,
        calibration: Calibration,
        period_s: float | None = None,
        sim_effort: bool | None = None,
        threads: int = 1,
        allow_urdf_change: bool = False,
        source: str | None = None,
        rules: EventRules | None = None,
        robot: str | None = None,
    ) -> None:
        calibration.require_threshold()
        where = calibration.source or "calibration"
        if not calibration.lowpass.causal:
            raise CalibrationError(
                "the calibration was fitted with the zero-phase filter, which needs the future "
                "of every sample; live detection needs a causal one",
                where,
                "fit and threshold a calibration with the causal filter",
            )
        period = period_s or calibration.period_s
        if not period:
            raise CalibrationError(
                "the calibration records no sampling rate",
                where,
                "re-fit it with this twincd version, or give period_s",
            )
        self.calibration = calibration
        self.period_s = float(period)
        self.joint_names = calibration.joint_names
        self.use_sim = (not calibration.simulated) if sim_effort is None else sim_effort
        # the twin's effort, or (identified models) the regressor, needs the robot model
        self.robot: RobotModel | None = None
        if not self.use_sim or calibration.model.features.regressor:
            model = calibration.robot_model(robot) or DEFAULT_ROBOT
            self.robot = robot_for(model, tuple(self.joint_names))
            check_robot(
                self.robot,
                calibration.dynamics_sha256,
                calibration.urdf_sha256,
                allow_urdf_change,
                source or where,
            )
            undriven = [n for n in self.joint_names if n not in self.robot.joint_names]
            if undriven:
                raise JointMismatchError(
                    f"calibrated joint(s) {', '.join(undriven)} are not driven by the robot model",
                    where,
                    "fit the calibration on the arm's joints only (the robot model's), or "
                    "detect with the log's own twin effort",
                )
        # absurd samples are dropped by the rule batch detection applies, from the same limits
        # (the calibration's robot model, when it names one)
        limits = self.robot
        if limits is None and calibration.robot is not None:
            limits = robot_for(calibration.robot, tuple(self.joint_names))
        self._limits = limits
        self.bounds = sample_bounds(limits, self.joint_names)
        self._source = source or where
        self._threads = threads
        self._chain: BuiltChain | None = None
        # pushed rows not released yet: their stamps and whether they went down the chain
        self._held: deque[tuple[IntArray, BoolArray]] = deque()
        self._fill = False
        self._scoring = ScoringStage(calibration, rules=rules)
        self._last_stamp: int | None = None
        self.samples = 0
        self.skipped = 0
        self.taken = np.zeros(0, dtype=bool)  # which rows of the last push went down the chain

    @property
    def latency_s(self) -> float:
        """Group delay of the causal filter at low frequency: how late a step shows."""
        from scipy import signal

        sos = self.calibration.lowpass.sos(1.0 / self.period_s)
        b, a = signal.sos2tf(sos)
        _, delay = signal.group_delay((b, a), w=[1e-3], fs=1.0 / self.period_s)
        return float(delay[0]) * self.period_s

    @property
    def hold_s(self) -> float:
        """The longest a sample waits in the chain before it is scored: one grid period where
        the twin and the filter run on a coarse grid (``twincd.prepare.grid``), else 0."""
        from twincd.prepare.grid import grid_period_ns

        cal = self.calibration
        grid = grid_period_ns(cal.lowpass.cutoff_hz, self.period_s, cal.fast_hz)
        return 0.0 if grid is None else grid * 1e-9

    @property
    def start_hold_s(self) -> float:
        """The longest a sample waits at a segment's start (a stream's first samples, or those
        after a gap): the causal derivative's window, whose samples the filter starts after
        (``twincd.prepare.chain.warmup_samples``), on the grid's period when there is one,
        plus ``hold_s``."""
        from twincd.prepare.chain import warmup_samples

        step = self.hold_s or self.period_s
        return warmup_samples(True, self._fill) * step + self.hold_s

    @property
    def pending(self) -> int:
        """Pushed samples not in any result yet (held by a coarse grid)."""
        return sum(len(stamps) for stamps, _ in self._held)

    def _build(self, fill: bool) -> BuiltChain:
        """The calibration's chain on pushed columns (the calibration's joints, in its order)."""
        names = self.joint_names
        robot = self.robot
        layout = JointLayout(names, names if robot is None else robot.joint_names, names)
        twin = None if self.use_sim else robot
        model = self._scoring.model
        regressor = robot if model.features.regressor else None
        built = build_chain(
            self.calibration.lowpass,
            model.features,
            layout=layout,
            period_s=self.period_s,
            twin=twin,
            fill_velocity=fill,
            regressor=regressor,
            threads=self._threads,
            model=model,
            fast_hz=self.calibration.fast_hz,
            jump=self.calibration.score.jump,
        )
        self._scoring.regressor_mask = built.regressor_mask
        self._scoring.regressor_theta = model.features.theta
        return built

    def _columns(self, values: object, n: int, what: str) -> FloatArray:
        arr = np.asarray(values, dtype=np.float64)
        if arr.ndim == 1 and n == 1:
            arr = arr[None, :]
        if arr.shape != (n, len(self.joint_names)):
            raise DataError(
                f"{what} has shape {arr.shape}, expected ({n}, {len(self.joint_names)})",
                "OnlineDetector.push",
                f"give one column per joint in the calibration's order: "
                f"{', '.join(self.joint_names)}",
            )
        return arr

    def push(
        self,
        stamp_ns: Sequence[int] | IntArray | int,
        position: object,
        velocity: object | None,
        effort: object,
        sim_effort: object | None = None,
    ) -> OnlineResult:
        stamps = np.atleast_1d(np.asarray(stamp_ns, dtype=np.int64))
        n = len(stamps)
        pos = self._columns(position, n, "position")
        eff = self._columns(effort, n, "effort")
        vel = (
            np.full_like(pos, np.nan)
            if velocity is None
            else self._columns(velocity, n, "velocity")
        )
        sim = None
        if self.use_sim:
            if sim_effort is None:
                raise DataError(
                    "this detector compares with the log's own twin effort",
                    "OnlineDetector.push",
                    "pass sim_effort, or build the detector with sim_effort=False",
                )
            sim = self._columns(sim_effort, n, "sim_effort")
        if self._chain is None:
            self._fill = velocity is None or not bool(np.isfinite(vel).all())
            self._chain = self._build(self._fill)
        ok = np.isfinite(pos).all(axis=1) & np.isfinite(eff).all(axis=1)
        if not self._fill:
            ok &= np.isfinite(vel).all(axis=1)
        if sim is not None:
            ok &= np.isfinite(sim).all(axis=1)
        ok &= _increasing(stamps, self._last_stamp)
        rows = np.flatnonzero(ok)
        values = {"position": pos[rows], "effort": eff[rows]}
        if not self._fill:
            values["velocity"] = vel[rows]
        if sim is not None:
            values["sim_effort"] = sim[rows]
        keep = self.bounds.keep(stamps[rows], **values)
        if not keep.all():
            ok[rows[~keep]] = False
            rows = rows[keep]
        self.taken = ok
        frame = Frame(
            {
                "stamp_ns": stamps[rows],
                "log_time_ns": stamps[rows],
                "position": pos[rows],
                "velocity": vel[rows],
                "effort": eff[rows],
                "sim_effort": None if sim is None else sim[rows],
            }
        )
        self._held.append((stamps, ok))
        out = self._chain.chain.push(frame)
        if len(rows):
            self._last_stamp = int(stamps[rows[-1]])
        self.samples += len(rows)
        self.skipped += n - len(rows)
        return self._release(out)

    def flush(self) -> OnlineResult:
        """End of the stream: the samples a coarse grid still holds, scored, and the events
        closed by them or still open. A later push starts a new stream."""
        self.bounds.warn(self._source)
        self.bounds = sample_bounds(self._limits, self.joint_names)  # a new stream's
        if self._chain is None:
            return self._release(Frame(), self._scoring.finish())
        out = self._release(self._chain.chain.finish(), final=True)
        self._last_stamp = None
        return out

    def _release(
        self, out: Frame, closing: list[Event] | None = None, final: bool = False
    ) -> OnlineResult:
        """The result of the chain's output ``out`` (the oldest held samples that went down
        the chain, in order): the held rows up to its last one, skipped rows among them, and
        at the end of a stream every held row."""
        if out.n:
            scored, events = self._scoring.push(out)
        else:
            scored, events = out, []
        if final:
            events = events + self._scoring.finish()
        events += closing or []
        stamps, oks = [], []
        left = out.n  # rows that went down the chain, released now
        while self._held:
            batch, ok = self._held[0]
            through = np.cumsum(ok)  # accepted rows up to each row
            # a row goes once every accepted row up to it has come out of the chain
            take = len(ok) if final else int(np.searchsorted(through, left, side="right"))
            left -= int(through[take - 1]) if take else 0
            stamps.append(batch[:take])
            oks.append(ok[:take])
            if take < len(ok):
                self._held[0] = (batch[take:], ok[take:])
                break
            self._held.popleft()
        stamp = np.concatenate(stamps) if stamps else np.zeros(0, dtype=np.int64)
        ok = np.concatenate(oks) if oks else np.zeros(0, dtype=bool)
        if int(ok.sum()) != out.n:
            raise RuntimeError(f"chain returned {out.n} samples for {int(ok.sum())} released")
        n = len(stamp)
        score = np.full(n, np.nan)
        flag = np.zeros(n, dtype=bool)
        resid = np.full((n, len(self.joint_names)), np.nan)
        if out.n:
            score[ok], flag[ok], resid[ok] = scored["score"], scored["flag"], scored["residual"]
        return OnlineResult(score, flag, resid, events, stamp, self._twin_of(out))

    def _twin_of(self, out: Frame) -> Frame | None:
        """The twin's per-sample effort the chain computed for ``out`` (``OnlineResult.twin``)."""
        per_sample = self._chain is not None and self._chain.grid is None
        if self.use_sim or not per_sample or (out.n and "sim_effort" not in out):
            return None
        columns = ("stamp_ns", "position", "velocity", "sim_effort")
        if not out.n:
            joints = len(self.joint_names)
            empty = np.zeros((0, joints))
            return Frame({"stamp_ns": np.zeros(0, np.int64), **{c: empty for c in columns[1:]}})
        return Frame({c: out[c] for c in columns})

    @property
    def velocity_from_position(self) -> bool:
        """True once a push without (finite) velocities made the detector differentiate
        position."""
        return self._fill

    @property
    def counts(self) -> FlagCount:
        """Judged and flagged samples so far."""
        return self._scoring.counts

    def close(self) -> list[Event]:
        """End of the stream: the events of the samples still held (``flush`` for their
        scores) and the event still open, if any."""
        return self.flush().events


def _increasing(stamps: IntArray, last: int | None) -> BoolArray:
    """Samples whose stamp is after every earlier accepted one."""
    if not len(stamps):
        return np.zeros(0, dtype=bool)
    running = np.maximum.accumulate(stamps)
    prev = np.concatenate(([np.iinfo(np.int64).min if last is None else last], running[:-1]))
    if last is not None:
        prev = np.maximum(prev, last)
    ok: BoolArray = stamps > prev
    return ok
