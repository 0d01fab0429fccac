"""Occupancy grid access and car drawing (engine_spec.md §1 and §3.3; v2 §1 and §4.3).

The grid is 7 lanes × 70 rows of 20 × 10 px. ``get``/``set`` floor both coordinates and treat
anything outside the grid as absent: ``get`` returns the caller's default, ``set`` does nothing.
A car is drawn by writing one value at the cells under the offsets ox ∈ {0, 10},
oy ∈ {0, 5, …, 30} of its top-left corner, each coordinate computed exactly as
``(x + ox)/20`` and ``(y + oy)/10`` — not ``y/10 + oy/10``, which is not always the same double
(spec §11). Every write of one car carries the same value, so the order inside a car does not
matter: the rows written are exactly the integers from ``⌊y/10⌋`` to ``⌊(y + 30)/10⌋`` (the
seven offsets are monotone and 5 px apart, so they leave no gap), and only those two quotients
are needed.

``row_base`` goes one step further: when ``y/10`` is at least 1e-6 away from an integer, every
row quotient of the car — ``(y + oy)/10`` for drawing, ``(y − 10k)/10`` for the safety check —
is ``⌊y/10⌋`` plus an integer, exactly (rounding errors are ~1e-13), so one multiplication
serves all eleven; near a boundary each quotient is computed in its exact form.

A settled car (``x = 20ℓ + 4`` exactly, the usual case) covers lane ℓ alone and its safety
column is ℓ: ``(x + ox)/20`` is ℓ + 0.2, ℓ + 0.7 or ℓ + 0.575, far from any integer, so those
divisions are skipped.

``floor_div`` computes ``⌊fl(s/d)⌋`` — the floor of the correctly rounded quotient, as JS does —
with a multiplication, and falls back to the real division only within 1e-7 of a boundary, where
the two could differ. The hot loop therefore needs almost no divisions and stays bit-exact.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from sim.layout import N_LANES, N_ROWS


@njit(cache=True, error_model="numpy", inline="always")
def js_min(a: float, b: float) -> float:
    """JS ``Math.min`` for two numbers: NaN if either is NaN (Python's ``min`` is not)."""
    if a != a or b != b:
        return math.nan
    return a if a < b else b


@njit(cache=True, error_model="numpy", inline="always")
def js_max(a: float, b: float) -> float:
    """JS ``Math.max`` for two numbers: NaN if either is NaN."""
    if a != a or b != b:
        return math.nan
    return a if a > b else b


@njit(cache=True, error_model="numpy", inline="always")
def floor_div(s: float, d: float, inv: float) -> float:
    """``⌊fl(s/d)⌋`` exactly, for |s| ≪ 1e8 and d a small integer with ``inv ≈ 1/d``."""
    n = np.floor(s * inv)
    if d * n <= s and s < d * (n + 1.0) - 1e-7:
        return n
    return np.floor(s / d)


@njit(cache=True, error_model="numpy", inline="always")
def row_base(y: float) -> float:
    """``⌊y/10⌋`` if ``y/10`` is safely away from an integer (see module doc), else NaN."""
    q = y * 0.1
    n = np.floor(q)
    f = q - n
    if f > 1e-6 and f < 1.0 - 1e-6:
        return n
    return np.nan


@njit(cache=True, error_model="numpy", inline="always")
def cell(g: np.ndarray, lane: float, row: float, default: float) -> float:
    """Cell at already-floored (lane, row), or ``default`` outside the grid."""
    if lane >= 0.0 and lane < N_LANES and row >= 0.0 and row < N_ROWS:
        return g[int(lane), int(row)]
    return default


@njit(cache=True, error_model="numpy", inline="always")
def grid_get(g: np.ndarray, lane: float, row: float, default: float) -> float:
    """Cell at (⌊lane⌋, ⌊row⌋), or ``default`` outside the grid (NaN coordinates are outside)."""
    fl = math.floor(lane)
    fr = math.floor(row)
    if fl >= 0.0 and fl < N_LANES and fr >= 0.0 and fr < N_ROWS:
        return g[int(fl), int(fr)]
    return default


@njit(cache=True, error_model="numpy", inline="always")
def clear_grid(g: np.ndarray, value: float) -> None:
    """Set every cell (a plain loop: ``reshape(-1)[:]`` calls a runtime helper every frame)."""
    for lane in range(N_LANES):
        for row in range(N_ROWS):
            g[lane, row] = value


@njit(cache=True, error_model="numpy", inline="always")
def draw_car(g: np.ndarray, x: float, y: float, lane: float, value: float) -> None:
    """Write ``value`` into the car's footprint (one lane when settled, two while changing)."""
    base = row_base(y)
    if base == base:
        first = base
        last = base + 3.0
    else:
        first = floor_div(y, 10.0, 0.1)
        last = floor_div(y + 30.0, 10.0, 0.1)
    if not (first < N_ROWS and last >= 0.0):  # off the grid, or NaN
        return
    r0 = int(max(first, 0.0))
    r1 = int(min(last, N_ROWS - 1.0))
    if x == 20.0 * lane + 4.0:  # settled: x/20 = ℓ + 0.2 and (x + 10)/20 = ℓ + 0.7, both floor to ℓ
        l0 = lane
        l1 = lane
    else:
        l0 = floor_div(x, 20.0, 0.05)
        l1 = floor_div(x + 10.0, 20.0, 0.05)
    if l0 >= 0.0 and l0 < N_LANES:
        li = int(l0)
        for r in range(r0, r1 + 1):
            g[li, r] = value
    if l1 != l0 and l1 >= 0.0 and l1 < N_LANES:
        li = int(l1)
        for r in range(r0, r1 + 1):
            g[li, r] = value
