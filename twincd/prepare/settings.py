"""The settings a user asks for by name (``SetupOptions``: each None when not given) and the
``twincd.Setup`` they resolve to: without a calibration, the defaults fill in what was not
given; with one, what it learned stays (the filter; the joints after the map and the robot's
dynamics, checked by content as logs are read) and a filter setting given that contradicts it
is an error, while how a recording is read (topics, the joint map and prefix, where the robot's
URDF is) is the run's own: the calibration's recorded values are only its defaults.

Here, below every stage that reads logs with them (``live``, ``evaluation``, ``commands``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any

from twincd.defaults import DEFAULT_CAUSAL_CUTOFF_HZ, DEFAULT_CUTOFF_HZ, DEFAULT_ORDER
from twincd.errors import UsageError

if TYPE_CHECKING:
    from twincd.io.options import LogOptions
    from twincd.io.window import TimeWindow
    from twincd.prepare.setup import CalibrationSettings, Setup

__all__ = ["SetupOptions"]


@dataclass(frozen=True, kw_only=True)
class SetupOptions:
    """How to read logs, as asked for (None: not given; see the module's docstring).

    >>> setup = SetupOptions(robot="panda", causal=True).resolve()  # doctest: +SKIP
    >>> setup = SetupOptions(topic="/arm/joint_states").resolve(calibration)  # doctest: +SKIP
    """

    robot: str | None = None  # example-robot-data name, package:// URI or URDF path
    topic: str | None = None
    label_topic: str | None = None
    sim_topic: str | None = None
    link_topic: str | None = None
    joint_map: Mapping[str, str] | None = None  # log joint name → model joint name
    joint_prefix: str | None = None  # taken off the log joint names that start with it
    cutoff_hz: float | None = None
    filter_order: int | None = None
    filter_kind: str | None = None  # None: Butterworth without a calibration
    causal: bool | None = None
    # fit: the fast band's upper cut-off (0: none; None: DEFAULT_FAST_CUTOFF_HZ for a model
    # scored by depth, none for the others; twincd.signal.bands)
    fast_cutoff_hz: float | None = None
    strict: bool = False  # refuse a truncated log instead of reading up to the damage
    allow_urdf_change: bool = False  # accept a robot model of other dynamics (warned)
    # the stretch of each log judged (``twincd.io.window``): seconds from its first sample, or
    # "@" and seconds since the epoch; the run's own, never recorded in a calibration
    start: float | str | None = None
    end: float | str | None = None

    def keywords(self) -> dict[str, Any]:
        """The settings as the keyword arguments every command takes (``twincd.commands``)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def window(self) -> TimeWindow | None:
        """The time window asked for (None: the whole log)."""
        from twincd.io.window import TimeWindow

        return TimeWindow.of(self.start, self.end)

    def log_options(self, defaults: LogOptions | None = None) -> LogOptions:
        """The topics and joint names given; those not given fall back to ``defaults``. A
        joint map or prefix given replaces both of the defaults' (the log's joints are named
        one way). The ones given are ``named`` (a log must have them; ``twincd.io.named``)."""
        from twincd.io.options import LogOptions

        base = defaults or LogOptions()
        renamed = self.joint_map is not None or self.joint_prefix is not None
        return LogOptions(
            topic=self.topic or base.topic,
            label_topic=self.label_topic or base.label_topic,
            sim_topic=self.sim_topic or base.sim_topic,
            joint_map=(self.joint_map or None) if renamed else base.joint_map,
            named=self.named(),
            link_topic=self.link_topic or base.link_topic,
            joint_prefix=(self.joint_prefix or "") if renamed else base.joint_prefix,
        )

    def named(self) -> frozenset[str]:
        """The log options given (``LogOptions.named``)."""
        from twincd.io.options import named_options

        return named_options(
            self.topic,
            self.label_topic,
            self.sim_topic,
            self.joint_map,
            self.link_topic,
            self.joint_prefix,
        )

    def resolve(self, calibration: CalibrationSettings | None = None) -> Setup:
        """The ``Setup`` these options ask for, on top of ``calibration``'s when given: its
        filter, joints, period and dynamics, with the log options and the robot model given
        in place of its recorded ones (``Calibration.robot_model`` finds the recorded URDF
        when none is given)."""
        if calibration is None:
            return self._without_calibration()
        self._check_filter(calibration)
        from twincd.prepare.setup import Setup

        setup = Setup.from_calibration(calibration)
        return replace(
            setup,
            options=self.log_options(calibration.options),
            robot=calibration.robot_model(self.robot),
            strict=self.strict,
            allow_urdf_change=self.allow_urdf_change,
            window=self.window(),
        )

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
        return Setup(
            self.log_options(), self.robot, lowpass, strict=self.strict, window=self.window()
        )

    def _check_filter(self, cal: CalibrationSettings) -> None:
        """A ``UsageError`` for the first filter setting given that the calibration's filter
        contradicts (the filter is part of what it learned)."""
        lp = cal.lowpass
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
        if self.fast_cutoff_hz is not None and cal.period_s is not None:
            from twincd.signal.bands import fast_band_at

            band = fast_band_at(lp, self.fast_cutoff_hz or None, cal.period_s)
            given_hz = None if band is None else band.high.cutoff_hz
            if given_hz != cal.fast_hz:
                was_hz = "no fast band" if cal.fast_hz is None else f"{cal.fast_hz:g} Hz"
                _contradiction(
                    "fast_cutoff_hz", f"fast band cut-off {self.fast_cutoff_hz:g} Hz", was_hz, cal
                )


def _contradiction(
    option: str, given: str, recorded: object, calibration: CalibrationSettings
) -> None:
    raise UsageError(
        f"{given} contradicts the calibration's {recorded}",
        calibration.source or "calibration",
        "leave the setting out, or fit a calibration with it",
        option=option,
    )
