"""The settings a user asks for by name (``SetupOptions``: each None when not given) and the
``twincd.Setup`` they resolve to: without a calibration, the defaults fill in what was not
given; with one, the calibration's recorded settings are the defaults, and a setting given that
contradicts them is an error (a calibration only judges logs read the way it was fitted)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from twincd.defaults import (
    DEFAULT_CAUSAL_CUTOFF_HZ,
    DEFAULT_CRITICAL_CUTOFF_HZ,
    DEFAULT_CUTOFF_HZ,
    DEFAULT_ORDER,
)
from twincd.errors import UsageError

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.io.options import LogOptions
    from twincd.prepare.setup import Setup


@dataclass(frozen=True, kw_only=True)
class SetupOptions:
    """How to read logs, as asked for (None: not given; see the module's docstring).

    >>> setup = SetupOptions(robot="panda", causal=True).resolve()  # doctest: +SKIP
    >>> setup = SetupOptions(topic="/arm/joint_states").resolve(calibration)  # doctest: +SKIP
    """

    robot: str | None = None  # example-robot-data name or URDF path
    topic: str | None = None
    label_topic: str | None = None
    sim_topic: str | None = None
    joint_map: Mapping[str, str] | None = None  # log joint name → model joint name
    cutoff_hz: float | None = None
    filter_order: int | None = None
    filter_kind: str | None = None  # None: Butterworth without a calibration
    causal: bool | None = None
    strict: bool = False  # refuse a truncated log instead of reading up to the damage
    allow_urdf_change: bool = False  # accept a changed URDF whose dynamics did not change

    def log_options(self, defaults: LogOptions | None = None) -> LogOptions:
        """The topics and joint map given; those not given fall back to ``defaults``. The ones
        given are ``named`` (a log must have them; ``twincd.io.named``)."""
        from twincd.io.options import LogOptions

        base = defaults or LogOptions()
        return LogOptions(
            topic=self.topic or base.topic,
            label_topic=self.label_topic or base.label_topic,
            sim_topic=self.sim_topic or base.sim_topic,
            joint_map=self.joint_map or base.joint_map,
            named=self.named(),
        )

    def named(self) -> frozenset[str]:
        """The log options given (``LogOptions.named``)."""
        from twincd.io.options import named_options

        return named_options(self.topic, self.label_topic, self.sim_topic, self.joint_map)

    def resolve(self, calibration: Calibration | None = None) -> Setup:
        """The ``Setup`` these options ask for, on top of ``calibration``'s when given."""
        if calibration is None:
            return self._without_calibration()
        self._check_against(calibration)
        from twincd.prepare.setup import Setup

        setup = Setup.from_calibration(calibration)
        setup = replace(
            setup,
            options=replace(setup.options, named=self.named()),  # given: the recorded ones
            strict=self.strict,
            allow_urdf_change=self.allow_urdf_change,
        )
        if self.robot is not None and calibration.robot is None:
            setup = replace(setup, robot=self.robot)
        return setup

    def _without_calibration(self) -> Setup:
        from twincd.prepare.setup import Setup
        from twincd.signal.filters import LowPass

        default_cutoff = DEFAULT_CAUSAL_CUTOFF_HZ if self.causal else DEFAULT_CUTOFF_HZ
        lowpass = LowPass(
            cutoff_hz=default_cutoff if self.cutoff_hz is None else self.cutoff_hz,
            order=DEFAULT_ORDER if self.filter_order is None else self.filter_order,
            causal=bool(self.causal),
            kind="butterworth" if self.filter_kind is None else self.filter_kind,
        )
        return Setup(self.log_options(), self.robot, lowpass, strict=self.strict)

    def _check_against(self, cal: Calibration) -> None:
        """A ``UsageError`` for the first setting given that the calibration contradicts."""
        recorded, lp = cal.options, cal.lowpass
        for option, label, given, was in (
            ("topic", "topic", self.topic, recorded.topic),
            ("label_topic", "label topic", self.label_topic, recorded.label_topic),
            ("sim_topic", "simulated effort topic", self.sim_topic, recorded.sim_topic),
        ):
            if given is not None and given != was:
                _contradiction(option, f"{label} {given}", was, cal)
        if self.joint_map is not None and dict(self.joint_map) != dict(recorded.joint_map or {}):
            was_map = _joint_map_text(recorded.joint_map) or "empty map"
            given_map = f"joint map {_joint_map_text(self.joint_map)}"
            _contradiction("joint_map", given_map, was_map, cal)
        robot = self.robot
        if robot is not None and cal.robot is not None and not _same_robot(robot, cal.robot):
            _contradiction("robot", f"robot {robot}", cal.robot, cal)
        if self.causal is not None and self.causal != lp.causal:
            filters = ("zero-phase", "causal")
            _contradiction(
                "causal",
                f"a {filters[self.causal]} filter",
                f"{filters[lp.causal]} filter",
                cal,
            )
        for option, label, given_f, was_f in (
            ("cutoff_hz", "cut-off (Hz)", self.cutoff_hz, lp.cutoff_hz),
            ("filter_order", "filter order", self.filter_order, lp.order),
        ):
            if given_f is not None and given_f != was_f:
                _contradiction(option, f"{label} {given_f:g}", f"{was_f:g}", cal)
        if self.filter_kind is not None and self.filter_kind != lp.kind:
            _contradiction("filter_kind", f"filter kind {self.filter_kind}", lp.kind, cal)


def fit_setup(options: SetupOptions, model: str | None = None) -> tuple[Setup, str | None]:
    """What fitting ``model`` reads logs with, and the model (None: the best the logs allow,
    ``twincd.calibration.fitting.best_model``).

    Unless a filter is given, the identified models (and the best model, identified when it
    can be) filter without overshoot (``critical``) at ``DEFAULT_CRITICAL_CUTOFF_HZ``: their
    residual is at the noise floor, where a Butterworth filter's ringing around a push shows
    as alarms before and after it (``filter_kind_for``)."""
    from twincd.calibration.fitting import filter_kind_for, scored_by_depth
    from twincd.signal.bands import FAST_CUTOFF_HZ

    if options.filter_kind is None:
        kind = filter_kind_for(model)
        options = replace(options, filter_kind=kind)
        if kind == "critical" and options.cutoff_hz is None and not options.causal:
            options = replace(options, cutoff_hz=DEFAULT_CRITICAL_CUTOFF_HZ)
    setup = options.resolve()
    if scored_by_depth(model):  # a strike's band too (twincd.signal.bands)
        setup = replace(setup, fast_hz=FAST_CUTOFF_HZ)
    return setup, model


def _contradiction(option: str, given: str, recorded: object, calibration: Calibration) -> None:
    raise UsageError(
        f"{given} contradicts the calibration's {recorded}",
        calibration.source or "calibration",
        "leave the setting out, or fit a calibration with it",
        option=option,
    )


def _joint_map_text(joint_map: Mapping[str, str] | None) -> str:
    return ",".join(f"{k}={v}" for k, v in (joint_map or {}).items())


def _same_robot(a: str, b: str) -> bool:
    if a == b:
        return True
    pa, pb = Path(a), Path(b)
    return pa.exists() and pb.exists() and pa.resolve() == pb.resolve()
