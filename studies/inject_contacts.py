"""What the detector finds on real noise: known contact torques injected into clean logs.

A contact's truth is exact when it is added to the *measured effort* of a clean log: a half-sine
strike or a trapezoid push (ramps of min(0.1 s, d/4)) of a given length and size on one or two
joints chosen at random (the same draws at every size), with random signs, and its span as
the label. This study does that on the real arms' recordings, read from ``../shared/data/``
beside the repository when present (or ``--data``; they are not part of the project, and
nothing derived from them is written into it), and on ``twincd synth`` plants, and runs
twincd on them as a user does — ``fit`` → ``threshold`` → ``detect``, the library's command
functions (``twincd.fit_calibration``, ``threshold_calibration``, ``detect_files``) with the
CLI's defaults — for each configuration:

    python studies/inject_contacts.py                              # every arm and configuration
    python studies/inject_contacts.py --arms doosan --configs default cutoff-1.5
    python studies/inject_contacts.py --configs default --extra c4 "--cutoff 4" "-k 4"
    python studies/inject_contacts.py --work /tmp/inject --json /tmp/inject.json

Arms (each judged on logs its calibration never saw):

- ``doosan``: Doosan M0609, 100 Hz, six ≈ 126 s logs with labelled pushes; rotation i tests on
  log i, thresholds on log i+1 and fits on the other four (as ``studies/real_arm.py``).
  Injections only ≥ 1.5 s from any labelled push; a copy's label is the union of both.
  In every log, contacts also keep 1.5 s from stretches where every joint's effort is exactly
  0 (the drives off: 78–100 s of ``doosan_dev_01``; a recorder's glitch in a UR10e log).
- ``ur10e``: UR10e, 100 Hz, 22 clean logs in three folds (each group of logs, sorted by name,
  dealt round-robin); fold k fits on the excitation logs (``…harm``) of the other folds,
  thresholds on the first single-joint sweep and the longest other log of fold k+1, and tests
  on fold k's logs, so that every log is tested once.
- ``panda``: Franka Panda, 1 kHz, one 21 s excitation run cut into six 3.5 s windows; rotation
  r tests on windows 2r and 2r+1 (one 7 s log), thresholds on window 2r+2 and fits on the
  other three.
- ``synth-100`` and ``synth-1k``: ``twincd synth`` at 100 Hz (seed 2) and 1 kHz (seed 3),
  fitted on train/, thresholded on two val/ paths, tested on the other val/ paths.

Contacts: strikes (half-sine) and pushes (trapezoid) at every length, 0.02, 0.05, 0.1, 0.2,
0.5, 1 and 3 s (``--shapes by-length``: strikes up to 0.2 s, pushes from 0.5 s, half the
copies to detect), of 5/10/20/40 N·m (2/5/10/20 N·m on the Panda), at least
``--per-cell`` (20) per cell pooled over the rotations; several per injected copy of a test log
(≥ 2.5 s apart, ≥ 0.3 s from its ends), as many copies as needed; deterministic (``--seed``).
A contact is **found** when an event of ``detect`` overlaps [start, end + 200 ms]; its delay is
the first such event's start − the contact's start (≥ 0). **False alarms** are the events on
the uninjected test logs that touch no labelled push ± 200 ms (``detect``'s own count), pooled
over each arm's judged clean time; "also on clean" counts the contacts whose window an event
of the uninjected log overlaps too (found, if found, partly by chance). The **SNR ceiling** d′
of a cell is what a matched filter could reach on that arm's noise: d′² = Σ_f |P(f)|² / S_j(f)
summed over the contact's joints (noise taken independent across joints), S_j being Welch's
spectrum of joint j's residual on the clean test samples under a near-raw calibration (the
default model at a Butterworth cut-off of 0.4 × the rate, its zero-phase gain divided out,
frequencies above the cut-off left out); the tables give the median over the cell's contacts.
The Doosan's own labelled pushes are also counted found per labelled duration: an injected
torque ignores the motion it would cause and the controller's answer, real contacts do not.

Configurations (``--configs``): ``default`` (no options), ``cutoff-X`` (``fit --cutoff X``,
``threshold --false-alarms-per-hour 1``) for X in 1, 1.5, 3, 5, 10, and the same with
``fit --causal`` (``causal``, ``causal-cutoff-X``); ``--extra NAME FIT_ARGS THRESHOLD_ARGS``
adds any other pair of options (fit: ``--cutoff``, ``--causal``, ``--model``,
``--filter-order``, ``--filter-kind``; threshold: ``-k``, ``--false-alarms-per-hour``). A
configuration the library refuses (a cut-off the rate cannot carry) is reported as skipped,
with the library's reason.

Everything is cached in ``--work``: the windows, ``synth`` logs and injected copies (keyed by
the injection plan), the calibrations and each configuration's detections (keyed also by a
digest of the installed twincd's source, so a changed library refits). One process, ``jobs=1``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import math
import shlex
import subprocess
import sys
import tempfile
import time
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import twincd
from twincd.errors import TwincdError

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
WORK = Path(tempfile.gettempdir()) / "twincd-inject"

STRIKES = (0.02, 0.05, 0.1, 0.2)  # half-sine strikes (s)
PUSHES = (0.5, 1.0, 3.0)  # trapezoid pushes (s)
AMPLITUDES = (5.0, 10.0, 20.0, 40.0)  # N·m
PANDA_AMPLITUDES = (2.0, 5.0, 10.0, 20.0)
GAP_S = 2.5  # between one contact's end and the next one's start
END_S = 0.3  # from a log's ends
EDGE_NOISE = 1.05  # a sample's filtered noise over the middle's, at most, for the spectrum
LABEL_GUARD_S = 1.5  # from any labelled push (the Doosan)
AFTER_NS = 200_000_000  # an event up to 200 ms after a contact still finds it
JITTER_S = 1.0  # a random shift before each contact, so contacts meet every phase of motion
WELCH_S = 4.0  # Welch segment length (rounded to a power of two in samples)
NEAR_RAW = 0.4  # the near-raw calibration's cut-off, × the rate
PLAN_VERSION = 4
NEAR_END_S = 1.0  # contacts this close to a log's end are also counted apart
CUTOFFS = ("1", "1.5", "3", "5", "10")
BUDGET = "--false-alarms-per-hour 1"
# a single cut-off is the filter's band alone: without the fast band the default fit adds
SINGLE = "--fast-cutoff 0"
# real labelled pushes by their labelled duration (s)
BINS = ((0.0, 0.2), (0.2, 0.5), (0.5, 1.0), (1.0, 3.0), (3.0, math.inf))

log = logging.getLogger("inject")


# ------------------------------------------------------------------ configurations


@dataclass(frozen=True)
class Config:
    """A configuration as a user types it: the options of ``fit`` and of ``threshold``."""

    name: str
    fit_args: str = ""
    threshold_args: str = ""
    cli: bool = False  # run fit and threshold through the CLI (any of their options)

    def fit_options(self) -> dict[str, Any]:
        """The library's keyword arguments for ``fit_args`` (the options the named
        configurations use; others need ``cli``)."""
        parser = argparse.ArgumentParser(prog=f"{self.name}: fit", add_help=False)
        parser.add_argument("--cutoff", type=float, dest="cutoff_hz")
        parser.add_argument("--causal", action="store_true", default=None)
        parser.add_argument("--model")
        parser.add_argument("--filter-order", type=int)
        parser.add_argument("--filter-kind")
        parser.add_argument("--fast-cutoff", type=float, dest="fast_cutoff_hz")
        given = vars(parser.parse_args(shlex.split(self.fit_args)))
        return {k: v for k, v in given.items() if v is not None}

    def threshold_options(self) -> dict[str, Any]:
        parser = argparse.ArgumentParser(prog=f"{self.name}: threshold", add_help=False)
        parser.add_argument("-k", "--sigma", type=float, dest="k_sigma")
        parser.add_argument("--false-alarms-per-hour", type=float)
        given = vars(parser.parse_args(shlex.split(self.threshold_args)))
        return {k: v for k, v in given.items() if v is not None}


def named_configs(single: str = SINGLE) -> dict[str, Config]:
    """The defaults and the single cut-offs (the filter's band alone: ``single``, the option
    that asks for it, empty for a twincd that judges one band anyway)."""
    configs = [Config("default")]
    configs += [Config(f"cutoff-{c}", f"--cutoff {c} {single}".strip(), BUDGET) for c in CUTOFFS]
    configs += [Config("causal", "--causal")]
    configs += [
        Config(f"causal-cutoff-{c}", f"--causal --cutoff {c} {single}".strip(), BUDGET)
        for c in CUTOFFS
    ]
    return {c.name: c for c in configs}


# ------------------------------------------------------------------ arms


@dataclass(frozen=True)
class Rotation:
    fit: tuple[Path, ...]
    threshold: tuple[Path, ...]
    test: tuple[Path, ...]


@dataclass(frozen=True)
class Arm:
    name: str
    robot: str | None  # None: the default robot (twincd synth's xArm 7)
    rate_hz: float
    amplitudes: tuple[float, ...]
    rotations: tuple[Rotation, ...]
    groups: dict[str, str] = field(default_factory=dict)  # test log name → its group
    labelled: bool = False  # the test logs carry real labels

    def options(self) -> dict[str, Any]:
        return {} if self.robot is None else {"robot": self.robot}


def log_name(path: Path) -> str:
    return path.stem if path.suffix == ".mcap" else path.name


def doosan(data: Path) -> Arm | None:
    root = data / "doosan_m0609"
    logs = [root / "logs" / f"doosan_dev_{i:02d}" for i in range(6)]
    if not all(p.is_dir() for p in logs):
        return None
    rotations = []
    for i in range(6):
        test, val = logs[i], logs[(i + 1) % 6]
        fit = tuple(p for p in logs if p not in (test, val))
        rotations.append(Rotation(fit, (val,), (test,)))
    urdf = str(root / "m0609.urdf")
    return Arm("doosan", urdf, 100.0, AMPLITUDES, tuple(rotations), labelled=True)


def ur10e(data: Path) -> Arm | None:
    root = data / "ur10e_clean"
    if not (root / "logs.json").is_file():
        return None
    listed = json.loads((root / "logs.json").read_text())
    group = {x["log"]: x["group"] for x in listed}
    seconds = {x["log"]: x["seconds"] for x in listed}
    harm = sorted(n for n in group if "harm" in n)
    other = sorted(n for n in group if "harm" not in n)
    fold = {n: i % 3 for names in (harm, other) for i, n in enumerate(names)}
    path = {n: root / "logs" / n for n in group}
    rotations = []
    for k in range(3):
        nxt = [n for n in other if fold[n] == (k + 1) % 3]
        sweep = next(n for n in nxt if group[n] == "jointwise_motion")
        longest = max((n for n in nxt if group[n] != "jointwise_motion"), key=seconds.get)
        rotations.append(
            Rotation(
                fit=tuple(path[n] for n in harm if fold[n] != k),
                threshold=(path[sweep], path[longest]),
                test=tuple(path[n] for n in sorted(group) if fold[n] == k),
            )
        )
    return Arm("ur10e", str(root / "ur10e.urdf"), 100.0, AMPLITUDES, tuple(rotations), group)


def panda(data: Path, work: Path) -> Arm | None:
    source = data / "panda_excitation" / "panda_excite_gaz2019"
    if not source.is_dir():
        return None
    folder = work / "panda" / "windows"
    windows = [folder / f"window_{k}.mcap" for k in range(6)]
    tests = [folder / f"test_{r}.mcap" for r in range(3)]
    if not all(p.is_file() for p in (*windows, *tests)):
        states = twincd.read_log(source)
        t = states.t_s
        width = 3.5

        def cut(path: Path, a: float, b: float) -> None:
            rows = (t >= a) & (t < b)
            write_log(path, states, rows, states.effort[rows])

        for k, path in enumerate(windows):
            cut(path, k * width, (k + 1) * width)
        for r, path in enumerate(tests):
            cut(path, 2 * r * width, (2 * r + 2) * width)
    rotations = []
    for r in range(3):
        val = (2 * r + 2) % 6
        fit = tuple(windows[k] for k in range(6) if k not in (2 * r, 2 * r + 1, val))
        rotations.append(Rotation(fit, (windows[val],), (tests[r],)))
    return Arm("panda", "panda", 1000.0, PANDA_AMPLITUDES, tuple(rotations))


def synth(work: Path, name: str, rate: float, seed: int, counts: tuple[int, int]) -> Arm:
    folder = work / name / "logs"
    train, val = counts
    if not (folder / "val" / f"val_{val - 1:03d}.mcap").is_file():
        more = ["--min-duration", "15", "--max-duration", "20"] if rate > 100 else []
        cmd = [sys.executable, "-m", "twincd_cli.main", "synth", str(folder), "--seed", str(seed)]
        cmd += ["--train", str(train), "--val", str(val), "--test", "0", "--rate-hz", str(rate)]
        subprocess.run(
            [*cmd, *more, "--no-rosbag2-copy", "-q"], check=True, stdout=subprocess.DEVNULL
        )
    fit = tuple(sorted((folder / "train").glob("*.mcap")))
    vals = sorted((folder / "val").glob("*.mcap"))
    return Arm(name, None, rate, AMPLITUDES, (Rotation(fit, tuple(vals[:2]), tuple(vals[2:])),))


def arms_wanted(names: Sequence[str], data: Path, work: Path) -> list[Arm]:
    makers = {
        "doosan": lambda: doosan(data),
        "ur10e": lambda: ur10e(data),
        "panda": lambda: panda(data, work),
        "synth-100": lambda: synth(work, "synth-100", 100.0, 2, (6, 6)),
        "synth-1k": lambda: synth(work, "synth-1k", 1000.0, 3, (4, 5)),
    }
    arms = []
    for name in names:
        arm = makers[name]()
        if arm is None:
            print(f"{name}: its recordings are not in {data}: not studied")
        else:
            arms.append(arm)
    return arms


# ------------------------------------------------------------------ writing logs


def write_log(
    path: Path,
    states: Any,
    rows: np.ndarray,
    effort: np.ndarray,
    labels: np.ndarray | None = None,
) -> None:
    """``states``' ``rows`` as a bare ros2 MCAP with ``effort`` as the measured effort (header
    stamps kept, log time = stamp) and, when given, ``labels`` on the label topic (each
    change at its sample's stamp)."""
    from twincd.defaults import DEFAULT_LABEL_TOPIC
    from twincd.io.cdr import BOOL, JOINT_STATE, bool_cdr, joint_state_cdr
    from twincd.io.mcap import McapLogWriter

    stamps = states.stamp_ns[rows]
    payloads = list(
        joint_state_cdr(
            stamps, states.joint_names, states.position[rows], states.velocity[rows], effort
        )
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    with McapLogWriter(path) as out:
        channel = out.add_topic(states.topic, JOINT_STATE)
        out.write_many(channel, stamps, payloads)
        if labels is not None:
            flag = out.add_topic(DEFAULT_LABEL_TOPIC, BOOL)
            values = labels.astype(np.int8)
            changes = np.flatnonzero(np.diff(values, prepend=values[0]))
            for i in [0, *changes.tolist()]:
                out.write(flag, int(stamps[i]), bool_cdr(bool(labels[i])))


# ------------------------------------------------------------------ contacts


def cells(arm: Arm, shapes: str) -> list[tuple[str, float, float]]:
    """(shape, duration s, amplitude) of every cell."""
    out = []
    for d in (*STRIKES, *PUSHES):
        kinds = ("strike", "push") if shapes == "both" else ("strike" if d in STRIKES else "push",)
        out += [(kind, d, a) for kind in kinds for a in arm.amplitudes]
    return out


def pulse(shape: str, duration: float, t: np.ndarray) -> np.ndarray:
    """The unit contact at times ``t`` (s from its start): a half-sine strike or a trapezoid
    push with ramps of min(0.1 s, d/4); zero outside [0, duration]."""
    inside = (t >= 0) & (t <= duration)
    if shape == "strike":
        return np.where(inside, np.sin(np.pi * np.clip(t / duration, 0, 1)), 0.0)
    ramp = min(0.1, duration / 4)
    up = np.clip(t / ramp, 0, 1)
    down = np.clip((duration - t) / ramp, 0, 1)
    return np.where(inside, np.minimum(up, down), 0.0)


def cell_key(shape: str, duration: float, amplitude: float) -> str:
    return f"{shape} {duration:g} s {amplitude:g} Nm"


@dataclass
class TestLog:
    """A clean test log: its stamps, the spans a contact may use, its real labelled pushes and
    the stretches where every joint's effort is exactly 0 (drives off: no noise to study)."""

    path: Path
    stamp_ns: np.ndarray
    free: list[tuple[float, float]]  # (from, to) s since the first stamp
    pushes: list[tuple[int, int]]  # real labelled spans (first, last stamp ns)
    off: list[tuple[int, int]]  # efforts all 0 (first, last stamp ns)

    @classmethod
    def read(cls, path: Path) -> TestLog:
        from twincd.detection.events import runs

        states = twincd.read_log(path)
        t = states.t_s
        blocked = [(-math.inf, END_S), (t[-1] - END_S, math.inf)]
        spans = {"pushes": [], "off": []}
        for kind, where in (("pushes", states.labels), ("off", np.all(states.effort == 0, 1))):
            for a, b in runs(where) if where is not None else []:
                spans[kind].append((int(states.stamp_ns[a]), int(states.stamp_ns[b])))
                blocked.append((t[a] - LABEL_GUARD_S, t[b] + LABEL_GUARD_S))
        free, at = [], -math.inf
        for a, b in sorted(blocked):
            if a > at:
                free.append((at, a))
            at = max(at, b)
        free = [(a, b) for a, b in free if b > a]
        return cls(path, states.stamp_ns, free, spans["pushes"], spans["off"])

    def fits(self, after: float, duration: float) -> float | None:
        """The earliest start ≥ ``after`` of a contact of ``duration`` in a free span."""
        for a, b in self.free:
            start = max(a, after)
            if start + duration <= b:
                return start
        return None


def plan_rotation(
    arm: Arm, r: int, tests: list[TestLog], wanted: list[tuple[str, float, float]], seed: int
) -> list[dict[str, Any]]:
    """Place ``wanted`` contacts in copies of the rotation's test logs: first fit, a random
    shift before each, ≥ GAP_S apart, as many copies (passes over the test logs) as needed.
    One or two joints at random, random signs, drawn alike for every size of a contact (so
    sizes compare on the same joints)."""
    arm_seed = zlib.crc32(arm.name.encode())
    rng = np.random.default_rng([seed, arm_seed, r])
    joints = len(twincd.read_log(tests[0].path).joint_names)
    queue = []
    seen: dict[tuple[str, float, float], int] = {}
    for shape, d, a in wanted:
        # the k-th contact of a shape and length has the same joints and signs at every size
        k = seen[shape, d, a] = seen.get((shape, d, a), -1) + 1
        draw = np.random.default_rng(
            [seed, arm_seed, r, zlib.crc32(shape.encode()), round(d * 1e3), k]
        )
        n = int(draw.integers(1, 3))
        picked = draw.choice(joints, size=n, replace=False)
        signs = draw.choice([-1.0, 1.0], size=n)
        queue.append((shape, d, a, [int(j) for j in picked], [float(s) for s in signs]))
    order = rng.permutation(len(queue))
    queue = [queue[i] for i in order]
    placed: list[dict[str, Any]] = []
    copy = 0
    while queue:
        progress = False
        for test in tests:
            at = END_S  # the first contact too starts a random shift after END_S
            while queue:
                shift = float(rng.uniform(0, JITTER_S))
                starts = [test.fits(at + shift, item[1]) for item in queue]
                options = [(s, i) for i, s in enumerate(starts) if s is not None]
                if not options:
                    break
                start_s, i = min(options)
                shape, d, a, picked, signs = queue.pop(i)
                first = test.stamp_ns[0]
                k = min(
                    int(np.searchsorted(test.stamp_ns - first, round(start_s * 1e9))),
                    len(test.stamp_ns) - 1,
                )
                start = int(test.stamp_ns[k])
                placed.append(
                    {
                        "rotation": r,
                        "log": str(test.path),
                        "copy": copy,
                        "shape": shape,
                        "duration_s": d,
                        "amplitude": a,
                        "joints": picked,
                        "signs": signs,
                        "start_ns": start,
                        "end_ns": start + round(d * 1e9),
                        "from_start_s": (start - int(first)) * 1e-9,
                        "to_end_s": (int(test.stamp_ns[-1]) - start) * 1e-9 - d,
                    }
                )
                at = (start - int(first)) * 1e-9 + d + GAP_S
                progress = True
            copy += 1
        if not progress:
            raise SystemExit(f"{arm.name}: no test log of rotation {r} holds {queue[0][:2]}")
    return placed


def copy_path(work: Path, arm: Arm, item: dict[str, Any]) -> Path:
    name = log_name(Path(item["log"]))
    return work / arm.name / "copies" / f"r{item['rotation']}_{name}_c{item['copy']:03d}.mcap"


@dataclass
class Plan:
    injections: list[dict[str, Any]]
    tests: dict[str, TestLog]  # by path

    def copies(self, work: Path, arm: Arm, r: int) -> list[Path]:
        paths = {copy_path(work, arm, i) for i in self.injections if i["rotation"] == r}
        return sorted(paths)


def make_plan(arm: Arm, work: Path, shapes: str, per_cell: int, seed: int) -> Plan:
    """The injections (cached in ``work``, with their copies, by the plan's settings)."""
    tests = {str(p): TestLog.read(p) for rot in arm.rotations for p in rot.test}
    key = {
        "version": PLAN_VERSION,
        "seed": seed,
        "per_cell": per_cell,
        "shapes": shapes,
        "amplitudes": list(arm.amplitudes),
        "rotations": [[str(p) for p in rot.test] for rot in arm.rotations],
    }
    where = work / arm.name / "plan.json"
    if where.is_file():
        cached = json.loads(where.read_text())
        if cached["key"] == key:
            plan = Plan(cached["injections"], tests)
            if all(copy_path(work, arm, i).is_file() for i in plan.injections):
                return plan
    wanted: list[list[tuple[str, float, float]]] = [[] for _ in arm.rotations]
    for cell in cells(arm, shapes):
        able = [
            r
            for r, rot in enumerate(arm.rotations)
            if any(tests[str(p)].fits(-math.inf, cell[1]) is not None for p in rot.test)
        ]
        if not able:
            raise SystemExit(f"{arm.name}: no test log holds a {cell[1]:g} s contact")
        for k in range(math.ceil(per_cell / len(able)) * len(able)):
            wanted[able[k % len(able)]].append(cell)
    injections = []
    for r, rot in enumerate(arm.rotations):
        logs = [tests[str(p)] for p in rot.test]
        injections += plan_rotation(arm, r, logs, wanted[r], seed)
    write_copies(arm, work, injections)
    where.parent.mkdir(parents=True, exist_ok=True)
    where.write_text(json.dumps({"key": key, "injections": injections}))
    return Plan(injections, tests)


def write_copies(arm: Arm, work: Path, injections: list[dict[str, Any]]) -> None:
    """Each copy: its test log with its contacts added to the measured effort and labelled."""
    by_copy: dict[Path, list[dict[str, Any]]] = {}
    for item in injections:
        by_copy.setdefault(copy_path(work, arm, item), []).append(item)
    states_of: dict[str, Any] = {}
    for path, items in sorted(by_copy.items()):
        source = items[0]["log"]
        if source not in states_of:
            states_of = {source: twincd.read_log(source)}  # one log's arrays at a time
        states = states_of[source]
        effort = states.effort.copy()
        labels = np.zeros(len(effort), bool) if states.labels is None else states.labels.copy()
        for item in items:
            t = (states.stamp_ns - item["start_ns"]) * 1e-9
            inside = (states.stamp_ns >= item["start_ns"]) & (states.stamp_ns <= item["end_ns"])
            shape = pulse(item["shape"], item["duration_s"], t[inside])
            for j, sign in zip(item["joints"], item["signs"], strict=True):
                effort[inside, j] += sign * item["amplitude"] * shape
            labels |= inside
        write_log(path, states, np.ones(len(effort), bool), effort, labels)


# ------------------------------------------------------------------ the SNR ceiling


def residual_psd(arm: Arm, r: int, work: Path, plan: Plan, digest: str) -> dict[str, Any]:
    """Welch's one-sided spectrum of each joint's residual on the rotation's clean test samples
    (away from the logs' edges and the real labels) under a near-raw calibration (cached)."""
    where = work / arm.name / "psd" / f"r{r}.json"
    if where.is_file():
        cached = json.loads(where.read_text())
        if cached["digest"] == digest:
            return cached
    from scipy.signal import welch

    from twincd.detection.events import runs

    rot = arm.rotations[r]
    cutoff = NEAR_RAW * arm.rate_hz
    fitted = twincd.fit_calibration(
        rot.fit, cutoff_hz=cutoff, filter_kind="butterworth", jobs=1, **arm.options()
    ).calibration
    # any threshold lets detect give the residual; the fit logs' own is always accepted (a
    # near-raw fit on seconds of data can be refused by threshold's check on other logs)
    cal = twincd.threshold_calibration(rot.fit, fitted, k_sigma=4.0, jobs=1).calibration
    nperseg = 2 ** round(math.log2(WELCH_S * arm.rate_hz))
    stretches = []
    for path in rot.test:
        prepared = cal.prepare(path)
        assert prepared.residual is not None and prepared.edge_factor is not None
        residual = prepared.residual
        ok = prepared.edge_factor[:, 0] <= EDGE_NOISE  # away from the ends' filter noise
        stamps = prepared.states.stamp_ns
        guard = round(LABEL_GUARD_S * 1e9)
        test = plan.tests[str(path)]
        for a, b in [*test.pushes, *test.off]:
            ok &= ~((stamps >= a - guard) & (stamps <= b + guard))
        stretches += [residual[a : b + 1] for a, b in runs(ok)]
    longest = max(len(s) for s in stretches)
    nperseg = min(nperseg, 2 ** int(math.log2(longest)))
    total, weight = 0.0, 0
    for s in stretches:
        if len(s) >= nperseg:
            f, p = welch(s, fs=arm.rate_hz, nperseg=nperseg, detrend=False, axis=0)
            n = 1 + (len(s) - nperseg) // (nperseg // 2)
            total, weight = total + n * p, weight + n
    out = {
        "digest": digest,
        "cutoff_hz": cutoff,
        "nperseg": nperseg,
        "segments": weight,
        "freq": f.tolist(),
        "psd": (total / weight).T.tolist(),  # (joints, freqs), (N·m)²/Hz
    }
    where.parent.mkdir(parents=True, exist_ok=True)
    where.write_text(json.dumps(out))
    return out


def unit_dprime(psd: dict[str, Any], rate: float, shape: str, duration: float) -> np.ndarray:
    """d′ per joint of a unit contact: sqrt(4 Σ_f |H P|²/S Δf) over 0 < f ≤ the near-raw
    cut-off, P the sampled pulse's spectrum, H the near-raw filter's zero-phase gain (the
    residual carries H P of an injected P) and S the residual's one-sided spectrum."""
    from scipy.signal import butter, sosfreqz

    t = np.arange(0, duration + 1e-9, 1 / rate)
    p = pulse(shape, duration, t)
    m = 2 ** math.ceil(math.log2(max(8 * len(p), 2 * psd["nperseg"])))
    freq = np.fft.rfftfreq(m, 1 / rate)
    spectrum = np.abs(np.fft.rfft(p, m) / rate) ** 2
    _, h = sosfreqz(butter(2, psd["cutoff_hz"], fs=rate, output="sos"), worN=freq, fs=rate)
    gain = np.abs(h) ** 4  # forward and backward: |H|², squared for power
    use = (freq > 0) & (freq <= psd["cutoff_hz"])
    f0 = np.asarray(psd["freq"])[1:]
    out = []
    for s in psd["psd"]:
        noise = np.interp(freq[use], f0, np.asarray(s)[1:])
        out.append(math.sqrt(4 * np.sum(spectrum[use] * gain[use] / noise) * rate / m))
    return np.asarray(out)


# ------------------------------------------------------------------ running a configuration


def library_digest() -> str:
    """A digest of the installed twincd's source: a changed library refits everything."""
    root = Path(twincd.__file__).parent
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(path.relative_to(root).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def calibrate(arm: Arm, r: int, config: Config, work: Path, digest: str) -> dict[str, Any]:
    """The rotation's calibration for ``config`` (cached): its path and what fit and threshold
    said, or why the library refused it."""
    folder = work / arm.name / "calibrations" / config.name
    cal_path, note = folder / f"r{r}.json", folder / f"r{r}.run.json"
    rot = arm.rotations[r]
    key = {
        "digest": digest,
        "fit_args": config.fit_args,
        "threshold_args": config.threshold_args,
        "fit": [str(p) for p in rot.fit],
        "threshold": [str(p) for p in rot.threshold],
    }
    if note.is_file():
        cached = json.loads(note.read_text())
        if cached["key"] == key and (cached["refused"] or cal_path.is_file()):
            return cached
    folder.mkdir(parents=True, exist_ok=True)
    out: dict[str, Any] = {"key": key, "refused": None, "path": str(cal_path)}
    cal_path.unlink(missing_ok=True)
    if config.cli:
        refused, warnings = calibrate_cli(arm, rot, config, cal_path)
    else:
        refused, warnings = calibrate_library(arm, rot, config, cal_path)
    out["refused"] = refused
    if refused is None:
        cal = twincd.Calibration.given(cal_path)
        th = cal.require_threshold()
        out.update(
            model=cal.model.kind,
            filter=cal.lowpass.describe(),
            threshold=th.value,
            threshold_false_alarms=th.false_alarms,
            threshold_judged_s=th.judged_s,
            warnings=warnings,
        )
    note.write_text(json.dumps(out))
    return out


def calibrate_library(
    arm: Arm, rot: Rotation, config: Config, cal_path: Path
) -> tuple[str | None, list[str]]:
    """fit and threshold through the library's command functions: (why refused, warnings)."""
    try:
        fitted = twincd.fit_calibration(rot.fit, jobs=1, **arm.options(), **config.fit_options())
        done = twincd.threshold_calibration(
            rot.threshold,
            fitted.calibration,
            output=cal_path,
            jobs=1,
            **config.threshold_options(),
        )
    except TwincdError as exc:
        return str(exc), []
    return None, [*fitted.warnings, *done.warnings]


def calibrate_cli(
    arm: Arm, rot: Rotation, config: Config, cal_path: Path
) -> tuple[str | None, list[str]]:
    """fit and threshold as typed: (why refused, warnings)."""
    robot = [] if arm.robot is None else ["--robot", arm.robot]
    warnings = []
    fit = ["fit", *map(str, rot.fit), *robot, "-o", str(cal_path)]
    threshold = ["threshold", *map(str, rot.threshold), "-c", str(cal_path)]
    for cmd in (
        [*fit, *shlex.split(config.fit_args)],
        [*threshold, *shlex.split(config.threshold_args)],
    ):
        done = subprocess.run(
            [sys.executable, "-m", "twincd_cli.main", *cmd],
            capture_output=True,
            text=True,
            check=False,
        )
        lines = done.stderr.splitlines()
        warnings += [line for line in lines if line.startswith("twincd: warning:")]
        if done.returncode:
            return f"twincd {cmd[0]} (exit {done.returncode}): {lines[-1] if lines else ''}", []
    return None, warnings


def events_of(summary: Any) -> list[tuple[int, int]]:
    return [(e.start_ns, e.end_ns) for e in summary.events]


def hits(events: Iterable[tuple[int, int]], start: int, end: int) -> list[int]:
    """The start of each event that overlaps [start, end + 200 ms]."""
    return [a for a, b in events if a <= end + AFTER_NS and b >= start]


def detect_rotation(
    arm: Arm, r: int, cal: dict[str, Any], plan: Plan, work: Path
) -> dict[str, Any]:
    """``detect`` on the rotation's clean test logs and on its injected copies."""
    rot = arm.rotations[r]
    options = {"jobs": 1, "step_summary": False}
    clean = twincd.detect_files(rot.test, cal["path"], **options)
    copies = plan.copies(work, arm, r)
    injected = twincd.detect_files(copies, cal["path"], **options)
    return {
        "clean": {
            s.source: {
                "events": events_of(s),
                "false_alarms": s.false_alarms,
                "clean_s": s.clean_s,
                "samples": s.samples,
                "judged_samples": s.judged_samples,
            }
            for s in clean.logs
        },
        "copies": {s.source: events_of(s) for s in injected.logs},
        "warnings": sorted({*clean.warnings, *injected.warnings}),
    }


def run_config(arm: Arm, config: Config, plan: Plan, work: Path, digest: str) -> dict[str, Any]:
    """Every rotation of ``config`` on ``arm``: calibrations and detections (cached)."""
    where = work / arm.name / "results" / f"{config.name}.json"
    started = time.perf_counter()
    cals = [calibrate(arm, r, config, work, digest) for r in range(len(arm.rotations))]
    key = {"digest": digest, "plan": plan_digest(plan), "calibrations": [c["key"] for c in cals]}
    if where.is_file():
        cached = json.loads(where.read_text())
        if cached["key"] == key:
            return cached
    rotations = []
    for r, cal in enumerate(cals):
        if cal["refused"]:
            rotations.append({"refused": cal["refused"]})
            continue
        try:
            rotations.append(detect_rotation(arm, r, cal, plan, work))
        except TwincdError as exc:
            rotations.append({"refused": f"detect: {exc}"})
    out = {
        "key": key,
        "calibrations": cals,
        "rotations": rotations,
        "runtime_s": time.perf_counter() - started,
    }
    where.parent.mkdir(parents=True, exist_ok=True)
    where.write_text(json.dumps(out))
    return out


def plan_digest(plan: Plan) -> str:
    return hashlib.sha256(json.dumps(plan.injections).encode()).hexdigest()[:16]


# ------------------------------------------------------------------ figures


def quantile(values: Sequence[float], q: float) -> float | None:
    return float(np.quantile(values, q)) if len(values) else None


def judge(arm: Arm, config: Config, plan: Plan, ran: dict[str, Any], work: Path) -> dict[str, Any]:
    """Every figure of one configuration on one arm."""
    refused = {r: rot["refused"] for r, rot in enumerate(ran["rotations"]) if rot.get("refused")}
    out: dict[str, Any] = {
        "fit_args": config.fit_args,
        "threshold_args": config.threshold_args,
        # rotation → why the library refused its calibration (or detection)
        "refused": refused,
        "all_refused": len(refused) == len(ran["rotations"]),
        "runtime_s": ran["runtime_s"],
        "calibrations": [
            {
                k: c.get(k)
                for k in ("model", "filter", "threshold", "threshold_false_alarms", "refused")
            }
            for c in ran["calibrations"]
        ],
        "warnings": sorted(
            {w for c in ran["calibrations"] for w in c.get("warnings", [])}
            | {w for r in ran["rotations"] for w in r.get("warnings", [])}
        ),
    }
    if out["all_refused"]:
        return out
    found_by: dict[str, list[float | None]] = {}
    chance: dict[str, int] = {}
    per_injection: list[float | None] = []
    ends: dict[bool, list[float | None]] = {False: [], True: []}
    for item in plan.injections:
        rot = ran["rotations"][item["rotation"]]
        if rot.get("refused"):
            per_injection.append(None)
            continue
        events = rot["copies"][str(copy_path(work, arm, item))]
        starts = hits(events, item["start_ns"], item["end_ns"])
        delay = (max(min(starts), item["start_ns"]) - item["start_ns"]) * 1e-6 if starts else None
        key = cell_key(item["shape"], item["duration_s"], item["amplitude"])
        found_by.setdefault(key, []).append(delay)
        per_injection.append(delay)
        near = min(item["from_start_s"], item["to_end_s"]) < NEAR_END_S
        ends[near].append(delay)
        clean = rot["clean"][item["log"]]["events"]
        chance[key] = chance.get(key, 0) + bool(hits(clean, item["start_ns"], item["end_ns"]))
    cells_out = {}
    for shape, duration, amplitude in cells(arm, plan_shapes(plan)):
        key = cell_key(shape, duration, amplitude)
        delays = [x for x in found_by.get(key, []) if x is not None]
        cells_out[key] = {
            "shape": shape,
            "duration_s": duration,
            "amplitude": amplitude,
            "found": len(delays),
            "injected": len(found_by.get(key, [])),
            "delay_median_ms": quantile(delays, 0.5),
            "delay_p95_ms": quantile(delays, 0.95),
            "clean_log_hits": chance.get(key, 0),
        }
    ran_ok = [rot for rot in ran["rotations"] if not rot.get("refused")]
    clean_logs = [(src, c) for rot in ran_ok for src, c in rot["clean"].items()]
    groups: dict[str, dict[str, float]] = {}
    for src, c in clean_logs:
        g = groups.setdefault(arm.groups.get(log_name(Path(src)), arm.name), {})
        g["false_alarms"] = g.get("false_alarms", 0) + c["false_alarms"]
        g["clean_minutes"] = g.get("clean_minutes", 0.0) + c["clean_s"] / 60
    delays = [x for x in per_injection if x is not None]
    alarms = []  # the false alarms themselves: which log, when (s from its first sample)
    for src, c in clean_logs:
        test = plan.tests[src]
        for a, b in c["events"]:
            if not any(a <= pb + AFTER_NS and b >= pa - AFTER_NS for pa, pb in test.pushes):
                first = int(test.stamp_ns[0])
                alarms.append([log_name(Path(src)), (a - first) * 1e-9, (b - first) * 1e-9])
    out.update(
        false_alarm_events=alarms,
        found=len(delays),
        injected=sum(len(v) for v in found_by.values()),
        clean_log_hits=sum(chance.values()),
        # contacts within NEAR_END_S of a log's end, and the others: (found, injected)
        near_ends=[sum(x is not None for x in ends[True]), len(ends[True])],
        inside=[sum(x is not None for x in ends[False]), len(ends[False])],
        delay_median_ms=quantile(delays, 0.5),
        delay_p95_ms=quantile(delays, 0.95),
        false_alarms=sum(c["false_alarms"] for _, c in clean_logs),
        clean_minutes=sum(c["clean_s"] for _, c in clean_logs) / 60,
        judged_share=sum(c["judged_samples"] for _, c in clean_logs)
        / sum(c["samples"] for _, c in clean_logs),
        false_alarms_by_group=groups,
        false_alarms_by_log={log_name(Path(s)): c["false_alarms"] for s, c in clean_logs},
        cells=cells_out,
        found_per_injection=per_injection,
    )
    if arm.labelled:
        out["real_pushes"] = real_pushes(plan, ran)
    return out


def real_pushes(plan: Plan, ran: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The real labelled pushes of the test logs found, by labelled duration."""
    out = {bin_name(b): {"found": 0, "total": 0, "delays_ms": []} for b in BINS}
    for rot in ran["rotations"]:
        for src, clean in rot.get("clean", {}).items():
            for a, b in plan.tests[src].pushes:
                seconds = (b - a) * 1e-9
                row = out[bin_name(next(x for x in BINS if x[0] <= seconds < x[1]))]
                row["total"] += 1
                starts = hits(clean["events"], a, b)
                if starts:
                    row["found"] += 1
                    row["delays_ms"].append((max(min(starts), a) - a) * 1e-6)
    for row in out.values():
        delays = row.pop("delays_ms")
        row["delay_median_ms"] = quantile(delays, 0.5)
        row["delay_p95_ms"] = quantile(delays, 0.95)
    return out


def bin_name(b: tuple[float, float]) -> str:
    return (
        f"<{b[1]:g} s"
        if b[0] == 0
        else f">{b[0]:g} s"
        if b[1] == math.inf
        else f"{b[0]:g}–{b[1]:g} s"
    )


def plan_shapes(plan: Plan) -> str:
    by_length = all(
        (i["shape"] == "strike") == (i["duration_s"] in STRIKES) for i in plan.injections
    )
    return "by-length" if by_length else "both"


def dprimes(
    arm: Arm, plan: Plan, work: Path, digest: str
) -> tuple[list[float], dict[tuple[int, str, float], np.ndarray]]:
    """Each injection's d′ (its rotation's noise, its joints, shape, length and size), and the
    d′ per joint of a unit contact by (rotation, shape, length)."""
    psds = [residual_psd(arm, r, work, plan, digest) for r in range(len(arm.rotations))]
    unit: dict[tuple[int, str, float], np.ndarray] = {}
    out = []
    for item in plan.injections:
        k = (item["rotation"], item["shape"], item["duration_s"])
        if k not in unit:
            unit[k] = unit_dprime(psds[k[0]], arm.rate_hz, k[1], k[2])
        out.append(item["amplitude"] * float(np.sqrt(np.sum(unit[k][item["joints"]] ** 2))))
    return out, unit


def snr_cells(arm: Arm, plan: Plan, dprime: list[float]) -> dict[str, float]:
    by: dict[str, list[float]] = {}
    for item, d in zip(plan.injections, dprime, strict=True):
        by.setdefault(cell_key(item["shape"], item["duration_s"], item["amplitude"]), []).append(d)
    return {k: float(np.median(v)) for k, v in by.items()}


# ------------------------------------------------------------------ tables


def ms(x: float | None) -> str:
    return "–" if x is None else f"{x:.0f}"


def cell_table(arm: Arm, figures: dict[str, Any], snr: dict[str, float]) -> list[str]:
    """Contact lengths × sizes: found/n · median d′ · delay median/p95 (ms)."""
    amps = arm.amplitudes
    lines = ["| contact | " + " | ".join(f"{a:g} N·m" for a in amps) + " |"]
    lines.append("|---" * (len(amps) + 1) + "|")
    rows: dict[tuple[str, float], list[dict[str, Any]]] = {}
    for c in figures["cells"].values():
        rows.setdefault((c["shape"], c["duration_s"]), []).append(c)
    for (shape, duration), row in rows.items():
        texts = []
        for c in row:
            d = snr[cell_key(shape, duration, c["amplitude"])]
            delay = f"{ms(c['delay_median_ms'])}/{ms(c['delay_p95_ms'])}" if c["found"] else "–"
            texts.append(f"{c['found']}/{c['injected']} · {d:.3g} · {delay}")
        lines.append(f"| {shape} {duration:g} s | " + " | ".join(texts) + " |")
    return lines


def comparison_table(doc: dict[str, Any]) -> list[str]:
    """Cells × configurations: found/n, with the cell's median d′."""
    names = [n for n, f in doc["configs"].items() if not f["all_refused"]]
    if not names:
        return []
    lines = ["| contact | d′ | " + " | ".join(names) + " |"]
    lines.append("|---" * (len(names) + 2) + "|")
    for key in doc["configs"][names[0]]["cells"]:
        found = [doc["configs"][n]["cells"][key] for n in names]
        texts = [f"{c['found']}/{c['injected']}" for c in found]
        lines.append(f"| {key} | {doc['snr'][key]:.3g} | " + " | ".join(texts) + " |")
    totals = [f"{doc['configs'][n]['found']}/{doc['configs'][n]['injected']}" for n in names]
    lines.append("| **total** | | " + " | ".join(totals) + " |")
    return lines


def arm_report(arm: Arm, doc: dict[str, Any]) -> list[str]:
    lines = [f"## {arm.name} ({arm.rate_hz:g} Hz, {len(arm.rotations)} rotation(s))", ""]
    lines.append(
        f"{doc['injections']} injected contacts in {doc['copies']} copies; clean test time "
        f"{doc['test_minutes']:.1f} min; study time {doc['runtime_s']:.0f} s"
    )
    lines += [
        "",
        "| configuration | found | < 1 s from an end | also on clean | FA | clean min "
        "| delay med/p95 ms | thresholds |",
        "|---|---|---|---|---|---|---|---|",
    ]
    refusals = []
    for name, f in doc["configs"].items():
        for r, why in f["refused"].items():
            short = why if len(why) <= 150 else why[:150] + "…"
            refusals.append(f"- {name}, rotation {r}: {short}")
        if f["all_refused"]:
            lines.append(f"| {name} | refused (below) | | | | | | |")
            continue
        near = f["near_ends"]
        ths = " ".join(
            "–" if c["threshold"] is None else f"{c['threshold']:.3g}" for c in f["calibrations"]
        )
        lines.append(
            f"| {name} | {f['found']}/{f['injected']} | {near[0]}/{near[1]} | "
            f"{f['clean_log_hits']} | "
            f"{f['false_alarms']} | "
            f"{f['clean_minutes']:.1f} | {ms(f['delay_median_ms'])}/{ms(f['delay_p95_ms'])} | "
            f"{ths} |"
        )
    if refusals:
        lines += ["", "refused by the library:", "", *refusals]
    shown = [
        (n, f["false_alarm_events"]) for n, f in doc["configs"].items() if not f["all_refused"]
    ]
    if any(events for _, events in shown):
        lines += ["", "false alarms (log: from–to s; the first 5):", ""]
        for name, events in shown:
            if events:
                text = ", ".join(f"{g} {a:.1f}–{b:.1f}" for g, a, b in events[:5])
                lines.append(f"- {name}: {text}{' …' if len(events) > 5 else ''}")
    groups = sorted(
        {g for f in doc["configs"].values() for g in f.get("false_alarms_by_group", {})}
    )
    if len(groups) > 1:
        lines += ["", "false alarms by test log group (clean minutes):", ""]
        lines.append("| configuration | " + " | ".join(groups) + " |")
        lines.append("|---" * (len(groups) + 1) + "|")
        for name, f in doc["configs"].items():
            if not f["all_refused"]:
                by = f["false_alarms_by_group"]
                cols = [f"{by[g]['false_alarms']} ({by[g]['clean_minutes']:.1f})" for g in groups]
                lines.append(f"| {name} | " + " | ".join(cols) + " |")
    real = [(n, f["real_pushes"]) for n, f in doc["configs"].items() if f.get("real_pushes")]
    if real:
        bins = list(real[0][1])
        lines += ["", "real labelled pushes found, by labelled duration:", ""]
        lines.append("| configuration | " + " | ".join(bins) + " |")
        lines.append("|---" * (len(bins) + 1) + "|")
        for name, rp in real:
            cols = [f"{rp[b]['found']}/{rp[b]['total']}" for b in bins]
            lines.append(f"| {name} | " + " | ".join(cols) + " |")
    lines += ["", "found/n per cell and configuration (d′: the cell's median SNR ceiling):", ""]
    lines += comparison_table(doc)
    for name, f in doc["configs"].items():
        if f["all_refused"]:
            continue
        lines += [
            "",
            f"### {arm.name} — {name} (fit [{f['fit_args']}], threshold "
            f"[{f['threshold_args']}]): found/n · median d′ · delay median/p95 ms",
            "",
        ]
        lines += cell_table(arm, f, doc["snr"])
    return lines


# ------------------------------------------------------------------ main


def study_arm(
    arm: Arm, configs: list[Config], args: argparse.Namespace, digest: str
) -> dict[str, Any]:
    started = time.perf_counter()
    plan = make_plan(arm, args.work, args.shapes, args.per_cell, args.seed)
    log.info("%s: %d contacts planned", arm.name, len(plan.injections))
    dprime, unit = dprimes(arm, plan, args.work, digest)
    snr = snr_cells(arm, plan, dprime)
    doc: dict[str, Any] = {
        "rate_hz": arm.rate_hz,
        "amplitudes": list(arm.amplitudes),
        "rotations": [
            {k: [log_name(p) for p in getattr(rot, k)] for k in ("fit", "threshold", "test")}
            for rot in arm.rotations
        ],
        "injections": len(plan.injections),
        "copies": len({str(copy_path(args.work, arm, i)) for i in plan.injections}),
        "test_minutes": sum(len(t.stamp_ns) for t in plan.tests.values()) / arm.rate_hz / 60,
        "snr": snr,
        # d′ of a 1 N·m contact on each joint alone (it scales with the size)
        "unit_dprime": [
            {"rotation": r, "shape": shape, "duration_s": d, "per_joint": v.tolist()}
            for (r, shape, d), v in sorted(unit.items())
        ],
        "configs": {},
    }
    for config in configs:
        t0 = time.perf_counter()
        ran = run_config(arm, config, plan, args.work, digest)
        doc["configs"][config.name] = judge(arm, config, plan, ran, args.work)
        log.info("%s %s: %.0f s", arm.name, config.name, time.perf_counter() - t0)
    found = {n: f.get("found_per_injection") for n, f in doc["configs"].items()}
    doc["injection_list"] = [
        {
            **item,
            "dprime": d,
            "delay_ms": {n: (f or [None] * len(dprime))[k] for n, f in found.items()},
        }
        for k, (item, d) in enumerate(zip(plan.injections, dprime, strict=True))
    ]
    for f in doc["configs"].values():
        f.pop("found_per_injection", None)
    doc["runtime_s"] = time.perf_counter() - started
    return doc


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    arm_names = ["doosan", "ur10e", "panda", "synth-100", "synth-1k"]
    known = named_configs()
    parser.add_argument("--data", type=Path, default=DATA, help="the recordings' folder")
    parser.add_argument("--work", type=Path, default=WORK, help="cache folder (reused)")
    parser.add_argument("--arms", nargs="+", choices=arm_names, default=arm_names)
    parser.add_argument("--configs", nargs="*", choices=list(known), default=list(known))
    parser.add_argument(
        "--extra",
        nargs=3,
        action="append",
        default=[],
        metavar=("NAME", "FIT_ARGS", "THRESHOLD_ARGS"),
        help="another configuration: the options of fit and of threshold",
    )
    parser.add_argument("--shapes", choices=["both", "by-length"], default="both")
    parser.add_argument("--per-cell", type=int, default=20, help="contacts per cell (at least)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, help="write every figure here")
    parser.add_argument("-v", "--verbose", action="store_true", help="twincd's warnings too")
    args = parser.parse_args()
    logging.basicConfig(format="%(name)s: %(message)s", level=logging.INFO)
    logging.getLogger("twincd").setLevel(logging.INFO if args.verbose else logging.ERROR)
    configs = [known[n] for n in args.configs] + [Config(*e, cli=True) for e in args.extra]
    args.work.mkdir(parents=True, exist_ok=True)
    digest = library_digest()
    doc: dict[str, Any] = {
        "twincd": twincd.__version__,
        "library_digest": digest,
        "seed": args.seed,
        "per_cell": args.per_cell,
        "shapes": args.shapes,
        "arms": {},
    }
    lines: list[str] = []
    for arm in arms_wanted(args.arms, args.data, args.work):
        doc["arms"][arm.name] = study_arm(arm, configs, args, digest)
        lines += ["", *arm_report(arm, doc["arms"][arm.name])]
        print("\n".join(arm_report(arm, doc["arms"][arm.name])), flush=True)
    if args.json:
        args.json.write_text(json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
