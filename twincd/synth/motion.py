"""A path of the arm (paper Table I, Fig. 3): teaching points drawn around a home pose, each
keeping the flange within 180 mm of its home position; a quintic interpolating spline in joint
space through home → points → home with zero velocity and acceleration at both ends (smoother
than a clamped cubic: no acceleration step at start and stop); 0.5 s at rest before and after.
The time scale is set so that the mean joint-space speed while moving, mean over time of ‖q̇‖₂,
is 30 °/s (a little less counting the rests); a path whose flange leaves the 200 mm sphere is
redrawn. Sampled every 10 ms; 22–35 s per path. The position controller tracks perfectly:
pushes show up in the effort only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.interpolate import make_interp_spline

from twincd.errors import DataError
from twincd.synth.config import MotionConfig, check_durations
from twincd.twin.robot import RobotModel
from twincd.types import FloatArray


@dataclass(frozen=True)
class Trajectory:
    t_s: FloatArray  # nominal sample times from 0
    position: FloatArray  # (N, 7)
    velocity: FloatArray
    acceleration: FloatArray
    teaching_points: FloatArray  # (K, 7), home first and last
    knots_s: FloatArray  # when the path passes each teaching point


def flange_positions(robot: RobotModel, position: FloatArray) -> FloatArray:
    """The flange's world position at each row of ``position`` (``link_eef`` when the URDF has
    it, else the last joint's origin)."""
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
    home_xyz = flange_positions(robot, home[None])[0]
    points = [home]
    total = 0.0
    for _ in range(10_000):
        candidates = home + rng.uniform(-1.0, 1.0, (16, len(home))) * spread
        ok = np.all((candidates > lower) & (candidates < upper), axis=1)
        dist = np.linalg.norm(flange_positions(robot, candidates) - home_xyz, axis=1)
        ok &= dist <= cfg.point_radius_m
        for cand in candidates[ok]:
            total += float(np.linalg.norm(cand - points[-1]))
            points.append(cand)
            if total + float(np.linalg.norm(cand - home)) >= path_rad:
                points.append(home)
                return np.array(points)
    raise DataError("cannot draw teaching points", "twincd.synth", "widen MotionConfig.spread_rad")


def make_trajectory(robot: RobotModel, cfg: MotionConfig, rng: np.random.Generator) -> Trajectory:
    """A smooth path home → teaching points → home at ≈ the configured mean speed."""
    check_durations(cfg)
    speed = np.deg2rad(cfg.mean_speed_deg_s)
    home_xyz = flange_positions(robot, np.asarray(cfg.home)[None])[0]
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
        within = np.linalg.norm(flange_positions(robot, position) - home_xyz, axis=1)
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
