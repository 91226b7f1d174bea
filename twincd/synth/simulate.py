"""One path of a run set: its plant's effort along a drawn trajectory, pushed by drawn presses,
as the driver reports it (``simulate_path``, ``SynthRun``).

Long paths (``duration_s[1]`` above ``segment_s``, 35 s): one spline through ever more points
leaves the sphere somewhere with a probability that grows with its length (seed 0's first 240 s
path was not drawn in 200 tries), and each redraw checks every sample. A long path is therefore
drawn as its length, cut into the fewest segments of at most ``segment_s`` (equal up to one
sample), each a short path as ``make_trajectory`` draws it (home → points → home, at rest at
both ends, its own presses) drawn from (seed, split, index, segment number), laid back to back
one sample period apart: position, velocity and acceleration are continuous at every join (home,
zero, zero), no press comes within a second of a join, so label and contact are off there. The
switch's initial ``false`` and the "nothing touches" messages come once, at the path's start.
Segments are made and written one at a time (``write_path``), so memory does not grow with the
length. Paths of at most ``segment_s`` are made exactly as before.

Every path is a pure function of (config, seed, split, index): ``simulate_path`` is vectorised
and paths can be generated in parallel; output bytes are deterministic for a seed. Paths start a
minute apart (``path_start_ns``): paths longer than that overlap in wall-clock time.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from twincd.errors import UsageError
from twincd.synth.config import (
    SPLITS,
    MotionConfig,
    PlantConfig,
    SynthConfig,
    check_durations,
    check_seed,
    seeded_rng,
)
from twincd.synth.contact import Press, contact_torque, draw_presses, press_force
from twincd.synth.motion import Trajectory, make_trajectory
from twincd.synth.plant import Plant, make_plant
from twincd.twin.dynamics import inverse_dynamics
from twincd.twin.robot import RobotModel
from twincd.types import BoolArray, FloatArray, IntArray

# 2024-05-01T01:00:00Z: the first sample of path 0 of seed 0
EPOCH_NS = 1_714_525_200_000_000_000


@dataclass(frozen=True)
class SynthRun:
    """One synthetic recording with its ground truth."""

    split: str
    index: int
    seed: int
    joint_names: tuple[str, ...]
    stamp_ns: IntArray
    log_time_ns: IntArray
    position: FloatArray  # reported
    velocity: FloatArray  # reported (noisy)
    effort: FloatArray  # reported
    true_velocity: FloatArray
    acceleration: FloatArray
    rigid: FloatArray  # RNEA_true(q, q̇, q̈)
    friction: FloatArray
    tau_ext: FloatArray
    contact_link: tuple[str, ...]  # per sample, "" when nothing touches
    contact_wrench: FloatArray  # (N, 6) in the link frame, about its origin
    contact_point: FloatArray  # (N, 3) in the link frame
    label: BoolArray  # the switch held onto the joint-state log times
    label_events: tuple[tuple[int, bool], ...]  # (log_time_ns, value)
    link_events: tuple[tuple[int, str], ...]  # (log_time_ns, link touched or ""), beside them
    presses: tuple[Press, ...]
    trajectory: Trajectory
    # it opens its path with "nothing touches" on the contact topics (a path with presses)
    contact_start: bool = False

    @property
    def t_s(self) -> FloatArray:
        return np.asarray((self.stamp_ns - self.stamp_ns[0]) * 1e-9, dtype=np.float64)

    @property
    def contact(self) -> BoolArray:
        return np.array([bool(c) for c in self.contact_link])


def _split_number(split: str) -> int:
    """A split's place in ``SPLITS`` (any other name after them)."""
    return SPLITS.index(split) if split in SPLITS else len(SPLITS)


def path_start_ns(seed: int, split: str, index: int) -> int:
    """Wall-clock start of a path: one run set per seed-day, paths a minute apart.

    Days wrap after 10 years so stamps stay within int32 seconds.
    """
    split_no = _split_number(split)
    day = seed % 3650
    return EPOCH_NS + (day * 86_400 + split_no * 3_600 + index * 60) * 1_000_000_000


def simulate_path(
    config: SynthConfig, seed: int, split: str, index: int, collisions: bool | None = None
) -> SynthRun:
    """One path of a run set, whole in memory: a pure function of its arguments.

    ``collisions`` defaults to ``split == "test"``. A long path is its segments joined
    (``path_segments``); to write one without holding it, use ``write_path``.
    """
    return join_segments(list(path_segments(config, seed, split, index, collisions)))


def segment_sizes(motion: MotionConfig, rng: np.random.Generator) -> list[int]:
    """Samples per segment of a long path: its duration drawn from ``motion.duration_s``,
    split into the fewest segments of at most ``motion.segment_s``, as equal as the sample grid
    allows. The segments lie back to back on one grid, one sample period apart."""
    total = int(np.floor(rng.uniform(*motion.duration_s) * motion.rate_hz + 1e-9)) + 1
    count = int(np.ceil((total - 1) / (motion.segment_s * motion.rate_hz)))
    return [total // count + (j < total % count) for j in range(count)]


def path_segments(
    config: SynthConfig, seed: int, split: str, index: int, collisions: bool | None = None
) -> Iterator[SynthRun]:
    """A path as segments that start and end at rest at home, made one at a time.

    A path whose longest duration (``duration_s[1]``) is at most ``segment_s`` is one segment,
    exactly the path ``twincd synth`` has always made. A longer path is made of segments, each
    a short path home → teaching points → home with its own presses, drawn from
    (seed, split, index, segment number): stamps continue on the path's sample grid, the switch
    and the contact topics announce "nothing" once at the path's start, and, since no press
    reaches the last second of a segment, label and contact are off at every join.
    """
    check_seed(seed)
    if index < 0:
        raise UsageError(f"path index must be ≥ 0, got {index}", "twincd.synth", "pass 0 or more")
    split_no = _split_number(split)
    collisions = split == "test" if collisions is None else collisions
    motion = config.motion
    start_ns = path_start_ns(seed, split, index)
    rng = seeded_rng(seed, 1 + split_no, index)
    if motion.duration_s[1] <= motion.segment_s:
        yield _simulate(config, seed, split, index, rng, collisions, start_ns, first=True)
        return
    check_durations(motion)
    period_ns = round(1e9 / motion.rate_hz)
    for number, samples in enumerate(segment_sizes(motion, rng)):
        span = (samples - 1) / motion.rate_hz
        segment = replace(config, motion=replace(motion, duration_s=(span, span)))
        yield _simulate(
            segment,
            seed,
            split,
            index,
            seeded_rng(seed, 1 + split_no, index, number),
            collisions,
            start_ns,
            first=number == 0,
            announce=collisions,
        )
        start_ns += samples * period_ns


def _simulate(
    config: SynthConfig,
    seed: int,
    split: str,
    index: int,
    rng: np.random.Generator,
    collisions: bool,
    start_ns: int,
    first: bool,
    announce: bool | None = None,
) -> SynthRun:
    """One segment from ``start_ns``; ``first``: it opens the path (the switch's initial
    ``false``); ``announce``: it opens the path with "nothing touches" on the link and contact
    topics (``None``: when it has presses, as a one-segment path does)."""
    plant = make_plant(config.plant, seed)
    robot = plant.nominal
    traj = make_trajectory(robot, config.motion, rng)
    presses = draw_presses(config.collision, plant, traj, rng) if collisions else []
    contact = _contact(robot, traj, presses)
    measured = _measure(plant, config.plant, traj, contact.tau_ext, rng)
    stamp, log_time = _sample_times(config.motion, start_ns, len(traj.t_s), rng)
    announce = bool(presses) if announce is None else announce and first
    events, link_events = _switch_events(presses, config.motion, start_ns, first, announce, rng)
    return SynthRun(
        split=split,
        index=index,
        seed=seed,
        joint_names=robot.joint_names,
        stamp_ns=stamp,
        log_time_ns=log_time,
        position=measured.position,
        velocity=measured.velocity,
        effort=measured.effort,
        true_velocity=traj.velocity,
        acceleration=traj.acceleration,
        rigid=measured.rigid,
        friction=measured.friction,
        tau_ext=contact.tau_ext,
        contact_link=contact.link,
        contact_wrench=contact.wrench,
        contact_point=contact.point,
        label=_held(events, log_time),
        label_events=tuple(events),
        link_events=tuple(link_events),
        presses=tuple(presses),
        trajectory=traj,
        contact_start=announce,
    )


@dataclass(frozen=True)
class _Contact:
    """What the presses of a segment do, per sample (zero, ``""`` where nothing touches)."""

    tau_ext: FloatArray  # (N, dof)
    wrench: FloatArray  # (N, 6) in the link frame, about its origin
    point: FloatArray  # (N, 3) in the link frame
    link: tuple[str, ...]


def _contact(robot: RobotModel, traj: Trajectory, presses: Sequence[Press]) -> _Contact:
    """The presses' forces along ``traj``: τ_ext, the link's wrench and point, the link."""
    n, dof = traj.position.shape
    tau_ext = np.zeros((n, dof))
    wrench = np.zeros((n, 6))
    point = np.zeros((n, 3))
    link = [""] * n
    for press in presses:
        magnitude = press_force(press, traj.t_s)
        rows = np.flatnonzero(magnitude > 0.0)
        if rows.size == 0:
            continue
        force = magnitude[rows, None] * press.direction[None, :]
        tau, w = contact_torque(robot, traj.position[rows], press.link, press.point, force)
        tau_ext[rows] = tau
        wrench[rows] = w
        point[rows] = press.point
        for r in rows:
            link[int(r)] = press.link
    return _Contact(tau_ext, wrench, point, tuple(link))


@dataclass(frozen=True)
class _Measured:
    """A segment's plant torques and what its driver reports."""

    rigid: FloatArray  # RNEA_true(q, q̇, q̈)
    friction: FloatArray
    position: FloatArray
    velocity: FloatArray  # noisy
    effort: FloatArray  # (rigid + friction − τ_ext) ⊘ gain + offset + noise


def _measure(
    plant: Plant,
    config: PlantConfig,
    traj: Trajectory,
    tau_ext: FloatArray,
    rng: np.random.Generator,
) -> _Measured:
    """The plant's torques along ``traj`` pushed by ``tau_ext``, and the driver's report of them
    (noise drawn from ``rng``; float32 values with ``config.float32``)."""
    n, dof = traj.position.shape
    rigid = inverse_dynamics(plant.true, traj.position, traj.velocity, traj.acceleration)
    friction = plant.friction(traj.velocity)
    noise = rng.normal(size=(n, dof)) * plant.noise
    effort = (rigid + friction - tau_ext) / plant.gain + plant.offset + noise
    velocity = traj.velocity + rng.normal(0.0, plant.velocity_noise, (n, dof))
    position = traj.position.copy()
    if config.float32:
        position, velocity, effort = (
            a.astype(np.float32).astype(np.float64) for a in (position, velocity, effort)
        )
    return _Measured(rigid, friction, position, velocity, effort)


def _sample_times(
    motion: MotionConfig, start_ns: int, n: int, rng: np.random.Generator
) -> tuple[IntArray, IntArray]:
    """The stamps of ``n`` samples from ``start_ns`` and their log times (a recorder latency
    drawn per sample)."""
    lat_lo, lat_hi = motion.latency_ms
    period_ns = round(1e9 / motion.rate_hz)
    stamp = start_ns + np.arange(n, dtype=np.int64) * period_ns
    log_time = stamp + np.round(rng.uniform(lat_lo, lat_hi, n) * 1e6).astype(np.int64)
    return stamp, log_time


def _switch_events(
    presses: Sequence[Press],
    motion: MotionConfig,
    start_ns: int,
    first: bool,
    announce: bool,
    rng: np.random.Generator,
) -> tuple[list[tuple[int, bool]], list[tuple[int, str]]]:
    """The switch's changes and, beside each, the link it reports, at log times (a latency
    drawn per change); ``first``: the initial ``false``, ``announce``: the initial ``""``."""
    lat_lo, lat_hi = motion.latency_ms
    events: list[tuple[int, bool]] = [(start_ns, False)] if first else []
    link_events: list[tuple[int, str]] = [(start_ns, "")] if announce else []
    for press in presses:
        for when, value in ((press.label_on_s, True), (press.label_off_s, False)):
            latency = round(rng.uniform(lat_lo, lat_hi) * 1e6)
            events.append((start_ns + round(when * 1e9) + latency, value))
            touched = press.link if value and press.touched else ""
            link_events.append((events[-1][0], touched))
    return events, link_events


def _held(events: Sequence[tuple[int, bool]], log_time: IntArray) -> BoolArray:
    """The switch held from each event onto the log times (``False`` before the first)."""
    if not events:
        return np.zeros(len(log_time), dtype=bool)
    ev_t = np.array([e[0] for e in events], dtype=np.int64)
    ev_v = np.array([e[1] for e in events], dtype=bool)
    held = np.searchsorted(ev_t, log_time, side="right") - 1
    return np.where(held >= 0, ev_v[np.maximum(held, 0)], False)


def join_segments(segments: Sequence[SynthRun]) -> SynthRun:
    """Segments of one path (``path_segments``) as one run: times from the path's start."""
    if len(segments) == 1:
        return segments[0]
    first = segments[0]
    offsets = [(s.stamp_ns[0] - first.stamp_ns[0]) * 1e-9 for s in segments]

    def stack(name: str) -> Any:
        return np.concatenate([getattr(s, name) for s in segments])

    def chain(name: str) -> tuple[Any, ...]:
        return tuple(item for s in segments for item in getattr(s, name))

    presses = tuple(
        replace(
            p,
            start_s=p.start_s + dt,
            label_on_s=p.label_on_s + dt,
            label_off_s=p.label_off_s + dt,
        )
        for s, dt in zip(segments, offsets, strict=True)
        for p in s.presses
    )

    def shifted(name: str) -> FloatArray:
        return np.concatenate(
            [getattr(s.trajectory, name) + dt for s, dt in zip(segments, offsets, strict=True)]
        )

    def joined(name: str) -> FloatArray:
        return np.concatenate([getattr(s.trajectory, name) for s in segments])

    trajectory = Trajectory(
        shifted("t_s"),
        joined("position"),
        joined("velocity"),
        joined("acceleration"),
        joined("teaching_points"),
        shifted("knots_s"),
    )
    arrays = [
        *("stamp_ns", "log_time_ns", "position", "velocity", "effort", "true_velocity"),
        *("acceleration", "rigid", "friction", "tau_ext", "contact_wrench", "contact_point"),
        "label",
    ]
    return replace(
        first,
        **{name: stack(name) for name in arrays},
        contact_link=chain("contact_link"),
        label_events=chain("label_events"),
        link_events=chain("link_events"),
        presses=presses,
        trajectory=trajectory,
    )
