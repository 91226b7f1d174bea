"""Does the default threshold keep its false-alarm budget on fresh clean logs?

A user calibrates from the little clean data they have (a couple of minutes) and runs `detect`
on hours of clean recordings. This study does exactly that on synthetic plants the twin does
not know (``twincd synth``): per plant, several calibrations, each fitted on its own ≈ 2 min of
clean training paths and thresholded on its own 1–3 min of clean validation paths, and one fresh
clean recording of the same plant (a path no calibration saw: 1 h at 100 Hz, 20 min at 1 kHz).
A calibration **keeps** the budget when its false alarms on the fresh recording (events of
`twincd detect`: hysteresis and merging applied) are at most the Poisson 95 % quantile of
budget × hours (3 in 1 h at 1/h, 1 in 20 min).

    python studies/choose_budget.py make   --work ~/.cache/twincd-budget            # logs
    python studies/choose_budget.py score  --work ~/.cache/twincd-budget            # scores
    python studies/choose_budget.py rules  --work ~/.cache/twincd-budget            # rules
    python studies/choose_budget.py check  --work ~/.cache/twincd-budget            # the CLI

``make`` writes the logs (deterministic per seed); ``score`` fits every calibration with
``twincd fit`` at its defaults and keeps per sample the calibration's score on its validation
logs and on the fresh recording (``.npz`` in the work folder); ``rules`` sets the threshold of
each candidate rule from the validation scores alone and counts the fresh recording's events at
it (the events' own rules, as `detect` applies them); ``check`` runs what a user runs —
``twincd threshold`` then ``twincd detect --json`` on the fresh recording — and prints the table
the docs quote; ``firm`` checks the rule once an hour of clean validation data lets it measure
the tail; ``scales`` sets every calibration's threshold as ``twincd threshold`` does (both
bands, the fit's cross-fitted clean data, the raise on its own logs) once per candidate scale of
the assumed tail (``--scales``: s₀ of ``BULK_TAIL_SCALE``), and counts the combined score's
events on the fresh recording at each (each log is scored once per calibration and cached).
``--rates 100`` or ``--rates 1000`` limits a phase to one rate.

    python studies/choose_budget.py scales --work ~/.cache/twincd-budget --rates 100 \
        --scales 0.35,0.5,0.55,0.6,0.65,0.7
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import stats

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

BUDGET = 1.0  # false alarms per hour: the default
JOINTS = 7  # the synthetic xArm 7's


@dataclass(frozen=True)
class Plan:
    """The run sets of one rate: plants (seeds), calibrations per plant, the fresh length."""

    rate_hz: int
    seeds: tuple[int, ...]
    val_paths: tuple[int, ...]  # validation paths (≈ 28 s each) of each calibration
    fresh_s: float
    train_paths: int = 4  # ≈ 2 min of training paths per calibration

    @property
    def calibrations(self) -> int:
        return len(self.val_paths)


PLANS = {
    100: Plan(100, tuple(range(10, 20)), (2, 4, 6), 3600.0),
    1000: Plan(1000, tuple(range(30, 35)), (2, 6), 1200.0),
}
# seeds no setting was chosen on: the chosen rule's confirmation (``--rates 100c``)
CONFIRM = {
    100: Plan(100, tuple(range(20, 30)), (2, 4, 6), 3600.0),
    1000: Plan(1000, tuple(range(50, 55)), (2, 6), 1200.0),
}
# seeds looked at only once the rule was fixed (``--rates 100f``): the final word
FINAL = {100: Plan(100, tuple(range(40, 50)), (2, 4, 6), 3600.0)}
FRESH_INDEX = 500  # the fresh recording: a path index no calibration uses


def twincd(*args: object, check: bool = True) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "twincd_cli.main", *map(str, args)]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if check and done.returncode not in (0, 1):
        sys.exit(f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stderr}")
    return done


def plant_dir(work: Path, plan: Plan, seed: int) -> Path:
    return work / f"{plan.rate_hz}hz" / f"seed{seed}"


def cal_logs(plan: Plan, c: int, root: Path) -> tuple[list[Path], list[Path]]:
    """Calibration c's own training and validation paths."""
    t0 = c * plan.train_paths
    v0 = sum(plan.val_paths[:c])
    train = [root / "train" / f"train_{i:03d}.mcap" for i in range(t0, t0 + plan.train_paths)]
    val = [root / "val" / f"val_{i:03d}.mcap" for i in range(v0, v0 + plan.val_paths[c])]
    return train, val


def make(work: Path, plan: Plan) -> None:
    from twincd.synth.config import MotionConfig, SynthConfig
    from twincd.synth.write import write_path

    for seed in plan.seeds:
        root = plant_dir(work, plan, seed)
        trains, vals = plan.train_paths * plan.calibrations, sum(plan.val_paths)
        if not (root / "val" / f"val_{vals - 1:03d}.mcap").exists():
            twincd("synth", root, "--seed", seed, "--train", trains, "--val", vals, "--test", 0,
                   "--rate-hz", plan.rate_hz, "--no-rosbag2-copy", "-q", "-j", 2)  # fmt: skip
        fresh = root / "fresh.mcap"
        if not fresh.exists():
            motion = MotionConfig(rate_hz=plan.rate_hz, duration_s=(plan.fresh_s, plan.fresh_s))
            write_path(SynthConfig(motion=motion), seed, "val", FRESH_INDEX, fresh)
        print(f"{plan.rate_hz} Hz seed {seed}: logs ready", file=sys.stderr)


# ------------------------------------------------------------------ scores


@dataclass
class Scores:
    """A calibration's score per sample on one log (or several joined) and which samples are
    judged (outside the filter's edges), at the log's period."""

    score: FloatArray
    judged: BoolArray
    period_s: float
    stamp_ns: NDArray[np.int64]
    labels: BoolArray | None = None  # the real arm's pushes (judged excludes them)
    joints: int = JOINTS  # the robot's (the depth statistic's noise-only median depends on it)

    @property
    def hours(self) -> float:
        return float(np.count_nonzero(self.judged)) * self.period_s / 3600.0


REAL = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "doosan_m0609"


def score_log(path: Path, cal_path: Path) -> Scores:
    """The calibration model's own band scored on one log (``score`` and ``rules``: the rules of
    a one-band score; ``scales`` judges the combined score of every band)."""
    from twincd.calibration import Calibration, clean_rows
    from twincd.prepare.setup import Setup
    from twincd.signal.features import ModelInputs

    cal = Calibration.load(cal_path)
    joints = len(cal.joint_names)
    setup = Setup.from_calibration(cal)
    parts: list[tuple[FloatArray, BoolArray, NDArray[np.int64], BoolArray]] = []
    with setup.open(path, model=cal.model) as stream:
        for frame in stream:
            theta = stream.features.theta
            s = cal.model.scores(
                ModelInputs.of(frame, stream.coulomb_eps, stream.regressor_mask, theta)
            )
            judged = clean_rows(frame.get("labels"), frame.n)
            lab = frame.get("labels")
            lab = np.zeros(frame.n, bool) if lab is None else np.asarray(lab, bool)
            parts.append((np.asarray(s, np.float64), judged, np.asarray(frame["stamp_ns"]), lab))
        period = stream.period_s
    score, judged, stamps, labels = (np.concatenate(c) for c in zip(*parts, strict=True))
    return Scores(
        score, judged.astype(bool), period, stamps.astype(np.int64), labels.astype(bool), joints
    )


def save(path: Path, logs: list[Scores]) -> None:
    tmp = path.with_name(f".{path.stem}.tmp.npz")  # renamed into place: never read half-written
    np.savez_compressed(
        tmp,
        score=np.concatenate([s.score for s in logs]).astype(np.float32),
        judged=np.concatenate([s.judged for s in logs]),
        stamp_ns=np.concatenate([s.stamp_ns for s in logs]),
        log=np.concatenate([np.full(len(s.score), i, np.int16) for i, s in enumerate(logs)]),
        labels=np.concatenate(
            [np.zeros(len(s.score), bool) if s.labels is None else s.labels for s in logs]
        ),
        period_s=logs[0].period_s,
        joints=logs[0].joints,
    )
    tmp.replace(path)


def load(path: Path) -> list[Scores]:
    z = np.load(path)
    out = []
    for i in np.unique(z["log"]):
        at = z["log"] == i
        out.append(
            Scores(
                z["score"][at].astype(np.float64),
                z["judged"][at],
                float(z["period_s"]),
                z["stamp_ns"][at],
                z["labels"][at] if "labels" in z else None,
                int(z["joints"]) if "joints" in z else 6 if "real" in str(path) else JOINTS,
            )
        )
    return out


def calibrations(work: Path, plan: Plan) -> Iterator[tuple[int, int, Path]]:
    for seed in plan.seeds:
        for c in range(plan.calibrations):
            yield seed, c, plant_dir(work, plan, seed) / f"cal{c}"


def score(work: Path, plan: Plan) -> None:
    for seed, c, where in calibrations(work, plan):
        root = plant_dir(work, plan, seed)
        where.mkdir(exist_ok=True)
        if (where / "fresh.npz").exists():
            continue
        train, val = cal_logs(plan, c, root)
        cal = where / "fit.json"
        twincd("fit", *train, "-o", cal, "-q", "--force")
        save(where / "val.npz", [score_log(p, cal) for p in val])
        save(where / "fresh.npz", [score_log(root / "fresh.mcap", cal)])
        print(f"{plan.rate_hz} Hz seed {seed} cal {c}: scored", file=sys.stderr)


def score_real(work: Path) -> None:
    """The real arm's six rotations (test on log i, threshold on log i + 1, fit on the other
    four, as studies/real_arm.py), scored: what each rule's threshold costs in pushes."""
    logs = [REAL / "logs" / f"doosan_dev_{i:02d}" for i in range(6)]
    if not all(p.exists() for p in logs):
        print(f"the real arm's logs are not at {REAL}: skipped", file=sys.stderr)
        return
    for i in range(6):
        where = work / "real" / f"rot{i}"
        where.mkdir(parents=True, exist_ok=True)
        if (where / "test.npz").exists():
            continue
        test, val = logs[i], logs[(i + 1) % 6]
        train = [p for p in logs if p not in (test, val)]
        cal = where / "fit.json"
        twincd("fit", *train, "--robot", REAL / "m0609.urdf", "-o", cal, "-q", "--force")
        save(where / "val.npz", [score_log(val, cal)])
        save(where / "test.npz", [score_log(test, cal)])
        print(f"real arm rotation {i}: scored", file=sys.stderr)


# ------------------------------------------------------------------ rules


def allowed(hours: float, budget: float = BUDGET) -> int:
    """The most false alarms a calibration may give in ``hours`` and keep the budget: the
    Poisson 95 % quantile of budget × hours."""
    return int(stats.poisson.ppf(0.95, budget * hours))


def events(s: Scores, threshold: float, mu: float) -> int:
    """`detect`'s events at ``threshold`` (its hysteresis and merging) on judged samples."""
    from twincd.detection.events import EventRules

    rules = EventRules()
    release = rules.release_level(threshold, mu)
    score = np.where(s.judged, s.score, -np.inf)
    flags = score >= threshold
    hold = score >= release
    count, open_until, last_end = 0, -1, -(10**18)
    merge = rules.merge_ns
    i, n = 0, len(score)
    starts = np.flatnonzero(flags)
    k = 0
    while k < len(starts):
        i = int(starts[k])
        if i <= open_until:
            k += 1
            continue
        # the event lasts while the score holds
        below = np.flatnonzero(~hold[i:])
        end = i + (int(below[0]) - 1 if len(below) else n - 1 - i)
        if s.stamp_ns[i] - last_end > merge:
            count += 1
        last_end = int(s.stamp_ns[end])
        open_until = end
        k = int(np.searchsorted(starts, end + 1))
    return count


Rule = Callable[[list[Scores]], tuple[float, float]]  # validation → (threshold, μ)


def rules_table(work: Path, plans: list[Plan], rules: dict[str, Rule]) -> None:
    for plan in plans:
        rows: dict[str, list[tuple[int, float, float]]] = {name: [] for name in rules}
        for seed, c, where in calibrations(work, plan):
            if not (where / "fresh.npz").exists():
                continue
            val, fresh = load(where / "val.npz"), load(where / "fresh.npz")[0]
            for name, rule in rules.items():
                th, mu = rule(val)
                rows[name].append((events(fresh, th, mu), fresh.hours, th))
            _ = seed, c
        print(f"\n{plan.rate_hz} Hz: {len(next(iter(rows.values())))} calibrations")
        for name, got in rows.items():
            if not got:
                continue
            keep = sum(n <= allowed(h) for n, h, _ in got)
            total = sum(n for n, _, _ in got)
            hours = sum(h for _, h, _ in got)
            ths = [t for _, _, t in got]
            print(
                f"  {name:28s} keep {keep:2d}/{len(got):2d}  events {total:4d} in "
                f"{hours:5.1f} h ({total / hours:6.2f}/h)  threshold median "
                f"{np.median(ths):6.3g} [{min(ths):.3g}, {max(ths):.3g}]"
            )


def real_table(work: Path, rules: dict[str, Rule]) -> None:
    """Per rule on the real arm's rotations: pushes found (a flag within a labelled push or
    200 ms after it), false alarms (events touching no push ± 200 ms) in the clean time."""
    rots = sorted((work / "real").glob("rot*/test.npz"))
    if not rots:
        return
    print(f"\nreal arm: {len(rots)} rotations")
    for name, rule in rules.items():
        found = pushes = alarms = 0
        hours = 0.0
        ths = []
        for t in rots:
            val, test = load(t.parent / "val.npz"), load(t.parent / "test.npz")[0]
            th, mu = rule(val)
            ths.append(th)
            f, p, a = judge_pushes(test, th, mu)
            found, pushes, alarms = found + f, pushes + p, alarms + a
            hours += test.hours
        print(
            f"  {name:28s} found {found:3d}/{pushes}  false alarms {alarms} in "
            f"{60 * hours:.1f} min  thresholds {' '.join(f'{x:.2f}' for x in ths)}"
        )


def judge_pushes(s: Scores, threshold: float, mu: float) -> tuple[int, int, int]:
    """(pushes found, pushes, false alarms) of one labelled log at ``threshold``."""
    from twincd.detection.events import runs

    assert s.labels is not None
    tol = round(0.2 / s.period_s)
    inside = np.where(s.judged | s.labels, s.score, -np.inf)
    flags = inside >= threshold
    spans = runs(s.labels)
    found = sum(1 for a, b in spans if flags[a : b + 1 + tol].any())
    near = s.labels.copy()
    for a, b in spans:
        near[max(0, a - tol) : b + 1 + tol] = True
    release = mu + 0.5 * (threshold - mu)
    hold = inside >= release
    alarms = 0
    for a, b in runs(hold):
        if flags[a : b + 1].any() and not near[a : b + 1].any():
            alarms += 1
    return found, len(spans), alarms


def library_rule(val: list[Scores]) -> tuple[float, float]:
    """twincd's default (``twincd.calibration.threshold.budget_threshold`` for the depth
    statistic)."""
    from twincd.calibration.models import depth_noise_median
    from twincd.calibration.threshold import budget_threshold

    total, ex = merged(val)
    noise = depth_noise_median(val[0].joints)
    th = budget_threshold(ex, total, BUDGET, depth=True, noise_median=noise)  # type: ignore[arg-type]
    return th.value, th.mu


def rice_level(counts: int, hours: float, u: float, mu: float, sigma: float) -> float:
    """Rice's formula for a smooth Gaussian score (the last release's rule): the level x whose
    upcrossing rate is the budget, from the rate at u, λ(x) = λ(u)·exp(−(z_x² − z_u²)/2)."""
    z_u = (u - mu) / sigma
    return mu + sigma * math.sqrt(z_u * z_u + 2.0 * max(math.log(counts / hours / BUDGET), 0.0))


def rice_rule(val: list[Scores]) -> tuple[float, float]:
    """The last release's: Rice's formula from the excursions at μ + 2σ (median, MAD)."""
    from twincd.calibration.tail import LEVELS

    total, ex = merged(val)
    mu, sigma = total.robust()  # type: ignore[attr-defined]
    j = int(np.searchsorted(LEVELS, mu + 2.0 * sigma, side="right")) - 1
    hours = ex.seconds / 3600.0  # type: ignore[attr-defined]
    return rice_level(max(ex.counts[j], 1), hours, float(LEVELS[j]), mu, sigma), mu  # type: ignore[attr-defined]


def merged(val: list[Scores]) -> tuple[object, object]:
    from twincd.calibration.tail import ExcursionCounter
    from twincd.calibration.threshold import ScoreStats

    total, ex = ScoreStats(), None
    for s in val:
        total = total + ScoreStats.from_scores(s.score, s.judged)
        c = ExcursionCounter(s.period_s)
        c.push(s.score, s.judged)
        ex = c.excursions if ex is None else ex + c.excursions
    return total, ex


def exp_rule(
    b0: float, robust: bool = False, level: float = 2.0, upper: float = 0.5, b1: float = 0.0
) -> Rule:
    """An exponential tail of the excursions' peaks above u = μ + level·σ (median, MAD): the
    rate λ(u) counted, the scale β = b0·σ (or the peaks' median excess / ln 2 when larger)."""

    def rule(val: list[Scores]) -> tuple[float, float]:
        from twincd.calibration.tail import LEVELS

        total, ex = merged(val)
        mu, sigma = total.robust()  # type: ignore[attr-defined]
        j = int(np.searchsorted(LEVELS, mu + level * sigma, side="right")) - 1
        u, count = float(LEVELS[j]), ex.counts[j]  # type: ignore[attr-defined]
        hours = ex.seconds / 3600.0  # type: ignore[attr-defined]
        rate = count / hours if upper == 0.5 else stats.chi2.ppf(upper, 2 * count + 2) / 2 / hours
        beta = (b0 + b1 * mu) * sigma
        peaks = ex.peaks[j]  # type: ignore[attr-defined]
        if robust and peaks:
            beta = max(beta, float(np.median(np.asarray(peaks) - u)) / math.log(2))
        return u + beta * math.log(max(rate / BUDGET, 1.0)), mu

    return rule


RULES: dict[str, Rule] = {
    "rice-gaussian (last release)": rice_rule,
    "twincd (bulk-exponential)": library_rule,
    **{f"exp b={b}": exp_rule(b) for b in (0.5, 0.55, 0.6)},
    **{f"exp b={b}+0.3μ": exp_rule(b, b1=0.3) for b in (0.2, 0.25, 0.3)},
    **{f"exp b={b}+0.4μ": exp_rule(b, b1=0.4) for b in (0.1, 0.15, 0.2)},
}


def check(work: Path, plan: Plan) -> None:
    """What a user runs: `twincd threshold` at its defaults, `twincd detect --json` on the fresh
    recording; false alarms = its events."""
    got = []
    for seed, c, where in calibrations(work, plan):
        root = plant_dir(work, plan, seed)
        _, val = cal_logs(plan, c, root)
        cal = where / "cal.json"
        fit = where / "fit.json"
        where.mkdir(exist_ok=True)
        if not fit.exists():
            twincd("fit", *cal_logs(plan, c, root)[0], "-o", fit, "-q", "--force")
        twincd("threshold", *val, "-c", fit, "-o", cal, "-q", "--force")
        done = twincd("detect", root / "fresh.mcap", "-c", cal, "--json", "-q")
        report = json.loads(done.stdout)
        n = sum(len(lg["events"]) for lg in report["logs"])
        th = json.loads(cal.read_text())["threshold"]
        hours = plan.fresh_s / 3600.0
        got.append((seed, c, n, allowed(hours), th["value"]))
        print(f"  seed {seed} cal {c}: {n} event(s), allowed {allowed(hours)}", file=sys.stderr)
    keep = sum(n <= a for _, _, n, a, _ in got)
    events_ = sum(n for _, _, n, _, _ in got)
    hours = len(got) * plan.fresh_s / 3600
    print(f"{plan.rate_hz} Hz: {keep}/{len(got)} calibrations keep the budget "
          f"({events_} events in {hours:.3g} h)")  # fmt: skip


def fresh_bands(path: Path, cal_path: Path) -> tuple[FloatArray, NDArray[np.int64], float]:
    """Each band's score (bands × samples) of one log under a calibration, its stamps and
    period: what the combined score is made of, at any levels."""
    from twincd.calibration import Calibration
    from twincd.prepare.settings import SetupOptions

    cal = Calibration.load(cal_path)
    setup = SetupOptions().resolve(cal).for_logs([path])
    model, score = cal.model, cal.score
    out, stamps = [], []
    with setup.open(path, model=model, jump=score.jump) as stream:
        for frame in stream:
            velocity = np.asarray(frame["velocity"], dtype=np.float64)
            bands, _ = score.band_scores(
                model,
                frame["residual"],
                velocity,
                frame.get("residual_fast"),
                frame.get("edge_factor"),
                frame.get("fast_off"),
            )
            out.append(np.vstack(bands))
            stamps.append(np.asarray(frame["stamp_ns"], dtype=np.int64))
        period = stream.period_s
    return np.hstack(out), np.concatenate(stamps), period


def scales(work: Path, plan: Plan, candidates: list[float]) -> None:
    """Per candidate s₀ of the assumed tail's scale, what ``twincd threshold`` would set on each
    calibration's validation logs and the fit's cross-fitted clean data, and the combined
    score's events on the fresh recording there."""
    import pickle

    from twincd.calibration import Calibration, tail
    from twincd.calibration.threshold import score_log, threshold_from_parts
    from twincd.detection.files import record_false_alarms, tally_false_alarms
    from twincd.prepare.settings import SetupOptions

    chosen = tail.BULK_TAIL_SCALE
    got: dict[float, list[tuple[int, int, float]]] = {c: [] for c in candidates}
    for seed, c, where in calibrations(work, plan):
        root = plant_dir(work, plan, seed)
        train, val = cal_logs(plan, c, root)
        where.mkdir(exist_ok=True)
        fit = where / "fit.json"
        if not fit.exists():
            twincd("fit", *train, "-o", fit, "-q", "--force")
        cal = Calibration.load(fit)
        setup = SetupOptions().resolve(cal).for_logs(val)
        cache = where / "scales.pkl"  # the study's own cache, from this calibration
        if cache.exists():
            parts, bands, stamps, period = pickle.loads(cache.read_bytes())
        else:
            parts = [score_log(p, cal, setup) for p in val]
            bands, stamps, period = fresh_bands(root / "fresh.mcap", fit)
            cache.write_bytes(pickle.dumps((parts, bands, stamps, period)))
        for s0 in candidates:
            tail.BULK_TAIL_SCALE = (s0, chosen[1])
            try:
                th_cal = threshold_from_parts(parts, cal)
                tallies = [tally_false_alarms(p, th_cal, setup) for p in val]
                th_cal = record_false_alarms(th_cal, tallies)
            finally:
                tail.BULK_TAIL_SCALE = chosen
            th = th_cal.require_threshold()
            combined = th_cal.score.combine(list(bands))
            fresh = Scores(combined, np.ones(len(combined), bool), period, stamps)
            got[s0].append((events(fresh, th.value, th.mu), allowed(plan.fresh_s / 3600), th.value))
        print(f"{plan.rate_hz} Hz seed {seed} cal {c}: done", file=sys.stderr)
    hours = plan.fresh_s / 3600
    print(f"\n{plan.rate_hz} Hz, seeds {plan.seeds[0]}–{plan.seeds[-1]}: {len(got[candidates[0]])} "
          f"calibrations, {hours:.3g} h fresh each")  # fmt: skip
    for s0, rows in got.items():
        keep = sum(n <= a for n, a, _ in rows)
        total = sum(n for n, _, _ in rows)
        ths = [t for *_, t in rows]
        print(f"  s0 = {s0:<5g} keep {keep:2d}/{len(rows)}  events {total:4d} in "
              f"{hours * len(rows):.3g} h  threshold median {np.median(ths):.3g} "
              f"[{min(ths):.3g}, {max(ths):.3g}]")  # fmt: skip


FIRM_SEEDS = (10, 11, 12, 13, 14)


def firm(work: Path) -> None:
    """With an hour of clean validation data the tail is measured, not assumed: per plant of
    ``FIRM_SEEDS`` (100 Hz), calibration 1's fit thresholded on a second fresh hour (a path no
    calibration saw) by twincd's rule, judged on the first."""
    from twincd.synth.config import MotionConfig, SynthConfig
    from twincd.synth.write import write_path

    plan = PLANS[100]
    rows = []
    for seed in FIRM_SEEDS:
        root = plant_dir(work, plan, seed)
        val = root / "fresh_val.mcap"
        if not val.exists():
            motion = MotionConfig(rate_hz=plan.rate_hz, duration_s=(plan.fresh_s, plan.fresh_s))
            write_path(SynthConfig(motion=motion), seed, "val", FRESH_INDEX + 1, val)
        where = root / "cal1"
        if not (where / "firm_val.npz").exists():
            save(where / "firm_val.npz", [score_log(val, where / "fit.json")])
        from twincd.calibration.models import depth_noise_median
        from twincd.calibration.threshold import budget_threshold

        total, ex = merged(load(where / "firm_val.npz"))
        noise = depth_noise_median(JOINTS)
        th = budget_threshold(ex, total, BUDGET, depth=True, noise_median=noise)  # type: ignore[arg-type]
        fresh = load(where / "fresh.npz")[0]
        n = events(fresh, th.value, th.mu)
        assert th.tail is not None
        rows.append((seed, th.tail.method, th.value, n, allowed(fresh.hours)))
    print("\n100 Hz, an hour of clean validation data:")
    for seed, method, value, n, ok in rows:
        print(f"  seed {seed}: {method} threshold {value:.3g}: {n} event(s), allowed {ok}")
    keep = sum(n <= ok for *_, n, ok in rows)
    print(f"  {keep}/{len(rows)} keep the budget")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("phase", choices=["make", "score", "rules", "check", "firm", "scales"])
    ap.add_argument("--work", type=Path, required=True, help="folder for logs and scores")
    ap.add_argument(
        "--rates",
        default="100,1000",
        help="comma-separated: 100, 1000 (100c, 1000c: confirmation seeds; 100f: the final set)",
    )
    ap.add_argument(
        "--scales", default="0.35,0.5,0.55,0.6,0.65,0.7", help="scales: the candidate s₀"
    )
    args = ap.parse_args()
    sets = {"c": CONFIRM, "f": FINAL}
    plans = [
        sets[r[-1]][int(r[:-1])] if r[-1] in sets else PLANS[int(r)] for r in args.rates.split(",")
    ]
    args.work.mkdir(parents=True, exist_ok=True)
    if args.phase == "rules":
        rules_table(args.work, plans, RULES)
        real_table(args.work, RULES)
        return 0
    if args.phase == "firm":
        firm(args.work)
        return 0
    if args.phase == "scales":
        for plan in plans:
            scales(args.work, plan, [float(x) for x in args.scales.split(",")])
        return 0
    if args.phase == "score":
        score_real(args.work)
    for plan in plans:
        {"make": make, "score": score, "check": check}[args.phase](args.work, plan)
    return 0


if __name__ == "__main__":
    _ = math
    raise SystemExit(main())
