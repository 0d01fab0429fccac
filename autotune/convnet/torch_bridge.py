"""The torch bridge of a convnetjs network: ``ConvNetModule`` built from expanded layers, weights both ways.

The torch module mirrors convnetjs in both modes where convnetjs differs from torch defaults:
``ConvnetDropout`` zeroes with probability p in training **without rescaling** and multiplies by p
in eval mode (the convnetjs prediction bug); a mid-network ``SVM`` blocks gradients (convnetjs
zeroes them); a mid-network ``Softmax`` passes its own outputs down as the input gradient.
Importing this module does not import torch; the first call does.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from autotune.convnet.spec import (
    FC,
    LRN,
    SVM,
    ConvNet,
    Dropout,
    Input,
    Layer,
    Maxout,
    NetSpecError,
    Regression,
    Relu,
    Sigmoid,
    Softmax,
    Tanh,
    layer_sizes,
)

__all__ = ["build_torch", "to_torch", "from_torch"]


def _torch():  # noqa: ANN202
    import torch

    return torch


def build_torch(layers: Sequence[Layer], dtype: Any = None) -> Any:
    """A ``ConvNetModule`` (``nn.Sequential`` subclass) for expanded ``layers``: Linear i ↔ FC i, in order.

    Weights are torch's default init; use ``to_torch`` to carry a ``ConvNet``'s parameters.
    ``module.fc_layers`` lists the Linear modules; the input layer is not a module.
    """
    torch = _torch()
    nn = torch.nn
    c = _classes()
    ConvNetModule, ConvnetMaxout, ConvnetDropout = c["ConvNetModule"], c["ConvnetMaxout"], c["ConvnetDropout"]
    ConvnetSVM, ConvnetSoftmax, ConvnetLRN = c["ConvnetSVM"], c["ConvnetSoftmax"], c["ConvnetLRN"]
    layers = tuple(layers)
    sizes = layer_sizes(layers)
    mods: list[Any] = []
    last = len(layers) - 1
    for idx, (layer, (n_in, n_out)) in enumerate(zip(layers, sizes, strict=True)):
        if isinstance(layer, Input):
            continue
        if isinstance(layer, FC):
            mods.append(nn.Linear(n_in, n_out, dtype=dtype))
        elif isinstance(layer, Relu):
            mods.append(nn.ReLU())
        elif isinstance(layer, Tanh):
            mods.append(nn.Tanh())
        elif isinstance(layer, Sigmoid):
            mods.append(nn.Sigmoid())
        elif isinstance(layer, Maxout):
            mods.append(ConvnetMaxout(layer.group_size))
        elif isinstance(layer, Dropout):
            mods.append(ConvnetDropout(layer.drop_prob))
        elif isinstance(layer, SVM):
            mods.append(ConvnetSVM(mid_network=idx != last))
        elif isinstance(layer, Softmax):
            mods.append(ConvnetSoftmax(mid_network=idx != last))
        elif isinstance(layer, Regression):
            mods.append(nn.Identity())
        elif isinstance(layer, LRN):
            mods.append(ConvnetLRN(layer.k, layer.n, layer.alpha, layer.beta))
    return ConvNetModule(layers, *mods)


def to_torch(net: ConvNet, dtype: Any = None) -> Any:
    """``ConvNet`` → ``ConvNetModule`` carrying its weights (dtype default float64; float32 allowed)."""
    torch = _torch()
    dtype = torch.float64 if dtype is None else dtype
    module = build_torch(net.layers, dtype=dtype)
    with torch.no_grad():
        for lin, (w, b) in zip(module.fc_layers, net.params, strict=True):
            lin.weight.copy_(torch.from_numpy(w).to(dtype))
            lin.bias.copy_(torch.from_numpy(b).to(dtype))
    return module


def from_torch(module: Any, template: ConvNet | Sequence[Layer]) -> ConvNet:
    """Torch module → ``ConvNet`` with ``template``'s layers and the module's Linear parameters (as float64).

    ``module`` may be a ``ConvNetModule``, any ``nn.Module`` whose ``nn.Linear`` submodules (in
    registration order) match the template's fc layers, or a state-dict-like mapping of such a module.
    """
    torch = _torch()
    layers = template.layers if isinstance(template, ConvNet) else tuple(template)
    sizes = layer_sizes(layers)
    shapes = [(n_out, n_in) for layer, (n_in, n_out) in zip(layers, sizes, strict=True) if isinstance(layer, FC)]
    linears = [m for m in module.modules() if isinstance(m, torch.nn.Linear)]
    if len(linears) != len(shapes):
        raise NetSpecError(
            f"from_torch: module has {len(linears)} Linear layers, the template has {len(shapes)} fc layers"
        )
    params = []
    for k, (lin, shape) in enumerate(zip(linears, shapes, strict=True)):
        w = lin.weight.detach().to("cpu", torch.float64).numpy().copy()
        if tuple(w.shape) != shape:
            raise NetSpecError(
                f"from_torch: Linear #{k} has weight shape {tuple(w.shape)}, template fc #{k} needs {shape}"
            )
        if lin.bias is None:
            b = np.zeros(shape[0])
        else:
            b = lin.bias.detach().to("cpu", torch.float64).numpy().copy()
        params.append((w, b))
    return ConvNet(tuple(layers), tuple(params))


def _make_torch_classes() -> dict[str, Any]:
    torch: Any = _torch()
    nn: Any = torch.nn
    autograd_function: Any = torch.autograd.Function

    class ConvNetModule(nn.Sequential):
        """``nn.Sequential`` of a convnetjs net; ``.layers`` keeps the expanded layer list."""

        def __init__(self, layers: tuple[Layer, ...], *mods: Any) -> None:
            super().__init__(*mods)
            self.layers = layers

        @property
        def fc_layers(self) -> list[Any]:
            return [m for m in self if isinstance(m, nn.Linear)]

    class ConvnetMaxout(nn.Module):
        """Max over groups of ``group_size`` consecutive features (extra features dropped, as ⌊n/g⌋)."""

        def __init__(self, group_size: int) -> None:
            super().__init__()
            self.group_size = group_size

        def forward(self, x: Any) -> Any:
            g = self.group_size
            n = x.shape[-1] // g
            return x[..., : n * g].reshape(*x.shape[:-1], n, g).max(dim=-1).values

    class ConvnetDropout(nn.Module):
        """convnetjs dropout: train → zero with prob p (no rescale); eval → multiply by p."""

        def __init__(self, p: float) -> None:
            super().__init__()
            self.p = p

        def forward(self, x: Any) -> Any:
            if self.training:
                return x * (torch.rand_like(x) >= self.p).to(x.dtype)
            return x * self.p

    class ConvnetSVM(nn.Module):
        """SVM layer: identity forward; mid-network it blocks the gradient (convnetjs zeroes it)."""

        def __init__(self, mid_network: bool) -> None:
            super().__init__()
            self.mid_network = mid_network

        def forward(self, x: Any) -> Any:
            return x.detach() if self.mid_network else x

    class _SoftmaxOwnGrad(autograd_function):
        @staticmethod
        def forward(ctx: Any, x: Any) -> Any:  # noqa: ANN401
            y = torch.softmax(x, dim=-1)
            ctx.save_for_backward(y)
            return y

        @staticmethod
        def backward(ctx: Any, grad: Any) -> Any:  # noqa: ANN401
            (y,) = ctx.saved_tensors
            return y.clone()

    class ConvnetSoftmax(nn.Module):
        """Softmax layer; mid-network its input gradient is its own output (convnetjs with no target)."""

        def __init__(self, mid_network: bool) -> None:
            super().__init__()
            self.mid_network = mid_network

        def forward(self, x: Any) -> Any:
            if self.mid_network:
                return _SoftmaxOwnGrad.apply(x)
            return torch.softmax(x, dim=-1)

    class ConvnetLRN(nn.Module):
        """1-D local response normalisation with convnetjs's k, n, alpha, beta."""

        def __init__(self, k: float, n: int, alpha: float, beta: float) -> None:
            super().__init__()
            self.k, self.n, self.alpha, self.beta = k, n, alpha, beta

        def forward(self, x: Any) -> Any:
            half = self.n // 2
            sq = x * x
            padded = torch.nn.functional.pad(sq, (half, half))
            window = padded.unfold(-1, 2 * half + 1, 1).sum(-1)
            return x / (window * (self.alpha / self.n) + self.k) ** self.beta

    return {
        "ConvNetModule": ConvNetModule,
        "ConvnetMaxout": ConvnetMaxout,
        "ConvnetDropout": ConvnetDropout,
        "ConvnetSVM": ConvnetSVM,
        "ConvnetSoftmax": ConvnetSoftmax,
        "ConvnetLRN": ConvnetLRN,
    }


_CLASSES: dict[str, Any] = {}


def _classes() -> dict[str, Any]:
    if not _CLASSES:
        _CLASSES.update(_make_torch_classes())
    return _CLASSES


def __getattr__(name: str) -> Any:
    """Torch module classes are created on first use so that importing this module does not import torch."""
    if name in ("ConvNetModule", "ConvnetMaxout", "ConvnetDropout", "ConvnetSVM", "ConvnetSoftmax", "ConvnetLRN"):
        return _classes()[name]
    raise AttributeError(name)
