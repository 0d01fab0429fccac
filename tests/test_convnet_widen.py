"""A linear net moved onto a wider view (``autotune.convnet.widen``): the same Q-values from the wider input, and so
the same official runs, to the digit; what it refuses."""

from __future__ import annotations

import numpy as np
import pytest

from autotune.convnet import widen
from autotune.convnet.deepqlearn import window_input
from autotune.convnet.forward import forward
from autotune.convnet.netjson import dumps_net, loads_net
from autotune.convnet.spec import NetSpecError
from autotune.learner.official import evaluate_official
from autotune.learner.training import train
from tests.test_search_ladder import TINY


def _state(view: widen.View, cell: dict[tuple[int, int], float]) -> np.ndarray:
    """A DeepTraffic state of ``view`` (engine_spec_v2.md §9 written out: rows from the farthest ahead, lanes left
    to right within a row) read from one road, ``cell[(lane offset, row offset)]``."""
    lanes, ahead, behind = view
    return np.array([cell[(k, h)] for h in range(-ahead, behind) for k in range(-lanes, lanes + 1)])


@pytest.mark.parametrize("tw", [0, 1, 3])
def test_a_widened_linear_net_gives_the_same_q_values_from_the_wider_input(tw: int) -> None:
    narrow, wide = (1, 3, 2), (3, 6, 4)
    rng = np.random.default_rng(tw)
    config = TINY.replace(layers="", lanes_side=1, patches_ahead=3, patches_behind=2, temporal_window=tw)
    net = loads_net(dumps_net(train(config.replace(train_iterations=0), seed=3, quick_eval=False).convnet()))
    w, b = net.params[0]
    net = type(net)(net.layers, ((rng.normal(size=w.shape), rng.normal(size=b.shape)),))  # every weight counts
    moved = widen.widen_linear(net, narrow, wide, tw)
    assert moved.input_size == (7 * 10) * (tw + 1) + 5 * tw
    window = max(tw, 2)
    for _ in range(5):
        roads = [{(k, h): rng.normal() for k in range(-3, 4) for h in range(-6, 4)} for _ in range(window + 1)]
        actions = rng.integers(0, 5, size=window)
        outs = []
        for view, size in ((narrow, net.input_size), (wide, moved.input_size)):
            states = np.array([_state(view, road) for road in roads[1:]])
            x = np.zeros(size)
            window_input(x, _state(view, roads[0]), states, actions, window - 1, tw, states.shape[1])
            outs.append(forward(net if view == narrow else moved, x))
        np.testing.assert_allclose(outs[1], outs[0], rtol=1e-12, atol=1e-12)


def test_a_widened_linear_net_scores_as_itself_on_the_official_runs() -> None:
    """The engine end to end, other agents driven by the net too: every run's score to the digit (at ε_test 0; above
    it the random actions draw from Math.random after the brain's build, whose weight initialisation takes as many
    draws as the net has weights, so a wider net's runs differ as another net's would)."""
    narrow = TINY.replace(layers="", lanes_side=1, patches_ahead=3, patches_behind=1, other_agents=2,
                          temporal_window=1, train_iterations=600, epsilon_test_time=0.0)  # fmt: skip
    net = train(narrow, seed=5, quick_eval=False).convnet()
    wide = narrow.replace(lanes_side=2, patches_ahead=5, patches_behind=2)
    moved = widen.widen_linear(net, (1, 3, 1), (2, 5, 2), 1)
    a = evaluate_official(net, narrow, runs=4)
    b = evaluate_official(moved, wide, runs=4)
    assert a.scores == b.scores and len(set(a.scores)) > 1


def test_widen_refuses_a_view_it_does_not_cover_a_hidden_layer_and_a_wrong_input() -> None:
    linear = train(TINY.replace(layers="", train_iterations=0), seed=0, quick_eval=False).convnet()  # view (0, 2, 0)
    assert widen.widen_linear(linear, (0, 2, 0), (0, 2, 0), 0) is linear
    with pytest.raises(NetSpecError, match=r"does not cover"):
        widen.widen_linear(linear, (0, 2, 0), (1, 1, 0), 0)
    with pytest.raises(NetSpecError, match=r"takes 2 inputs; view \(0, 2, 0\) with temporal window 1 gives 9"):
        widen.widen_linear(linear, (0, 2, 0), (1, 2, 0), 1)
    hidden = train(TINY.replace(train_iterations=0), seed=0, quick_eval=False).convnet()
    with pytest.raises(NetSpecError, match=r"only a net without hidden layers"):
        widen.widen_linear(hidden, (0, 2, 0), (1, 2, 0), 0)
    assert widen.union([(0, 2, 0), (1, 1, 3), (0, 4, 1)]) == (1, 4, 3)
    assert widen.covers((1, 4, 3), (1, 4, 0)) and not widen.covers((1, 4, 3), (2, 0, 0))
