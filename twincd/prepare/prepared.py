"""``PreparedLog``: one whole log prepared, its raw and filtered efforts (and what a model's
features or residual add) in memory, as ``Setup.prepare`` returns it (what the baselines and
``evaluate``'s methods that fit on training logs use, one log at a time).

It holds arrays only: importing it loads neither the reader nor the chain.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from twincd.errors import DataError
from twincd.io.logs import JointStates
from twincd.signal.features import FittedModel, ModelFeatures
from twincd.signal.filters import LowPass
from twincd.types import BoolArray, FloatArray

if TYPE_CHECKING:
    from twincd.twin.robot import RobotModel


@dataclass(frozen=True)
class PreparedLog:
    """One whole log ready for fitting or scoring: raw and filtered efforts in ``joint_names``
    order.

    ``effort_f`` is the paper's τ̃ and ``sim_effort_f`` its τ̂̃ (prepared for a fit: every input
    of the features through the filter). Prepared for a fitted model (scoring) it carries the
    model's residual in each band instead (``residual``, ``residual_fast``, ``predicted``,
    ``fast_off``: ``twincd.prepare.chain.build_chain``), and no ``sim_effort_f``. ``robot`` is
    None when the twin's effort came from the log itself and no model was asked for.
    """

    states: JointStates  # restricted to joint_names
    # τ̂ of every sample (None: prepared for scoring on a coarse grid, which has it on its nodes)
    sim_effort: FloatArray | None
    effort_f: FloatArray
    sim_effort_f: FloatArray | None
    robot: RobotModel | None
    simulated: bool  # False: the log carried /twincd/sim_effort
    # the filter behind effort_f: methods that filter other inputs do it alike
    lowpass: LowPass = field(default_factory=LowPass)
    period_s: float | None = None
    velocity_f: FloatArray | None = None  # q̇̃, the velocity through the same filter (friction)
    coulomb_f: FloatArray | None = None  # filtered tanh(q̇/ε), (N, E, joints), ε in coulomb_eps
    # what the chain computed for a model: the ε of ``coulomb_f``, the θ of
    # ``regressor_effort_f``
    features: ModelFeatures = field(default_factory=ModelFeatures)
    # Y(q, q̇, q̈) through the same filter, (N, joints, parameters) (identified models)
    regressor_f: FloatArray | None = None
    # Ỹθ per joint, (N, D), instead of ``regressor_f`` when prepared to score a fitted
    # identified model (its ``ModelFeatures.theta``)
    regressor_effort_f: FloatArray | None = None
    # (N, bands) each sample's edge factor: the noise of its filtered values over the segment's
    # middle (``twincd.signal.edges``; None: unfiltered)
    edge_factor: FloatArray | None = None
    # prepared for a fitted model: its residual in the filter's band and in the fast band, its
    # prediction (τ̃ − residual) and where the fast band is not judged (a velocity jump)
    residual: FloatArray | None = None
    residual_fast: FloatArray | None = None
    predicted: FloatArray | None = None
    fast_off: FloatArray | None = None
    model: FittedModel | None = None  # the fitted model of ``residual``

    @property
    def source(self) -> str:
        return self.states.source

    @property
    def coulomb_eps(self) -> tuple[float, ...]:
        return self.features.coulomb_eps

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.states.joint_names

    @property
    def labels(self) -> BoolArray | None:
        return self.states.labels

    @property
    def effort(self) -> FloatArray:
        assert self.states.effort is not None  # prepare() refuses logs without effort
        return self.states.effort

    @property
    def twin_f(self) -> FloatArray:
        """τ̂̃, the twin's filtered effort (a log prepared with a fit's features; a
        ``DataError`` for one prepared for scoring, which holds its model's residual)."""
        if self.sim_effort_f is None:
            raise DataError(
                "this log was prepared for scoring: it holds its model's residual, not the "
                "filtered twin effort",
                self.source,
                "prepare it with the features to fit (Setup.prepare(path, features))",
            )
        return self.sim_effort_f

    def __len__(self) -> int:
        return len(self.states)

    @property
    def samples(self) -> int:
        return len(self.states)
