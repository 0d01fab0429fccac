"""Occupancy grid access and car drawing (engine_spec.md §1 and §3.3; v2 §1 and §4.3).

The grid is 7 lanes × 70 rows of 20 × 10 px. ``get``/``set`` floor both coordinates and treat
anything outside the grid as absent: ``get`` returns the caller's default, ``set`` does nothing.
A car is drawn by writing one value at the cells under the offsets ox ∈ {0, 10},
oy ∈ {0, 5, …, 30} of its top-left corner, each coordinate computed exactly as
``(x + ox)/20`` and ``(y + oy)/10`` — not ``y/10 + oy/10``, which is not always the same double
(spec §11). Every write of one car carries the same value, so the order inside a car does not
matter and each row index is computed once and reused for both lanes.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from sim.layout import N_LANES, N_ROWS


@njit(cache=True, inline="always")
def js_min(a: float, b: float) -> float:
    """JS ``Math.min`` for two numbers: NaN if either is NaN (Python's ``min`` is not)."""
    if a != a or b != b:
        return math.nan
    return a if a < b else b


@njit(cache=True, inline="always")
def js_max(a: float, b: float) -> float:
    """JS ``Math.max`` for two numbers: NaN if either is NaN."""
    if a != a or b != b:
        return math.nan
    return a if a > b else b


@njit(cache=True, inline="always")
def grid_get(g: np.ndarray, lane: float, row: float, default: float) -> float:
    """Cell at (⌊lane⌋, ⌊row⌋), or ``default`` outside the grid (NaN coordinates are outside)."""
    fl = math.floor(lane)
    fr = math.floor(row)
    if fl >= 0.0 and fl < N_LANES and fr >= 0.0 and fr < N_ROWS:
        return g[int(fl), int(fr)]
    return default


@njit(cache=True, inline="always")
def draw_car(g: np.ndarray, x: float, y: float, value: float) -> None:
    """Write ``value`` into the car's footprint (one lane when settled, two while changing)."""
    l0 = math.floor(x / 20.0)
    l1 = math.floor((x + 10.0) / 20.0)
    for k in range(7):
        r = math.floor((y + 5.0 * k) / 10.0)
        if r >= 0.0 and r < N_ROWS:
            ri = int(r)
            if l0 >= 0.0 and l0 < N_LANES:
                g[int(l0), ri] = value
            if l1 != l0 and l1 >= 0.0 and l1 < N_LANES:
                g[int(l1), ri] = value
