"""A synthetic "real" xArm 7: a stand-in for the seed paper's recordings, with everything the
digital twin does not know.

Ground truth (the *plant*) is the xArm 7 URDF with errors that the twin does not model, drawn
once per run set from the seed (``make_plant``):

- link masses × (1 + N(0, 0.08)), centres of mass shifted by N(0, 4 mm) per axis, rotational
  inertias scaled with the mass; an unmodelled 0.25 kg payload (a solid cylinder, r = 3 cm) whose
  centre is 6 cm beyond the flange, rigidly on link 7;
- joint friction fc·tanh(q̇/0.02) + fv·q̇ per joint (nominal fc, fv each × U(0.8, 1.2));
- the reported effort is a current-based estimate that reads high, as the paper's fitted
  a ≈ 1.16–1.39 show for the real xArm 7 (its twin under-estimates the effort): the estimate
  divides by a per-joint current-to-torque gain ∈ U(0.72, 0.88), i.e. reports 1.14–1.39 × the
  torque; offset N(0, 0.2) N·m, white noise of σ = (0.35, 0.35, 0.25, 0.25, 0.12, 0.10, 0.03)
  N·m; velocity noise σ = 0.002 rad/s; the driver reports float32 values (as the xArm SDK does).

    measured effort = (RNEA_true(q, q̇, q̈) + friction − τ_ext) ⊘ gain + offset + noise

Motion (paper Table I, Fig. 3): teaching points drawn around a home pose, each keeping the
flange within 180 mm of its home position; a quintic interpolating spline in joint space through
home → points → home with zero velocity and acceleration at both ends (smoother than a clamped
cubic: no acceleration step at start and stop); 0.5 s at rest before and after. The time scale
is set so that the mean joint-space speed while moving, mean over time of ‖q̇‖₂, is 30 °/s (a
little less counting the rests); a path whose
flange leaves the 200 mm sphere is redrawn. Sampled every 10 ms; 22–35 s per path. The position
controller tracks perfectly: pushes show up in the effort only.

Long paths (``duration_s[1]`` above ``segment_s``, 35 s): one spline through ever more points
leaves the sphere somewhere with a probability that grows with its length (seed 0's first 240 s
path was not drawn in 200 tries), and each redraw checks every sample. A long path is therefore
drawn as its length, cut into the fewest segments of at most ``segment_s`` (equal up to one
sample), each a short path as above (home → points → home, at rest at both ends, its own
presses) drawn from (seed, split, index, segment number), laid back to back one sample period
apart: position, velocity and acceleration are continuous at every join (home, zero, zero), no
press comes within a second of a join, so label and contact are off there. The switch's initial
``false`` and the "nothing touches" messages come once, at the path's start. Segments are made
and written one at a time (``write_path``), so memory does not grow with the length. Paths of at
most ``segment_s`` are made exactly as before.

Collisions (paper Fig. 4), test paths only: 5–7 presses per path (mean 6), one per equal time
slot. A hand pushes on link3, link4, link5 or link6 (between joints 3–4, 4–5, 5–6, 6–7) at a
point of that link (on the segment between its joint and the next, 4.5 cm off the axis), with a
force of 8–35 N peak in a random direction (uniform on the half-sphere pointing into the
surface: a hand pushes, it does not pull), fixed in the world frame during the press, with
magnitude peak·sin²(π s/T) over T = 0.4–1.6 s. τ_ext = J(q)ᵀ w, with J Pinocchio's joint
Jacobian of the contact link (LOCAL) and w the contact force moved to the link origin. The label
is the experimenter's switch: on 0–150 ms before contact, off 0–100 ms after; 15 % of presses
touch nothing (label on, no force).

Topics of a written log (bare MCAP, ros2 profile, or rosbag2 sqlite3):

- ``/joint_states`` sensor_msgs/msg/JointState every 10 ms: ``joint1``…``joint7``, position,
  velocity, effort. ``header.stamp`` is the nominal sample time; the log time is the stamp plus
  a recorder latency of 0.2–1.0 ms.
- ``/collision_flag`` std_msgs/msg/Bool: ``false`` at the start, then one message at every
  switch change (held until the next; log time = switch time + latency).
- ``/collision_link`` std_msgs/msg/String (contract: Inputs, ground truth for isolation; test logs
  only): beside every ``/collision_flag`` message, with the same log time, the link the press
  touches (``link3``…``link6``) when the switch goes on, ``""`` when it goes off, at the start,
  and for a press that touches nothing.
- ``/twincd/contact`` geometry_msgs/msg/WrenchStamped (ground truth, for isolation work; test
  logs only), while a hand touches: one per joint-state sample (same stamp and log time), plus
  one message with an empty ``frame_id`` and zero wrench at the first sample and at the first
  sample after each contact (hold semantics). ``header.frame_id`` = the Pinocchio body frame touched
  (``link3``…``link6``); the wrench is expressed in that link's frame, about its origin: force =
  the hand's force, torque = p × force. τ_ext = J_LOCAL(q)ᵀ [force; torque], with J the joint
  Jacobian of the link's parent joint (the xArm 7's link frames coincide with its joint frames).
- ``/twincd/contact_point`` geometry_msgs/msg/PointStamped, alongside each contact message: the
  contact point p in the link frame (``header.frame_id`` = link).

Every path is a pure function of (config, seed, split, index): ``simulate_path`` is vectorised
and paths can be generated in parallel; output bytes are deterministic for a seed. Paths start a
minute apart (``path_start_ns``): paths longer than that overlap in wall-clock time.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache, partial
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
from scipy.interpolate import make_interp_spline

from twincd.defaults import SYNTH_SEGMENT_S
from twincd.errors import DataError, OutputError, UsageError
from twincd.executors.local import Executor, Progress
from twincd.io.cdr import bool_cdr, header, joint_state_cdr, serialize, typestore
from twincd.twin.dynamics import inverse_dynamics
from twincd.twin.robot import RobotModel, load_robot
from twincd.types import BoolArray, FloatArray, IntArray

ROBOT = "xarm7"
SPLITS = ("train", "val", "test")
JOINT_TOPIC = "/joint_states"
LABEL_TOPIC = "/collision_flag"
LINK_TOPIC = "/collision_link"
CONTACT_TOPIC = "/twincd/contact"
CONTACT_POINT_TOPIC = "/twincd/contact_point"
JOINT_STATE = "sensor_msgs/msg/JointState"
BOOL = "std_msgs/msg/Bool"
STRING = "std_msgs/msg/String"
WRENCH = "geometry_msgs/msg/WrenchStamped"
POINT = "geometry_msgs/msg/PointStamped"
# 2024-05-01T01:00:00Z: the first sample of path 0 of seed 0
EPOCH_NS = 1_714_525_200_000_000_000

_Wrench = typestore().types["geometry_msgs/msg/Wrench"]
_WrenchStamped = typestore().types[WRENCH]
_Vector3 = typestore().types["geometry_msgs/msg/Vector3"]
_Point = typestore().types["geometry_msgs/msg/Point"]
_PointStamped = typestore().types[POINT]
_String = typestore().types[STRING]


# ---------------------------------------------------------------- configuration


@dataclass(frozen=True)
class PlantConfig:
    """What the twin does not know; drawn once per run set."""

    mass_sigma: float = 0.08
    com_sigma_m: float = 0.004
    payload_kg: float = 0.25
    payload_offset_m: float = 0.06  # centre beyond the flange, along the flange normal
    payload_radius_m: float = 0.03
    payload_length_m: float = 0.06
    coulomb_nm: tuple[float, ...] = (1.2, 1.2, 0.8, 0.8, 0.4, 0.3, 0.12)
    viscous_nms: tuple[float, ...] = (0.8, 0.8, 0.5, 0.5, 0.3, 0.2, 0.05)
    friction_spread: float = 0.2  # each coefficient × U(1 − s, 1 + s)
    coulomb_velocity: float = 0.02  # rad/s in tanh(q̇ / v)
    gain_range: tuple[float, float] = (0.72, 0.88)
    offset_sigma_nm: float = 0.2
    effort_noise_nm: tuple[float, ...] = (0.35, 0.35, 0.25, 0.25, 0.12, 0.10, 0.03)
    velocity_noise: float = 0.002  # rad/s
    float32: bool = True  # the driver reports float32 values


@dataclass(frozen=True)
class MotionConfig:
    """Teaching-point paths around a home pose (paper Table I)."""

    rate_hz: float = 100.0
    duration_s: tuple[float, float] = (22.0, 35.0)
    mean_speed_deg_s: float = 30.0
    radius_m: float = 0.2  # the flange stays within this of its home position
    point_radius_m: float = 0.18  # teaching points keep this margin
    home: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0)
    spread_rad: tuple[float, ...] = (0.25, 0.2, 0.3, 0.25, 0.5, 0.35, 0.8)
    rest_s: float = 0.5
    # a longer path is joined from segments of at most this, each home → points → home
    segment_s: float = SYNTH_SEGMENT_S
    latency_ms: tuple[float, float] = (0.2, 1.0)


@dataclass(frozen=True)
class CollisionConfig:
    """Hand presses on the moving arm (paper Fig. 4)."""

    presses: tuple[int, int] = (5, 7)  # per path, inclusive
    links: tuple[str, ...] = ("link3", "link4", "link5", "link6")
    force_n: tuple[float, float] = (8.0, 35.0)
    duration_s: tuple[float, float] = (0.4, 1.6)
    lead_s: tuple[float, float] = (0.0, 0.15)  # switch on before contact
    lag_s: tuple[float, float] = (0.0, 0.10)  # switch off after contact
    miss_probability: float = 0.15  # label on, nothing touched
    surface_radius_m: float = 0.045
    margin_s: float = 1.0  # no press in the first/last second


@dataclass(frozen=True)
class SynthConfig:
    plant: PlantConfig = field(default_factory=PlantConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    collision: CollisionConfig = field(default_factory=CollisionConfig)


# ---------------------------------------------------------------- the plant


@dataclass(frozen=True)
class Plant:
    """The "real" robot of one run set."""

    nominal: RobotModel  # what the twin uses
    true: RobotModel  # same kinematics, perturbed inertias, payload
    mass_scale: FloatArray  # per link 1..7
    com_shift_m: FloatArray  # (7, 3)
    coulomb: FloatArray
    viscous: FloatArray
    coulomb_velocity: float
    gain: FloatArray
    offset: FloatArray
    noise: FloatArray
    velocity_noise: float

    def friction(self, velocity: FloatArray) -> FloatArray:
        return self.coulomb * np.tanh(velocity / self.coulomb_velocity) + self.viscous * velocity

    def ideal_effort(
        self, position: FloatArray, velocity: FloatArray, acceleration: FloatArray
    ) -> FloatArray:
        """RNEA_true + friction, without τ_ext, gain, offset or noise."""
        rigid = inverse_dynamics(self.true, position, velocity, acceleration)
        return rigid + self.friction(velocity)


def _rng(seed: int, *key: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), *key]))


def _check_seed(seed: int) -> None:
    if seed < 0:
        raise UsageError(
            f"seed must be ≥ 0, got {seed}", "seed", "give a non-negative integer", option="seed"
        )


@lru_cache(maxsize=8)
def make_plant(config: PlantConfig, seed: int) -> Plant:
    """Draw the plant of a run set; the cached nominal model is never modified."""
    _check_seed(seed)
    nominal = load_robot(ROBOT)
    dof = nominal.dof
    rng = _rng(seed, 0)
    model = pin.Model(nominal.model)
    mass_scale = np.maximum(1.0 + rng.normal(0.0, config.mass_sigma, dof), 0.5)
    com_shift = rng.normal(0.0, config.com_sigma_m, (dof, 3))
    for k in range(dof):
        jid = k + 1
        inertia = model.inertias[jid]
        model.inertias[jid] = pin.Inertia(
            float(inertia.mass * mass_scale[k]),
            np.asarray(inertia.lever) + com_shift[k],
            np.asarray(inertia.inertia) * mass_scale[k],
        )
    # payload beyond the flange (link_eef when the URDF has it, else the last joint's origin)
    last = model.njoints - 1
    flange = (
        model.frames[model.getFrameId("link_eef")].placement
        if model.existFrame("link_eef")
        else pin.SE3.Identity()
    )
    m, r, h = config.payload_kg, config.payload_radius_m, config.payload_length_m
    cylinder = np.diag([m * (3 * r * r + h * h) / 12, m * (3 * r * r + h * h) / 12, m * r * r / 2])
    rot = np.asarray(flange.rotation)
    centre = flange.act(np.array([0.0, 0.0, config.payload_offset_m]))
    model.inertias[last] = model.inertias[last] + pin.Inertia(m, centre, rot @ cylinder @ rot.T)

    spread = config.friction_spread
    coulomb = np.asarray(config.coulomb_nm) * rng.uniform(1 - spread, 1 + spread, dof)
    viscous = np.asarray(config.viscous_nms) * rng.uniform(1 - spread, 1 + spread, dof)
    gain = rng.uniform(*config.gain_range, dof)
    offset = rng.normal(0.0, config.offset_sigma_nm, dof)
    return Plant(
        nominal=nominal,
        true=replace(nominal, model=model),
        mass_scale=mass_scale,
        com_shift_m=com_shift,
        coulomb=coulomb,
        viscous=viscous,
        coulomb_velocity=config.coulomb_velocity,
        gain=gain,
        offset=offset,
        noise=np.asarray(config.effort_noise_nm, dtype=np.float64),
        velocity_noise=config.velocity_noise,
    )


# ---------------------------------------------------------------- motion


@dataclass(frozen=True)
class Trajectory:
    t_s: FloatArray  # nominal sample times from 0
    position: FloatArray  # (N, 7)
    velocity: FloatArray
    acceleration: FloatArray
    teaching_points: FloatArray  # (K, 7), home first and last
    knots_s: FloatArray  # when the path passes each teaching point


def _flange_positions(robot: RobotModel, position: FloatArray) -> FloatArray:
    model = robot.model
    data = model.createData()
    fid = model.getFrameId("link_eef") if model.existFrame("link_eef") else None
    out = np.empty((len(position), 3))
    for i, q in enumerate(robot.configuration(position)):
        if fid is None:
            pin.forwardKinematics(model, data, q)
            out[i] = data.oMi[model.njoints - 1].translation
        else:
            pin.framesForwardKinematics(model, data, q)
            out[i] = data.oMf[fid].translation
    return out


def _teaching_points(
    robot: RobotModel, cfg: MotionConfig, rng: np.random.Generator, path_rad: float
) -> FloatArray:
    home = np.asarray(cfg.home)
    spread = np.asarray(cfg.spread_rad)
    lower = robot.model.lowerPositionLimit + 0.05
    upper = robot.model.upperPositionLimit - 0.05
    home_xyz = _flange_positions(robot, home[None])[0]
    points = [home]
    total = 0.0
    for _ in range(10_000):
        candidates = home + rng.uniform(-1.0, 1.0, (16, len(home))) * spread
        ok = np.all((candidates > lower) & (candidates < upper), axis=1)
        dist = np.linalg.norm(_flange_positions(robot, candidates) - home_xyz, axis=1)
        ok &= dist <= cfg.point_radius_m
        for cand in candidates[ok]:
            total += float(np.linalg.norm(cand - points[-1]))
            points.append(cand)
            if total + float(np.linalg.norm(cand - home)) >= path_rad:
                points.append(home)
                return np.array(points)
    raise DataError("cannot draw teaching points", "twincd.synth", "widen MotionConfig.spread_rad")


def _check_durations(cfg: MotionConfig) -> None:
    if not 2 * cfg.rest_s + 1.0 <= cfg.duration_s[0] <= cfg.duration_s[1]:
        raise UsageError(
            f"bad path duration range {cfg.duration_s[0]}–{cfg.duration_s[1]} s",
            "MotionConfig.duration_s",
            f"give {2 * cfg.rest_s + 1.0:g} s ≤ min ≤ max",
            option="min_duration,max_duration",
        )
    if not cfg.segment_s >= 2 * (2 * cfg.rest_s + 1.0):
        raise UsageError(
            f"segment length {cfg.segment_s} s too short",
            "MotionConfig.segment_s",
            f"give {2 * (2 * cfg.rest_s + 1.0):g} s or more",
        )


def make_trajectory(robot: RobotModel, cfg: MotionConfig, rng: np.random.Generator) -> Trajectory:
    """A smooth path home → teaching points → home at ≈ the configured mean speed."""
    _check_durations(cfg)
    speed = np.deg2rad(cfg.mean_speed_deg_s)
    home_xyz = _flange_positions(robot, np.asarray(cfg.home)[None])[0]
    lo, hi = cfg.duration_s
    dt = 1.0 / cfg.rate_hz
    zero = np.zeros(len(cfg.home))
    bc = ([(1, zero), (2, zero)], [(1, zero), (2, zero)])
    for _ in range(200):
        target = rng.uniform(lo, hi)
        moving = target - 2 * cfg.rest_s
        points = _teaching_points(robot, cfg, rng, 0.85 * speed * moving)
        chord = np.linalg.norm(np.diff(points, axis=0), axis=1)
        knots = np.concatenate([[0.0], np.cumsum(chord)])
        spline = make_interp_spline(knots, points, k=5, bc_type=bc)
        dense = np.linspace(0.0, knots[-1], 4000)
        arc = float(np.mean(np.linalg.norm(spline(dense, 1), axis=1))) * knots[-1]
        scale = float(np.clip(arc / speed, lo - 2 * cfg.rest_s, hi - 2 * cfg.rest_s)) / knots[-1]
        duration = knots[-1] * scale + 2 * cfg.rest_s
        n = int(np.floor(duration / dt + 1e-9)) + 1
        t = np.arange(n) * dt
        s = np.clip(t - cfg.rest_s, 0.0, knots[-1] * scale) / scale
        moving_mask = (t > cfg.rest_s) & (t < cfg.rest_s + knots[-1] * scale)
        position = spline(s)
        velocity = np.where(moving_mask[:, None], spline(s, 1) / scale, 0.0)
        acceleration = np.where(moving_mask[:, None], spline(s, 2) / scale**2, 0.0)
        position[~moving_mask] = np.where(
            t[~moving_mask, None] <= cfg.rest_s, points[0], points[-1]
        )
        within = np.linalg.norm(_flange_positions(robot, position) - home_xyz, axis=1)
        limits = np.all(
            (position >= robot.model.lowerPositionLimit)
            & (position <= robot.model.upperPositionLimit)
        )
        if within.max() <= cfg.radius_m and limits:
            return Trajectory(
                np.asarray(t, dtype=np.float64),
                position,
                velocity,
                acceleration,
                points,
                knots * scale + cfg.rest_s,
            )
    raise DataError("cannot draw a path within the radius", "twincd.synth", "check MotionConfig")


# ---------------------------------------------------------------- collisions


@dataclass(frozen=True)
class Press:
    """One press of the experimenter; ``touched`` False: the switch went on, nothing touched."""

    link: str
    point: FloatArray  # contact point in the link frame (m)
    direction: FloatArray  # unit force direction in the world frame
    peak_n: float
    start_s: float  # contact start (for a miss: when it would have started)
    duration_s: float
    label_on_s: float
    label_off_s: float
    touched: bool

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s


def _link_point(model: pin.Model, jid: int, radius: float, rng: np.random.Generator) -> FloatArray:
    """A point on the surface of a link: along its joint-to-next-joint segment, off the axis."""
    seg = (
        np.asarray(model.jointPlacements[jid + 1].translation)
        if jid + 1 < model.njoints
        else np.zeros(3)
    )
    length = float(np.linalg.norm(seg))
    normal = rng.normal(size=3)
    if length > 1e-6:
        axis = seg / length
        normal -= axis * float(normal @ axis)
    normal /= np.linalg.norm(normal)
    return np.asarray(rng.uniform(0.15, 0.85) * seg + radius * normal, dtype=np.float64)


def draw_presses(
    cfg: CollisionConfig, plant: Plant, traj: Trajectory, rng: np.random.Generator
) -> list[Press]:
    model = plant.nominal.model
    total = float(traj.t_s[-1])
    count = int(rng.integers(cfg.presses[0], cfg.presses[1] + 1))
    span = total - 2 * cfg.margin_s
    longest = cfg.duration_s[1] + cfg.lead_s[1] + cfg.lag_s[1] + 0.2
    count = min(count, max(0, int(span // longest)))  # short paths take fewer presses
    slot = span / max(count, 1)
    presses: list[Press] = []
    for k in range(count):
        a = cfg.margin_s + k * slot
        duration = rng.uniform(*cfg.duration_s)
        lead = rng.uniform(*cfg.lead_s)
        lag = rng.uniform(*cfg.lag_s)
        first = a + lead + 0.1
        last = max(first, a + slot - duration - lag - 0.1)
        start = rng.uniform(first, last)
        link = cfg.links[int(rng.integers(len(cfg.links)))]
        frame = model.frames[model.getFrameId(link)]
        jid = int(frame.parentJoint)
        point = _link_point(model, jid, cfg.surface_radius_m, rng)  # in the joint frame
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        peak = rng.uniform(*cfg.force_n)
        touched = bool(rng.uniform() >= cfg.miss_probability)
        # push, do not pull: the force points into the surface at the press's middle
        mid = int(np.searchsorted(traj.t_s, start + duration / 2).clip(0, len(traj.t_s) - 1))
        data = model.createData()
        q_mid = plant.nominal.configuration(traj.position[mid : mid + 1])[0]
        pin.forwardKinematics(model, data, q_mid)
        outward = np.asarray(data.oMi[jid].rotation) @ (point - _axis_projection(model, jid, point))
        if float(direction @ outward) > 0:
            direction = -direction
        presses.append(
            Press(
                link=link,
                point=np.asarray(frame.placement.actInv(point), dtype=np.float64),
                direction=direction,
                peak_n=float(peak),
                start_s=float(start),
                duration_s=float(duration),
                label_on_s=float(start - lead),
                label_off_s=float(start + duration + lag),
                touched=touched,
            )
        )
    return presses


def _axis_projection(model: pin.Model, jid: int, point: FloatArray) -> FloatArray:
    seg = (
        np.asarray(model.jointPlacements[jid + 1].translation)
        if jid + 1 < model.njoints
        else np.zeros(3)
    )
    length2 = float(seg @ seg)
    if length2 < 1e-12:
        return np.zeros(3)
    return np.asarray(seg * float(point @ seg) / length2, dtype=np.float64)


def press_force(press: Press, t_s: FloatArray) -> FloatArray:
    """Force magnitude over time: peak · sin²(π (t − start) / T) inside the press, else 0."""
    phase = (t_s - press.start_s) / press.duration_s
    inside = (phase > 0.0) & (phase < 1.0)
    if not press.touched:
        return np.zeros(len(t_s))
    return np.asarray(np.where(inside, press.peak_n * np.sin(np.pi * phase) ** 2, 0.0), np.float64)


def contact_torque(
    robot: RobotModel, position: FloatArray, link: str, point: FloatArray, force_world: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """τ_ext = J_LOCAL(q)ᵀ w per sample, and w = (force, p × force) in the link frame (N, 6).

    ``force_world`` (N, 3) acts at ``point`` (link frame); ``position`` is (N, dof).
    """
    model = robot.model
    data = model.createData()
    jid = int(model.frames[model.getFrameId(link)].parentJoint)
    body = model.frames[model.getFrameId(link)].placement  # body frame in the joint frame
    p_joint = body.act(point)
    tau = np.zeros((len(position), model.nv))
    wrench = np.zeros((len(position), 6))
    for i, q in enumerate(robot.configuration(position)):
        pin.forwardKinematics(model, data, q)
        f_local = np.asarray(data.oMi[jid].rotation).T @ force_world[i]
        w = np.concatenate([f_local, np.cross(p_joint, f_local)])
        jac = pin.computeJointJacobian(model, data, q, jid)
        tau[i] = jac.T @ w
        w_body = np.concatenate(
            [body.rotation.T @ f_local, np.cross(point, body.rotation.T @ f_local)]
        )
        wrench[i] = w_body
    return robot.joint_values(tau), wrench


# ---------------------------------------------------------------- one path


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


def path_start_ns(seed: int, split: str, index: int) -> int:
    """Wall-clock start of a path: one run set per seed-day, paths a minute apart.

    Days wrap after 10 years so stamps stay within int32 seconds.
    """
    split_no = SPLITS.index(split) if split in SPLITS else len(SPLITS)
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
    _check_seed(seed)
    if index < 0:
        raise UsageError(f"path index must be ≥ 0, got {index}", "twincd.synth", "pass 0 or more")
    split_no = SPLITS.index(split) if split in SPLITS else len(SPLITS)
    collisions = split == "test" if collisions is None else collisions
    motion = config.motion
    start_ns = path_start_ns(seed, split, index)
    rng = _rng(seed, 1 + split_no, index)
    if motion.duration_s[1] <= motion.segment_s:
        yield _simulate(config, seed, split, index, rng, collisions, start_ns, first=True)
        return
    _check_durations(motion)
    period_ns = round(1e9 / motion.rate_hz)
    for number, samples in enumerate(segment_sizes(motion, rng)):
        span = (samples - 1) / motion.rate_hz
        segment = replace(config, motion=replace(motion, duration_s=(span, span)))
        yield _simulate(
            segment,
            seed,
            split,
            index,
            _rng(seed, 1 + split_no, index, number),
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
    n, dof = traj.position.shape
    t = traj.t_s

    presses = draw_presses(config.collision, plant, traj, rng) if collisions else []
    tau_ext = np.zeros((n, dof))
    wrench = np.zeros((n, 6))
    point = np.zeros((n, 3))
    link = [""] * n
    for press in presses:
        magnitude = press_force(press, t)
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

    rigid = inverse_dynamics(plant.true, traj.position, traj.velocity, traj.acceleration)
    friction = plant.friction(traj.velocity)
    noise = rng.normal(size=(n, dof)) * plant.noise
    effort = (rigid + friction - tau_ext) / plant.gain + plant.offset + noise
    velocity = traj.velocity + rng.normal(0.0, plant.velocity_noise, (n, dof))
    position = traj.position.copy()
    if config.plant.float32:
        position, velocity, effort = (
            a.astype(np.float32).astype(np.float64) for a in (position, velocity, effort)
        )

    lat_lo, lat_hi = config.motion.latency_ms
    period_ns = round(1e9 / config.motion.rate_hz)
    stamp = start_ns + np.arange(n, dtype=np.int64) * period_ns
    log_time = stamp + np.round(rng.uniform(lat_lo, lat_hi, n) * 1e6).astype(np.int64)

    announce = bool(presses) if announce is None else announce and first
    events: list[tuple[int, bool]] = [(int(stamp[0]), False)] if first else []
    link_events: list[tuple[int, str]] = [(int(stamp[0]), "")] if announce else []
    for press in presses:
        for when, value in ((press.label_on_s, True), (press.label_off_s, False)):
            latency = round(rng.uniform(lat_lo, lat_hi) * 1e6)
            events.append((start_ns + round(when * 1e9) + latency, value))
            touched = press.link if value and press.touched else ""
            link_events.append((events[-1][0], touched))
    label = _held(events, log_time)

    return SynthRun(
        split=split,
        index=index,
        seed=seed,
        joint_names=robot.joint_names,
        stamp_ns=stamp,
        log_time_ns=log_time,
        position=position,
        velocity=velocity,
        effort=effort,
        true_velocity=traj.velocity,
        acceleration=traj.acceleration,
        rigid=rigid,
        friction=friction,
        tau_ext=tau_ext,
        contact_link=tuple(link),
        contact_wrench=wrench,
        contact_point=point,
        label=label,
        label_events=tuple(events),
        link_events=tuple(link_events),
        presses=tuple(presses),
        trajectory=traj,
        contact_start=announce,
    )


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


# ---------------------------------------------------------------- writing


def _contact_cdr(
    stamp_ns: int, link: str, wrench: FloatArray, point: FloatArray
) -> tuple[bytes, bytes]:
    hdr: Any = header(stamp_ns, link)
    w = _WrenchStamped(
        header=hdr,
        wrench=_Wrench(
            force=_Vector3(x=float(wrench[0]), y=float(wrench[1]), z=float(wrench[2])),
            torque=_Vector3(x=float(wrench[3]), y=float(wrench[4]), z=float(wrench[5])),
        ),
    )
    p = _PointStamped(
        header=hdr,
        point=_Point(x=float(point[0]), y=float(point[1]), z=float(point[2])),
    )
    return serialize(w, WRENCH), serialize(p, POINT)


def run_messages(run: SynthRun) -> list[tuple[str, int, bytes]]:
    """Every message of a run (or segment) as (topic, log_time_ns, cdr), sorted by log time
    (stable)."""
    out: list[tuple[str, int, bytes]] = []
    states = joint_state_cdr(run.stamp_ns, run.joint_names, run.position, run.velocity, run.effort)
    for i, data in enumerate(states):
        out.append((JOINT_TOPIC, int(run.log_time_ns[i]), data))
    for when, value in run.label_events:
        out.append((LABEL_TOPIC, when, bool_cdr(value)))
    for when, link in run.link_events:
        out.append((LINK_TOPIC, when, serialize(_String(data=link), STRING)))
    if run.presses or run.contact_start:
        # "nothing touches" at the path's first sample and at the first sample after a contact
        previous: str | None = None if run.contact_start else ""
        for i, link in enumerate(run.contact_link):
            if link or (previous is None or previous):
                wrench, point = _contact_cdr(
                    int(run.stamp_ns[i]), link, run.contact_wrench[i], run.contact_point[i]
                )
                out.append((CONTACT_TOPIC, int(run.log_time_ns[i]), wrench))
                out.append((CONTACT_POINT_TOPIC, int(run.log_time_ns[i]), point))
            previous = link
    out.sort(key=lambda m: m[1])
    return out


_TOPICS = (
    (JOINT_TOPIC, JOINT_STATE),
    (LABEL_TOPIC, BOOL),
    (LINK_TOPIC, STRING),
    (CONTACT_TOPIC, WRENCH),
    (CONTACT_POINT_TOPIC, POINT),
)

# samples written so far (for a progress display); called after each segment
SampleProgress = Callable[[int], None]


def _stream(
    segments: Iterable[SynthRun],
    add_topic: Callable[[str, str], Any],
    write: Callable[[Any, int, bytes], None],
    progress: SampleProgress | None = None,
) -> int:
    """Every message of ``segments`` to a writer, a segment at a time; returns the samples.

    A topic is registered when first used, in the order of ``_TOPICS`` within a segment.
    """
    channels: dict[str, Any] = {}
    samples = 0
    for segment in segments:
        messages = run_messages(segment)
        count = len(segment.stamp_ns)
        del segment  # its arrays go before the writer's buffers grow
        used = {m[0] for m in messages}
        for topic, msgtype in _TOPICS:
            if topic in used and topic not in channels:
                channels[topic] = add_topic(topic, msgtype)
        for topic, log_time, data in messages:
            write(channels[topic], log_time, data)
        samples += count
        if progress:
            progress(count)
    return samples


def _mcap_messages(
    segments: Iterable[SynthRun], path: Path, progress: SampleProgress | None = None
) -> int:
    from twincd.io.mcap import McapLogWriter

    with McapLogWriter(Path(path)) as out:
        return _stream(segments, out.add_topic, out.write, progress)


def write_mcap(run: SynthRun, path: Path) -> Path:
    """A run held in memory as a bare ros2 MCAP file (atomic)."""
    _mcap_messages([run], path)
    return Path(path)


def write_path(
    config: SynthConfig,
    seed: int,
    split: str,
    index: int,
    path: Path,
    progress: SampleProgress | None = None,
) -> int:
    """A path of a run set as a bare ros2 MCAP file (atomic), made and written a segment at a
    time: memory does not grow with its length. Returns its samples. Same bytes as
    ``write_mcap(simulate_path(...))`` whenever log times do not interleave across a join
    (latency below one sample period)."""
    return _mcap_messages(path_segments(config, seed, split, index), path, progress)


def write_rosbag2(run: SynthRun | Iterable[SynthRun], path: Path) -> Path:
    """A run, or the segments of a path, as a rosbag2 sqlite3 folder (written beside, renamed
    into place)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.metadata import parse_qos

    from twincd.io.mcap import DEFAULT_QOS

    qos = parse_qos(DEFAULT_QOS)
    segments = [run] if isinstance(run, SynthRun) else run

    path = Path(path)
    tmp_parent = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    shutil.rmtree(tmp_parent, ignore_errors=True)
    try:
        tmp_parent.mkdir(parents=True)
        writer = Writer(tmp_parent / path.name, version=8, storage_plugin=StoragePlugin.SQLITE3)
        writer.open()
        try:
            _stream(
                segments,
                lambda topic, msgtype: writer.add_connection(
                    topic, msgtype, typestore=typestore(), offered_qos_profiles=qos
                ),
                writer.write,
            )
        finally:
            writer.close()
        if path.exists():
            shutil.rmtree(path)
        os.replace(tmp_parent / path.name, path)
    except OSError as exc:
        raise OutputError(
            f"cannot write rosbag2 folder: {exc}", str(path), "pick a writable OUTDIR"
        ) from exc
    finally:
        shutil.rmtree(tmp_parent, ignore_errors=True)
    return path


# ---------------------------------------------------------------- a whole run set


def log_name(split: str, index: int) -> str:
    return f"{split}_{index:03d}"


@dataclass(frozen=True)
class _Written:
    path: Path
    samples: int  # those not yet reported to a progress display


def _make_one(
    args: tuple[SynthConfig, int, str, int, Path], progress: Progress | None = None
) -> _Written:
    """One path written; with ``progress`` (in this process), its samples reported as its
    segments are written."""
    config, seed, split, index, target = args
    if progress is None:
        return _Written(target, write_path(config, seed, split, index, target))
    write_path(config, seed, split, index, target, lambda samples: progress(0, samples))
    return _Written(target, 0)


def write_dataset(
    outdir: Path,
    config: SynthConfig | None = None,
    seed: int = 0,
    counts: Sequence[int] = (30, 5, 5),
    rosbag2_copy: bool = True,
    jobs: int = 1,
    progress: Progress | None = None,
) -> list[Path]:
    """The paper's protocol: ``outdir/{train,val,test}/<split>_NNN.mcap``.

    Train and val paths are collision-free, test paths have presses. With ``rosbag2_copy``, the
    first test path is also written as a rosbag2 sqlite3 folder ``outdir/rosbag2/test_000``
    (outside ``test/``, so a folder argument does not read the same log twice).
    ``progress(paths, samples)`` is told of the paths and samples written as they are (of each
    segment with ``jobs`` 1, of each path otherwise). Returns the paths written, in order.
    """
    config = config or SynthConfig()
    _check_seed(seed)
    if len(counts) != len(SPLITS) or any(c < 0 for c in counts):
        raise UsageError(
            "path counts must be three numbers ≥ 0",
            "train/val/test counts",
            "give 0 or more each",
            option="train,val,test",
        )
    if jobs < 1:
        raise UsageError(f"jobs must be ≥ 1, got {jobs}", "jobs", "give 1 or more", option="jobs")
    outdir = Path(outdir)
    if outdir.exists() and not outdir.is_dir():
        raise OutputError("output exists and is not a folder", str(outdir), "give a folder name")
    tasks: list[tuple[SynthConfig, int, str, int, Path]] = []
    for split, count in zip(SPLITS, counts, strict=True):
        for index in range(count):
            tasks.append(
                (config, seed, split, index, outdir / split / f"{log_name(split, index)}.mcap")
            )
    try:
        for split, count in zip(SPLITS, counts, strict=True):
            if count:
                (outdir / split).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(
            f"cannot create folder: {exc.strerror}", str(outdir), "pick a writable OUTDIR"
        ) from exc
    executor = Executor(jobs)
    make = partial(_make_one, progress=progress) if executor.workers == 1 else _make_one
    written = [w.path for w in executor.map(make, tasks, progress)]
    if rosbag2_copy and counts[2] > 0:
        (outdir / "rosbag2").mkdir(exist_ok=True)
        target = outdir / "rosbag2" / log_name("test", 0)
        written.append(write_rosbag2(path_segments(config, seed, "test", 0), target))
    return written
