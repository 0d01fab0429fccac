"""The network of a DeepQLearner: convnetjs construction and initialisation, the hand-written batch update.

The update is a forward/backward over preallocated buffers (``Kernel``; the s₀ and s₁ halves of
the batch go through the net as one 2B-row matrix); ``numpy_forward_ops`` is the prediction-mode
forward of one vector on numpy views of the same parameter memory (cheaper than torch dispatch).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from autotune.convnet import spec, torch_bridge
from autotune.learner.config import NUM_ACTIONS, ConfigError, TrainConfig

__all__ = ["Kernel", "build_network", "numpy_forward_ops", "NP_DTYPES", "TORCH_DTYPES"]


TORCH_DTYPES = {"float32": torch.float32, "float64": torch.float64}
NP_DTYPES = {"float32": np.float32, "float64": np.float64}


# --------------------------------------------------------------------------------------------
# network construction
# --------------------------------------------------------------------------------------------


def build_network(config: TrainConfig, generator: torch.Generator) -> tuple[Any, tuple[spec.Layer, ...]]:
    """The convnetjs net of ``config`` as a ``torch_bridge.ConvNetModule`` with convnetjs initialisation."""
    layers = config.expanded_layers
    dtype = TORCH_DTYPES[config.dtype]
    module = torch_bridge.build_torch(layers, dtype=dtype)
    prefs = spec.fc_bias_prefs(layers)
    with torch.no_grad():
        for lin, pref in zip(module.fc_layers, prefs, strict=True):
            fan_in = lin.weight.shape[1]
            lin.weight.normal_(0.0, math.sqrt(1.0 / fan_in), generator=generator)
            lin.bias.fill_(pref)
    _flatten_parameters(module)
    module.eval()
    return module, layers


def _flatten_parameters(module: Any) -> torch.Tensor:
    """Move every fc's parameters into one flat tensor — all weights first, then all biases.

    The Linear parameters become views of it, so the optimizer updates the whole net with a few
    whole-tensor operations (decay on the weight block only). Returns the flat tensor.
    """
    fcs = module.fc_layers
    weights = [lin.weight.data for lin in fcs]
    biases = [lin.bias.data for lin in fcs]
    total = sum(t.numel() for t in weights + biases)
    flat = torch.empty(total, dtype=weights[0].dtype)
    off = 0
    for t in [lin.weight for lin in fcs] + [lin.bias for lin in fcs]:
        n = t.numel()
        view = flat[off : off + n].view(t.shape)
        view.copy_(t.data)
        t.data = view
        off += n
    for p in module.parameters():
        p.requires_grad_(False)
    module.flat_params = flat  # type: ignore[attr-defined]
    module.n_weights = sum(t.numel() for t in weights)  # type: ignore[attr-defined]
    return flat


# --------------------------------------------------------------------------------------------
# the batch update: hand-written forward/backward over preallocated buffers
# --------------------------------------------------------------------------------------------
#
# Activations live in (2B, n) buffers: rows 0…B−1 are the s₀ samples (training mode), rows B…2B−1
# the s₁ samples (prediction mode, for the targets). Row-wise layers treat both halves alike; the
# dropout layer masks the s₀ half and scales the s₁ half by drop_prob (convnetjs's prediction
# mode). The backward pass only involves the s₀ half.


class _FCOp:
    def __init__(self, lin: Any, x: torch.Tensor, B: int, need_dx: bool, flat_grad: torch.Tensor) -> None:
        self.W = lin.weight.data
        self.b = lin.bias.data
        self.WT = self.W.t()
        n_out = self.W.shape[0]
        self.x = x
        self.x0 = x[:B]
        self.out = torch.empty(2 * B, n_out, dtype=x.dtype)
        # gradients live in a flat tensor laid out like module.flat_params
        w_off, b_off = self.W.storage_offset(), self.b.storage_offset()
        self.gW = flat_grad[w_off : w_off + self.W.numel()].view(self.W.shape)
        self.gb = flat_grad[b_off : b_off + self.b.numel()]
        self.dx = torch.empty(B, x.shape[1], dtype=x.dtype) if need_dx else None

    def fwd(self) -> None:
        torch.addmm(self.b, self.x, self.WT, out=self.out)

    def bwd(self, d: torch.Tensor) -> torch.Tensor | None:
        torch.mm(d.t(), self.x0, out=self.gW)
        torch.sum(d, 0, out=self.gb)
        if self.dx is None:
            return None
        torch.mm(d, self.W, out=self.dx)
        return self.dx


class _ReluOp:
    """In place on the fc output (the fc backward does not need its own output)."""

    def __init__(self, x: torch.Tensor, B: int) -> None:
        self.out = x
        self.y0 = x[:B]
        self.mask = torch.empty(B, x.shape[1], dtype=x.dtype)

    def fwd(self) -> None:
        self.out.relu_()

    def bwd(self, d: torch.Tensor) -> torch.Tensor:
        # gradient passes where the output is > 0: sign(y) ∈ {0, 1} for y = relu(x) (NaN only in a
        # diverged net, where training stops anyway). Cheaper than a boolean mask + masked_fill.
        torch.sign(self.y0, out=self.mask)
        return d.mul_(self.mask)


class _TanhOp:
    def __init__(self, x: torch.Tensor, B: int) -> None:
        self.out = x
        self.y0 = x[:B]
        self.tmp = torch.empty(B, x.shape[1], dtype=x.dtype)

    def fwd(self) -> None:
        self.out.tanh_()

    def bwd(self, d: torch.Tensor) -> torch.Tensor:
        torch.mul(self.y0, self.y0, out=self.tmp)  # dx = d·(1 − y²)
        return d.addcmul_(d, self.tmp, value=-1.0)


class _SigmoidOp:
    def __init__(self, x: torch.Tensor, B: int) -> None:
        self.out = x
        self.y0 = x[:B]
        self.tmp = torch.empty(B, x.shape[1], dtype=x.dtype)

    def fwd(self) -> None:
        self.out.sigmoid_()

    def bwd(self, d: torch.Tensor) -> torch.Tensor:
        torch.mul(d, self.y0, out=self.tmp)  # dx = d·y·(1 − y) = d·y − (d·y)·y
        return torch.addcmul(self.tmp, self.tmp, self.y0, value=-1.0, out=d)


class _MaxoutOp:
    def __init__(self, x: torch.Tensor, B: int, group: int) -> None:
        n_in = x.shape[1]
        m = n_in // group
        self.g = group
        self.m = m
        self.xv = x[:, : m * group].view(2 * B, m, group)
        self.out = torch.empty(2 * B, m, dtype=x.dtype)
        self.idx = torch.empty(2 * B, m, dtype=torch.int64)
        self.idx0 = self.idx[:B].unsqueeze(2)
        self.dx = torch.zeros(B, n_in, dtype=x.dtype)
        self.dxv = self.dx[:, : m * group].view(B, m, group)

    def fwd(self) -> None:
        torch.max(self.xv, 2, out=(self.out, self.idx))

    def bwd(self, d: torch.Tensor) -> torch.Tensor:
        self.dx.zero_()
        self.dxv.scatter_(2, self.idx0, d.unsqueeze(2))
        return self.dx


class _DropoutOp:
    def __init__(self, x: torch.Tensor, B: int, p: float, gen: torch.Generator) -> None:
        n = x.shape[1]
        self.p = float(p)
        self.gen = gen
        self.x0 = x[:B]
        self.x1 = x[B:]
        self.out = torch.empty(2 * B, n, dtype=x.dtype)
        self.o0 = self.out[:B]
        self.o1 = self.out[B:]
        self.u = torch.empty(B, n, dtype=x.dtype)
        self.keep = torch.empty(B, n, dtype=torch.bool)

    def fwd(self) -> None:
        torch.rand(self.u.shape, generator=self.gen, dtype=self.u.dtype, out=self.u)
        torch.ge(self.u, self.p, out=self.keep)  # convnetjs zeroes a value when its draw < drop_prob
        torch.mul(self.x0, self.keep, out=self.o0)
        torch.mul(self.x1, self.p, out=self.o1)  # prediction mode multiplies by drop_prob (convnetjs bug)

    def bwd(self, d: torch.Tensor) -> torch.Tensor:
        return d.mul_(self.keep)


class _SVMOp:
    """Mid-network svm layer: identity forward; its input gradient is all zeros (nothing below learns)."""

    def __init__(self, x: torch.Tensor) -> None:
        self.out = x

    def fwd(self) -> None:
        pass

    def bwd(self, d: torch.Tensor) -> None:
        return None


class _SoftmaxOp:
    """Mid-network softmax: its input gradient is its own output (convnetjs backward without a target)."""

    def __init__(self, x: torch.Tensor, B: int) -> None:
        self.x = x
        self.out = torch.empty_like(x)
        self.y0 = self.out[:B]
        self.dx = torch.empty(B, x.shape[1], dtype=x.dtype)

    def fwd(self) -> None:
        self.out.copy_(torch.softmax(self.x, dim=1))

    def bwd(self, d: torch.Tensor) -> torch.Tensor:
        return self.dx.copy_(self.y0)


def _lrn(x: torch.Tensor, k: float, n: int, alpha: float, beta: float) -> torch.Tensor:
    half = n // 2
    sq = torch.nn.functional.pad(x * x, (half, half))
    window = sq.unfold(1, 2 * half + 1, 1).sum(2)
    return x / (k + (alpha / n) * window) ** beta


class _LRNOp:
    """1-D local response normalisation; backward = its exact derivative (via autograd on the layer)."""

    def __init__(self, x: torch.Tensor, B: int, layer: spec.LRN) -> None:
        self.x = x
        self.x0 = x[:B]
        self.layer = layer
        self.out = torch.empty_like(x)

    def fwd(self) -> None:
        L = self.layer
        self.out.copy_(_lrn(self.x, L.k, L.n, L.alpha, L.beta))

    def bwd(self, d: torch.Tensor) -> torch.Tensor:
        L = self.layer
        with torch.enable_grad():
            xg = self.x0.detach().clone().requires_grad_(True)
            y = _lrn(xg, L.k, L.n, L.alpha, L.beta)
            (g,) = torch.autograd.grad(y, xg, d)
        return g


class Kernel:
    """Preallocated batch machinery: sample rows → fused forward → TD error → backward → update."""

    def __init__(self, config: TrainConfig, module: Any, layers: tuple, gen: torch.Generator) -> None:
        B = config.batch_size
        dtype = TORCH_DTYPES[config.dtype]
        D = config.net_inputs
        self.B = B
        self.gamma = float(config.gamma)
        self.x = torch.empty(2 * B, D, dtype=dtype)  # [s₀ rows; s₁ rows]
        self.x_pair = self.x.view(2, B, D)
        self.oh = torch.empty(B, NUM_ACTIONS, dtype=dtype)
        self.r = torch.empty(B, dtype=dtype)
        fcs = iter(module.fc_layers)
        self.P = module.flat_params
        self.G = torch.zeros_like(self.P)
        n_w = module.n_weights
        ops: list[Any] = []
        cur = self.x
        first_fc = next(i for i, layer in enumerate(layers) if isinstance(layer, spec.FC))
        last = len(layers) - 1
        self.fc_ops: list[_FCOp] = []
        for i, layer in enumerate(layers):
            if isinstance(layer, spec.Input):
                continue
            if isinstance(layer, spec.FC):
                op: Any = _FCOp(next(fcs), cur, B, need_dx=i > first_fc, flat_grad=self.G)
                self.fc_ops.append(op)
            elif isinstance(layer, spec.Relu):
                op = _ReluOp(cur, B)
            elif isinstance(layer, spec.Tanh):
                op = _TanhOp(cur, B)
            elif isinstance(layer, spec.Sigmoid):
                op = _SigmoidOp(cur, B)
            elif isinstance(layer, spec.Maxout):
                op = _MaxoutOp(cur, B, layer.group_size)
            elif isinstance(layer, spec.Dropout):
                op = _DropoutOp(cur, B, layer.drop_prob, gen)
            elif isinstance(layer, spec.SVM):
                op = _SVMOp(cur)
            elif isinstance(layer, spec.Softmax):
                if i == last:  # pragma: no cover - deepqlearn always ends in regression
                    raise ValueError("a final softmax layer is not a Q-function")
                op = _SoftmaxOp(cur, B)
            elif isinstance(layer, spec.Regression):
                continue  # identity; the last fc's output is Q
            elif isinstance(layer, spec.LRN):
                op = _LRNOp(cur, B, layer)
            else:  # pragma: no cover
                raise ValueError(f"layer {layer!r} is not supported")
            ops.append(op)
            cur = op.out
        self.ops = ops
        self.ops_rev = ops[::-1]
        # fc layers below a mid-network svm never receive a gradient: their dw stays 0 (decay still acts)
        blocked: list[torch.Tensor] = []
        below = False
        for op in self.ops_rev:
            if below and isinstance(op, _FCOp):
                blocked += [op.gW, op.gb]
            if isinstance(op, _SVMOp):
                below = True
        self.blocked = blocked
        q = cur  # (2B, 5)
        self.q0 = q[:B]
        self.q1 = q[B:]
        self.mx = torch.empty(B, dtype=dtype)
        self.y = torch.empty(B, 1, dtype=dtype)
        self.y_flat = self.y.view(B)
        self.dq = torch.empty(B, NUM_ACTIONS, dtype=dtype)
        self.dq_flat = self.dq.view(-1)
        # optimizer state (flat: weights block first, then biases; see _flatten_parameters)
        fc_layers = [layer for layer in layers if isinstance(layer, spec.FC)]
        self.Ws = [op.W for op in self.fc_ops]
        self.gWs = [op.gW for op in self.fc_ops]
        self.Pw = self.P[:n_w]
        self.Gw = self.G[:n_w]
        l2 = float(config.l2_decay)
        l1 = float(config.l1_decay)
        self.l2 = [l2 * layer.l2_decay_mul for layer in fc_layers]
        self.l1 = [l1 * layer.l1_decay_mul for layer in fc_layers]
        self.l2_uniform = self.l2[0] if len(set(self.l2)) == 1 else None
        self.any_l2 = any(c != 0.0 for c in self.l2)
        self.any_l1 = any(c != 0.0 for c in self.l1)
        self.method = config.method
        self.lr = float(config.learning_rate)
        self.mu = float(config.momentum)
        self.ro = float(config.ro)
        self.eps = float(config.eps)
        self.inv_b = 1.0 / B
        self.S1 = torch.zeros_like(self.P)  # gsum: velocity / squared-gradient average
        self.S2 = torch.zeros_like(self.P) if self.method == "adadelta" else None  # xsum
        self.tmp = torch.empty_like(self.P)
        self.tmp2 = torch.empty_like(self.P) if self.method in ("adadelta", "nesterov") else None

    def step(self, SS: torch.Tensor, OH: torch.Tensor, R: torch.Tensor, idx: torch.Tensor) -> None:
        """One convnetjs batch update from the replay rows ``idx``."""
        torch.index_select(SS, 1, idx, out=self.x_pair)
        torch.index_select(OH, 0, idx, out=self.oh)
        torch.index_select(R, 0, idx, out=self.r)
        for op in self.ops:
            op.fwd()
        torch.amax(self.q1, 1, out=self.mx)
        torch.add(self.r, self.mx, alpha=self.gamma, out=self.y_flat)  # y = r + γ·max_a Q(s₁, a)
        torch.sub(self.q0, self.y, out=self.dq)
        self.dq.mul_(self.oh)  # ∂½(Q(s₀)_a₀ − y)²: only the taken action
        d: torch.Tensor | None = self.dq
        for op in self.ops_rev:
            d = op.bwd(d)
            if d is None:
                break
        if self.blocked:  # torch has no public fused multi-tensor zero (``_foreach_*`` is its optimizers' own API)
            torch._foreach_zero_(self.blocked)
        self._update()

    def loss(self) -> float:
        """Mean ½(Q(s₀)_a₀ − y)² of the last batch (convnetjs's cost loss, without the decay terms)."""
        return 0.5 * float(torch.dot(self.dq_flat, self.dq_flat)) * self.inv_b

    def _update(self) -> None:
        """convnetjs Trainer update of every parameter (spec §10.5, §10.9), on the flat tensors."""
        P, G, S = self.P, self.G, self.S1
        if self.any_l2:
            if self.l2_uniform is not None:
                self.Gw.add_(self.Pw, alpha=self.l2_uniform)  # l2·w on weights only (biases: l2_decay_mul 0)
            else:
                for g, w, c in zip(self.gWs, self.Ws, self.l2, strict=True):
                    g.add_(w, alpha=c)
        if self.any_l1:
            for g, w, c in zip(self.gWs, self.Ws, self.l1, strict=True):
                if c:
                    g.add_(torch.where(w > 0, 1.0, -1.0).to(w.dtype), alpha=c)  # sign(w), with sign(0) = −1
        method = self.method
        if method == "sgd":
            if self.mu > 0.0:
                S.mul_(self.mu).add_(G, alpha=-self.lr * self.inv_b)  # v = μv − lr·g
                P.add_(S)  # w += v
            else:
                P.add_(G, alpha=-self.lr * self.inv_b)  # w −= lr·g
            return
        G.mul_(self.inv_b)  # g = (decay + dw)/batch_size
        tmp = self.tmp
        if method == "adagrad":
            S.addcmul_(G, G)  # G += g²
            torch.add(S, self.eps, out=tmp).sqrt_()
            P.addcdiv_(G, tmp, value=-self.lr)  # w −= lr·g/√(G + ε)
        elif method == "windowgrad":
            S.mul_(self.ro).addcmul_(G, G, value=1.0 - self.ro)  # G = ρG + (1−ρ)g²
            torch.add(S, self.eps, out=tmp).sqrt_()
            P.addcdiv_(G, tmp, value=-self.lr)
        elif method == "adadelta":
            X, dx = self.S2, self.tmp2
            assert X is not None and dx is not None
            S.mul_(self.ro).addcmul_(G, G, value=1.0 - self.ro)
            torch.add(X, self.eps, out=dx)
            torch.add(S, self.eps, out=tmp)
            dx.div_(tmp).sqrt_().mul_(G).neg_()  # Δ = −√((X + ε)/(G + ε))·g
            X.mul_(self.ro).addcmul_(dx, dx, value=1.0 - self.ro)  # X = ρX + (1−ρ)Δ²
            P.add_(dx)
        elif method == "nesterov":
            torch.mul(S, self.mu, out=tmp)  # μ·V_old
            S.mul_(self.mu).add_(G, alpha=self.lr)  # V = μV + lr·g
            P.add_(tmp).add_(S, alpha=-(1.0 + self.mu))  # w += μ·V_old − (1 + μ)·V
        # G is overwritten by the next backward pass (fc layers below a mid-network svm: re-zeroed)


# --------------------------------------------------------------------------------------------
# prediction-mode forward of one vector (numpy views of the parameters)
# --------------------------------------------------------------------------------------------


def numpy_forward_ops(module: Any, layers: tuple, np_dtype: Any) -> list[Callable[[np.ndarray], np.ndarray]]:
    """Closures computing the prediction-mode forward pass of one input vector, in place where possible."""
    fcs = iter(module.fc_layers)
    ops: list[Callable[[np.ndarray], np.ndarray]] = []
    for layer in layers:
        if isinstance(layer, spec.FC):
            lin = next(fcs)
            W = lin.weight.data.numpy()  # shares memory with the trained parameters
            b = lin.bias.data.numpy()
            out = np.empty(W.shape[0], dtype=np_dtype)

            def fc(x: np.ndarray, W: np.ndarray = W, b: np.ndarray = b, out: np.ndarray = out) -> np.ndarray:
                np.dot(W, x, out=out)
                out += b
                return out

            ops.append(fc)
        elif isinstance(layer, spec.Relu):

            def relu(x: np.ndarray) -> np.ndarray:
                return np.maximum(x, 0, out=x)  # NaN passes, as in convnetjs

            ops.append(relu)
        elif isinstance(layer, spec.Tanh):
            ops.append(lambda x: np.tanh(x, out=x))
        elif isinstance(layer, spec.Sigmoid):

            def sigmoid(x: np.ndarray) -> np.ndarray:
                np.negative(x, out=x)
                np.exp(x, out=x)
                x += 1.0
                return np.reciprocal(x, out=x)

            ops.append(sigmoid)
        elif isinstance(layer, spec.Maxout):
            g = layer.group_size

            def maxout(x: np.ndarray, g: int = g) -> np.ndarray:
                m = x.shape[0] // g
                return x[: m * g].reshape(m, g).max(axis=1)

            ops.append(maxout)
        elif isinstance(layer, spec.Dropout):
            p = float(layer.drop_prob)

            def dropout(x: np.ndarray, p: float = p) -> np.ndarray:
                x *= p  # convnetjs prediction mode
                return x

            ops.append(dropout)
        elif isinstance(layer, spec.Softmax):

            def softmax(x: np.ndarray) -> np.ndarray:
                e = np.exp(x - x.max())
                return e / e.sum()

            ops.append(softmax)
        elif isinstance(layer, spec.LRN):
            L = layer

            def lrn(x: np.ndarray, L: spec.LRN = L) -> np.ndarray:
                half = L.n // 2
                sq = np.pad(x * x, half)
                window = np.convolve(sq, np.ones(2 * half + 1, dtype=x.dtype), mode="valid")
                return x / (L.k + (L.alpha / L.n) * window) ** L.beta

            ops.append(lrn)
        # Input, SVM, Regression: identity
    return ops


def load_weights(module: Any, layers: tuple[spec.Layer, ...], net: spec.ConvNet) -> None:
    """Copy ``net``'s weights and biases into ``module`` (built for ``layers``) in place, as convnetjs's
    ``Net.fromJSON`` fills a page's net: the flat parameter views stay the optimizer's.

    Raises ``ConfigError`` (field ``init_net``) when ``net``'s layers are not ``layers``: a loaded net must be the
    net the config builds (the same inputs, layers, sizes and activations)."""
    if not spec.same_structure(net.layers, layers):
        raise ConfigError(
            f"init_net: its layers ({spec.describe_layers(net.layers)}) are not the config's "
            f"({spec.describe_layers(layers)}); load a net trained with the same inputs and layers"
        )
    with torch.no_grad():
        for lin, (w, b) in zip(module.fc_layers, net.params, strict=True):
            lin.weight.copy_(torch.from_numpy(w).to(lin.weight.dtype))
            lin.bias.copy_(torch.from_numpy(b).to(lin.bias.dtype))
