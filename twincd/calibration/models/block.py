"""The calibration file's ``model`` block read back (``ResidualModel.to_dict`` writes it), every
number validated."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from itertools import pairwise
from typing import TYPE_CHECKING, Any

import numpy as np

from twincd.calibration.models.constants import MODEL_KINDS, SPEED_BINS, STATISTICS
from twincd.calibration.models.kinds import make_model, model_class
from twincd.calibration.values import finite_array, finite_number
from twincd.errors import CalibrationError
from twincd.types import FloatArray

if TYPE_CHECKING:
    from twincd.calibration.models.base import ResidualModel


def _optional_column(
    coeff: Mapping[str, Any], names: Sequence[str], key: str, where: str
) -> FloatArray | None:
    """A per-joint coefficient that only some models have: all joints or none."""
    values = [coeff[n].get(key) for n in names]
    if all(v is None for v in values):
        return None
    if any(v is None for v in values):
        raise ValueError(f"coefficient {key!r} is missing for some joints")
    return finite_array(values, names, key, where)


def _speed_bins(model: Mapping[str, Any], where: str) -> tuple[float, ...] | None:
    """The depth statistic's speed bins (None: a model scored by the sum): rising, positive,
    finite edges."""
    statistic = model["statistic"]
    if statistic not in STATISTICS:
        raise CalibrationError(
            f"calibration field model.statistic is {statistic!r}, not one of "
            f"{', '.join(STATISTICS)}",
            where,
            "re-run `twincd fit`",
        )
    if statistic == "sum":
        return None
    edges = model["speed_bins"]
    if not isinstance(edges, list) or not edges:
        raise CalibrationError(
            "calibration field model.speed_bins is not a list of speeds",
            where,
            "re-run `twincd fit`",
        )
    out = tuple(finite_number(e, "model.speed_bins", where, positive=True) for e in edges)
    if any(b <= a for a, b in pairwise(out)):
        raise CalibrationError(
            "calibration field model.speed_bins does not rise", where, "re-run `twincd fit`"
        )
    return out


def _scale(
    coeff: Mapping[str, Any],
    names: Sequence[str],
    speed_bins: tuple[float, ...] | None,
    where: str,
) -> FloatArray | None:
    """The whitening scale: one number per joint (the sum), or one per speed bin (the depth
    statistic), all joints or none."""
    if speed_bins is None:
        return _optional_column(coeff, names, "scale", where)
    rows = [coeff[n].get("scale") for n in names]
    bins = len(speed_bins) + 1
    if any(not isinstance(r, list) or len(r) != bins for r in rows):
        raise CalibrationError(
            f"calibration field scale is not a list of {bins} numbers (one per speed bin) for "
            "every joint",
            where,
            "re-run `twincd fit`",
        )
    return np.array(
        [
            [finite_number(v, f"scale[{n}]", where) for v in r]
            for r, n in zip(rows, names, strict=True)
        ]
    )


def _theta(coeff: Mapping[str, Any], names: Sequence[str], where: str) -> FloatArray | None:
    """The identified models' per-joint regressor weights: all joints, of one length, or none."""
    rows = [coeff[n].get("theta") for n in names]
    if all(r is None for r in rows):
        return None
    if any(r is None for r in rows):
        raise ValueError("coefficient 'theta' is missing for some joints")
    lengths = {len(r) if isinstance(r, list) else -1 for r in rows}
    if len(lengths) != 1 or -1 in lengths:
        raise CalibrationError(
            "calibration field theta is not a list of numbers of one length per joint",
            where,
            "re-run `twincd fit`",
        )
    length = lengths.pop()
    if length == 0 or length % 10:
        raise CalibrationError(
            f"calibration field theta has {length} numbers per joint, not 10 per link",
            where,
            "re-run `twincd fit`",
        )
    return np.array(
        [
            [finite_number(v, f"theta[{n}]", where) for v in r]
            for r, n in zip(rows, names, strict=True)
        ],
        dtype=np.float64,
    )


def _require_coefficients(kind: str, extra: Mapping[str, FloatArray | None], where: str) -> None:
    cls, whitened = model_class(kind)
    needed = (
        (["c", "d", "epsilon"] if cls.needs_coulomb else [])
        + (["scale"] if whitened else [])
        + (["theta"] if cls.needs_regressor else [])
    )
    if extra.get("theta") is not None and not cls.needs_regressor:
        raise CalibrationError(
            f"the {kind} model has regressor weights (theta), which only identified models use",
            where,
            "re-run `twincd fit`",
        )
    missing = [k for k in needed if extra.get(k) is None]
    if missing:
        raise CalibrationError(
            f"the {kind} model lacks its coefficient(s) {', '.join(missing)}",
            where,
            "re-run `twincd fit`",
        )
    eps, scale = extra.get("epsilon"), extra.get("scale")
    if (eps is not None and not np.all(eps > 0)) or (scale is not None and not np.all(scale > 0)):
        raise CalibrationError("epsilon and scale must be positive", where, "re-run `twincd fit`")


def read_model(
    raw: Mapping[str, Any],
    names: Sequence[str],
    order: Sequence[int],
    where: str,
    r2: FloatArray | None = None,
    rmse: FloatArray | None = None,
) -> ResidualModel:
    """The fitted model of a calibration file's ``model`` block (``ResidualModel.to_dict``),
    every number validated; ``order`` the joints base first (the depth statistic's), ``r2``
    and ``rmse`` the fit's per joint. A ``CalibrationError`` for a block that is not one."""
    kind = raw.get("kind")
    if kind not in MODEL_KINDS:
        raise CalibrationError(
            f"unknown model kind {kind!r} (this twincd knows {', '.join(MODEL_KINDS)})",
            where,
            "re-run `twincd fit`",
        )
    coeff = raw["joints"]
    a = finite_array([coeff[n]["a"] for n in names], names, "a", where)
    b = finite_array([coeff[n]["b"] for n in names], names, "b", where)
    extra = {key: _optional_column(coeff, names, key, where) for key in ("c", "d", "epsilon")}
    speed_bins = _speed_bins(raw, where)
    extra["scale"] = _scale(coeff, names, speed_bins, where)
    extra["theta"] = _theta(coeff, names, where)
    _require_coefficients(str(kind), extra, where)
    model = make_model(str(kind), order, SPEED_BINS if speed_bins is None else speed_bins)
    return model.with_coefficients({"a": a, "b": b, **extra}, r2, rmse)
