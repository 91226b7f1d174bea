"""Optional test dependencies: skipped where they are missing, except in CI, which installs
every extra the tests use (``.ci/run``): there a missing one fails the run instead of silently
skipping the tests that need it."""

from __future__ import annotations

import importlib
import os
from types import ModuleType

import pytest


def in_ci() -> bool:
    return os.environ.get("CI", "").lower() == "true"


def need(module: str) -> ModuleType:
    """``module`` imported; missing: the calling test module is skipped, or fails under
    ``CI=true``."""
    if in_ci():
        return importlib.import_module(module)
    return pytest.importorskip(module)
