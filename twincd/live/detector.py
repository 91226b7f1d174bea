"""The one place where ``watch`` uses ``OnlineDetector``.

Results are matched to samples by stamp: a detector that holds samples back (a coarse time grid
at high rates) returns them later with their ``stamp_ns``, and ``flush`` gives what it still
holds at the end of a segment. A detector whose results carry no stamps returns one row per
pushed sample, at once.

With ``twin=True`` (a recorded session) and a calibration whose twin runs on the robot model,
each pushed sample's τ̂ is returned with the push (``Scored.twin``), for ``/twincd/sim_effort``:
the detector's own, where its chain twins each sample (``OnlineResult.twin``: the twin runs
once per sample); where it twins a coarse grid's cells instead (1 kHz), computed per sample on
the samples the detector takes, through the calibration's chain up to the twin (its causal
derivative, inverse dynamics; no filter, no grid: ``build_chain(..., filtered=False)``, what
``detect --causal`` twins on at 100 Hz).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from twincd.detection.events import Event
from twincd.prepare.frames import Frame
from twincd.types import BoolArray, FloatArray, IntArray

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.detection.online import OnlineDetector
    from twincd.prepare.frames import Chain


@dataclass
class Scored:
    """Scored samples (by stamp), the events that closed, and (``twin``) the twin's effort of
    the samples pushed: a frame with ``stamp_ns``, ``log_time_ns``, ``position``, ``velocity``
    and ``sim_effort``."""

    stamp_ns: IntArray
    score: FloatArray
    flag: BoolArray
    residual: FloatArray
    events: list[Event] = field(default_factory=list)
    twin: Frame = field(default_factory=Frame)

    @staticmethod
    def empty(joints: int) -> Scored:
        return Scored(np.zeros(0, np.int64), np.zeros(0), np.zeros(0, bool), np.zeros((0, joints)))


class LiveDetector:
    """A restartable ``OnlineDetector``: one per segment of the stream."""

    def __init__(
        self,
        calibration: Calibration,
        source: str,
        twin: bool = False,
        robot: str | None = None,
    ) -> None:
        self.calibration = calibration
        self.source = source
        self.robot = robot  # the robot model when not the calibration's (OnlineDetector's)
        self._detector = self._new()
        self.joint_names: list[str] = list(self._detector.joint_names)
        self.use_sim: bool = bool(self._detector.use_sim)
        self.twin = twin and not self.use_sim  # τ̂ to compute for the session file
        self._twin_chain: Chain | None = None
        self._log_times: dict[int, int] = {}  # stamp → log time of samples not out yet
        self._warm_up()
        self.samples = 0
        self.skipped = 0
        self.flagged = 0
        self._judged_before = 0  # judged samples of the segments that ended

    def _new(self) -> OnlineDetector:
        from twincd.detection.online import OnlineDetector

        return OnlineDetector(self.calibration, source=self.source, robot=self.robot)

    def _warm_up(self) -> None:
        """What the first push would import and compute (the filter's edge factors, its
        delay; a few hundred ms), done before the session starts instead of on the first
        sample's time."""
        from twincd.signal.bands import slow_band
        from twincd.signal.edges import edge_profile

        edge_profile(slow_band(self.calibration.lowpass), self._detector.period_s)
        self.filter_delay_s = float(self._detector.latency_s)  # the causal filter's group delay

    @property
    def period_s(self) -> float:
        """The sampling period the chain filters at: the calibration's."""
        return float(self._detector.period_s)

    @property
    def judged(self) -> int:
        """Samples judged (past each segment's start-up span) over every segment."""
        return self._judged_before + int(self._detector.counts.judged)

    def push(
        self,
        stamp_ns: IntArray,
        position: FloatArray,
        velocity: FloatArray,
        effort: FloatArray,
        sim_effort: FloatArray | None,
        log_time_ns: IntArray | None = None,
    ) -> Scored:
        det = self._detector
        before = det.skipped
        out = det.push(stamp_ns, position, velocity, effort, sim_effort if self.use_sim else None)
        self.skipped += det.skipped - before
        stamps = np.asarray(getattr(out, "stamp_ns", stamp_ns), dtype=np.int64)
        scored = Scored(stamps, out.score, out.flag, out.residual, list(out.events))
        self.samples += len(stamps) - (det.skipped - before)
        self.flagged += int(np.count_nonzero(out.flag))
        if self.twin:
            times = stamp_ns if log_time_ns is None else log_time_ns
            own = getattr(out, "twin", None)
            if own is not None:  # the detector's τ̂ of its samples, at their log times
                # (a sample may come out of a later push: held for its grid cell or the
                # derivative's window, its log time waits with it)
                at = self._log_times
                at.update(zip(np.asarray(stamp_ns).tolist(), np.asarray(times).tolist()))
                done = own["stamp_ns"].tolist()
                logged = [at.pop(t) for t in done]
                if done:  # samples older than the last out were dropped (absurd, not finite)
                    self._log_times = {t: v for t, v in at.items() if t > done[-1]}
                scored.twin = own.with_columns(log_time_ns=np.asarray(logged, dtype=np.int64))
            else:
                scored.twin = self._twin(stamp_ns, times, position, velocity, effort)
        return scored

    def _twin(
        self,
        stamp_ns: IntArray,
        log_time_ns: IntArray,
        position: FloatArray,
        velocity: FloatArray,
        effort: FloatArray,
    ) -> Frame:
        """τ̂ of the pushed samples the detector takes."""
        from twincd.prepare.chain import JointLayout, build_chain
        from twincd.signal.features import ModelFeatures

        det = self._detector
        stamps = np.asarray(stamp_ns, dtype=np.int64)
        if self._twin_chain is None:
            robot = det.robot
            assert robot is not None, "a detector that simulates has its robot model"
            names = tuple(self.joint_names)
            layout = JointLayout(names, robot.joint_names, names)
            fill = det.velocity_from_position
            lowpass, features = self.calibration.lowpass, ModelFeatures()  # no filter: none
            built = build_chain(
                lowpass,
                features,
                layout=layout,
                period_s=det.period_s,
                twin=robot,
                fill_velocity=fill,
                threads=1,
                filtered=False,
            )
            self._twin_chain = built.chain
        ok = det.taken  # the rows the detector took: finite, newer, not absurd
        frame = Frame(
            {
                "stamp_ns": stamps[ok],
                "log_time_ns": np.asarray(log_time_ns, dtype=np.int64)[ok],
                "position": np.asarray(position)[ok],
                "velocity": np.asarray(velocity)[ok],
            }
        )
        return self._twin_chain.push(frame)

    def finish(self) -> Scored:
        """End of a segment: what the detector still holds, and the event still open."""
        det = self._detector
        scored = Scored.empty(len(self.joint_names))
        flush = getattr(det, "flush", None)
        if flush is not None:
            out = flush()
            stamps = np.asarray(getattr(out, "stamp_ns", np.zeros(0, np.int64)), dtype=np.int64)
            scored = Scored(stamps, out.score, out.flag, out.residual, list(out.events))
            self.samples += len(stamps)
            self.flagged += int(np.count_nonzero(out.flag))
            own = getattr(out, "twin", None)
            if self.twin and own is not None and own.n:
                # none is held without a grid; any would be recorded at its stamp
                scored.twin = own.with_columns(log_time_ns=own["stamp_ns"])
        scored.events += det.close()
        if self._twin_chain is not None:
            scored.twin = self._twin_chain.finish()
            self._twin_chain = None
        return scored

    def restart(self) -> Scored:
        """A new segment: finish this one, and start afresh (filter and events)."""
        done = self.finish()
        self._judged_before += int(self._detector.counts.judged)
        self._detector = self._new()
        return done
