"""The calibration file's ``model`` block read back (``ResidualModel.to_dict`` writes it), every
number validated: exactly the coefficients its kind's class learns (``ResidualModel.learned``,
found through the registry ``kinds.MODEL_CLASSES``), each a number or a list of numbers per joint
(``scale`` per speed bin and ``theta`` per link checked for their lengths)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from itertools import pairwise
from typing import TYPE_CHECKING, Any

import numpy as np

from twincd.calibration.models.constants import SPEED_BINS, STATISTICS
from twincd.calibration.models.kinds import MODEL_KINDS, make_model, model_class
from twincd.calibration.values import finite_array, finite_number
from twincd.errors import CalibrationError
from twincd.types import FloatArray

if TYPE_CHECKING:
    from twincd.calibration.models.base import ResidualModel

POSITIVE = ("epsilon", "scale")  # coefficients that must be above 0
SCALARS = ("a", "b", "c", "d", "epsilon")  # one number per joint (another kind's may be lists)


def _number_rows(rows: Sequence[Any], names: Sequence[str], key: str, where: str) -> FloatArray:
    """(D, K) from one list of numbers per joint (their lengths checked by the caller), each a
    finite number."""
    return np.array(
        [
            [finite_number(x, f"{key}[{n}]", where) for x in r]
            for r, n in zip(rows, names, strict=True)
        ],
        dtype=np.float64,
    )


def _column(
    coeff: Mapping[str, Any], names: Sequence[str], key: str, where: str
) -> FloatArray | None:
    """A per-joint coefficient, all joints or none: a number per joint (D,), or a list of
    numbers of one length per joint (D, K)."""
    held = [key in coeff[n] for n in names]  # a null value is held, and refused as not a number
    if not any(held):
        return None
    if not all(held):
        raise ValueError(f"coefficient {key!r} is missing for some joints")
    values = [coeff[n][key] for n in names]
    if key in SCALARS or not any(isinstance(v, list) for v in values):
        return finite_array(values, names, key, where)
    if len({len(v) if isinstance(v, list) else -1 for v in values} - {0}) != 1 or not all(
        isinstance(v, list) and v for v in values
    ):
        raise CalibrationError(
            f"calibration field {key} is not a number, or a list of numbers of one length, "
            "for every joint",
            where,
            "re-run `twincd fit`",
        )
    return _number_rows(values, names, key, where)


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
        return _column(coeff, names, "scale", where)
    rows = [coeff[n].get("scale") for n in names]
    bins = len(speed_bins) + 1
    if any(not isinstance(r, list) or len(r) != bins for r in rows):
        raise CalibrationError(
            f"calibration field scale is not a list of {bins} numbers (one per speed bin) for "
            "every joint",
            where,
            "re-run `twincd fit`",
        )
    return _number_rows(rows, names, "scale", where)


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
    return _number_rows(rows, names, "theta", where)


def _learned(
    kind: str,
    coeff: Mapping[str, Any],
    names: Sequence[str],
    speed_bins: tuple[float, ...] | None,
    where: str,
) -> dict[str, FloatArray | None]:
    """Every coefficient ``kind`` learns (``ResidualModel.learned``), read and checked: none
    missing (a plain model has no ``scale``), none the kind does not learn."""
    cls, whitened = model_class(kind)
    stray = sorted({k for n in names for k in coeff[n]} - set(cls.learned))
    if stray:
        raise CalibrationError(
            f"the {kind} model has coefficient(s) {', '.join(stray)}, which it does not learn "
            f"(it learns {', '.join(cls.learned)})",
            where,
            "re-run `twincd fit`",
        )
    read = {"scale": lambda: _scale(coeff, names, speed_bins, where),
            "theta": lambda: _theta(coeff, names, where)}  # fmt: skip
    out = {
        key: read[key]() if key in read else _column(coeff, names, key, where)
        for key in cls.learned
    }
    missing = [k for k, v in out.items() if v is None and (k != "scale" or whitened)]
    if missing:
        raise CalibrationError(
            f"the {kind} model lacks its coefficient(s) {', '.join(missing)}",
            where,
            "re-run `twincd fit`",
        )
    if any(not np.all(v > 0) for k, v in out.items() if k in POSITIVE and v is not None):
        raise CalibrationError(
            f"{' and '.join(POSITIVE)} must be positive", where, "re-run `twincd fit`"
        )
    return out


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
    speed_bins = _speed_bins(raw, where)
    learned = _learned(str(kind), raw["joints"], names, speed_bins, where)
    model = make_model(str(kind), order, SPEED_BINS if speed_bins is None else speed_bins)
    return model.with_coefficients(learned, r2, rmse)
