"""The learner: a deepqlearn-faithful DQN in torch, and the DeepTraffic training protocol.

What is reproduced from convnetjs ``deepqlearn.js`` (engine_spec.md §10, v2 §13) — the behaviour,
not the code:

* **Input** (§10.2): ``[x_t, x_{t−1}, e(a_{t−1}), …, x_{t−tw}, e(a_{t−tw})]`` with ``e(a)`` one-hot
  scaled by **num_states** (not 1). During the first ``tw`` decisions of the brain's life no input
  is built and the action is a warm-up action: uniformly random in v1, **always 0** in v2 (the v2
  ``deepqlearn.js`` computes ``⌊nextFloat()⌋·5``).
* **Action** (§10.3): ``ε = min(1, max(ε_min, 1 − (age − burnin)/(total − burnin)))`` while learning
  (``epsilon_test_time`` otherwise); ``rf`` is drawn at every decision, even when ε = 0; if
  ``rf < ε`` a uniformly random action, else the greedy ``argmax_a Q`` (ties → lowest index).
* **Storage** (§10.4): ``backward(r)`` runs before ``forward(x)`` inside ``learn``, so the stored
  transition is ``(S_{t−2}, A_{t−2}, R_{t−1}, S_{t−1})`` — correctly aligned, one decision late.
  Quirks kept on purpose: the first reward of every run covers a single frame (≈ −2.9, "bogus"),
  and the transition that spans a run boundary (reset) is stored like any other — there are no
  terminal flags. The replay memory appends until ``experience_size`` entries, then overwrites a
  **uniformly random slot** (not FIFO).
* **Learning** starts when the memory holds **more than** ``start_learn_threshold`` entries; then
  every ``backward`` does exactly **one** update on ``batch_size`` samples drawn with replacement:
  target ``y = r + γ·max_a Q(s₁, a)`` from the **same online network** (no target network, no
  terminal handling), loss ``½(Q(s₀)_{a₀} − y)²`` on the taken action only; gradients summed over the
  batch with the pre-update weights (s₀ in training mode, s₁ in prediction mode — they differ only
  for dropout).
* **Update** (§10.5, §10.9): per weight ``g = (l2·l2_mul·w + l1·l1_mul·sign(w) + dw)/batch_size``
  (``l2_mul`` 1 for fc weights, 0 for biases; ``l1_mul`` 0 unless a layer sets it, ``sign(0) = −1``);
  sgd ``w −= lr·g`` or, with momentum, ``v = μv − lr·g; w += v``; adagrad / windowgrad / adadelta /
  nesterov as convnetjs computes them. Implemented by hand with ``torch._foreach_*`` (not
  ``torch.optim``, whose momentum/decay conventions differ).
* **Initialisation**: fc weights ~ N(0, √(1/fan_in)), biases ``bias_pref`` (0.1 for relu fc layers,
  else 0) — from the run's own torch generator (original stream: convnetjs's polar-method
  Gaussians from ``Math.random``).
* Divergence: convnetjs lets Q-values run to NaN. Here training stops at the first non-finite
  greedy Q-value or sampled loss: ``learn`` raises ``DivergedError``; ``train`` records it
  (``TrainResult.diverged``, ``diverged_reason``) and returns the net as it was.

Randomness of the original (``train(…, stream="original")``): the original learner draws from
``Math.random`` (shared with v1's traffic; in v2 also feeding the training-mode seeds) — the
weight-initialisation Gaussians, and per decision the replacement slot, the replay indices, ``rf``,
the random actions and the discarded Gaussians of every ``new Vol`` (spec §10.6).
``js_learner.OriginalStream`` supplies exactly those draws in that order, so in float64 this learner
makes the original's decisions and ends its runs with the original's scores (learner_scores*.json,
``tests/test_js_learner.py``). The default
(``stream="independent"``) uses independent seeded generators and no Vol draws: ~25 % faster,
the same learner statistically.

Training protocol (``train``; train.js / train_webworker.js, spec §9, v2 §12): one world,
``⌈numRuns⌉`` runs of ``⌈totalFrames/numRuns⌉`` frames (``config.schedule``), the brain persisting
across runs. In v2 with ``other_agents > 0`` the agents act as the original's frozen brain copies
do during training (v2 §8.3): action 0 while the ego has made ≤ tw decisions (the load-time copies'
warm-up), then uniformly random (the copies keep ``age = tw + 1``, so their ε is 1 for any
burnin > tw + 1; for burnin ≤ tw + 1 they act greedily with probability 1 − ε on a frozen snapshot,
as the copies would). The simulator applies the shared-action rules itself.

Randomness (independent stream): everything derives from ``np.random.SeedSequence(seed)`` — a numpy
generator for the learner's draws, one for the agents, a torch generator for initialisation and
dropout masks, and the simulator's ``Math.random`` state; no global RNG is touched.

Parity with the JS learner (``bench/learner_parity.py``; network_basic, seeds 1–8, evaluated like
learner_scores*.json): with the original stream in float64, the same 8 runs as the original in
both engines (v1 median 70.41, 1 collapsed; v2 66.30, none); v1 in float32 the runs follow the
original's for a while and then part (median 70.89, none collapsed); independent stream, v2:
median 66.20, no collapsed seed. The
original itself (the replica over seeds 1–93) has a median of 69.4 with 6 of 93 seeds collapsed;
the independent-stream learner gives 68.8 (float32) / 69.1 (float64) over 56 seeds.

Speed: one decision = one simulator call + one ``learn`` call. The batch update is a hand-written
forward/backward over preallocated buffers (``_Kernel``; the s₀ and s₁ halves of the batch go
through the net as one 2B-row matrix), the greedy action uses numpy views of the same parameter
memory (cheaper than torch dispatch for one row), scalar draws come from pre-drawn blocks, and
the simulator is stepped through its compiled ``advance_one`` directly.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import numba
import numpy as np
import torch

from autotune.convnet import spec, torch_bridge
from autotune.learner.config import NUM_ACTIONS, ConfigError, TrainConfig
from autotune.learner.js_learner import OriginalStream
from autotune.runtime import process_configured
from sim import engine
from sim.grid import js_max, js_min
from sim.layout import I_RUNS_DONE
from sim.protocols import EvalResult, evaluate
from sim.simulator import Simulator

__all__ = [
    "DeepQLearner",
    "DivergedError",
    "StopTraining",
    "CurvePoint",
    "TrainResult",
    "GreedyPolicy",
    "quick_evaluate",
    "train",
    "js_epsilon",
]

_TORCH_DTYPES = {"float32": torch.float32, "float64": torch.float64}
_NP_DTYPES = {"float32": np.float32, "float64": np.float64}
_BLOCK = 4096  # pre-drawn uniforms per refill
QUICK_EVAL_SEED = 1_000_000  # quick evaluations use custom-protocol seeds far from every official seed


class StopTraining(Exception):
    """Raise from a reporter (or return True from it) to end training early; ``train`` returns normally.

    ``TrainResult.stopped`` is then True and ``stop_reason`` holds the message. Any other exception
    a reporter raises (e.g. ``optuna.TrialPruned``) propagates out of ``train`` unchanged.
    """


class DivergedError(RuntimeError):
    """The network produced a non-finite Q-value or loss; ``train`` catches it into ``TrainResult``."""


def js_epsilon(age: int, burnin: int, total: int, epsilon_min: float) -> float:
    """``min(1, max(ε_min, 1 − (age − burnin)/(total − burnin)))`` with JS arithmetic (x/0 = ±∞, 0/0 = NaN)."""
    num = float(age - burnin)
    den = float(total - burnin)
    if den == 0.0:
        frac = math.nan if num == 0.0 else math.copysign(math.inf, num)
    else:
        frac = num / den
    return js_min(1.0, js_max(epsilon_min, 1.0 - frac))


# --------------------------------------------------------------------------------------------
# network construction
# --------------------------------------------------------------------------------------------


def build_network(config: TrainConfig, generator: torch.Generator) -> tuple[Any, tuple[spec.Layer, ...]]:
    """The convnetjs net of ``config`` as a ``torch_bridge.ConvNetModule`` with convnetjs initialisation."""
    layers = config.expanded_layers
    dtype = _TORCH_DTYPES[config.dtype]
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


class _Kernel:
    """Preallocated batch machinery: sample rows → fused forward → TD error → backward → update."""

    def __init__(self, config: TrainConfig, module: Any, layers: tuple, gen: torch.Generator) -> None:
        B = config.batch_size
        dtype = _TORCH_DTYPES[config.dtype]
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
        if self.blocked:
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


def _numpy_forward_ops(module: Any, layers: tuple, np_dtype: Any) -> list[Callable[[np.ndarray], np.ndarray]]:
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


# --------------------------------------------------------------------------------------------
# the brain
# --------------------------------------------------------------------------------------------


class DeepQLearner:
    """A deepqlearn ``Brain`` (learning on): ``learn(state, reward) -> action`` per ego decision.

    ``learn`` = ``backward(reward)`` then ``forward(state)``, exactly as DeepTraffic's template.
    Counters as in deepqlearn: ``age`` (backward calls while learning), ``forward_passes``,
    ``epsilon`` (of the latest decision); plus ``updates`` (batch updates made).
    """

    def __init__(
        self, config: TrainConfig, seed: int | np.random.SeedSequence = 0, stream: OriginalStream | None = None
    ) -> None:
        ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(int(seed))
        s_rng, s_torch = ss.spawn(2)
        self.config = config
        self.rng = np.random.default_rng(s_rng)
        self.torch_gen = torch.Generator().manual_seed(int(s_torch.generate_state(1, np.uint64)[0] >> 1))
        self.module, self.layers = build_network(config, self.torch_gen)
        self._stream = stream
        if stream is not None:  # the original's draws: weights, slots, indices, rf, actions, Vol Gaussians
            shapes = [tuple(lin.weight.shape) for lin in self.module.fc_layers]
            with torch.no_grad():
                for lin, w in zip(self.module.fc_layers, stream.init_weights(shapes), strict=True):
                    lin.weight.data.copy_(torch.from_numpy(w))
            self._uniform = stream.uniform  # type: ignore[method-assign]
        self.kernel = _Kernel(config, self.module, self.layers, self.torch_gen)
        self._np_ops = _numpy_forward_ops(self.module, self.layers, _NP_DTYPES[config.dtype])
        np_dtype = _NP_DTYPES[config.dtype]
        tdtype = _TORCH_DTYPES[config.dtype]
        S = config.num_states
        tw = config.temporal_window
        D = config.net_inputs
        self.num_states = S
        self.tw = tw
        self.v2 = config.ruleset == "v2"
        # replay memory: SS[0] = s₀ rows, SS[1] = s₁ rows; OH = one-hot(a₀); R = r₀
        size = config.experience_size
        self.SS = torch.zeros(2, size, D, dtype=tdtype)
        self.OH = torch.zeros(size, NUM_ACTIONS, dtype=tdtype)
        self.R = torch.zeros(size, dtype=tdtype)
        self._SS = self.SS.numpy()
        self._OH = self.OH.numpy()
        self._R = self.R.numpy()
        self.experience_size = size
        self.n_exp = 0
        B = config.batch_size
        self._idx = np.zeros(B, dtype=np.int64)
        self._idx_t = torch.from_numpy(self._idx)
        self._iblock = np.zeros((0, B), dtype=np.int64)
        self._ib = 0
        # windows: the two latest net inputs (net_window[n−1], [n−2]), actions, rewards; tw history
        self._inputs = [np.zeros(D, dtype=np_dtype), np.zeros(D, dtype=np_dtype)]
        self._cur = 0  # index of the latest input (S_{t−1} before forward)
        self._a1 = 0  # A_{t−1}
        self._a2 = 0  # A_{t−2}
        self._r1 = math.nan  # latest reward (reward_window[n−1])
        self._hist = np.zeros(tw * (S + NUM_ACTIONS), dtype=np_dtype)
        self._onehot_value = float(S)
        # counters and schedule
        self.age = 0
        self.forward_passes = 0
        self.updates = 0
        self.epsilon = 1.0
        self.learning = True
        self._burnin = config.learning_steps_burnin
        self._total = config.learning_steps_total
        self._eps_min = config.epsilon_min
        self._start = config.start_learn_threshold
        self._u: list[float] = []
        self._ui = 0
        # statistics
        self.loss_every = 16
        self._loss_sum = 0.0
        self._loss_n = 0
        self._reward_sum = 0.0
        self._reward_n = 0
        self.last_q: np.ndarray | None = None

    # -- draws ----------------------------------------------------------------------------------
    def _uniform(self) -> float:
        i = self._ui
        if i >= len(self._u):
            self._u = self.rng.random(_BLOCK).tolist()
            i = 0
        self._ui = i + 1
        return self._u[i]

    def _sample_indices(self) -> None:
        n = self.n_exp
        if self._stream is not None:
            self._stream.batch_indices(n, self.config.net_inputs, self._idx)
        elif n == self.experience_size:  # full memory: indices pre-drawn in blocks
            j = self._ib
            if j >= self._iblock.shape[0]:
                self._iblock = self.rng.integers(0, n, size=(256, self.kernel.B))
                j = 0
            self._idx[:] = self._iblock[j]
            self._ib = j + 1
        else:
            self._idx[:] = self.rng.integers(0, n, size=self.kernel.B)

    # -- the decision ----------------------------------------------------------------------------
    def learn(self, state: np.ndarray, reward: float) -> int:
        """``brain.backward(reward); return brain.forward(state)`` (DeepTraffic's ``learn``)."""
        # ---- backward(reward) ----
        r_prev = self._r1  # reward_window[n−2] after the push below
        self._r1 = reward
        self._reward_sum += reward
        self._reward_n += 1
        tw = self.tw
        if self.learning:
            self.age += 1
            if self.forward_passes > tw + 1:
                # (S_{t−2}, A_{t−2}, R_{t−1}, S_{t−1}); no terminal flag even across a reset
                n = self.n_exp
                if n < self.experience_size:
                    slot = n
                    self.n_exp = n + 1
                else:
                    slot = int(self.experience_size * self._uniform())  # random replacement
                cur = self._cur
                SS = self._SS
                SS[0, slot] = self._inputs[1 - cur]
                SS[1, slot] = self._inputs[cur]
                oh = self._OH[slot]
                oh[:] = 0.0
                oh[self._a2] = 1.0
                self._R[slot] = r_prev
            if self.n_exp > self._start:
                self._sample_indices()
                self.kernel.step(self.SS, self.OH, self.R, self._idx_t)
                self.updates += 1
                if self.updates % self.loss_every == 0:
                    loss = self.kernel.loss()
                    if not math.isfinite(loss):
                        raise DivergedError(f"loss became {loss} at update {self.updates} (decision {self.age})")
                    self._loss_sum += loss
                    self._loss_n += 1
        # ---- forward(state) ----
        fp = self.forward_passes + 1
        self.forward_passes = fp
        nxt = 1 - self._cur
        if fp > tw:
            x = self._inputs[nxt]
            S = self.num_states
            x[:S] = state
            if tw:
                x[S:] = self._hist
            if self.learning:
                num = self.age - self._burnin
                den = self._total - self._burnin
                if den != 0:
                    eps = 1.0 - num / den
                    eps = self._eps_min if eps < self._eps_min else eps
                    self.epsilon = 1.0 if eps > 1.0 else eps
                else:
                    self.epsilon = js_epsilon(self.age, self._burnin, self._total, self._eps_min)
            else:
                self.epsilon = self.config.epsilon_test_time
            rf = self._uniform()  # drawn even when ε = 0
            if rf < self.epsilon:
                action = int(5.0 * self._uniform())
            else:
                if self._stream is not None:
                    self._stream.vol(self.config.net_inputs)  # policy() allocates a random Vol first
                h = x
                for op in self._np_ops:
                    h = op(h)
                action = int(h.argmax())
                if not math.isfinite(h[action]):
                    self.last_q = h.copy()
                    raise DivergedError(f"Q-values became non-finite {h.tolist()} at decision {fp}")
        else:
            # warm-up: no input (net_window gets [], never stored); v2 returns ⌊nextFloat()⌋·5 = 0
            action = 0 if self.v2 else int(5.0 * self._uniform())
        self._cur = nxt
        self._a2 = self._a1
        self._a1 = action
        if tw:
            S = self.num_states
            step = S + NUM_ACTIONS
            hist = self._hist
            hist[step:] = hist[:-step].copy()
            hist[:S] = state
            hist[S:step] = 0.0
            hist[S + action] = self._onehot_value
        return action

    # -- evaluation helpers ------------------------------------------------------------------------
    def q_values(self, net_input: np.ndarray) -> np.ndarray:
        """Prediction-mode Q-values of one full net input (copy)."""
        h = np.array(net_input, dtype=self._inputs[0].dtype)
        for op in self._np_ops:
            h = op(h)
        return np.array(h, copy=True)

    def take_stats(self) -> tuple[float, float]:
        """(mean reward, mean sampled loss) since the previous call (NaN when none)."""
        r = self._reward_sum / self._reward_n if self._reward_n else math.nan
        loss = self._loss_sum / self._loss_n if self._loss_n else math.nan
        self._reward_sum = self._loss_sum = 0.0
        self._reward_n = self._loss_n = 0
        return r, loss


# --------------------------------------------------------------------------------------------
# batched greedy policy (quick evaluation of the current network)
# --------------------------------------------------------------------------------------------


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


class GreedyPolicy:
    """A network as a batched simulator policy: per-(world, car) temporal windows, ε_test, warm-up.

    Each (world, car) behaves like a fresh evaluation-time brain (``learning = false``): its first
    ``tw`` decisions are warm-up actions (v1 random, v2 0), then ``rf < epsilon_test_time`` gives a
    random action, else greedy. Used for the quick scores during training; the exact, draw-for-draw
    evaluation of a trained net is ``autotune.learner.brain_policy``.
    """

    def __init__(self, module: Any, config: TrainConfig, rng: np.random.Generator | None = None) -> None:
        self.module = module
        self.config = config
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.dtype = next(module.parameters()).dtype
        self.tw = config.temporal_window
        self.S = config.num_states
        self.stateful = self.tw > 0
        self.name = f"greedy[{config.hidden or 'linear'}]"
        self._slots = 1 + config.other_agents
        self._hist = np.zeros((0, self.tw * (self.S + NUM_ACTIONS)))
        self._fp = np.zeros(0, dtype=np.int64)

    def _grow(self, n: int) -> None:
        if n > self._fp.shape[0]:
            hist = np.zeros((n, self._hist.shape[1]))
            hist[: self._hist.shape[0]] = self._hist
            fp = np.zeros(n, dtype=np.int64)
            fp[: self._fp.shape[0]] = self._fp
            self._hist, self._fp = hist, fp

    def __call__(self, obs: Any) -> np.ndarray:
        n = len(obs)
        if n == 0:
            return np.zeros(0, dtype=np.int64)
        tw, S = self.tw, self.S
        slots = np.asarray(obs.world, dtype=np.int64) * self._slots + np.asarray(obs.car, dtype=np.int64)
        self._grow(int(slots.max()) + 1)
        self._fp[slots] += 1
        fp = self._fp[slots]
        x = obs.inputs if tw == 0 else np.concatenate([obs.inputs, self._hist[slots]], axis=1)
        with torch.inference_mode():
            q = self.module(torch.from_numpy(np.ascontiguousarray(x)).to(self.dtype)).double().numpy()
        actions = js_argmax_rows(q)
        eps = self.config.epsilon_test_time
        if eps > 0:
            explore = self.rng.random(n) < eps
            actions[explore] = (5.0 * self.rng.random(int(explore.sum()))).astype(np.int64)
        warm = fp <= tw
        if warm.any():
            actions[warm] = (
                0 if self.config.ruleset == "v2" else (5.0 * self.rng.random(int(warm.sum()))).astype(np.int64)
            )
        if tw:
            step = S + NUM_ACTIONS
            h = self._hist[slots]
            h[:, step:] = h[:, :-step]
            h[:, :S] = obs.inputs
            h[:, S:step] = 0.0
            h[np.arange(n), S + actions] = float(S)
            self._hist[slots] = h
        return actions


def quick_evaluate(
    module: Any,
    config: TrainConfig,
    runs: int = 20,
    frames: int = 2000,
    seed: int = QUICK_EVAL_SEED,
    rng: np.random.Generator | None = None,
) -> EvalResult:
    """Short custom-protocol evaluation (``runs`` independent worlds × ``frames``) of the greedy net."""
    policy = GreedyPolicy(module, config, rng)
    # One numba thread: a 20-world batch is too small to amortise the parallel region's barriers,
    # which become very slow when the other cores are busy (e.g. parallel trials).
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        return evaluate(config.engine_config, policy, "custom", seed=seed, runs=runs, frames=frames)
    finally:
        numba.set_num_threads(old)


# --------------------------------------------------------------------------------------------
# training protocol
# --------------------------------------------------------------------------------------------


class _Stepper:
    """One simulator world stepped decision by decision through the compiled ``advance_one``.

    Same trajectory as ``Simulator.start``/``step`` (see tests) without building an ``Observation``
    per decision; falls back to the public API if the simulator's internals ever change.
    """

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        try:
            self.args = (
                sim.cars, sim.grid, sim.fs, sim.ints, sim.mrand, sim.cfg, sim._actions,
                sim._obs, sim._obs_car, sim._obs_reward, sim.scores, sim.ego_scores, sim.run_seeds,
            )  # fmt: skip
            self.inputs = sim._obs[0]
            self._car = sim._obs_car
            self._reward = sim._obs_reward
            self._actions = sim._actions
            self.fast = True
        except AttributeError:  # pragma: no cover - public fallback
            self.fast = False
        self._obs: Any = None

    def start(self) -> int:
        if not self.fast:  # pragma: no cover
            self._obs = self.sim.start()
            return self._public()
        if not self.sim._seeded:
            raise RuntimeError("seed the simulator before training")
        self.sim._pending = np.zeros(1, dtype=np.int64)
        engine.advance_one(*self.args)
        return int(self._car[0])

    def step(self, action: int) -> int:
        if not self.fast:  # pragma: no cover
            self._obs = self.sim.step(np.array([action], dtype=np.int64))
            return self._public()
        self._actions[0] = action
        engine.advance_one(*self.args)
        return int(self._car[0])

    @property
    def reward(self) -> float:
        return float(self._reward[0]) if self.fast else float(self._obs.reward[0])

    def _public(self) -> int:  # pragma: no cover
        if self._obs is None:
            return -1
        self.inputs = self._obs.inputs[0]
        return int(self._obs.car[0])


class CurvePoint(NamedTuple):
    """One learning-curve point (reported every ``1/report_points`` of training)."""

    frames: int
    """Training frames simulated so far."""
    quick_score: float | None
    """Mean run score (mph) of the quick evaluation of the greedy net (None when disabled)."""
    mean_reward: float
    """Mean ego reward per decision since the previous point ((mph̄ − 40)·0.075 per interval)."""
    loss: float
    """Mean sampled TD loss ½(Q − y)² since the previous point (NaN before learning starts)."""
    decisions: int
    """Ego decisions so far (= brain age)."""
    epsilon: float
    """ε of the latest decision."""
    wall_seconds: float
    """Wall time since training started (quick evaluations included)."""


@dataclasses.dataclass
class TrainResult:
    """What ``train`` returns. ``module`` is the trained ``torch_bridge.ConvNetModule`` (eval mode)."""

    config: TrainConfig
    seed: int
    module: Any
    layers: tuple
    curve: list[CurvePoint]
    frames: int
    """Frames simulated (all runs, partial last run included)."""
    decisions: int
    """Ego decisions (learn calls)."""
    agent_decisions: int
    updates: int
    """Batch updates made (one per decision once learning started)."""
    wall_seconds: float
    train_seconds: float
    """Wall time without the quick evaluations."""
    train_cpu_seconds: float
    """Process CPU time without the quick evaluations (robust to a busy machine; single-threaded run)."""
    runs_completed: int
    training_run_scores: list[float]
    """Scores of the completed training runs (what train.js's doEvalRun computes)."""
    final_epsilon: float
    experience_size_final: int
    final_gauss_cache: int | None = None
    """``stream="original"``: convnetjs's Gaussian cache flag at the end (what a brain built next in the
    same process starts from); None otherwise."""
    diverged: bool = False
    diverged_reason: str | None = None
    stopped: bool = False
    stop_reason: str | None = None

    @property
    def iterations_per_second(self) -> float:
        """Training throughput in trainIterations (ego decisions) per second, quick evaluations excluded."""
        return self.decisions / self.train_seconds if self.train_seconds > 0 else math.inf

    @property
    def frames_per_second(self) -> float:
        return self.frames / self.train_seconds if self.train_seconds > 0 else math.inf

    def convnet(self) -> spec.ConvNet:
        """The trained net as a float64 ``ConvNet`` (for export and exact evaluation)."""
        return torch_bridge.from_torch(self.module, self.layers)

    def summary(self) -> dict[str, Any]:
        """JSON-ready counters and status (no weights, no curve)."""
        return {
            "seed": self.seed,
            "frames": self.frames,
            "decisions": self.decisions,
            "agent_decisions": self.agent_decisions,
            "updates": self.updates,
            "wall_seconds": self.wall_seconds,
            "train_seconds": self.train_seconds,
            "train_cpu_seconds": self.train_cpu_seconds,
            "iterations_per_second": self.iterations_per_second,
            "frames_per_second": self.frames_per_second,
            "runs_completed": self.runs_completed,
            "training_run_scores": self.training_run_scores,
            "final_epsilon": self.final_epsilon,
            "experience_size_final": self.experience_size_final,
            "final_gauss_cache": self.final_gauss_cache,
            "diverged": self.diverged,
            "diverged_reason": self.diverged_reason,
            "stopped": self.stopped,
            "stop_reason": self.stop_reason,
        }


Reporter = Callable[[int, int, float], Any]
"""``reporter(step_index, frames_done, quick_score)`` → truthy to stop (or raise ``StopTraining``)."""


def _seed_material(seed: int) -> tuple[np.random.SeedSequence, np.random.SeedSequence, int, np.random.SeedSequence]:
    ss = np.random.SeedSequence(int(seed))
    s_brain, s_agents, s_sim, s_eval = ss.spawn(4)
    sim_state = int(s_sim.generate_state(1, np.uint32)[0])
    return s_brain, s_agents, sim_state, s_eval


def train(
    config: TrainConfig,
    seed: int,
    reporter: Reporter | None = None,
    *,
    report_points: int = 10,
    quick_eval: bool = True,
    quick_eval_runs: int = 20,
    quick_eval_frames: int = 2000,
    quick_eval_seed: int = QUICK_EVAL_SEED,
    progress: Callable[[int, int], None] | None = None,
    torch_threads: int | None = None,
    stream: str = "independent",
) -> TrainResult:
    """Train ``config`` with the DeepTraffic training protocol from ``seed``.

    ``stream``: ``"independent"`` (default) derives the engine's ``Math.random`` state, the
    learner's draws and the initialisation from ``np.random.SeedSequence(seed)``;
    ``"original"`` is the original harness's randomness: ``Math.random := mulberry32(seed)``, the
    weights drawn from it by convnetjs's Gaussian routine, then every learner draw from that one
    stream (``js_learner.OriginalStream``) — in v1 (train.js) shared with the traffic, in v2 (the
    training worker) after the engine load and the training-mode seeding, whose Park–Miller run
    seeds it also provides. With ``dtype="float64"`` that reproduces the original's training runs
    (learner_scores*.json); dropout masks, if any, still come from torch's generator.

    Every ``1/report_points`` of the ego decisions a ``CurvePoint`` is recorded — with a quick score
    (``quick_evaluate``: ``quick_eval_runs`` × ``quick_eval_frames`` custom-protocol runs of the
    current greedy net, seeds ``quick_eval_seed + i``, the same for every trial) unless
    ``quick_eval`` is False — and ``reporter(k, frames_done, quick_score)`` is called with
    k = 0 … report_points − 1. The reporter stops training by returning True or raising
    ``StopTraining``; other exceptions propagate. A diverging net (non-finite Q or loss) ends
    training with ``result.diverged`` set. ``progress(frames_done, total_frames)`` is called about
    every 1 % (for progress bars).

    Process settings: after ``autotune.configure_process`` (the CLI, a worker) ``train`` leaves
    torch's threads and denormal flushing as the process set them. ``torch_threads`` (or a process
    nobody configured, then with 1 thread) sets them for this call only: that many intra-op
    threads and denormal flushing on, both restored afterwards.
    """
    if reporter is not None and not quick_eval:
        raise ValueError("reporter: needs quick_eval=True (the reporter receives the quick score)")
    if report_points < 1:
        raise ValueError(f"report_points: must be ≥ 1, got {report_points}")
    if stream not in ("independent", "original"):
        raise ConfigError(f"stream: '{stream}' is not a stream; use independent or original")
    s_brain, s_agents, sim_state, s_eval = _seed_material(seed)
    original = OriginalStream(seed) if stream == "original" else None
    if torch_threads is None and not process_configured():
        torch_threads = 1
    old_threads = torch.get_num_threads()
    if torch_threads is not None:
        torch.set_num_threads(torch_threads)
        torch.set_flush_denormal(True)  # tiny activations must not hit the slow denormal path (reset to off after)
    try:
        with torch.no_grad():
            return _train(
                config, seed, reporter, report_points, quick_eval, quick_eval_runs, quick_eval_frames,
                quick_eval_seed, progress, s_brain, s_agents, sim_state, s_eval, original,
            )  # fmt: skip
    finally:
        if torch_threads is not None:
            torch.set_num_threads(old_threads)
            torch.set_flush_denormal(False)


def _train(
    config: TrainConfig,
    seed: int,
    reporter: Reporter | None,
    report_points: int,
    quick_eval: bool,
    quick_eval_runs: int,
    quick_eval_frames: int,
    quick_eval_seed: int,
    progress: Callable[[int, int], None] | None,
    s_brain: np.random.SeedSequence,
    s_agents: np.random.SeedSequence,
    sim_state: int,
    s_eval: np.random.SeedSequence,
    original: OriginalStream | None,
) -> TrainResult:
    t0 = time.perf_counter()
    c0 = time.process_time()
    brain = DeepQLearner(config, s_brain, stream=original)
    eval_rng = np.random.default_rng(s_eval)
    runs, frames_per_run = config.schedule
    curve: list[CurvePoint] = []
    eval_seconds = 0.0
    eval_cpu = 0.0
    result: dict[str, Any] = dict(diverged=False, diverged_reason=None, stopped=False, stop_reason=None)
    agent_decisions = 0
    sim: Simulator | None = None
    if runs == 0:
        return _result(config, seed, brain, curve, None, 0, (t0, c0), (eval_seconds, eval_cpu), result)

    sim = Simulator(config.engine_config, 1, frames_per_run, runs)
    start_state = original.state if original is not None else sim_state
    if config.ruleset == "v2":
        # engine load, then training mode: brain.reset_seed and one reset_seed per agent copy existing at load
        sim.seed_training(start_state, brain_draws=1 + min(config.other_agents, 9))
    else:
        sim.seed_stream(start_state)  # train.js: the runs start right after the brain build
    if original is not None:
        original.attach(sim.mrand)
    stepper = _Stepper(sim)
    decisions_per_run = -(-frames_per_run // 30)
    total_decisions = runs * decisions_per_run
    total_frames = runs * frames_per_run
    marks = [max(1, round(total_decisions * (k + 1) / report_points)) for k in range(report_points)]
    progress_every = max(1, total_decisions // 100)
    agents = _TrainingAgents(config, brain, s_agents, original) if config.other_agents > 0 else None

    learn = brain.learn
    step = stepper.step
    inputs = stepper.inputs
    reward_arr = stepper._reward if stepper.fast else None
    decisions = 0
    k_mark = 0
    next_mark = marks[0]
    next_progress = progress_every
    car = stepper.start()
    try:
        while car >= 0:
            if car == 0:
                reward = float(reward_arr[0]) if reward_arr is not None else stepper.reward
                action = learn(inputs if stepper.fast else stepper.inputs, reward)
                decisions += 1
                car = step(action)
                if decisions >= next_mark:
                    te = time.perf_counter()
                    ce = time.process_time()
                    stop = _report(
                        k_mark, brain, sim, config, curve, quick_eval, quick_eval_runs, quick_eval_frames,
                        quick_eval_seed, eval_rng, reporter, t0,
                    )  # fmt: skip
                    eval_seconds += time.perf_counter() - te
                    eval_cpu += time.process_time() - ce
                    k_mark += 1
                    next_mark = marks[k_mark] if k_mark < len(marks) else total_decisions + 1
                    if stop is not None:
                        result["stopped"] = True
                        result["stop_reason"] = stop
                        break
                if progress is not None and decisions >= next_progress:
                    next_progress += progress_every
                    progress(sim.frames_simulated, total_frames)
            else:
                agent_decisions += 1
                car = step(agents.act(car, stepper.inputs if not stepper.fast else inputs))  # type: ignore[union-attr]
    except DivergedError as exc:
        result["diverged"] = True
        result["diverged_reason"] = str(exc)
    if progress is not None:
        progress(sim.frames_simulated, total_frames)
    return _result(config, seed, brain, curve, sim, agent_decisions, (t0, c0), (eval_seconds, eval_cpu), result)


def _report(
    k: int,
    brain: DeepQLearner,
    sim: Simulator,
    config: TrainConfig,
    curve: list[CurvePoint],
    quick_eval: bool,
    runs: int,
    frames: int,
    seed: int,
    rng: np.random.Generator,
    reporter: Reporter | None,
    t0: float,
) -> str | None:
    """Record a curve point, call the reporter; returns a stop reason or None."""
    score: float | None = None
    if quick_eval:
        res = quick_evaluate(brain.module, config, runs=runs, frames=frames, seed=seed, rng=rng)
        score = res.mean
    mean_reward, loss = brain.take_stats()
    frames_done = sim.frames_simulated
    curve.append(
        CurvePoint(
            frames=frames_done,
            quick_score=score,
            mean_reward=mean_reward,
            loss=loss,
            decisions=brain.age,
            epsilon=brain.epsilon,
            wall_seconds=time.perf_counter() - t0,
        )
    )
    if reporter is None:
        return None
    try:
        verdict = reporter(k, frames_done, score)  # type: ignore[arg-type]
    except StopTraining as exc:
        return str(exc) or f"stopped by the reporter at report {k}"
    if verdict:
        return f"stopped by the reporter at report {k} (frames {frames_done})"
    return None


def _result(
    config: TrainConfig,
    seed: int,
    brain: DeepQLearner,
    curve: list[CurvePoint],
    sim: Simulator | None,
    agent_decisions: int,
    starts: tuple[float, float],
    eval_times: tuple[float, float],
    status: dict[str, Any],
) -> TrainResult:
    wall = time.perf_counter() - starts[0]
    cpu = time.process_time() - starts[1]
    brain.module.eval()
    if sim is not None:
        done = int(sim.ints[0, I_RUNS_DONE])
        scores = [float(s) for s in sim.scores[0, :done]]
        frames = sim.frames_simulated
    else:
        done, scores, frames = 0, [], 0
    return TrainResult(
        config=config,
        seed=int(seed),
        module=brain.module,
        layers=brain.layers,
        curve=curve,
        frames=frames,
        decisions=brain.forward_passes,
        agent_decisions=agent_decisions,
        updates=brain.updates,
        wall_seconds=wall,
        train_seconds=max(wall - eval_times[0], 1e-9),
        train_cpu_seconds=max(cpu - eval_times[1], 1e-9),
        runs_completed=done,
        training_run_scores=scores,
        final_epsilon=brain.epsilon,
        experience_size_final=brain.n_exp,
        final_gauss_cache=int(brain._stream.cache[0]) if brain._stream is not None else None,
        **status,
    )


class _TrainingAgents:
    """The v2 agents during training: frozen brain copies that never learn (spec v2 §8.3).

    Before the ego has made more than tw decisions the load-time copies are in their warm-up
    (action 0, v2 §13). The copy taken then has ``age = tw + 1``, so its ε is
    ``min(1, max(ε_min, 1 − (tw + 1 − burnin)/(total − burnin)))`` — 1 for every burnin > tw + 1:
    uniformly random actions. With a smaller burnin the copies act greedily with probability 1 − ε,
    on the network frozen at that moment, each with its own temporal window.
    """

    def __init__(
        self,
        config: TrainConfig,
        brain: DeepQLearner,
        seed: np.random.SeedSequence,
        stream: OriginalStream | None = None,
    ) -> None:
        self.config = config
        self.brain = brain
        self.rng = np.random.default_rng(seed)
        self._u: list[float] = []
        self._ui = 0
        self._stream = stream
        if stream is not None:  # the copies draw from the same Math.random as everything else
            self._uniform = stream.uniform  # type: ignore[method-assign]
        self.tw = config.temporal_window
        self.epsilon = js_epsilon(
            self.tw + 1, config.learning_steps_burnin, config.learning_steps_total, config.epsilon_min
        )
        self.frozen: Any = None
        self._hist: np.ndarray | None = None

    def _uniform(self) -> float:
        i = self._ui
        if i >= len(self._u):
            self._u = self.rng.random(_BLOCK).tolist()
            i = 0
        self._ui = i + 1
        return self._u[i]

    def act(self, car: int, inputs: np.ndarray) -> int:
        if self.brain.forward_passes <= self.tw:
            return 0  # load-time copies, warm-up branch
        rf = self._uniform()
        if rf < self.epsilon:  # always when ε = 1
            return int(5.0 * self._uniform())
        return self._greedy(car, inputs)

    def _greedy(self, car: int, inputs: np.ndarray) -> int:
        brain = self.brain
        S = brain.num_states
        step = S + NUM_ACTIONS
        if self.frozen is None:
            import copy

            dtype = brain._hist.dtype
            self.frozen = _numpy_forward_ops(copy.deepcopy(brain.module), brain.layers, dtype)
            self._hist = np.tile(brain._hist, (self.config.other_agents + 1, 1))
        hist = self._hist[car]  # type: ignore[index]
        x = np.concatenate([np.asarray(inputs, dtype=hist.dtype), hist])
        if self._stream is not None:
            self._stream.vol(self.config.net_inputs)
        h = x
        for op in self.frozen:
            h = op(h)
        action = int(js_argmax_rows(h[None, :])[0])
        if self.tw:
            hist[step:] = hist[:-step].copy()
            hist[:S] = inputs
            hist[S:step] = 0.0
            hist[S + action] = float(S)
        return action
