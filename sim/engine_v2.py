"""The 2018 multi-agent site engine, v2 (engine_spec_v2.md §2–§11), one frame split at the decision.

A frame (spec §4): clear the grid to 100; move and draw every car with value ``c·a``; camera
``E := 1.5 − (y₀ − 525)``; safety for every car and, for white cars (index > n), a random
lane-change test drawn from the Park–Miller traffic generator ``v``; agent i decides on frames
with ``G mod 30 = 3i``; redraw the ego; ``N += c₀·a₀``; the ego decides on ``G mod 30 = 0``; the
frame's action is applied to the ego; ``G += 1``. ``frame_pre`` stops where a car decides and
``frame_post`` finishes the frame with that car's action.

Quirks reproduced on purpose, because they define what the 2018 leaderboard scores meant:

* **Shared-action bug** (§7): one action variable per frame — when agent i decides, agents
  i…n and the ego all apply its action (each in its own lane and position).
* **Agent 10 never decides** (§7): 3·10 ≡ 0 (mod 30) is the ego's residue.
* **Once-per-decision actions** (§7): accelerate/decelerate act once (±0.02), unlike v1.
* **White-car speed switch bug** (§3.5): every white car gets ``a = 1 + 0.7·(0.5·q)``.
* **Run coupling through reset()** (§3.3): a run's cars are constructed with the previous
  run's traffic generator before it is re-seeded, so white-car starting speeds depend on how
  much traffic randomness the previous run consumed; the construction also draws 20
  ``Math.random`` values for y positions that the placement overwrites.
* **Placement "remove last" bug** (§3.4): removing a cell that is not in the legal list deletes
  the list's last element instead; ``y = ⌊(ρ/70)·700⌋`` is 10ρ − 1 for seven rows.
* **Controlled respawn** (§3.6): a respawning agent or ego keeps its speed setting (1 draw).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from sim.grid import clear_grid, draw_car, grid_get, js_max
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
    I_DECIDER,
    I_FRAME,
    I_PM_U,
    I_PM_V,
    I_RUN_COUNTER,
    K_AGENTS,
    K_AHEAD,
    K_BEHIND,
    K_LANES_SIDE,
    N_CARS,
    N_LANES,
    N_ROWS,
)
from sim.rng import mrand, pm_draw, pm_draw_exceeds, pm_seed_state
from sim.rules import apply_action, move, safety_factor, spawn_lane, try_lane_change

FREE = 100.0
DECISION_PERIOD = 30
AGENT_PHASE = 3
N_CELLS = N_LANES * N_ROWS
EGO_ZONE_ROW = 56  # ⌊525/10 + 4⌋


@njit(cache=True, error_model="numpy", inline="always")
def _spawn(cars: np.ndarray, ints: np.ndarray, w: int, i: int, controlled: bool) -> None:
    """Spawn routine (§3.6): lane from ``v``; a white car also gets a new speed from ``v``."""
    spawn_lane(cars, w, i, pm_draw(ints, w, I_PM_V))
    if not controlled:
        cars[w, CA, i] = 1.0 + 0.7 * (0.5 * pm_draw(ints, w, I_PM_V))


@njit(cache=True, error_model="numpy", inline="always")
def _construct(cars: np.ndarray, ints: np.ndarray, mr: np.ndarray, w: int, i: int) -> None:
    """Car constructor (§3.2): 2 ``v`` draws (flag still unset) and 1 ``Math.random`` for y."""
    cars[w, CX, i] = 0.0
    cars[w, CY, i] = 0.0
    cars[w, CA, i] = 1.0
    cars[w, CC, i] = 1.0
    cars[w, CB, i] = 0.0
    _spawn(cars, ints, w, i, False)
    cars[w, CY, i] = 10.0 * math.floor(700.0 * mrand(mr, w) / 10.0)


@njit(cache=True, error_model="numpy", inline="always")
def _js_remove(legal: np.ndarray, size: int, value: int) -> int:
    """Remove ``value`` from the sorted list ``legal[:size]``; if absent remove the last element."""
    lo = 0
    hi = size
    while lo < hi:
        mid = (lo + hi) >> 1
        if legal[mid] < value:
            lo = mid + 1
        else:
            hi = mid
    if lo < size and legal[lo] == value:
        for j in range(lo, size - 1):
            legal[j] = legal[j + 1]
    return size - 1


@njit(cache=True, error_model="numpy", inline="always")
def _remove_zone(legal: np.ndarray, size: int, lane: int, row: int) -> int:
    """Remove the 16-slot exclusion zone rows ρ−4 … ρ+11 of a lane (empty slots remove the last)."""
    for j in range(16):
        r = row - 4 + j
        value = 7 * r + lane if r >= 0 else -1
        size = _js_remove(legal, size, value)
    return size


@njit(cache=True, error_model="numpy")
def initialize_map(cars: np.ndarray, ints: np.ndarray, w: int, n_agents: int) -> None:
    """Initial placement ``initializeMap(u)`` (§3.4): 19 draws of ``u``, non-overlapping cells."""
    legal = np.arange(N_CELLS)
    size = N_CELLS
    cars[w, CY, 0] = 525.0
    cars[w, CX, 0] = 64.0
    cars[w, CB, 0] = 3.0
    cars[w, CA, 0] = 2.0
    size = _remove_zone(legal, size, 3, EGO_ZONE_ROW)
    for gi in range(1, N_CARS):
        k = int(math.floor(size * pm_draw(ints, w, I_PM_U)))
        cell = legal[k]
        row = cell // 7
        lane = cell % 7
        size = _remove_zone(legal, size, lane, row)
        cars[w, CX, gi] = math.floor(20.0 * lane + 4.0)
        cars[w, CY, gi] = math.floor((row / 70.0) * 700.0)
        cars[w, CB, gi] = lane
        if gi <= n_agents:
            cars[w, CA, gi] = 1.7
    cars[w, CA, 0] = 2.0


@njit(cache=True, error_model="numpy")
def reset_v2(cars: np.ndarray, fs: np.ndarray, ints: np.ndarray, mr: np.ndarray, cfg: np.ndarray, w: int) -> None:
    """``reset()`` (§3.3): construct with the OLD ``v``, bump the run counter, re-seed, place."""
    for i in range(N_CARS):
        _construct(cars, ints, mr, w, i)
    r = ints[w, I_RUN_COUNTER] + 1
    ints[w, I_RUN_COUNTER] = r
    ints[w, I_PM_U] = pm_seed_state(r)
    ints[w, I_PM_V] = pm_seed_state(r)
    initialize_map(cars, ints, w, cfg[K_AGENTS])
    ints[w, I_FRAME] = 0
    ints[w, I_DECIDER] = -1
    fs[w, F_CAMERA] = 1.5
    fs[w, F_REWARD_ACC] = 0.0
    fs[w, F_SCORE_SUM] = 0.0
    fs[w, F_EGO_SUM] = 0.0


@njit(cache=True, error_model="numpy")
def load_v2(cars: np.ndarray, ints: np.ndarray, mr: np.ndarray, w: int) -> None:
    """Engine load (§2, §11): run counter 1, ``u = v = PM(1)``, 20 cars constructed, a placement.

    Only its draws matter (20 ``Math.random``, 40 of ``v``): the first reset re-places everything.
    """
    ints[w, I_RUN_COUNTER] = 1
    ints[w, I_PM_U] = pm_seed_state(1)
    ints[w, I_PM_V] = pm_seed_state(1)
    for i in range(N_CARS):
        _construct(cars, ints, mr, w, i)
    initialize_map(cars, ints, w, 0)


@njit(cache=True, error_model="numpy", inline="always")
def _agent_deciding(frame: int, n_agents: int) -> int:
    """Index of the agent deciding on this frame (``G mod 30 = 3i``, i ≤ min(n, 9)), else 0."""
    phase = frame % DECISION_PERIOD
    if phase == 0 or phase % AGENT_PHASE != 0:
        return 0
    i = phase // AGENT_PHASE
    return i if i <= n_agents else 0


@njit(cache=True, error_model="numpy", inline="always")
def _ego_redraw_and_reward(cars: np.ndarray, g: np.ndarray, fs: np.ndarray, w: int) -> None:
    """Steps 7 and 9: redraw the ego with its new ``c`` and accumulate the reward."""
    c0a0 = cars[w, CC, 0] * cars[w, CA, 0]
    draw_car(g, cars[w, CX, 0], cars[w, CY, 0], cars[w, CB, 0], c0a0)
    fs[w, F_REWARD_ACC] = fs[w, F_REWARD_ACC] + c0a0


@njit(cache=True, error_model="numpy")
def frame_pre_v2(cars: np.ndarray, grid: np.ndarray, fs: np.ndarray, ints: np.ndarray, cfg: np.ndarray, w: int) -> int:
    """Steps 2–5 (and 7–9 unless an agent decides); returns the deciding car or −1."""
    n = cfg[K_AGENTS]
    g = grid[w]
    clear_grid(g, FREE)
    camera = fs[w, F_CAMERA]
    for i in range(N_CARS):
        move(cars, w, i, camera)
        if cars[w, CY, i] + 68.0 < 0.0:
            cars[w, CY, i] = 734.0
            _spawn(cars, ints, w, i, i <= n)
        if cars[w, CY, i] - 68.0 > 700.0:
            cars[w, CY, i] = -34.0
            _spawn(cars, ints, w, i, i <= n)
        draw_car(g, cars[w, CX, i], cars[w, CY, i], cars[w, CB, i], cars[w, CC, i] * cars[w, CA, i])
    fs[w, F_CAMERA] = 1.5 - (cars[w, CY, 0] - 525.0)
    for i in range(N_CARS):
        c = safety_factor(g, cars, w, i, FREE)
        cars[w, CC, i] = c
        if i > n:
            if pm_draw_exceeds(ints, w, I_PM_V, 0.99 + 0.004 * c):
                direction = -1.0 if pm_draw_exceeds(ints, w, I_PM_V, 0.5) else 1.0
                try_lane_change(g, cars, w, i, direction, FREE)
    agent = _agent_deciding(ints[w, I_FRAME], n)
    if agent > 0:
        ints[w, I_DECIDER] = agent
        return agent
    _ego_redraw_and_reward(cars, g, fs, w)
    if ints[w, I_FRAME] % DECISION_PERIOD == 0:
        fs[w, F_LAST_REWARD] = (fs[w, F_REWARD_ACC] - 60.0) / 20.0
        ints[w, I_DECIDER] = 0
        return 0
    ints[w, I_DECIDER] = -1
    return -1


@njit(cache=True, error_model="numpy")
def frame_post_v2(
    cars: np.ndarray, grid: np.ndarray, fs: np.ndarray, ints: np.ndarray, cfg: np.ndarray, w: int, action: int
) -> None:
    """The rest of the frame with the decided action (shared-action bug), then the score term."""
    n = cfg[K_AGENTS]
    g = grid[w]
    decider = ints[w, I_DECIDER]
    if decider >= 0:
        d = action if 0 <= action < 5 else 0
        if decider > 0:
            for j in range(decider, n + 1):
                apply_action(g, cars, w, j, d, FREE)
            _ego_redraw_and_reward(cars, g, fs, w)
        else:
            fs[w, F_REWARD_ACC] = 0.0
        apply_action(g, cars, w, 0, d, FREE)
        ints[w, I_DECIDER] = -1
    ints[w, I_FRAME] += 1
    share = n + 1
    total = fs[w, F_SCORE_SUM]
    for b in range(n + 1):
        total = total + js_max(0.0, cars[w, CC, b] * cars[w, CA, b]) / share
    fs[w, F_SCORE_SUM] = total
    fs[w, F_EGO_SUM] = fs[w, F_EGO_SUM] + js_max(0.0, cars[w, CC, 0] * cars[w, CA, 0])


@njit(cache=True, error_model="numpy")
def observe_v2(cars: np.ndarray, grid: np.ndarray, cfg: np.ndarray, w: int, car: int, out: np.ndarray) -> None:
    """Input vector of a car (§9): rows ⌊⌊y⌋/10 + h⌋ relative to its own front row, ÷ 100."""
    g = grid[w]
    lanes_side = cfg[K_LANES_SIDE]
    ahead = cfg[K_AHEAD]
    behind = cfg[K_BEHIND]
    width = 2 * lanes_side + 1
    lane = cars[w, CB, car]
    top = math.floor(cars[w, CY, car]) / 10.0
    for h in range(-ahead, behind):
        row = top + h
        base = width * (h + ahead)
        for k in range(-lanes_side, lanes_side + 1):
            out[base + k + lanes_side] = grid_get(g, lane + k, row, 0.0) / FREE
