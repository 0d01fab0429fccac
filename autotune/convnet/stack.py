"""Stacked ensembles: nets of one structure side by side in one wider convnetjs net that outputs the mean of theirs.

A deep Q-net acts by the argmax of its Q-values, so the ensemble of k trainings acts by the argmax of their mean.
For nets without a hidden layer that mean is the mean of their weights (``autotune.search.soup.average_nets``);
with hidden layers the mean of weights mixes unrelated units, but the ensemble is still one plain net:

* the first fc layer stacks the members' weight rows (every member sees the same input);
* each later hidden fc layer is block-diagonal (member j's units feed only member j's units);
* the output fc layer puts the members' weights side by side, each divided by k, and averages their biases.

Activations (relu, tanh, sigmoid: unit by unit; maxout: over groups of consecutive units, which stay inside one
member when a member's width is a multiple of the group size) and prediction-mode dropout (a constant factor)
act per unit, so the stacked net computes exactly the members' mean (up to the order of float additions) and the
page loads it like any net: its layers are the members' with every hidden width × k. Measured on gsurma's crowd
setting (seeds at 90k scoring 74.81, 74.03, 73.61, 73.02, 73.00, 72.11): stacks of its best 2, 3, 4, 5 and 6
scored 74.78, 75.07, 75.08, 75.19 and 75.27 mph, the last above every member.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from autotune.convnet import spec
from autotune.convnet.spec import FC, ConvNet, Layer, NetSpecError

__all__ = ["stack_nets", "stackable", "stacked_hidden", "widest_hidden"]

_PER_UNIT = (spec.Relu, spec.Tanh, spec.Sigmoid, spec.Dropout)


def stack_nets(nets: Sequence[ConvNet]) -> ConvNet:
    """The one net whose Q-values are the mean of ``nets``' (≥ 1 net, one structure: input, fc layers with per-unit
    activations or maxout, an fc of the actions and a regression). Without a hidden layer: the mean of the weights."""
    if not nets:
        raise NetSpecError("a stacked ensemble needs at least one net")
    first = nets[0]
    for j, net in enumerate(nets[1:], 1):
        if not spec.same_structure(net.layers, first.layers):
            raise NetSpecError(f"ensemble member {j}: its layers differ from member 0's; a stack joins one structure")
    k = len(nets)
    n_fc = sum(isinstance(layer, FC) for layer in first.layers)
    layers: list[Layer] = []
    fc_seen = 0
    width = 0
    for i, layer in enumerate(first.layers):
        if isinstance(layer, FC):
            fc_seen += 1
            width = layer.num_neurons
            if fc_seen < n_fc:
                layer = dataclasses.replace(layer, num_neurons=width * k)
        elif isinstance(layer, spec.Maxout):
            if width % layer.group_size:
                raise NetSpecError(f"layers[{i}]: maxout groups of {layer.group_size} over {width} units would "
                                   "span two members of a stack; only multiples of the group size stack")  # fmt: skip
        elif not isinstance(layer, (spec.Input, spec.Regression, *_PER_UNIT)):
            raise NetSpecError(f"layers[{i}]: a {type(layer).__name__} layer mixes units across members; only fc "
                               "layers with relu, tanh, sigmoid, maxout or dropout stack")  # fmt: skip
        layers.append(layer)
    params = []
    for i in range(n_fc):
        weights = [net.params[i][0] for net in nets]
        biases = [net.params[i][1] for net in nets]
        if n_fc == 1:
            w, b = np.mean(weights, axis=0), np.mean(biases, axis=0)
        elif i == 0:
            w, b = np.vstack(weights), np.concatenate(biases)
        elif i < n_fc - 1:
            w = np.zeros((sum(x.shape[0] for x in weights), sum(x.shape[1] for x in weights)))
            r = c = 0
            for x in weights:
                w[r : r + x.shape[0], c : c + x.shape[1]] = x
                r, c = r + x.shape[0], c + x.shape[1]
            b = np.concatenate(biases)
        else:
            w, b = np.hstack(weights) / k, np.mean(biases, axis=0)
        params.append((w, b))
    return ConvNet(tuple(layers), tuple(params))


def stacked_hidden(hidden: Sequence[Layer], k: int) -> tuple[Layer, ...]:
    """The hidden layer definitions of a stack of ``k`` nets built from ``hidden`` (every fc's width × k): what its
    config records, so a refinement run trains the stacked net on."""
    return tuple(dataclasses.replace(d, num_neurons=d.num_neurons * k) if isinstance(d, FC) else d for d in hidden)


def stackable(hidden: Sequence[Layer]) -> bool:
    """Whether nets with the hidden layer definitions ``hidden`` stack (``stack_nets`` would not refuse them): fc
    layers only (an LRN mixes units across members), a maxout one a multiple of its group size wide."""
    return all(
        isinstance(d, FC) and not (d.activation == "maxout" and d.num_neurons % (d.group_size or 2)) for d in hidden
    )


def widest_hidden(hidden: Sequence[Layer]) -> int:
    """The widest fc of ``hidden`` layer definitions (0 without one): a stack of k is k times as wide."""
    return max((d.num_neurons for d in hidden if isinstance(d, FC)), default=0)
