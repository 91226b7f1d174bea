"""How the isolation rule's κ and margin ρ were chosen (``twincd.detection.isolation``): a link is
named only when every significance level in [κ / ρ, κ × ρ] names it; otherwise the event says
``null`` with its candidates.

On synth development seeds only (the real arm has no link labels; seeds 0 and 1 hold the test
paths kept for the README's figures): fit and threshold as a user does, detect the test paths
with the default event rules, and for every found press whose ground-truth link is known
(``/collision_link``) compare the link the rule names at each ρ. Targets: named links right
≥ 90 % of the time they are named, a link named for ≥ 70 % of found presses.

    twincd synth /tmp/ev_s2 --seed 2 --train 10 --val 10 --test 20 --no-rosbag2-copy
    python studies/choose_isolation.py /tmp/ev_s2 /tmp/ev_s3 /tmp/ev_s4 [--fit-args ...]
    python studies/choose_isolation.py /tmp/ev_s2 /tmp/ev_s3 /tmp/ev_s4 --statistic rms

``--statistic`` scores another per-joint evidence of an event than detect's largest magnitude.
"""

from __future__ import annotations

import argparse
import itertools
import shlex
import sys
import tempfile
from collections import Counter
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
from choose_events import HELD_OUT_SEEDS, synth  # type: ignore[import-not-found]

from twincd.calibration import Calibration
from twincd.defaults import DEFAULT_LINK_TOPIC
from twincd.detection.events import EventRules, find_events, runs
from twincd.detection.isolation import LinkIsolator, kappa_for, margin_for
from twincd.io.links import read_links
from twincd.twin.robot import child_links

TARGET_RIGHT, TARGET_NAMED = 0.90, 0.70  # the targets for the isolation rule
# one setting's right-when-named differs by ±3 points between seeds (κ 4, ρ 1.2 on seeds 2, 3,
# 4: 94.3, 91.9, 89.1 %): the pooled figure must clear the target by that much to hold on a
# seed not seen
SPREAD = 0.03
MARGINS = (1.0, 1.1, 1.2, 1.3, 1.4, 1.5)
KAPPAS = (2.0, 2.5, 3.0, 3.25, 3.5, 4.0, 4.5, 5.0, 6.0)
Evidence = dict[str, np.ndarray]  # per-joint evidence of one event, by statistic


def _first(seconds: float) -> Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]:
    def largest_early(evidence: np.ndarray, _: np.ndarray, stamps: np.ndarray) -> np.ndarray:
        early = stamps - stamps[0] <= seconds * 1e9
        return np.asarray(np.abs(evidence[early]).max(axis=0))

    return largest_early


# per joint, over an event's samples (evidence, score, stamp_ns): detect keeps "largest", which
# streams as a running maximum
STATISTICS: dict[str, Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]] = {
    "largest": lambda e, s, t: np.abs(e).max(axis=0),
    "at-score-peak": lambda e, s, t: np.abs(e[int(np.argmax(s))]),
    "rms": lambda e, s, t: np.sqrt((e**2).mean(axis=0)),
    "mean-magnitude": lambda e, s, t: np.abs(e).mean(axis=0),
    "first-0.1s": _first(0.1),
    "first-0.3s": _first(0.3),
}


def presses(folder: Path, work: Path, fit_args: list[str]) -> list[tuple[str, Evidence]]:
    """(true link, per-joint evidence of the detect event holding the first flag, by each of
    ``STATISTICS``): the evidence is the residual, over each joint's noise at its speed for a
    model with speed bins (as detect weighs joints)."""
    out = []
    for s in synth(folder, work, fit_args):
        lg = s.log
        stamps = lg.states.stamp_ns
        cal = Calibration.load(work / f"{folder.name}.json")
        white = cal.model.whitened_residual(s.residual, lg.states.velocity)
        evidence = s.residual if white is None else white
        hold = (s.scores >= EventRules().release_level(s.threshold, s.mu)) & s.judged
        events = find_events(
            s.flags, s.scores, evidence, stamps, lg.joint_names, None, EventRules(), hold
        )
        truth = read_links(lg.source, DEFAULT_LINK_TOPIC, lg.states.log_time_ns)
        if truth is None or lg.labels is None:
            continue
        for a, b in runs(lg.labels):
            named = [x for x in truth[a : b + 1] if x]
            if not named:
                continue
            hit = [
                e
                for e in events
                if e.start_ns <= int(stamps[b]) + 200_000_000 and e.end_ns >= int(stamps[a])
            ]
            if hit:
                rows = slice(hit[0].first, hit[0].last + 1)
                values = {
                    name: f(evidence[rows], s.scores[rows], stamps[rows])
                    for name, f in STATISTICS.items()
                }
                out.append((Counter(named).most_common(1)[0][0], values))
    return out


Scan = dict[tuple[float, float], tuple[float, float, list[tuple[str, str]]]]


def scan(found: list[tuple[str, np.ndarray]], rule: LinkIsolator) -> Scan:
    """Per (κ, ρ): right when named, the share named, and the (touched, named) misses."""
    out: Scan = {}
    for kappa, margin in itertools.product(KAPPAS, MARGINS):
        iso = replace(rule, kappa=kappa, margin=margin)
        shown = [(t, n) for t, n in ((t, iso.link(p)) for t, p in found) if n is not None]
        right = sum(t == n for t, n in shown)
        misses = [(t, n) for t, n in shown if t != n]
        out[kappa, margin] = (right / max(len(shown), 1), len(shown) / max(len(found), 1), misses)
    return out


def chosen(table: Scan) -> tuple[float, float] | None:
    """The setting that names the most presses while right ≥ the target plus the seeds' spread."""
    sure = [key for key, row in table.items() if row[0] >= TARGET_RIGHT + SPREAD]
    return max(sure, key=lambda key: table[key][1]) if sure else None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", type=Path, nargs="+", help="synth run sets (dev seeds)")
    parser.add_argument("--fit-args", default="", help="extra options of twincd fit")
    parser.add_argument(
        "--statistic", choices=sorted(STATISTICS), default="largest",
        help="the per-joint evidence of the full scan (detect's: largest)",
    )  # fmt: skip
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        every: list[tuple[str, Evidence]] = []
        seeds: list[str] = []
        for folder in args.folders:
            more = presses(folder, Path(tmp), shlex.split(args.fit_args))
            every += more
            seeds += [folder.name] * len(more)
        cal = Calibration.load(Path(tmp) / f"{args.folders[0].name}.json")
    from twincd.twin.robot import load_robot

    links, depths = child_links(load_robot(cal.robot or "xarm7"), cal.joint_names)
    scale = cal.joint_scale
    assert scale is not None
    rule = LinkIsolator(links, depths, scale, kappa_for(cal.kind, cal.model.statistic))
    rule = replace(rule, margin=margin_for(cal.model.statistic))
    found = [(t, values[args.statistic]) for t, values in every]
    print(f"{len(found)} found presses with a known link; held-out seeds {HELD_OUT_SEEDS} unused")
    print(f"{cal.kind}: κ {rule.kappa:g}, ρ {rule.margin:g} (the model's); κ × ρ scanned")
    print(f"{'κ':>5}{'ρ':>5}{'named':>8}{'right|named':>13}{'right overall':>15}  misses")
    table = scan(found, rule)
    for (kappa, margin), (accuracy, share, misses) in table.items():
        common = Counter(f"{t}→{n}" for t, n in misses).most_common(3)
        print(
            f"{kappa:>5.2f}{margin:>5.2f}{share:>8.1%}{accuracy:>13.1%}"
            f"{accuracy * share:>15.1%}  {common}"
        )
    best = chosen(table)
    if best is not None:
        accuracy, share, misses = table[best]
        print(
            f"the most named with ≥ {TARGET_RIGHT + SPREAD:.0%} right (the target plus the"
            f" spread between seeds): κ {best[0]:g}, ρ {best[1]:g}: {share:.1%} named"
            f" (target ≥ {TARGET_NAMED:.0%}), {accuracy:.1%} right"
        )
        # a miss the evidence cannot fix: the touched link's own joint reads at noise level
        picked = replace(rule, kappa=best[0], margin=best[1])
        own = [
            p[links.index(t)] / scale[links.index(t)]
            for t, p in found
            if picked.link(p) not in (None, t)
        ]
        if own:
            print(
                f"its {len(own)} misses: the touched link's own joint peaks at"
                f" {np.median(own):.1f} noise units (median; max {max(own):.1f}; κ / ρ ="
                f" {best[0] / best[1]:.2f}): what a push through that joint's axis reads"
            )
    print("each statistic's setting by the same rule (named, right|named):")
    for name in STATISTICS:
        other = scan([(t, values[name]) for t, values in every], rule)
        pick = chosen(other)
        top = max(other.values(), key=lambda row: row[0])
        cell = (
            "none clears it"
            if pick is None
            else (f"κ {pick[0]:g}, ρ {pick[1]:g}: {other[pick][1]:.1%}, {other[pick][0]:.1%}")
        )
        print(f"  {name:15s} {cell}; the most right of any: {top[0]:.1%} ({top[1]:.1%} named)")
    if len(args.folders) > 1:
        print("per run set at the model's κ: named, right|named (spread across seeds)")
        for margin in MARGINS:
            iso = replace(rule, margin=margin)
            cells = []
            for folder in args.folders:
                pairs = [(t, iso.link(p)) for (t, p), s in zip(found, seeds) if s == folder.name]
                n = sum(x is not None for _, x in pairs)
                right = sum(t == x for t, x in pairs)
                cells.append(f"{n / max(len(pairs), 1):.0%} {right / max(n, 1):.1%}")
            print(f"  ρ {margin:.1f}: " + " | ".join(cells))
    return 0


if __name__ == "__main__":
    sys.exit(main())
