"""Seeded generators of the original engines (engine_spec.md §12, engine_spec_v2.md §2).

* ``mulberry32`` stands in for JS ``Math.random`` in every reference run: the v1 engine, the
  ``random`` policy and the convnetjs learner all draw from this one stream.
* Park–Miller (``x ← 16807·x mod (2³¹−1)``) drives v2 traffic: the placement generator ``u``
  and the traffic generator ``v``.

States are plain int64 values kept in the simulator's arrays; every function here is a pure
``state → (state, draw)`` step or an in-place step on one array cell, so randomness only ever
enters through explicit seeds.
"""

from __future__ import annotations

import numpy as np
from numba import njit

PM_MODULUS = 2147483647
PM_MULTIPLIER = 16807
_MASK32 = 0xFFFFFFFF


@njit(cache=True, error_model="numpy", inline="always")
def _imul(a: int, b: int) -> int:
    """Low 32 bits of a·b for 32-bit operands (JS ``Math.imul``).

    The int64 product may wrap, but wrapping keeps the low 32 bits, which is all we keep.
    """
    return (a * b) & _MASK32


@njit(cache=True, error_model="numpy", inline="always")
def mulberry32_next(state: int) -> tuple[int, float]:
    """One ``Math.random()`` call: returns the new state and the draw in [0, 1)."""
    s = (state + 0x6D2B79F5) & _MASK32
    t = _imul(s ^ (s >> 15), s | 1)
    t = (t ^ ((t + _imul(t ^ (t >> 7), t | 61)) & _MASK32)) & _MASK32
    return s, ((t ^ (t >> 14)) & _MASK32) / 4294967296.0


@njit(cache=True, error_model="numpy", inline="always")
def mrand(states: np.ndarray, w: int) -> float:
    """Draw from world ``w``'s Math.random stream, advancing it in place."""
    s, u = mulberry32_next(states[w])
    states[w] = s
    return u


@njit(cache=True, error_model="numpy", inline="always")
def pm_seed_state(seed: int) -> int:
    """Park–Miller state for a seed: ``s mod (2³¹−1)``, non-positive values fixed up by +2³¹−2."""
    g = seed % PM_MODULUS
    if g <= 0:
        g += PM_MODULUS - 1
    return g


@njit(cache=True, error_model="numpy", inline="always")
def pm_next(state: int) -> int:
    """Park–Miller ``next()``: the new state (1 … 2³¹−2), exact in int64."""
    return (PM_MULTIPLIER * state) % PM_MODULUS


@njit(cache=True, error_model="numpy", inline="always")
def pm_draw(ints: np.ndarray, w: int, col: int) -> float:
    """Draw ``(next() − 1)/2147483646`` from the Park–Miller state stored at ``ints[w, col]``."""
    g = (PM_MULTIPLIER * ints[w, col]) % PM_MODULUS
    ints[w, col] = g
    return (g - 1) / 2147483646.0


@njit(cache=True, error_model="numpy", inline="always")
def pm_draw_exceeds(ints: np.ndarray, w: int, col: int, threshold: float) -> bool:
    """``draw > threshold`` for a Park–Miller draw, exact, dividing only near the threshold."""
    g = (PM_MULTIPLIER * ints[w, col]) % PM_MODULUS
    ints[w, col] = g
    approx = (g - 1) * (1.0 / 2147483646.0)
    if abs(approx - threshold) > 1e-9:
        return approx > threshold
    return (g - 1) / 2147483646.0 > threshold


def mulberry32_stream(seed: int, n: int) -> list[float]:
    """The first ``n`` draws of ``mulberry32(seed)`` (reference helper for tests and tools)."""
    s = seed & _MASK32
    out = []
    for _ in range(n):
        s, u = mulberry32_next(s)
        out.append(u)
    return out


def mulberry32_advance(seed_or_state: int, n: int) -> int:
    """State of a mulberry32 stream after ``n`` draws."""
    s = seed_or_state & _MASK32
    for _ in range(n):
        s, _u = mulberry32_next(s)
    return s
