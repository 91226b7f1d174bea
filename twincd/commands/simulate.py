"""``simulate``: the twin's effort written into a lossless MCAP copy of each log."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from twincd.commands.runs import (
    CommandRun,
    Options,
    as_path,
    split_options,
)
from twincd.errors import UsageError

if TYPE_CHECKING:
    from typing_extensions import Unpack

    from twincd.prepare.settings import SetupOptions
    from twincd.prepare.simulate import SimulateResult

# settings of the filter and the calibration: simulate writes the twin's effort as computed
_NOT_FOR_SIMULATE = (
    "cutoff_hz",
    "filter_order",
    "filter_kind",
    "causal",
    "fast_cutoff_hz",
    "allow_urdf_change",
)


@dataclass(frozen=True, kw_only=True)
class SimulateRun(CommandRun):
    """What ``simulate_logs`` gives: each log's output (in the order given)."""

    outputs: list[SimulateResult] = field(default_factory=list)


def simulate_logs(
    logs: Iterable[str | Path],
    *,
    output: str | Path | None = None,
    in_place: bool = False,
    force: bool = False,
    **options: Unpack[Options],
) -> SimulateRun:
    """``twincd simulate``: run the twin (``robot``, None: the default model) over ``logs``
    and write its effort on ``sim_topic``, each log copied losslessly into MCAP: to
    ``<log>.twin.mcap`` beside it, to ``output`` (a file for one log, a folder for several),
    or over a bare ``.mcap`` input (``in_place``). ``options`` as ``fit_calibration``'s (no
    filter setting: the twin's effort is written as computed)."""
    from twincd.executors.local import Bound, gathered_warnings
    from twincd.io.logs import expand_logs
    from twincd.io.named import settle_named
    from twincd.prepare.simulate import simulate_item

    with gathered_warnings() as warnings:
        running, asked = split_options(options)
        _refuse_filter_settings(asked)
        paths = expand_logs(logs)
        target = as_path(output)
        _prepare_output(paths, target, in_place)
        # the twin's topic is what simulate writes, not something a log must have
        reading = settle_named(paths, asked.log_options().unnamed("sim_topic"))
        targets = _targets(paths, target, in_place, force)
        items = list(zip(paths, targets, strict=True))
        work: Bound[tuple[Path, Path | None], SimulateResult] = Bound(
            simulate_item, asked.robot, reading, in_place, asked.strict
        )
        from twincd.executors.run import all_or_nothing

        with all_or_nothing() as written:
            written.extend(t for t in targets if t is not None)
            done = running.each(work, items, "simulating")
    return SimulateRun(
        outputs=done.results, warnings=tuple(warnings), failures=tuple(done.failures)
    )


def _refuse_filter_settings(asked: SetupOptions) -> None:
    """A usage error when a filter or calibration setting is given: simulate has none."""
    # given at all, whatever the value (causal=False, a cut-off of 0 are settings too);
    # allow_urdf_change only when asked for (False is every command's default)
    given = [
        name
        for name in _NOT_FOR_SIMULATE
        if (
            asked.allow_urdf_change
            if name == "allow_urdf_change"
            else getattr(asked, name) is not None
        )
    ]
    if given:
        raise UsageError(
            "simulate writes the twin's effort unfiltered, without a calibration",
            "simulate",
            "leave the filter and calibration settings out",
            option=",".join(given),
        )


def _prepare_output(paths: list[Path], target: Path | None, in_place: bool) -> None:
    """Refuse an output that cannot be (in place and ``output`` at once, in place over
    another file than a bare ``.mcap``, one ``.mcap`` for several logs); make the output
    folder of several logs."""
    from twincd.detection.outputs import make_output_folder

    if in_place and target is not None:
        raise UsageError(
            "in-place and output exclude each other",
            "simulate",
            "pick one",
            option="in_place,output",
        )
    for path in paths if in_place else []:
        if not (path.is_file() and path.suffix == ".mcap"):
            raise UsageError(
                "in-place rewriting works on bare .mcap files only",
                str(path),
                "write to another output file",
                option="in_place",
            )
    if len(paths) > 1 and target is not None:
        if target.suffix == ".mcap":
            raise UsageError(
                "several logs need an output folder", str(target), "give a folder name",
                option="output",
            )  # fmt: skip
        make_output_folder(target)


def _targets(
    paths: list[Path], target: Path | None, in_place: bool, force: bool
) -> list[Path | None]:
    """Each log's output (None: in place), each checked writable before any work."""
    from twincd.detection.outputs import distinct_targets
    from twincd.io.atomic import check_target, check_writable
    from twincd.prepare.simulate import default_output

    several = len(paths) > 1
    targets: list[Path | None] = [None] * len(paths)
    if not in_place:
        folder = target if several else None
        planned = distinct_targets(paths, default_output, folder)
        targets = [target if target is not None and not several else t for t in planned]
    for path, out in zip(paths, targets):
        if out is None:
            check_writable(path)  # in place: a read-only log is refused
        else:
            check_target(out, "simulate", force=force, inputs=paths)
    return targets
