"""Per-sample detection outputs: augmented MCAP, CSV or JSONL (DESIGN §3)."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Iterable, Iterator
from pathlib import Path

from twincd.detection.detect import LogDetection
from twincd.errors import OutputError

RESIDUAL_TOPIC = "/twincd/residual"
SCORE_TOPIC = "/twincd/score"
COLLISION_TOPIC = "/twincd/collision"

OUTPUT_SUFFIXES = (".mcap", ".csv", ".jsonl")


def write_detection(result: LogDetection, source: Path, target: Path) -> None:
    """``target`` by suffix: augmented MCAP, or one CSV/JSONL row per sample (atomic)."""
    suffix = target.suffix.lower()
    if suffix == ".mcap":
        _write_mcap(result, source, target)
    elif suffix in (".csv", ".jsonl"):
        from twincd.io.mcap_write import atomic_output

        with atomic_output(target) as stream:
            text = io.TextIOWrapper(stream, encoding="utf-8", newline="")
            rows = _rows(result)
            if suffix == ".csv":
                _write_csv(text, result, rows)
            else:
                for row in rows:
                    text.write(json.dumps(row) + "\n")
            text.flush()
            text.detach()
    else:
        raise OutputError(
            f"unknown output type {target.suffix!r}",
            str(target),
            "end -o with .mcap, .csv or .jsonl",
        )


def _rows(result: LogDetection) -> Iterator[dict[str, object]]:
    names = result.log.joint_names
    stamps = result.log.states.stamp_ns
    for i in range(len(result.scores)):
        row: dict[str, object] = {
            "stamp_ns": int(stamps[i]),
            "score": float(result.scores[i]),
            "collision": bool(result.flags[i]),
        }
        for j, n in enumerate(names):
            row[f"residual_{n}"] = float(result.residual[i, j])
        yield row


def _write_csv(
    text: io.TextIOWrapper, result: LogDetection, rows: Iterator[dict[str, object]]
) -> None:
    fields = ["stamp_ns", "score", "collision"] + [f"residual_{n}" for n in result.log.joint_names]
    writer = csv.DictWriter(text, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({**row, "collision": int(bool(row["collision"]))})  # 0/1 for any tool


def _write_mcap(result: LogDetection, source: Path, target: Path) -> None:
    from twincd.io.cdr import bool_cdr, float64_cdr, joint_state_cdr
    from twincd.io.logs import JOINT_STATE
    from twincd.io.mcap_write import NewTopic, write_augmented

    if target.resolve() == Path(source).resolve():
        raise OutputError("output would overwrite the input", str(target), "pick another -o")
    states = result.log.states
    stamps, log_times = states.stamp_ns, states.log_time_ns

    def timed(payloads: Iterable[bytes]) -> Iterator[tuple[int, int, bytes]]:
        for t, data in zip(log_times, payloads, strict=False):
            yield int(t), int(t), data

    # Float64 and Bool have no header: their log time ties them to the sample
    residual_msgs = joint_state_cdr(
        stamps, states.joint_names, states.position, states.velocity, result.residual
    )
    write_augmented(
        source,
        target,
        [
            NewTopic(RESIDUAL_TOPIC, JOINT_STATE, timed(residual_msgs)),
            NewTopic(SCORE_TOPIC, "std_msgs/msg/Float64", timed(map(float64_cdr, result.scores))),
            NewTopic(COLLISION_TOPIC, "std_msgs/msg/Bool", timed(map(bool_cdr, result.flags))),
        ],
    )
