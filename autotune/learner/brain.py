"""The brain: a deepqlearn-faithful DQN in torch (``DeepQLearner``: act, store, learn per decision).

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
* **Loaded weights** (``init_net``): the net a DeepTraffic page built and then filled with
  ``brain.value_net.fromJSON(...)`` before training on — the site's way to train a net further. The
  initial draws are made as usual (the run's other draws stay where they were) and replaced by the
  loaded weights and biases; the replay memory and the counters start empty, as in a new ``Brain``.
* Divergence: convnetjs lets Q-values run to NaN. Here training stops at the first non-finite
  greedy Q-value or sampled loss: ``learn`` raises ``DivergedError``; ``train`` records it
  (``TrainResult.diverged``, ``diverged_reason``) and returns the net as it was.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch

from autotune.convnet import spec
from autotune.convnet.deepqlearn import GREEDY, BlockUniform, explore_action, js_epsilon, shift_window, warmup_action
from autotune.learner.config import NUM_ACTIONS, TrainConfig
from autotune.learner.js_learner import OriginalStream
from autotune.learner.kernel import NP_DTYPES, TORCH_DTYPES, Kernel, build_network, load_weights, numpy_forward_ops

__all__ = ["DeepQLearner", "DivergedError"]


class DivergedError(RuntimeError):
    """The network produced a non-finite Q-value or loss; ``train`` catches it into ``TrainResult``."""


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
        self,
        config: TrainConfig,
        seed: int | np.random.SeedSequence = 0,
        stream: OriginalStream | None = None,
        init_net: spec.ConvNet | None = None,
    ) -> None:
        ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(int(seed))
        s_rng, s_torch = ss.spawn(2)
        self.config = config
        self.rng = np.random.default_rng(s_rng)
        self.torch_gen = torch.Generator().manual_seed(int(s_torch.generate_state(1, np.uint64)[0] >> 1))
        self.module, self.layers = build_network(config, self.torch_gen)
        self._stream = stream
        self._uniform: Callable[[], float] = stream.uniform if stream is not None else BlockUniform(self.rng)
        if stream is not None:  # the original's draws: weights, slots, indices, rf, actions, Vol Gaussians
            shapes = [tuple(lin.weight.shape) for lin in self.module.fc_layers]
            with torch.no_grad():
                for lin, w in zip(self.module.fc_layers, stream.init_weights(shapes), strict=True):
                    lin.weight.data.copy_(torch.from_numpy(w))
        if init_net is not None:
            load_weights(self.module, self.layers, init_net)
        self.kernel = Kernel(config, self.module, self.layers, self.torch_gen)
        self._np_ops = numpy_forward_ops(self.module, self.layers, NP_DTYPES[config.dtype])
        np_dtype = NP_DTYPES[config.dtype]
        tdtype = TORCH_DTYPES[config.dtype]
        S = config.num_states
        tw = config.temporal_window
        D = config.net_inputs
        self.num_states = S
        self.tw = tw
        self.v2 = config.ruleset == "v2"
        # replay memory: SS[0] = s₀ rows, SS[1] = s₁ rows; OH = one-hot(a₀); R = r₀
        self._tdtype = tdtype
        self.experience_size = config.experience_size
        self.n_exp = 0
        self.SS: torch.Tensor
        self.OH: torch.Tensor
        self.R: torch.Tensor
        self._alloc(config.replay_rows)  # what the training can fill, not experience_size
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
        # statistics
        self.loss_every = 16
        self._loss_sum = 0.0
        self._loss_n = 0
        self._reward_sum = 0.0
        self._reward_n = 0
        self.last_q: np.ndarray | None = None

    def _alloc(self, rows: int) -> None:
        """(Re)allocate the replay memory with ``rows`` rows, keeping the entries stored so far."""
        D = self.config.net_inputs
        SS = torch.zeros(2, rows, D, dtype=self._tdtype)
        OH = torch.zeros(rows, NUM_ACTIONS, dtype=self._tdtype)
        R = torch.zeros(rows, dtype=self._tdtype)
        n = self.n_exp
        if n:
            SS[:, :n] = self.SS[:, :n]
            OH[:n] = self.OH[:n]
            R[:n] = self.R[:n]
        self.SS, self.OH, self.R = SS, OH, R
        self._SS, self._OH, self._R = SS.numpy(), OH.numpy(), R.numpy()
        self._rows = rows

    # -- draws ----------------------------------------------------------------------------------
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
                    if slot == self._rows:  # more decisions than the schedule's: grow (not in train)
                        self._alloc(min(self.experience_size, 2 * slot))
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
                x[S:] = self._hist  # [x_t, x_{t−1}, e(a_{t−1}), …]
            if self.learning:
                self.epsilon = js_epsilon(self.age, self._burnin, self._total, self._eps_min)
            else:
                self.epsilon = self.config.epsilon_test_time
            action = explore_action(self._uniform, self.epsilon)  # rf drawn even when ε = 0
            if action == GREEDY:
                if self._stream is not None:
                    self._stream.vol(self.config.net_inputs)  # policy() allocates a random Vol first
                h = x
                for op in self._np_ops:
                    h = op(h)
                action = int(h.argmax())  # = the strict-> scan while every Q is finite (checked next)
                if not math.isfinite(h[action]):
                    self.last_q = h.copy()
                    raise DivergedError(f"Q-values became non-finite {h.tolist()} at decision {fp}")
        else:
            # warm-up: no input (net_window gets [], never stored); v2 returns ⌊nextFloat()⌋·5 = 0
            action = warmup_action(self.v2, self._uniform)
        self._cur = nxt
        self._a2 = self._a1
        self._a1 = action
        if tw:
            shift_window(self._hist, state, action, self.num_states)
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
