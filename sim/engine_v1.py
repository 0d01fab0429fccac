"""The 2017 single-car engine, v1 (engine_spec.md §2–§9), one frame split at the decision.

A frame (spec §3) is: clear the grid to 7; move and draw every car (respawning with 2 draws);
camera ``t := 1.5 − (y₀ − 525)``; for every car the safety factor and, for white cars, a random
lane-change test (one draw, a second one when it passes); redraw the ego with value ``10·c·a``;
``I += c₀·a₀``; every 30th frame the ego decides; the action ``m`` in force is applied; ``F += 1``.
``frame_pre`` runs everything up to the decision and ``frame_post`` the rest, so the same code
serves a policy called from Python between the two halves and one compiled into the loop.

Quirks reproduced on purpose, because the 2017 leaderboard scores were made with them:

* **Persistent action** (§6): ``m`` is applied on every frame until the next decision, so
  accelerate/decelerate change ``a`` by up to 0.6 per decision; a lane change is tried once and
  then ``m := 0``.
* **Ego ×10 redraw** (§3 step 5, §7): the ego's cells hold ``10·c·a``, visible to a learner that
  looks behind (patches_behind ≥ 1) and to the ego's own lane-change test.
* **Frame-0 quirk** (§3.2): the ego starts at a random y; frame 1 shifts the world by the huge
  first camera term and usually respawns several cars.
* **Reset coupling** (§2, §9): all randomness — traffic and policy — comes from the one
  ``Math.random`` stream, and ``reset()`` draws exactly 60 numbers, so consecutive runs of
  ``evaluate.js`` are one stream.
* **Bogus first reward** (§8): at frame 0 of a run ``I`` holds a single frame.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from sim.grid import clear_grid, draw_car, grid_get
from sim.layout import (
    CA,
    CB,
    CC,
    CX,
    CY,
    F_CAMERA,
    F_EGO_SUM,
    F_LAST_REWARD,
    F_REWARD_ACC,
    F_SCORE_SUM,
    I_ACTION,
    I_DECIDER,
    I_FRAME,
    K_AHEAD,
    K_BEHIND,
    K_LANES_SIDE,
    N_CARS,
)
from sim.rng import mrand
from sim.rules import apply_action, move, safety_factor, spawn_lane, try_lane_change

FREE = 7.0
DECISION_PERIOD = 30


@njit(cache=True, error_model="numpy", inline="always")
def _spawn(cars: np.ndarray, mr: np.ndarray, w: int, i: int) -> None:
    """Spawn routine (§2): lane then speed ``a = 1 + 0.7·u`` (2 draws)."""
    spawn_lane(cars, w, i, mrand(mr, w))
    cars[w, CA, i] = 1.0 + 0.7 * mrand(mr, w)


@njit(cache=True, error_model="numpy")
def reset_v1(cars: np.ndarray, fs: np.ndarray, ints: np.ndarray, mr: np.ndarray, w: int) -> None:
    """``reset()`` (§2): 20 random cars (60 draws), frame 0, camera 1.5, I = 0; ``m`` is kept."""
    for i in range(N_CARS):
        cars[w, CX, i] = 0.0
        cars[w, CY, i] = 0.0
        cars[w, CA, i] = 1.0
        cars[w, CC, i] = 1.0
        cars[w, CB, i] = 0.0
        _spawn(cars, mr, w, i)
        cars[w, CY, i] = 10.0 * math.floor((700.0 * mrand(mr, w)) / 10.0)
    ints[w, I_FRAME] = 0
    ints[w, I_DECIDER] = -1
    fs[w, F_CAMERA] = 1.5
    fs[w, F_REWARD_ACC] = 0.0
    fs[w, F_SCORE_SUM] = 0.0
    fs[w, F_EGO_SUM] = 0.0


@njit(cache=True, error_model="numpy")
def frame_pre_v1(cars: np.ndarray, grid: np.ndarray, fs: np.ndarray, ints: np.ndarray, mr: np.ndarray, w: int) -> int:
    """Steps 1–7 of a frame; returns 0 when the ego must decide now, else −1."""
    g = grid[w]
    clear_grid(g, FREE)
    camera = fs[w, F_CAMERA]
    for i in range(N_CARS):
        move(cars, w, i, camera)
        if cars[w, CY, i] + 68.0 < 0.0:
            cars[w, CY, i] = 734.0
            _spawn(cars, mr, w, i)
        if cars[w, CY, i] - 68.0 > 700.0:
            cars[w, CY, i] = -34.0
            _spawn(cars, mr, w, i)
        draw_car(g, cars[w, CX, i], cars[w, CY, i], cars[w, CB, i], cars[w, CC, i] * cars[w, CA, i])
    fs[w, F_CAMERA] = 1.5 - (cars[w, CY, 0] - 525.0)
    for i in range(N_CARS):
        c = safety_factor(g, cars, w, i, FREE)
        cars[w, CC, i] = c
        if i != 0:
            if mrand(mr, w) > 0.99 + 0.004 * c:
                direction = -1.0 if 0.5 < mrand(mr, w) else 1.0
                try_lane_change(g, cars, w, i, direction, FREE)
    c0a0 = cars[w, CC, 0] * cars[w, CA, 0]
    draw_car(g, cars[w, CX, 0], cars[w, CY, 0], cars[w, CB, 0], (10.0 * cars[w, CC, 0]) * cars[w, CA, 0])
    fs[w, F_REWARD_ACC] = fs[w, F_REWARD_ACC] + c0a0
    if ints[w, I_FRAME] % DECISION_PERIOD == 0:
        fs[w, F_LAST_REWARD] = (fs[w, F_REWARD_ACC] - 60.0) / 20.0
        ints[w, I_DECIDER] = 0
        return 0
    ints[w, I_DECIDER] = -1
    return -1


@njit(cache=True, error_model="numpy")
def frame_post_v1(cars: np.ndarray, grid: np.ndarray, fs: np.ndarray, ints: np.ndarray, w: int, action: int) -> None:
    """Steps 8 (end) – 10: take the decision, apply ``m``, advance the frame, add to ``G``."""
    if ints[w, I_DECIDER] == 0:
        ints[w, I_ACTION] = action if 0 <= action < 5 else 0
        fs[w, F_REWARD_ACC] = 0.0
        ints[w, I_DECIDER] = -1
    m = ints[w, I_ACTION]
    if m != 0:
        if apply_action(grid[w], cars, w, 0, m, FREE):
            ints[w, I_ACTION] = 0
    ints[w, I_FRAME] += 1
    c0a0 = cars[w, CC, 0] * cars[w, CA, 0]
    fs[w, F_SCORE_SUM] = fs[w, F_SCORE_SUM] + c0a0
    fs[w, F_EGO_SUM] = fs[w, F_EGO_SUM] + c0a0


@njit(cache=True, error_model="numpy")
def observe_v1(cars: np.ndarray, grid: np.ndarray, cfg: np.ndarray, w: int, out: np.ndarray) -> None:
    """Ego input vector (§7): fixed rows ⌊52.5 + u⌋ around the ego's target lane, ÷ 7, column-major."""
    g = grid[w]
    lanes_side = cfg[K_LANES_SIDE]
    ahead = cfg[K_AHEAD]
    behind = cfg[K_BEHIND]
    width = 2 * lanes_side + 1
    p = cars[w, CB, 0]
    for u in range(-ahead, behind):
        row = 52.5 + u
        base = width * (u + ahead)
        for k in range(-lanes_side, lanes_side + 1):
            out[base + k + lanes_side] = grid_get(g, p + k, row, 0.0) / FREE
