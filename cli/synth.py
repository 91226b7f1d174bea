"""``twincd synth``: a synthetic xArm 7 run set (train / val / test) in the paper's protocol."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import Annotated

import typer

from twincd.defaults import SYNTH_SEGMENT_S
from twincd.errors import UsageError

from .common import Quiet, command, counter, stdout


@command
def synth(
    outdir: Annotated[Path, typer.Argument(help="Folder to write train/, val/, test/ into.")],
    seed: Annotated[int, typer.Option("--seed", help="Seed of the run set (plant and paths).")] = 0,
    train: Annotated[int, typer.Option("--train", help="Collision-free training paths.")] = 30,
    val: Annotated[int, typer.Option("--val", help="Collision-free validation paths.")] = 5,
    test: Annotated[int, typer.Option("--test", help="Paths with hand presses.")] = 5,
    min_duration: Annotated[
        float, typer.Option("--min-duration", help="Shortest path, seconds (3600: an hour).")
    ] = 22.0,
    max_duration: Annotated[
        float,
        typer.Option(
            "--max-duration",
            help=f"Longest path, seconds. Paths over {SYNTH_SEGMENT_S:g} s are joined from "
            "segments that start and end at rest.",
        ),
    ] = 35.0,
    rate_hz: Annotated[float, typer.Option("--rate-hz", help="Joint-state rate.")] = 100.0,
    rosbag2_copy: Annotated[
        bool,
        typer.Option(
            "--rosbag2-copy/--no-rosbag2-copy",
            help="Also write the first test path as a rosbag2 sqlite3 folder (OUTDIR/rosbag2/).",
            metavar="",
        ),
    ] = True,
    jobs: Annotated[
        int, typer.Option("--jobs", "-j", help="Paths generated in parallel (0: all CPUs).")
    ] = 1,
    quiet: Quiet = False,
) -> None:
    """Generate synthetic xArm 7 logs: a plant the twin does not know, hand presses in test/.

    Output is byte-identical for the same seed and options. A long path is made and written a
    segment at a time, in flat memory.

    Example: twincd synth data --seed 0 --train 30 --val 5 --test 5

    Example (one hour at 1 kHz): twincd synth long --train 1 --val 0 --test 0 --min-duration
    3600 --max-duration 3600 --rate-hz 1000 --no-rosbag2-copy
    """
    from twincd.synth.config import SynthConfig
    from twincd.synth.write import write_dataset

    if not 0 < min_duration <= max_duration:
        raise UsageError(
            f"bad duration range {min_duration}–{max_duration} s",
            "--min-duration/--max-duration",
            "give 0 < min ≤ max",
        )
    if not 1.0 <= rate_hz <= 10_000.0:
        raise UsageError(f"rate {rate_hz} Hz out of range", "--rate-hz", "use 1–10000 Hz")
    if min(train, val, test) < 0:
        raise UsageError("path counts must be ≥ 0", "--train/--val/--test", "pass 0 or more each")
    base = SynthConfig()
    config = replace(
        base,
        motion=replace(base.motion, duration_s=(min_duration, max_duration), rate_hz=rate_hz),
    )
    with counter(train + val + test, "synth", quiet, minimum=1) as advance:
        written = write_dataset(
            outdir,
            config,
            seed=seed,
            counts=(train, val, test),
            rosbag2_copy=rosbag2_copy,
            jobs=jobs if jobs > 0 else (os.cpu_count() or 1),
            progress=advance,
        )
    for path in written:
        stdout.print(str(path), soft_wrap=True)
    stdout.print(
        f"{len(written)} logs written to {outdir} (seed {seed}: "
        f"train {train}, val {val}, test {test})",
        soft_wrap=True,
    )
