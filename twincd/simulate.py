"""``simulate``: run the twin over a log and write its effort back next to the input messages."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from twincd.errors import UsageError
from twincd.io.cdr import joint_state_cdr
from twincd.io.logs import JOINT_STATE, TWIN_SUFFIX, LogOptions, read_log
from twincd.io.mcap_write import NewTopic, write_augmented
from twincd.pipeline import twin_effort
from twincd.twin.dynamics import Differentiator


@dataclass(frozen=True)
class SimulateResult:
    source: Path
    output: Path
    samples: int
    joints: tuple[str, ...]
    locked: tuple[str, ...]


def default_output(source: Path) -> Path:
    """``<input name>.twin.mcap`` beside the input (a folder's name, a file's stem); a twin
    file stays itself rather than becoming ``x.twin.twin.mcap``."""
    if source.name.endswith(TWIN_SUFFIX):
        return source
    stem = source.name if source.is_dir() else source.stem
    return source.with_name(f"{stem}{TWIN_SUFFIX}")


def simulate_log(
    source: Path,
    output: Path | None,
    robot: str,
    options: LogOptions | None = None,
    differentiator: Differentiator | None = None,
    in_place: bool = False,
) -> SimulateResult:
    """Write ``output``: ``source`` copied losslessly plus ``options.sim_topic`` with τ̂."""
    options = options or LogOptions()
    source = Path(source)
    if in_place:
        if not (source.is_file() and source.suffix == ".mcap"):
            raise UsageError(
                "--in-place rewrites bare .mcap files only", str(source), "use -o for other logs"
            )
        target = source
    else:
        target = Path(output) if output is not None else default_output(source)
        if target.resolve() == source.resolve():
            raise UsageError(
                "output would overwrite the input",
                str(target),
                "pass --in-place to simulate it again, or -o another file",
            )
    states = read_log(source, options)
    sel, tau_hat, model, _ = twin_effort(states, robot, differentiator, force_simulate=True)
    assert model is not None
    messages = (
        (int(log_time), int(log_time), data)
        for log_time, data in zip(
            sel.log_time_ns,
            joint_state_cdr(sel.stamp_ns, model.joint_names, sel.position, sel.velocity, tau_hat),
        )
    )
    write_augmented(source, target, [NewTopic(options.sim_topic, JOINT_STATE, messages)])
    return SimulateResult(source, target, len(sel), model.joint_names, model.locked)
