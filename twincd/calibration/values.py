"""The calibration file's numbers, each validated on load (docs/contract.md): JSON numbers only,
finite, one per joint where a coefficient is per joint; anything else is a clear
``CalibrationError`` naming the field."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from twincd.errors import CalibrationError
from twincd.types import FloatArray


def finite_number(value: Any, name: str, where: str, *, positive: bool = False) -> float:
    """``value`` as a float, or a ``CalibrationError``: JSON numbers only (no strings, no
    booleans), finite, and above 0 when ``positive`` (every number of the calibration file is
    validated: docs/contract.md)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CalibrationError(
            f"calibration field {name} is {type(value).__name__} {value!r}, not a number",
            where,
            "re-run `twincd fit` to write a new one",
        )
    number = float(value)
    if not math.isfinite(number) or (positive and number <= 0):
        need = "a positive finite number" if positive else "a finite number"
        raise CalibrationError(
            f"calibration field {name} is {value!r}, not {need}",
            where,
            "re-run `twincd fit` to write a new one",
        )
    return number


def finite_array(values: Sequence[Any], names: Sequence[str], field: str, where: str) -> FloatArray:
    """One finite float per joint of ``names`` (a per-joint coefficient of any model kind), or a
    ``CalibrationError`` naming the joint and the field at fault."""
    if isinstance(values, (str, bytes)) or not isinstance(values, Sequence):
        raise CalibrationError(
            f"calibration field {field} is not a list of numbers", where, "re-run `twincd fit`"
        )
    if len(values) != len(names):
        raise CalibrationError(
            f"calibration field {field} has {len(values)} value(s) for {len(names)} joint(s)",
            where,
            "re-run `twincd fit` to write a new one",
        )
    return np.array(
        [finite_number(v, f"{field}[{n}]", where) for v, n in zip(values, names, strict=True)],
        dtype=np.float64,
    )
