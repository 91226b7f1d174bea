"""What limits isolation — on a development run set of its own, never on `sample_logs/test`.

The isolation rule of the time (detect has since moved to the value at the peak score, chosen
by ``choose_isolation.py``) names the child link of the deepest joint whose residual, at its
largest during the flagged run, reaches κ times the joint's training RMS. Where it is wrong,
this study asks why, with the plant's ground truth that ``twincd synth`` can regenerate for any
path: the push's own joint torques, through the same filter and in the same units (``true z``).
Each miss falls in one of these kinds:

- **below the noise**: the push's own torque on the next joint after the named link stays under
  κ (a push whose line of action passes near that joint's axis). The residual cannot show it to
  any rule on joint torques: a push on link k+1 there loads the same joints as one on link k.
- **noise hid it**: the push's torque on that joint reached κ, the measured residual did not.
- **too deep**: a joint beyond the touched link, where the push makes no torque at all, reached
  κ by noise over the run (a long run of a large push gives the noise many chances).

It then prints the kept rule beside alternatives on the same flagged runs: κ from 2.5 to 4.5,
a κ that grows with the run's length n as the largest of n Gaussian samples does (κ² + 2 ln
(n / n₀)), the largest magnitude only within ±W samples of the score's peak, and a matched
filter (each joint's residual projected on the time profile of the strongest one, over the
noise's own spread along that profile, from the clean residual's autocorrelation on the val/
paths); and, as a ceiling, the kept rule on the noise-free push torques (``true z``), which no
rule on these residuals can beat.

The run set must come from a seed other than 0 (`sample_logs/`) and 1 (the full protocol),
whose test paths are held out:

    twincd synth /tmp/dev2 --seed 2 --train 10 --val 40 --test 40 -j 2
    twincd fit /tmp/dev2/train --model identified-whitened -o /tmp/dev2/cal.json
    twincd threshold /tmp/dev2/val -c /tmp/dev2/cal.json --false-alarms-per-hour 1
    python studies/isolation_limits.py /tmp/dev2 --seed 2
"""

from __future__ import annotations

import argparse
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from twincd.calibration.file import Calibration
from twincd.detection.events import runs
from twincd.detection.isolation import LinkIsolator
from twincd.evaluation.methods import make_method
from twincd.evaluation.own import ModelMethod
from twincd.prepare.setup import Setup
from twincd.synth.config import SynthConfig
from twincd.synth.plant import make_plant
from twincd.synth.simulate import simulate_path
from twincd.twin.robot import child_links

HELD_OUT_SEEDS = (0, 1)  # sample_logs/ and the full protocol: their test paths are never read
KAPPAS = (2.5, 3.0, 3.25, 3.5, 3.75, 4.0, 4.5)

EVERY = 1.0  # ρ: the rule of the time named a link for every event


@dataclass(frozen=True)
class FlaggedPress:
    """One flagged run inside a press, in units of each joint's training RMS."""

    truth: str
    signed: np.ndarray  # residual / scale over the run, (n, joints)
    score: np.ndarray  # the score over the run
    true_z: np.ndarray  # the push's own filtered torque, largest |.| / scale per joint

    @property
    def run(self) -> np.ndarray:
        out: np.ndarray = np.abs(self.signed)
        return out

    @property
    def largest(self) -> np.ndarray:
        out: np.ndarray = self.run.max(axis=0)
        return out


def flagged_presses(dev: Path, seed: int) -> tuple[list[FlaggedPress], LinkIsolator, float]:
    """Every flagged run that overlaps a press with force, in the dev set's test paths."""
    calibration = Calibration.load(dev / "cal.json")
    setup = Setup.from_calibration(calibration)
    method = make_method(calibration.model.kind).from_calibration(calibration)
    assert isinstance(method, ModelMethod)
    model = method.model_
    scale = model.scale if model.scale is not None else method.rmse_
    threshold = calibration.require_threshold().value
    plant = make_plant(SynthConfig().plant, seed)
    presses: list[FlaggedPress] = []
    isolator = None
    paths = sorted((dev / "test").glob("test_*.mcap"))
    if not paths:
        raise SystemExit(f"{dev / 'test'} holds no test_*.mcap paths")
    for path in paths:
        log = setup.prepare(path, calibration.model.features)
        truth = simulate_path(SynthConfig(), seed, "test", int(path.stem.split("_")[1]))
        if len(truth.effort) != len(log) or not np.allclose(
            truth.effort, log.effort, atol=1e-4, rtol=1e-5
        ):
            raise SystemExit(f"{path} is not path {path.stem} of seed {seed}: give its --seed")
        assert log.robot is not None
        links, depths = child_links(log.robot, log.joint_names)
        kappa = 3.25 if model.kind.startswith("identified") else 3.0  # the rule's κ of the time
        isolator = LinkIsolator(links, depths, scale, kappa, EVERY)
        residual = method.residual(log)
        score = model.score(residual)
        judged = ~log.edge if log.edge is not None else np.ones(len(score), dtype=bool)
        # the push appears in the effort as −τ_ext ⊘ gain, filtered like it
        push = log.lowpass.apply(log.states.t_s, truth.tau_ext / plant.gain)
        for first, last in runs((score >= threshold) & judged):
            touched = [x for x in truth.contact_link[first : last + 1] if x]
            if not touched:
                continue
            span = slice(first, last + 1)
            presses.append(
                FlaggedPress(
                    truth=max(set(touched), key=touched.count),
                    signed=residual[span] / scale,
                    score=score[span],
                    true_z=np.abs(push[span]).max(axis=0) / scale,
                )
            )
    assert isolator is not None
    return presses, isolator, threshold


def kind_of_miss(press: FlaggedPress, named: str, isolator: LinkIsolator) -> str:
    links, kappa = isolator.links, isolator.kappa
    touched, said = links.index(press.truth), links.index(named)
    if said > touched:
        return "too deep"
    if press.true_z[said + 1] < kappa:
        return "below the noise"
    return "noise hid it"


def around_peak(press: FlaggedPress, half_width: int) -> np.ndarray:
    peak = int(np.argmax(press.score))
    out: np.ndarray = press.run[max(peak - half_width, 0) : peak + half_width + 1].max(axis=0)
    return out


def noise_autocorrelation(dev: Path, lags: int = 400, logs: int = 20) -> np.ndarray:
    """The clean residual's autocorrelation (scale units, pooled over joints) on val/ paths."""
    calibration = Calibration.load(dev / "cal.json")
    setup = Setup.from_calibration(calibration)
    method = make_method(calibration.model.kind).from_calibration(calibration)
    total = np.zeros(lags)
    for path in sorted((dev / "val").glob("*.mcap"))[:logs]:
        log = setup.prepare(path, calibration.model.features)
        r = method.residual(log)
        r = r[~log.edge] if log.edge is not None else r
        r = r - r.mean(axis=0)
        spectrum = np.fft.rfft(r, 2 * len(r), axis=0)
        total += np.fft.irfft(spectrum * np.conj(spectrum), axis=0)[:lags].sum(axis=1)
    out: np.ndarray = total / total[0]
    return out


def matched(press: FlaggedPress, rho: np.ndarray) -> np.ndarray:
    """Per joint: the run projected on the strongest joint's profile, in noise units."""
    profile = press.signed[:, int(np.argmax(press.largest))]
    lag = np.abs(np.subtract.outer(np.arange(len(profile)), np.arange(len(profile))))
    covariance = np.where(lag < len(rho), rho[np.minimum(lag, len(rho) - 1)], 0.0)
    spread = float(np.sqrt(max(profile @ covariance @ profile, 1e-12)))
    out: np.ndarray = np.abs(press.signed.T @ profile) / spread
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("dev", type=Path, help="a `twincd synth` folder with test/ and cal.json")
    parser.add_argument("--seed", type=int, required=True, help="the seed it was made with")
    args = parser.parse_args()
    if args.seed in HELD_OUT_SEEDS:
        raise SystemExit(f"seed {args.seed}'s test paths are held out: make a dev set of another")
    presses, kept, threshold = flagged_presses(args.dev, args.seed)
    # the kept rule works on the residual in scale units: its scale is one here
    unit = LinkIsolator(kept.links, kept.depths, np.ones(len(kept.links)), kept.kappa, EVERY)
    misses: Counter[tuple[str, str, str]] = Counter()
    for p in presses:
        named = unit.link(p.largest)
        if named != p.truth:
            misses[p.truth, named, kind_of_miss(p, named, unit)] += 1
    right = len(presses) - sum(misses.values())
    print(
        f"{len(presses)} flagged presses at threshold {threshold:.4g}; the kept rule (κ = "
        f"{kept.kappa:g}) names {right} right ({right / len(presses):.1%})"
    )
    by_kind: Counter[str] = Counter()
    for (truth, named, kind), n in misses.most_common():
        by_kind[kind] += n
        print(f"  {truth} → {named}: {n} ({kind})")
    print("  misses by kind: " + ", ".join(f"{k} {n}" for k, n in by_kind.most_common()))

    rho = noise_autocorrelation(args.dev)
    projected = [matched(p, rho) for p in presses]
    print("alternatives on the same runs (share named right):")
    for kappa in KAPPAS:
        rule = LinkIsolator(unit.links, unit.depths, unit.scale, kappa, EVERY)
        columns = {
            "max": [rule.link(p.largest) for p in presses],
            **{f"κ²+2ln(n/{n0})": [length_rule(p, rule, n0) for p in presses] for n0 in (25, 50)},
            **{
                f"±{half} of peak": [rule.link(around_peak(p, half)) for p in presses]
                for half in (10, 25)
            },
            "matched": [rule.link(z) for z in projected],
            "noise-free": [rule.link(p.true_z) for p in presses],
        }
        cells = [f"{key} {share(named, presses):.3f}" for key, named in columns.items()]
        print(f"  κ {kappa:<5g}" + "  ".join(cells))


def share(named: list[str], presses: list[FlaggedPress]) -> float:
    return float(np.mean([n == p.truth for n, p in zip(named, presses, strict=True)]))


def length_rule(press: FlaggedPress, rule: LinkIsolator, n0: int) -> str:
    """κ grown with the run's length n as the largest of n Gaussian samples grows."""
    kappa = float(np.sqrt(rule.kappa**2 + 2 * np.log(max(len(press.run) / n0, 1.0))))
    return LinkIsolator(rule.links, rule.depths, rule.scale, kappa, EVERY).link(press.largest)


if __name__ == "__main__":
    main()
