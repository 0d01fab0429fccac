"""Stacked ensembles (``autotune.convnet.stack``): one wider net computes the mean of its members' Q-values, exactly,
builds from its config's layers, survives the JSON round trip, and refuses what would not be exact."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from autotune.convnet import stack
from autotune.convnet.forward import forward
from autotune.convnet.netjson import dumps_net, loads_net
from autotune.convnet.spec import FC, LRN, ConvNet, NetSpecError, init_convnet, same_structure
from autotune.learner.config import TrainConfig
from autotune.search import soup

CONFIG = TrainConfig(lanes_side=1, patches_ahead=3, patches_behind=1, temporal_window=1, layers="fc:6:tanh")


def _nets(hidden: Any, k: int = 3) -> list[ConvNet]:
    layers = CONFIG.replace(layers=hidden).expanded_layers
    nets = []
    for seed in range(k):  # fresh weights and biases moved off their init, so no member is like another
        net = init_convnet(layers, seed)
        rng = np.random.default_rng(100 + seed)
        nets.append(ConvNet(net.layers, tuple((w, b + rng.normal(size=b.shape)) for w, b in net.params)))
    return nets


MAXOUT_DROPOUT = (FC(8, "maxout"), FC(4, "tanh", drop_prob=0.5))
WIDEST = {"fc:6:tanh": 6, "fc:5:relu|fc:3:sigmoid": 5, MAXOUT_DROPOUT: 8, "": 0}


@pytest.mark.parametrize("hidden", list(WIDEST))
def test_a_stack_computes_the_mean_of_its_members_q_values(hidden: Any) -> None:
    nets = _nets(hidden)
    stacked = stack.stack_nets(nets)
    xs = np.random.default_rng(0).normal(size=(32, CONFIG.net_inputs)) * 3
    for x in xs:
        expected = np.mean([forward(n, x) for n in nets], axis=0)
        np.testing.assert_allclose(forward(stacked, x), expected, rtol=0, atol=1e-12)
    # its layers are what a config with every hidden width × k builds, and the JSON round trip keeps it
    wide = CONFIG.replace(layers=stack.stacked_hidden(CONFIG.replace(layers=hidden).layers, len(nets)))
    assert same_structure(stacked.layers, wide.expanded_layers)
    again = loads_net(dumps_net(stacked))
    np.testing.assert_array_equal(forward(again, xs[0]), forward(stacked, xs[0]))
    widest = stack.widest_hidden(CONFIG.replace(layers=hidden).layers)
    assert widest == WIDEST[hidden]


def test_without_hidden_layers_a_stack_is_the_weight_soup_bit_for_bit() -> None:
    nets = _nets("")
    for (w, b), (ws, bs) in zip(stack.stack_nets(nets).params, soup.average_nets(nets).params, strict=True):
        np.testing.assert_array_equal(w, ws)
        np.testing.assert_array_equal(b, bs)
    one = stack.stack_nets(_nets("fc:6:tanh", k=1))  # a stack of one is its member
    np.testing.assert_array_equal(one.params[0][0], _nets("fc:6:tanh", k=1)[0].params[0][0])


def test_what_would_not_stack_exactly_is_refused_naming_the_layer() -> None:
    with pytest.raises(NetSpecError, match="at least one net"):
        stack.stack_nets([])
    with pytest.raises(NetSpecError, match="member 1: its layers differ"):
        stack.stack_nets([_nets("fc:6:tanh", 1)[0], _nets("fc:5:tanh", 1)[0]])
    odd = _nets("fc:5:maxout", 2)  # groups of 2 over 5 units: the stack's groups would straddle two members
    with pytest.raises(NetSpecError, match=r"layers\[2\]: maxout groups of 2 over 5 units"):
        stack.stack_nets(odd)
    net = _nets("fc:6:relu", 1)[0]
    with_lrn = ConvNet((*net.layers[:3], LRN(1.0, 3, 0.1, 0.75), *net.layers[3:]), net.params)
    with pytest.raises(NetSpecError, match=r"layers\[3\]: a LRN layer mixes units across members"):
        stack.stack_nets([with_lrn, with_lrn])
