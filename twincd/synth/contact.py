"""Hand presses on the moving arm (paper Fig. 4), test paths only: 5–7 presses per path (mean 6),
one per equal time slot. A hand pushes on link3, link4, link5 or link6 (between joints 3–4, 4–5,
5–6, 6–7) at a point of that link (on the segment between its joint and the next, 4.5 cm off the
axis), with a force of 8–35 N peak in a random direction (uniform on the half-sphere pointing
into the surface: a hand pushes, it does not pull), fixed in the world frame during the press,
with magnitude peak·sin²(π s/T) over T = 0.4–1.6 s. τ_ext = J(q)ᵀ w, with J Pinocchio's joint
Jacobian of the contact link (LOCAL) and w the contact force moved to the link origin. The label
is the experimenter's switch: on 0–150 ms before contact, off 0–100 ms after; 15 % of presses
touch nothing (label on, no force).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from twincd.synth.config import CollisionConfig
from twincd.synth.motion import Trajectory
from twincd.synth.plant import Plant
from twincd.twin.robot import RobotModel
from twincd.types import FloatArray


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
