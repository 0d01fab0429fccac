"""Car rules shared by both engines: move, safety system, lane change, speed actions.

* Move (engine_spec.md §3.2, v2 §4.2): ``y := y − (c·a − t)`` with the camera term ``t`` of the
  previous frame, then a lateral slide of 20/30 px per frame towards the target lane, snapping
  when closer than 20/30 px. Respawn checks are left to the caller (their draws differ).
* Safety (v1 §4, v2 §5): ``c`` starts at 2 and, for each occupied row k = 1…4 ahead in the
  lane under the car's centre, is capped at 0.5·(k−1) and at the occupant's drawn value over
  ``a``; NaN propagates as in JS ``Math.min``. ``free`` is 7 (v1) or 100 (v2).
* Lane change (v1 §5, v2 §6): allowed only when settled (|x − (20b+4)| < 0.5) and when the
  target lane is free in the rows ``y/10 + h`` for h = −3a, −3a+1, … < 4, with ``h`` accumulated
  by repeated +1 exactly as the original loop does. Off-road or off-grid cells read 0: blocked.
* Speed actions (v1 §6, v2 §7): accelerate adds 0.02 if a < 2, decelerate subtracts 0.02 if
  a > 0 — the bound is tested before the step, so ``a`` may end at 2.02 − ε or −0.02 + ε.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from sim.grid import cell, floor_div, grid_get, js_min, row_base
from sim.layout import CA, CB, CC, CX, CY, N_LANES, N_ROWS

LATERAL_STEP = 20.0 / 30.0


@njit(cache=True, error_model="numpy", inline="always")
def move(cars: np.ndarray, w: int, i: int, camera: float) -> None:
    """Longitudinal move relative to the camera and one lateral step (no respawn)."""
    y = cars[w, CY, i]
    cars[w, CY, i] = y - (cars[w, CC, i] * cars[w, CA, i] - camera)
    target = 20.0 * cars[w, CB, i] + 4.0
    x = cars[w, CX, i]
    delta = target - x
    if abs(delta) < LATERAL_STEP:
        cars[w, CX, i] = target
    elif delta > 0.0:
        cars[w, CX, i] = x + LATERAL_STEP
    else:
        cars[w, CX, i] = x - LATERAL_STEP


@njit(cache=True, error_model="numpy", inline="always")
def safety_factor(g: np.ndarray, cars: np.ndarray, w: int, i: int, free: float) -> float:
    """The car's new safety factor c from the four rows ahead of its front row."""
    x = cars[w, CX, i]
    y = cars[w, CY, i]
    a = cars[w, CA, i]
    lane = cars[w, CB, i]
    col = lane if x == 20.0 * lane + 4.0 else floor_div(x + 7.5, 20.0, 0.05)  # settled: see sim.grid
    base = row_base(y)
    v = 2.0
    if base >= 4.0 and base <= N_ROWS and col >= 0.0 and col < N_LANES:
        # common case: the four rows ahead are on the grid, read them without bounds checks
        li = int(col)
        top = int(base)
        for k in range(1, 5):
            d = g[li, top - k]
            if d < free:
                v = js_min(v, 0.5 * (k - 1))
                v = js_min(v, d / a)
        return v
    for k in range(1, 5):
        row = base - k if base == base else floor_div(y - 10.0 * k, 10.0, 0.1)
        d = cell(g, col, row, free)
        if d < free:
            v = js_min(v, 0.5 * (k - 1))
            v = js_min(v, d / a)
    return v


@njit(cache=True, error_model="numpy", inline="always")
def try_lane_change(g: np.ndarray, cars: np.ndarray, w: int, i: int, direction: float, free: float) -> bool:
    """Attempt a lane change by ``direction`` (−1 left, +1 right); on success the target lane moves."""
    x = cars[w, CX, i]
    y = cars[w, CY, i]
    b = cars[w, CB, i]
    col = (x + 7.5) / 20.0 + direction
    r0 = y / 10.0
    if not abs(x - (20.0 * b + 4.0)) < 0.5:
        return False
    h = 3.0 * (-cars[w, CA, i])
    while h < 4.0:
        if not grid_get(g, col, r0 + h, 0.0) >= free:
            return False
        h = h + 1.0
    cars[w, CB, i] = b + direction
    return True


@njit(cache=True, error_model="numpy", inline="always")
def apply_action(g: np.ndarray, cars: np.ndarray, w: int, i: int, action: int, free: float) -> bool:
    """Apply one action to car i; returns True when it was a lane change (tried once)."""
    if action == 1:
        if cars[w, CA, i] < 2.0:
            cars[w, CA, i] = cars[w, CA, i] + 0.02
    elif action == 2:
        if cars[w, CA, i] > 0.0:
            cars[w, CA, i] = cars[w, CA, i] - 0.02
    elif action == 3:
        try_lane_change(g, cars, w, i, -1.0, free)
        return True
    elif action == 4:
        try_lane_change(g, cars, w, i, 1.0, free)
        return True
    return False


@njit(cache=True, error_model="numpy", inline="always")
def spawn_lane(cars: np.ndarray, w: int, i: int, q: float) -> None:
    """Lane part of the spawn routine: ``ℓ = ⌊(140·q)/20⌋``, ``x = 20ℓ + 4``, ``b = ℓ``."""
    lane = math.floor((140.0 * q) / 20.0)
    cars[w, CX, i] = 20.0 * lane + 4.0
    cars[w, CB, i] = lane
