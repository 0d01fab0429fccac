"""deepqlearn's decision rules, one home for every fast path (torch learner, exact brain policy, forward).

* ε (``js_epsilon``): ``min(1, max(ε_min, 1 − (age − burnin)/(total − burnin)))`` in JS arithmetic;
* the greedy choice (``argmax_js`` compiled, ``js_argmax_rows`` numpy): a scan from action 0 with
  strict ``>`` — ties go to the lowest index, NaN never wins (spec §10.3).

The float64 replica (``autotune.learner.js_learner``) keeps its own copies on purpose: it is the
reference the fast paths are tested against.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from sim.grid import js_max, js_min

__all__ = ["argmax_js", "js_argmax_rows", "js_epsilon"]


def js_epsilon(age: int, burnin: int, total: int, epsilon_min: float) -> float:
    """``min(1, max(ε_min, 1 − (age − burnin)/(total − burnin)))`` with JS arithmetic (x/0 = ±∞, 0/0 = NaN)."""
    num = float(age - burnin)
    den = float(total - burnin)
    if den == 0.0:
        frac = math.nan if num == 0.0 else math.copysign(math.inf, num)
    else:
        frac = num / den
    return js_min(1.0, js_max(epsilon_min, 1.0 - frac))


def js_argmax_rows(q: np.ndarray) -> np.ndarray:
    """deepqlearn's greedy scan per row: strict ``>`` from index 0 (ties → lowest; NaN never wins, NaN Q₀ → 0)."""
    actions = q.argmax(axis=1)
    bad = ~np.isfinite(q).all(axis=1)
    for r in np.flatnonzero(bad):
        best, val = 0, q[r, 0]
        for k in range(1, q.shape[1]):
            if q[r, k] > val:
                best, val = k, q[r, k]
        actions[r] = best
    return actions


@njit(cache=True, error_model="numpy", inline="always")
def argmax_js(buf: np.ndarray, k: int, n: int) -> int:
    """deepqlearn's greedy choice: scan 0…n−1 with strict ``>`` (ties → lowest; NaN never wins)."""
    best = 0
    val = buf[k, 0]
    for j in range(1, n):
        if buf[k, j] > val:
            best = j
            val = buf[k, j]
    return best
