"""Helpers for the chunked = whole tests of streaming signal stages."""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np


def chunked(stage: Any, stamps: np.ndarray, values: np.ndarray, cuts: list[int]) -> np.ndarray:
    """Push in pieces split at ``cuts``, then finish; every output is C-ordered (a layout that
    followed the chunking would change reductions downstream)."""
    edges = [0, *sorted(c for c in set(cuts) if 0 < c < len(stamps)), len(stamps)]
    out = [stage.push(stamps[a:b], values[a:b]) for a, b in itertools.pairwise(edges)]
    out.append(stage.finish())
    assert all(o.flags.c_contiguous and o.shape[1:] == values.shape[1:] for o in out)
    return np.concatenate(out)


def split_points(n: int, how: str | int, rng: np.random.Generator) -> list[int]:
    """Where to cut ``n`` samples: nowhere, at random places, or every ``how`` samples."""
    if how == "whole":
        return []
    if how == "random":
        return sorted(rng.choice(np.arange(1, max(n, 2)), size=min(n - 1, 6), replace=False))
    return list(range(int(how), n, int(how)))
