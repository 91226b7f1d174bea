"""How the isolation margin ρ was chosen (``twincd.detection.isolation``): a link is named only
when every significance level in [κ / ρ, κ × ρ] names it; otherwise the event says ``null`` with
its candidates.

On synth development seeds only (the real arm has no link labels; seeds 0 and 1 hold the test
paths kept for the README's figures): fit and threshold as a user does, detect the test paths
with the default event rules, and for every found press whose ground-truth link is known
(``/collision_link``) compare the link the rule names at each ρ. Targets: named links right
≥ 90 % of the time they are named, a link named for ≥ 70 % of found presses.

    twincd synth /tmp/ev_s2 --seed 2 --train 10 --val 10 --test 20 --no-rosbag2-copy
    python studies/choose_isolation.py /tmp/ev_s2 [/tmp/ev_s4 ...] [--fit-args ...]
"""

from __future__ import annotations

import argparse
import itertools
import shlex
import sys
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np
from choose_events import HELD_OUT_SEEDS, synth  # type: ignore[import-not-found]

from twincd.calibration import Calibration
from twincd.defaults import DEFAULT_LINK_TOPIC
from twincd.detection.events import EventRules, find_events, runs
from twincd.detection.isolation import LinkIsolator, kappa_for
from twincd.io.links import read_links
from twincd.twin.robot import child_links

MARGINS = (1.0, 1.2, 1.5)
KAPPAS = (2.0, 3.0, 3.25, 4.0, 5.0, 6.0, 8.0)


def presses(folder: Path, work: Path, fit_args: list[str]) -> list[tuple[str, np.ndarray]]:
    """(true link, per-joint largest |evidence| of the detect event holding the first flag): the
    evidence is the residual, over each joint's noise at its speed for a model with speed bins
    (as detect weighs joints)."""
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
                e = hit[0]
                peak = np.abs(evidence[e.first : e.last + 1]).max(axis=0)
                out.append((Counter(named).most_common(1)[0][0], peak))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", type=Path, nargs="+", help="synth run sets (dev seeds)")
    parser.add_argument("--fit-args", default="", help="extra options of twincd fit")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        found = []
        for folder in args.folders:
            found += presses(folder, Path(tmp), shlex.split(args.fit_args))
        cal = Calibration.load(Path(tmp) / f"{args.folders[0].name}.json")
    from twincd.twin.robot import load_robot

    robot = load_robot(cal.robot or "xarm7")
    links, depths = child_links(robot, cal.joint_names)
    scale = cal.joint_scale
    assert scale is not None
    print(f"{len(found)} found presses with a known link; held-out seeds {HELD_OUT_SEEDS} unused")
    print(
        f"{cal.kind}: κ {kappa_for(cal.kind, cal.model.statistic):g} (the model's); κ × ρ scanned"
    )
    print(f"{'κ':>5}{'ρ':>5}{'named':>8}{'right|named':>13}{'right overall':>15}  misses")
    for kappa, margin in itertools.product(KAPPAS, MARGINS):
        iso = LinkIsolator(links, depths, scale, kappa, margin)
        named = [(t, iso.link(p)) for t, p in found]
        shown = [(t, n) for t, n in named if n is not None]
        right = sum(t == n for t, n in shown)
        misses = Counter(f"{t}→{n}" for t, n in shown if t != n).most_common(3)
        print(
            f"{kappa:>5.2f}{margin:>5.2f}{len(shown) / max(len(found), 1):>8.1%}"
            f"{right / max(len(shown), 1):>13.1%}{right / max(len(found), 1):>15.1%}  {misses}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
