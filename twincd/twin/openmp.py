"""Pinocchio, loaded the way the twin wants its OpenMP threads to wait.

Pinocchio's batched RNEA runs on OpenMP, whose threads by default spin for a while after each
parallel region, burning the core that reading and filtering need between two twin calls:
passive waiting made detect 15 % faster (benchmarks/bench_long.py). The OpenMP runtime reads
``OMP_WAIT_POLICY`` once, when Pinocchio first loads it, so the twin loads Pinocchio through
``load_pinocchio``, which sets it to ``PASSIVE`` first unless it is set already (a value the
user set is kept). Importing twincd sets nothing.
"""

from __future__ import annotations

import os
from typing import Any


def prefer_passive_wait() -> None:
    """``OMP_WAIT_POLICY=PASSIVE`` for the OpenMP runtime loaded after this (and for child
    processes started after this), unless it is set already."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def load_pinocchio() -> Any:  # the module (untyped: Pinocchio ships no stubs)
    """The ``pinocchio`` module; the first load brings OpenMP in with passive waiting."""
    prefer_passive_wait()
    import pinocchio

    return pinocchio
