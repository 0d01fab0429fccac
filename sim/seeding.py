"""How worlds are seeded before their first ``reset()`` (engine_spec.md §9, §12–§13; v2 §2, §11–§12).

Each function prepares the generators of one world exactly as a reference protocol does, then
performs the first ``reset()``:

* ``seed_v1(state)`` — ``Math.random := mulberry32(state)``; the v1 engine draws everything from it.
* ``seed_v2_official`` — ``Math.random := mulberry32(state)`` before a fresh engine load (20
  ``Math.random`` and 40 traffic draws), then evaluation mode (run counter 0): run k uses
  Park–Miller seed k + 1 and the first run's cars come from the load-time traffic generator.
  ``seed_v2_evaluation(state, r0)`` is the same with the run counter starting at ``r0`` (run k uses seed
  ``r0 + k + 1``): the ``v2-heldout`` protocol, the official harness on runs it never plays.
* ``seed_v2_independent(seed)`` — one independent v2 world per seed, for the ``custom`` protocol:
  ``Math.random := mulberry32(seed)``, and the run uses Park–Miller seed ``seed`` with the
  pre-reset traffic generator at PM(seed) (as if a previous run had consumed none of it).
* ``seed_v2_training(state)`` — training mode (§12): the brain and its copies take seeds from
  ``Math.random`` first (``brain_draws`` of them), then ``r := ⌊10⁷·M⌋`` and ``t := ⌊10⁷·M⌋``, so
  run k uses seed ``r + k + 1``; the engine is loaded fresh before.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from sim.engine import reset
from sim.engine_v2 import load_v2
from sim.layout import I_PM_V, I_RUN_COUNTER
from sim.rng import mrand, pm_seed_state


@njit(cache=True, error_model="numpy")
def seed_v1(
    cars: np.ndarray, fs: np.ndarray, ints: np.ndarray, mr: np.ndarray, cfg: np.ndarray, w: int, state: int
) -> None:
    mr[w] = state & 0xFFFFFFFF
    reset(cars, fs, ints, mr, cfg, w)


@njit(cache=True, error_model="numpy")
def seed_v2_official(
    cars: np.ndarray, fs: np.ndarray, ints: np.ndarray, mr: np.ndarray, cfg: np.ndarray, w: int, state: int
) -> None:
    seed_v2_evaluation(cars, fs, ints, mr, cfg, w, state, 0)


@njit(cache=True, error_model="numpy")
def seed_v2_evaluation(
    cars: np.ndarray, fs: np.ndarray, ints: np.ndarray, mr: np.ndarray, cfg: np.ndarray, w: int, state: int, r0: int
) -> None:
    """The evaluation worker's seeding with the run counter (``r``, engine_spec_v2 §2) starting at ``r0``: run k
    uses Park–Miller seed ``r0 + k + 1`` (0: ``seed_v2_official``)."""
    mr[w] = state & 0xFFFFFFFF
    load_v2(cars, ints, mr, w)
    ints[w, I_RUN_COUNTER] = r0
    reset(cars, fs, ints, mr, cfg, w)


@njit(cache=True, error_model="numpy")
def seed_v2_independent(
    cars: np.ndarray, fs: np.ndarray, ints: np.ndarray, mr: np.ndarray, cfg: np.ndarray, w: int, seed: int
) -> None:
    mr[w] = seed & 0xFFFFFFFF
    ints[w, I_PM_V] = pm_seed_state(seed)
    ints[w, I_RUN_COUNTER] = seed - 1
    reset(cars, fs, ints, mr, cfg, w)


@njit(cache=True, error_model="numpy")
def seed_v2_training(
    cars: np.ndarray,
    fs: np.ndarray,
    ints: np.ndarray,
    mr: np.ndarray,
    cfg: np.ndarray,
    w: int,
    state: int,
    brain_draws: int,
) -> None:
    mr[w] = state & 0xFFFFFFFF
    load_v2(cars, ints, mr, w)
    for _ in range(brain_draws):
        mrand(mr, w)
    r = int(math.floor(10000000.0 * mrand(mr, w)))
    mrand(mr, w)  # t := ⌊10⁷·M⌋, never used again
    ints[w, I_RUN_COUNTER] = r
    reset(cars, fs, ints, mr, cfg, w)
