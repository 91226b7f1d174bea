"""What ``fit`` reads its logs with: the settings asked for by name
(``twincd.prepare.settings.SetupOptions``) with the filter and the fast band its model wants."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

from twincd.defaults import DEFAULT_CRITICAL_CUTOFF_HZ

if TYPE_CHECKING:
    from twincd.prepare.settings import SetupOptions
    from twincd.prepare.setup import Setup


def fit_setup(options: SetupOptions, model: str | None = None) -> tuple[Setup, str | None]:
    """What fitting ``model`` reads logs with, and the model (None: the best the logs allow,
    ``twincd.calibration.fitting.best_model``).

    Unless a filter is given, the identified models (and the best model, identified when it
    can be) filter without overshoot (``critical``) at ``DEFAULT_CRITICAL_CUTOFF_HZ``: their
    residual is at the noise floor, where a Butterworth filter's ringing around a push shows
    as alarms before and after it (``filter_kind_for``)."""
    from twincd.calibration.fitting import fast_cutoff, filter_kind_for

    if options.filter_kind is None:
        kind = filter_kind_for(model)
        options = replace(options, filter_kind=kind)
        if kind == "critical" and options.cutoff_hz is None and not options.causal:
            options = replace(options, cutoff_hz=DEFAULT_CRITICAL_CUTOFF_HZ)
    setup = options.resolve()
    return replace(setup, fast_hz=fast_cutoff(model, options.fast_cutoff_hz)), model
