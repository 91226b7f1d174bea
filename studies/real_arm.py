"""Rotation study on the real arm: twincd as a user runs it, judged on logs it never saw.

The real Doosan M0609 recordings (six ≈ 126 s rosbag2 logs at 100 Hz, 169 labelled pushes) are
read from ``../shared/data/doosan_m0609/`` beside the repository when present; they are not part
of the project and nothing derived from them is written into it. Each rotation ``i`` tests on log
``i``, sets the threshold on log ``i+1`` (mod 6) and fits on the other four, exactly with the
commands a user types (``twincd fit``, ``twincd threshold``, ``twincd detect``, ``twincd
evaluate``), at their defaults unless options are given. Every figure is the mean over the six
rotations with its spread (min–max), and the pooled counts:

    python studies/real_arm.py                          # the defaults, twin from the URDF
    python studies/real_arm.py --fit-args "--model affine" --threshold-args "-k 4"
    python studies/real_arm.py --no-urdf                # twin = the controller's model torque
    python studies/real_arm.py --segments 3 4           # threshold and test on 3–4 s segments

Figures: collisions found (pooled and per rotation), median delay, false alarms in the whole
collision-free time of the six test logs, events per found push (``evaluate``'s
``events_per_detected``: detect's events that touch a labelled push, over the pushes found), AUC,
and how often a found push's event names a link (the recordings label none, so not whether
it is right).

Real datasets often come as segments of a few seconds: ``--segments LOW HIGH`` cuts the
threshold log and the test log into consecutive segments of LOW–HIGH seconds (lengths drawn
with a fixed seed; labels kept), thresholds on the one's segments and tests on the other's, the
fit still on the four whole logs. A push cut by a segment's end counts once per segment it
touches; a segment cut from a stretch with the drives off (every effort exactly 0: twincd
refuses such a log, it measures nothing) is left out.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import tempfile
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from statistics import mean, median
from typing import Any

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "doosan_m0609"
LOGS = [DATA / "logs" / f"doosan_dev_{i:02d}" for i in range(6)]
URDF = DATA / "m0609.urdf"
PERIOD_S = 0.01  # the recordings' sampling period


def twincd(*args: object) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "twincd_cli.main", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, check=False)


def must(result: subprocess.CompletedProcess[str], ok: tuple[int, ...] = (0,)) -> str:
    if result.returncode not in ok:
        sys.exit(f"{' '.join(result.args)} failed ({result.returncode}):\n{result.stderr}")
    return result.stdout


@dataclass
class Rotation:
    test: str
    evaluate: dict[str, Any]
    clean_s: float  # the test log's unlabelled time judged (100 Hz samples)
    delays_ms: list[float]  # each found push's delay, from detect's events
    links: list[str | None]  # the link its first event names (None: not singled out)


def rotate(i: int, work: Path, args: argparse.Namespace) -> Rotation:
    test, val = LOGS[i], LOGS[(i + 1) % 6]
    train = [p for p in LOGS if p not in (test, val)]
    cal = work / f"cal{i}.json"
    twin = ["--robot", URDF] if not args.no_urdf else ["--sim-topic", "/controller/model_effort"]
    must(twincd("fit", *train, *twin, "-o", cal, "-q", *shlex.split(args.fit_args)))
    vals, tests = [val], [test]
    if args.segments:
        vals = segments(val, work / f"val{i}", *args.segments, seed=2 * i)
        tests = segments(test, work / f"test{i}", *args.segments, seed=2 * i + 1)
    must(twincd("threshold", *vals, "-c", cal, "-q", *shlex.split(args.threshold_args)))
    doc = json.loads(must(twincd("evaluate", *tests, "-c", cal, "--json", "-q")))
    found = json.loads(must(twincd("detect", *tests, "-c", cal, "--json", "-q"), ok=(0, 1)))
    delays: list[float] = []
    links: list[str | None] = []
    for path, judged in zip(tests, found["logs"], strict=True):
        d, lk = found_pushes(path, judged["events"])
        delays, links = delays + d, links + lk
    clean_s = (doc["samples"] - doc["positives"]) * PERIOD_S
    return Rotation(test.name, doc["methods"][0], clean_s, delays, links)


def segments(log: Path, folder: Path, low: float, high: float, seed: int) -> list[Path]:
    """``log`` cut into consecutive segments of ``low``–``high`` seconds (the last one what
    is left, when at least ``low``), each a log of its own with its labels."""
    import numpy as np
    from inject_contacts import write_log

    from twincd.prepare.setup import read_log

    states = read_log(log)
    assert states.labels is not None
    t = states.t_s
    rng = np.random.default_rng(seed)
    out, start = [], float(t[0])
    while start + low <= float(t[-1]) + 1e-9:
        end = start + float(rng.uniform(low, high))
        rows = (t >= start) & (t < end)
        start = end
        if not np.any(states.effort[rows]):  # drives off throughout: no effort to judge
            continue
        path = folder / f"{log.name}_{len(out):03d}.mcap"
        write_log(path, states, rows, states.effort[rows], states.labels[rows])
        out.append(path)
    return out


def found_pushes(log: Path, events: list[dict[str, Any]]) -> tuple[list[float], list[str | None]]:
    """Each found push's delay (ms) from detect's events, as evaluate counts it: from the push's
    first labelled sample to the first event sample inside it or within 200 ms after it; and the
    link that first event names (the recordings label no links, so only how often one is
    named can be judged)."""
    from twincd.detection.events import runs
    from twincd.prepare.setup import read_log

    states = read_log(log)
    assert states.labels is not None
    stamps = states.stamp_ns
    delays: list[float] = []
    links: list[str | None] = []
    for a, b in runs(states.labels):
        start, end = int(stamps[a]), int(stamps[b]) + 200_000_000
        hits = [e for e in events if e["start_ns"] <= end and e["end_ns"] >= start]
        if hits:
            first = min(hits, key=lambda e: e["start_ns"])
            delays.append((max(first["start_ns"], start) - start) * 1e-6)
            links.append(first.get("link"))
    return delays, links


def spread(values: list[float | None]) -> str:
    """Mean (min–max) of the rotations that have the figure (a rotation that found nothing has
    no delay)."""
    values = [v for v in values if v is not None]
    return f"{mean(values):.3g} ({min(values):.3g}–{max(values):.3g})" if values else "n/a"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fit-args", default="", help="extra options of twincd fit")
    parser.add_argument("--threshold-args", default="", help="extra options of twincd threshold")
    parser.add_argument("--no-urdf", action="store_true", help="twin = the controller's torque")
    parser.add_argument("--json", type=Path, help="also write the per-rotation figures here")
    parser.add_argument(
        "--segments",
        nargs=2,
        type=float,
        metavar=("LOW", "HIGH"),
        help="threshold and test on segments of LOW–HIGH s cut from the logs",
    )
    args = parser.parse_args()
    if not all(p.is_dir() for p in LOGS):
        print(f"the real arm's recordings are not at {DATA}: nothing to study")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        rotations = [rotate(i, Path(tmp), args) for i in range(6)]
    rows = [r.evaluate for r in rotations]
    total = sum(m["events_total"] for m in rows)
    found = sum(m["events_detected"] for m in rows)
    alarms = sum(m["false_alarms"] for m in rows)
    minutes = sum(r.clean_s for r in rotations) / 60
    on = sum((m["events_per_detected"] or 0) * m["events_detected"] for m in rows)
    print(
        f"model {rows[0]['name']}, options fit [{args.fit_args}] threshold [{args.threshold_args}]"
    )
    print(f"{'test log':<16}{'found':>9}{'delay ms':>10}{'FA':>5}{'ev/push':>9}{'AUC':>7}")
    for r, m in zip(rotations, rows, strict=True):
        per = m["events_per_detected"] or float("nan")
        delay = m["delay_ms_median"]
        delay = float("nan") if delay is None else delay
        print(
            f"{r.test:<16}{m['events_detected']:>4.0f}/{m['events_total']:<4.0f}"
            f"{delay:>10.0f}{m['false_alarms']:>5.0f}"
            f"{per:>9.2f}{m['auc']:>7.3f}"
        )
    print(
        f"pooled: {found}/{total} found ({found / total:.1%}); per rotation "
        f"{spread([m['events_detected'] / m['events_total'] for m in rows])}"
    )
    print(f"median delay ms per rotation: {spread([m['delay_ms_median'] for m in rows])}")
    pooled = sorted(d for r in rotations for d in r.delays_ms)
    if pooled:
        print(
            f"delay over every found push (detect's events): median {median(pooled):.0f} ms, "
            f"p95 {pooled[int(0.95 * (len(pooled) - 1))]:.0f} ms ({len(pooled)} pushes)"
        )
    print(f"false alarms: {alarms} in {minutes:.1f} min of collision-free test time")
    print(f"events per found push: {on / max(found, 1):.2f} ({on:.0f} events on {found} pushes)")
    print(f"AUC per rotation: {spread([m['auc'] for m in rows])}")
    named = [link for r in rotations for link in r.links]
    if named:
        shown = Counter(link for link in named if link is not None)
        print(
            f"a link named for {shown.total()} of {len(named)} found pushes"
            f" ({shown.total() / len(named):.0%}): {dict(sorted(shown.items()))}"
        )
    if args.json:
        args.json.write_text(json.dumps([r.__dict__ for r in rotations], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
