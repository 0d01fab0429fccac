"""A net without hidden layers moved onto a wider view: the same Q-values from a larger input.

deepqlearn feeds its net ``[x_t, x_{t−1}, e(a_{t−1}), …]`` (``deepqlearn.window_input``): each x a DeepTraffic
state — the (2L+1)·(P+B) cells of the view, lane by lane within a row, rows from the farthest ahead
(engine_spec_v2.md §9, engine_spec.md §7: ``state[(2L+1)·(h+P) + (k+L)]`` for lane offset k, row offset h) — and
e(a) the previous action one-hot, scaled by the state's length. A view (L', P', B') with L' ≥ L, P' ≥ P and B' ≥ B
reads every cell of (L, P, B) at the same lane and row (off-road and off-grid cells read 0 in both), so a linear
net Q = W·x + b computes exactly its own Q-values from the wider input when each weight moves to its cell's place,
the new cells weigh 0, and an action weight is scaled by (2L+1)(P+B) / ((2L'+1)(P'+B')) (the one-hot's scale).

Why: seed soups average linear nets' weights, which is their ensemble only when they read one input. Moved onto
the union of their views, nets of neighbouring views (a lane a side more, a quarter of the patches ahead fewer)
soup too (``autotune.search.ensemble``). Offline, 8 seeds each of gsurma's linear adagrad twin and of two of its
view neighbours at 90k greedily souped at 75.21, 75.23 and 75.32 apiece, and at 75.47 together (6 nets of the 3
views); on 2 × 500 unseen runs 75.79 / 75.70 together against 75.90 / 75.68 for the best view's own soup.

The temporal window must match: it also sets how many decisions a brain takes at random before its window is full.
At ε_test 0 the wider net's official runs are its own's to the digit; above it they differ as another net's would
(the random actions draw from Math.random after the brain's build, whose weight initialisation takes one draw per
weight or so, engine_spec.md §10), though the policy — Q-values and ε — is the same.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from autotune.convnet import spec
from autotune.convnet.spec import FC, NUM_ACTIONS, ConvNet, NetSpecError

__all__ = ["View", "covers", "union", "widen_linear"]

View = tuple[int, int, int]
"""(lanes_side, patches_ahead, patches_behind) of a DeepTraffic view."""


def covers(wide: View, view: View) -> bool:
    """Whether ``wide`` reads every cell ``view`` does."""
    return all(w >= v for w, v in zip(wide, view, strict=True))


def union(views: Iterable[View]) -> View:
    """The smallest view that covers every one of ``views`` (≥ 1)."""
    vs = list(views)
    if not vs:
        raise ValueError("union of no views")
    return (max(v[0] for v in vs), max(v[1] for v in vs), max(v[2] for v in vs))


def _cells(view: View) -> int:
    lanes, ahead, behind = view
    return (2 * lanes + 1) * (ahead + behind)


def widen_linear(net: ConvNet, view: View, wide: View, temporal_window: int) -> ConvNet:
    """``net`` (no hidden layer: input, fc of the 5 actions, regression) of a brain seeing ``view`` with
    ``temporal_window``, as the net of a brain seeing ``wide`` with the same window and Q-values (module
    docstring). ``wide`` = ``view``: ``net`` itself."""
    if not covers(wide, view):
        raise NetSpecError(f"view {wide} does not cover {view}: each of lanes_side, patches_ahead and patches_behind "
                           "must be at least the net's")  # fmt: skip
    if wide == view:
        return net
    layers = net.layers
    if len(net.params) != 1 or not isinstance(layers[0], spec.Input) or not isinstance(layers[1], FC):
        raise NetSpecError("only a net without hidden layers moves onto a wider view (its Q-values are W·x + b)")
    ns, ns_wide = _cells(view), _cells(wide)
    weights, biases = net.params[0]
    expected = ns * (temporal_window + 1) + NUM_ACTIONS * temporal_window
    if weights.shape[1] != expected:
        raise NetSpecError(f"the net takes {weights.shape[1]} inputs; view {view} with temporal window "
                           f"{temporal_window} gives {expected}")  # fmt: skip
    lanes, ahead, behind = view
    lanes_w, ahead_w = wide[0], wide[1]
    cells = np.array([(2 * lanes_w + 1) * (h + ahead_w) + (k + lanes_w)
                      for h in range(-ahead, behind) for k in range(-lanes, lanes + 1)], dtype=np.int64)  # fmt: skip
    out = np.zeros((weights.shape[0], ns_wide * (temporal_window + 1) + NUM_ACTIONS * temporal_window))
    out[:, cells] = weights[:, :ns]
    for t in range(temporal_window):
        src, dst = ns + t * (ns + NUM_ACTIONS), ns_wide + t * (ns_wide + NUM_ACTIONS)
        out[:, dst + cells] = weights[:, src : src + ns]
        out[:, dst + ns_wide : dst + ns_wide + NUM_ACTIONS] = weights[:, src + ns : src + ns + NUM_ACTIONS] * (
            ns / ns_wide
        )
    first = layers[0]
    assert isinstance(first, spec.Input)
    wider = spec.Input(out_depth=out.shape[1], out_sx=first.out_sx, out_sy=first.out_sy)
    return ConvNet((wider, *layers[1:]), ((out, biases.copy()),))
