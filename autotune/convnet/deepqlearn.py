"""deepqlearn's decision rules, one home for every fast path (torch learner, training agents, quick
evaluation, exact brain policy, forward) — spec §10.2, §10.3, v2 §13.

* **ε** (``js_epsilon``): ``min(1, max(ε_min, 1 − (age − burnin)/(total − burnin)))`` in JS
  arithmetic (x/0 = ±∞, 0/0 = NaN, and a NaN ε never explores).
* **ε-greedy** (``explore_action`` / compiled ``explore_action_mr``): ``rf`` is drawn at every
  decision, even when ε = 0; ``rf < ε`` → a second draw gives ``⌊5u⌋`` (``random_action``), else
  ``GREEDY`` (the caller runs ``policy()``). Warm-up (the first tw decisions of a brain's life):
  v1 ``⌊5u⌋`` (one draw), v2 always 0 without a draw (``warmup_action`` / ``warmup_action_mr``).
* **greedy choice** (``argmax_js`` compiled, ``js_argmax_rows`` numpy): a scan from action 0 with
  strict ``>`` — ties go to the lowest index, NaN never wins.
* **temporal window** (§10.2): the net input is ``[x_t, x_{t−1}, e(a_{t−1}), …, x_{t−tw}, e(a_{t−tw})]``
  with ``e(a)`` one-hot scaled by **num_states**. Two equivalent layouts: a flat history
  ``[x_{t−1}, e(a_{t−1}), …]`` shifted after each decision (``shift_window`` / ``shift_windows``, the
  Python paths: the input is ``[x_t, history]``), and ring buffers of states and actions
  (``window_input`` / ``window_push``, the compiled brain policy).

The float64 replica (``autotune.learner.js_learner``) keeps its own copies on purpose: it is the
reference the fast paths are tested against (``tests/test_js_learner.py``).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numba import njit

from autotune.convnet.spec import NUM_ACTIONS
from sim.rng import mrand

__all__ = [
    "BLOCK",
    "GREEDY",
    "BlockUniform",
    "argmax_js",
    "explore_action",
    "explore_action_mr",
    "explore_rows",
    "js_argmax_rows",
    "js_epsilon",
    "random_action",
    "shift_window",
    "shift_windows",
    "warmup_action",
    "warmup_action_mr",
    "warmup_rows",
    "window_input",
    "window_push",
]

GREEDY = -1  # explore_action's answer when the greedy action is to be taken

# --------------------------------------------------------------------------------------------
# Python / numpy rules (the torch learner, the training agents, the quick evaluation)
# --------------------------------------------------------------------------------------------


BLOCK = 4096  # BlockUniform's pre-drawn uniforms per refill


class BlockUniform:
    """Uniforms in [0, 1) from a numpy ``Generator``, ``BLOCK`` at a time: one cheap call per draw on the hot path."""

    __slots__ = ("_rng", "_u", "_i")

    def __init__(self, rng: np.random.Generator) -> None:
        self._rng = rng
        self._u: list[float] = []
        self._i = 0

    def __call__(self) -> float:
        i = self._i
        if i >= len(self._u):
            self._u = self._rng.random(BLOCK).tolist()
            i = 0
        self._i = i + 1
        return self._u[i]


def js_epsilon(age: int, burnin: int, total: int, epsilon_min: float) -> float:
    """``min(1, max(ε_min, 1 − (age − burnin)/(total − burnin)))`` with JS arithmetic (x/0 = ±∞, 0/0 = NaN)."""
    num = float(age - burnin)
    den = float(total - burnin)
    if den == 0.0:
        frac = math.nan if num == 0.0 else math.copysign(math.inf, num)
    else:
        frac = num / den
    eps = 1.0 - frac
    if eps != eps or epsilon_min != epsilon_min:  # Math.max / Math.min propagate NaN
        return math.nan
    eps = epsilon_min if epsilon_min > eps else eps
    return 1.0 if 1.0 < eps else eps


def random_action(u: float) -> int:
    """deepqlearn's ``random_action()``: ``⌊5u⌋`` for a uniform ``u`` in [0, 1)."""
    return int(5.0 * u)


def explore_action(uniform: Callable[[], float], epsilon: float) -> int:
    """``rf`` (always drawn), then ``⌊5u⌋`` if ``rf < ε`` (a second draw), else ``GREEDY``."""
    if uniform() < epsilon:
        return int(5.0 * uniform())
    return GREEDY


def warmup_action(v2: bool, uniform: Callable[[], float]) -> int:
    """The action of the first tw decisions (no input built): v2 always 0, no draw; v1 ``⌊5u⌋``."""
    return 0 if v2 else int(5.0 * uniform())


def explore_rows(actions: np.ndarray, epsilon: float, rng: np.random.Generator) -> None:
    """Batched ε-exploration in place (quick evaluation; not draw-exact): rows with ``rf < ε`` get ``⌊5u⌋``."""
    if epsilon > 0:
        explore = np.asarray(rng.random(actions.shape[0])) < epsilon
        actions[explore] = (5.0 * rng.random(int(explore.sum()))).astype(np.int64)


def warmup_rows(actions: np.ndarray, warm: np.ndarray, v2: bool, rng: np.random.Generator) -> None:
    """Batched warm-up in place: rows in their first tw decisions get 0 (v2) or ``⌊5u⌋`` (v1)."""
    if warm.any():
        actions[warm] = 0 if v2 else (5.0 * rng.random(int(warm.sum()))).astype(np.int64)


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


def shift_window(hist: np.ndarray, state: np.ndarray, action: int, num_states: int) -> None:
    """After a decision: the flat history ``[x, e(a), …]`` (tw entries) shifts one entry and takes ``(state, action)``.

    ``e(a)`` is the one-hot scaled by ``num_states``; the net input of the next decision is
    ``[x_next, hist]``.
    """
    step = num_states + NUM_ACTIONS
    hist[step:] = hist[:-step].copy()
    hist[:num_states] = state
    hist[num_states:step] = 0.0
    hist[num_states + action] = float(num_states)


def shift_windows(hist: np.ndarray, states: np.ndarray, actions: np.ndarray, num_states: int) -> None:
    """``shift_window`` for every row of a batch of flat histories (``hist``: rows × tw·(num_states + 5))."""
    step = num_states + NUM_ACTIONS
    hist[:, step:] = hist[:, :-step].copy()
    hist[:, :num_states] = states
    hist[:, num_states:step] = 0.0
    hist[np.arange(hist.shape[0]), num_states + actions] = float(num_states)


# --------------------------------------------------------------------------------------------
# compiled twins (the exact brain policy; draws from a world's Math.random stream ``mr[w]``)
# --------------------------------------------------------------------------------------------


@njit(cache=True, error_model="numpy", inline="always")
def explore_action_mr(mr: np.ndarray, w: int, epsilon: float) -> int:
    """``explore_action`` from ``Math.random`` stream ``w``: ``rf``, then ``⌊5u⌋`` if ``rf < ε``, else GREEDY."""
    if mrand(mr, w) < epsilon:
        return int(math.floor(mrand(mr, w) * 5.0))
    return GREEDY


@njit(cache=True, error_model="numpy", inline="always")
def warmup_action_mr(mr: np.ndarray, w: int, v2: bool) -> int:
    """``warmup_action`` drawing from stream ``w``: v2 0 without a draw, v1 ``⌊5u⌋``."""
    if v2:
        return 0
    return int(math.floor(mrand(mr, w) * 5.0))


@njit(cache=True, error_model="numpy", inline="always")
def argmax_js(buf: np.ndarray, k: int, n: int) -> int:
    """deepqlearn's greedy choice over ``buf[k, :n]``: scan 0…n−1 with strict ``>`` (ties → lowest; NaN never wins)."""
    best = 0
    val = buf[k, 0]
    for j in range(1, n):
        if buf[k, j] > val:
            best = j
            val = buf[k, j]
    return best


@njit(cache=True, error_model="numpy", inline="always")
def window_input(
    netin: np.ndarray, state: np.ndarray, states: np.ndarray, actions: np.ndarray, head: int, tw: int, ns: int
) -> None:
    """The net input ``[x_t, x_{t−1}, e(a_{t−1}), …]`` into ``netin`` from ring buffers.

    ``states``/``actions`` hold the brain's past decisions (ring of ``window = max(tw, 2)`` rows,
    ``head`` = the latest); ``e(a)`` is the one-hot scaled by ``ns`` (num_states).
    """
    window = states.shape[0]
    for d in range(ns):
        netin[d] = state[d]
    pos = ns
    for k in range(tw):
        idx = (head - k) % window
        for d in range(ns):
            netin[pos + d] = states[idx, d]
        pos += ns
        a = actions[idx]
        for q in range(NUM_ACTIONS):
            netin[pos + q] = float(ns) if q == a else 0.0
        pos += NUM_ACTIONS


@njit(cache=True, error_model="numpy", inline="always")
def window_push(states: np.ndarray, actions: np.ndarray, head: int, state: np.ndarray, action: int, ns: int) -> int:
    """After a decision: ``(state, action)`` become the ring buffers' latest entry; returns the new head."""
    head = (head + 1) % states.shape[0]
    for d in range(ns):
        states[head, d] = state[d]
    actions[head] = action
    return head
