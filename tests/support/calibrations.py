"""Helpers for tests of calibration files."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator
from typing import Any

import pytest

from twincd.calibration import Calibration
from twincd.errors import CalibrationError


@contextlib.contextmanager
def refused(doc: dict[str, Any], match: str | None = None) -> Iterator[dict[str, Any]]:
    """A copy of the calibration document ``doc`` to break in the block; loading it
    (``Calibration.from_dict``) must then fail with a ``CalibrationError`` matching ``match``."""
    broken: dict[str, Any] = json.loads(json.dumps(doc))
    yield broken
    with pytest.raises(CalibrationError, match=match):
        Calibration.from_dict(broken)
