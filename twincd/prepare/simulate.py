"""``simulate``: run the twin over a log and write its effort back next to the input messages,
block by block (flat memory for any log length)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from twincd.errors import UsageError
from twincd.io.cdr import JOINT_STATE
from twincd.io.logs import TWIN_SUFFIX
from twincd.io.options import LogOptions
from twincd.prepare.setup import Setup


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
    robot: str | None,
    options: LogOptions | None = None,
    in_place: bool = False,
    setup: Setup | None = None,
) -> SimulateResult:
    """Write ``output``: ``source`` copied losslessly plus ``options.sim_topic`` with τ̂.
    ``robot`` None: the default robot model, on a log of its joints only."""
    from twincd.io.cdr import joint_state_block
    from twincd.io.mcap import AugmentedMcap

    options = options or LogOptions()
    setup = setup or Setup(options=options, robot=robot)
    source = Path(source)
    if in_place:
        if not (source.is_file() and source.suffix == ".mcap"):
            raise UsageError(
                "in-place rewriting works on bare .mcap files only",
                str(source),
                "write to another output file",
            )
        target = source
    else:
        target = Path(output) if output is not None else default_output(source)
        if target.resolve() == source.resolve():
            raise UsageError(
                "output would overwrite the input",
                str(target),
                "simulate it in place, or write another file",
            )
    stream = setup.open(source, filtered=False, need_effort=False, force_simulate=True)
    copy = AugmentedMcap(
        source, target, [options.sim_topic], output="simulate", partial=not setup.strict
    )
    with stream, copy as out:
        channel = out.add_channel(options.sim_topic, JOINT_STATE)
        for frame in stream:
            assert stream.robot is not None  # force_simulate: the twin always has a model
            payloads = joint_state_block(
                frame["stamp_ns"],
                stream.robot.joint_names,
                frame["position"],
                frame["velocity"],
                frame["sim_effort"],
            )
            out.write(channel, frame["log_time_ns"], payloads)
    assert stream.robot is not None
    return SimulateResult(
        source, target, stream.samples, stream.robot.joint_names, stream.robot.locked
    )


def simulate_item(
    item: tuple[Path, Path | None],
    robot: str | None,
    options: LogOptions | None = None,
    in_place: bool = False,
    strict: bool = False,
) -> SimulateResult:
    """``simulate_log`` of one (source, output) pair: the per-log step of a multi-log run."""
    setup = Setup(options=options or LogOptions(), robot=robot, strict=strict)
    return simulate_log(item[0], item[1], robot, options, in_place=in_place, setup=setup)
