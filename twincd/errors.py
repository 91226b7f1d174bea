"""One exception root for the whole library; each subclass carries its CLI exit code.

A message reads as ``<what> (<where>) — <what to do>`` so that the CLI can print it on one
line as ``twincd: error: <message>`` (contract: Exit codes and streams). Messages speak in library
words and never
name a command-line flag: an error about a setting names it in ``option`` (``"robot"``,
``"train"``, several joined by commas), and the CLI turns that into its flags.
"""

from __future__ import annotations

from typing import Any


class TwincdError(Exception):
    """Root of every error twincd raises on purpose."""

    exit_code: int = 2

    def __init__(self, what: str, where: str, hint: str, *, option: str | None = None) -> None:
        self.what = what
        self.where = where
        self.hint = hint
        # the setting(s) concerned, in library words ("robot", "train,val"); None: no setting
        self.option = option
        super().__init__(self.message)

    def __reduce__(
        self,
    ) -> tuple[type[TwincdError], tuple[str, str, str], dict[str, Any]]:
        # errors cross process boundaries (a pool worker's failure): rebuild from the parts;
        # the keyword-only option (and any other attribute) comes back as state
        # (BaseException.__setstate__)
        return (type(self), (self.what, self.where, self.hint), dict(self.__dict__))

    @property
    def message(self) -> str:
        text = self.what
        if self.where:
            text += f" ({self.where})"
        if self.hint:
            text += f" — {self.hint}"
        return text


class UsageError(TwincdError):
    """An option or a combination of options that cannot work."""


class LogReadError(TwincdError):
    """A log that cannot be opened, is empty, truncated or corrupt."""


class TopicError(TwincdError):
    """A topic that is missing, ambiguous or of the wrong type."""


class JointMismatchError(TwincdError):
    """Joints of a log, a robot model and a calibration that do not fit together."""


class SplitJointsError(JointMismatchError):
    """An arm whose joints arrive split over several messages (publishers) per sample."""


class RobotModelError(TwincdError):
    """An unknown robot name or a URDF that cannot be loaded."""


class CalibrationError(TwincdError):
    """A calibration file that is missing, of another schema, or incomplete."""


class NotFittedError(CalibrationError):
    """An estimator used before ``fit()``."""


class OutputError(TwincdError):
    """An output that cannot be written."""


class InternalError(TwincdError):
    """A defect in twincd: an exception no code path expected (exit 3, never 1, which CI reads
    as "collision found"). Carries the original's type, message and traceback text, so that it
    can cross a process boundary (a pool worker's failure) and still be shown with --debug."""

    exit_code = 3
    HINT = "re-run with --debug and report it"

    @classmethod
    def from_exception(cls, exc: BaseException, where: str = "") -> InternalError:
        import traceback

        text = " ".join(str(exc).split())
        error = cls(
            f"{type(exc).__name__}: {text}" if text else type(exc).__name__, where, cls.HINT
        )
        error.details = "".join(traceback.format_exception(exc))
        return error

    details: str = ""


class DataError(TwincdError):
    """Data that is valid on disk but unusable for the method (too short, no labels, ...)."""


class ClusterError(TwincdError):
    """A Dask cluster that cannot be reached, or whose workers keep dying on a log."""


class Terminated(KeyboardInterrupt):
    """SIGTERM (CI cancellation, ``docker stop``), raised like Ctrl-C so that every clean-up
    that runs on an interrupt runs for it too (contract: Exit codes and streams: exit 143)."""


def raise_terminated(signum: int, frame: object) -> None:
    """A SIGTERM handler: ``signal.signal(signal.SIGTERM, raise_terminated)``."""
    raise Terminated(signum)
