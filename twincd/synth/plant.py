"""The "real" xArm 7 of a run set (the *plant*): the xArm 7 URDF with errors that the twin does
not model, drawn once per run set from the seed (``make_plant``):

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
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
import pinocchio as pin

from twincd.synth.config import PlantConfig, check_seed, seeded_rng
from twincd.twin.dynamics import inverse_dynamics
from twincd.twin.robot import RobotModel, load_robot
from twincd.types import FloatArray

ROBOT = "xarm7"


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


@lru_cache(maxsize=8)
def make_plant(config: PlantConfig, seed: int) -> Plant:
    """Draw the plant of a run set; the cached nominal model is never modified."""
    check_seed(seed)
    nominal = load_robot(ROBOT)
    dof = nominal.dof
    rng = seeded_rng(seed, 0)
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
