"""The original deepqlearn training run, replicated operation by operation (float64, numba).

``autotune.learner`` is the fast learner: torch, float32, its own seeded generators. This module
is its reference: the convnetjs ``deepqlearn`` brain and ``SGDTrainer`` exactly as the original
harnesses run them (v1 ``train.js``: engine_spec.md §9, §10; v2 training worker: engine_spec_v2.md
§12, §13), taking every learner draw from ``Math.random`` in the original's order, so that a
training run here is the *same* run as the original's — same weights, same training-run scores,
same count of random draws — and ``learner_scores*.json`` can be checked to the digit rather than
statistically. What makes that possible (spec §10.6):

* every ``new Vol(1, 1, n)`` draws ``n`` Gaussians (Marsaglia polar method, 2 uniforms per
  attempt, one global cached value) even when its values are overwritten at once; ``policy()``
  allocates one per call, and every training sample allocates one for s₀. Only the *count* of
  those draws and the cache flag matter, so they are skipped without computing logarithms
  (``gauss_skip``, the replica's own copy); the weight initialisation needs the values
  (``_init_weights``: ``u·√(−2 ln r / r)``, the cached ``v·√(…)`` next);
* sums run in convnetjs's order with no fused multiply-add and no re-association: fc
  ``a = 0; a += x_d·w_id; a += b_i``; backward ``dx_d += w_id·g_i`` and ``dw_id += x_d·g_i`` per
  sample, over the batch in sample order; the update ``g = (l2·w + l1·sign(w) + dw)/B`` then
  ``w += −lr·g`` (or the momentum step);
* the draw order of one ``learn(state, r)`` = ``backward(r)`` then ``forward(state)``:
  replacement slot ``⌊size·u⌋`` (memory full), then per sample ``⌊len·u⌋``, the s₀ Vol, the s₁
  ``policy()`` Vol; then ``rf``, and either ``⌊5u⌋`` or the greedy ``policy()`` Vol.

In v1 the traffic draws from the same stream; in v2 ``Math.random`` only feeds the engine load,
the training-mode seeds of the Park–Miller traffic generators and the learner (v2 §2, §12), and
the warm-up action is 0 without a draw (v2 §13).

Scope: v1 and v2 without other agents, fc layers with relu / tanh / sigmoid / no activation ending
in the regression output, the sgd trainer with or without momentum — the templates of spec §10.8
and every ``learner_scores*.json`` configuration. ``train_exact`` raises ``ConfigError`` naming
the field for anything else. It is single-threaded and has no reporter: it is for verification
(``tests/test_js_learner.py``, ``bench/learner_parity.py --learner exact``), not for search.
``OriginalStream`` gives the torch learner the same draws (``learner.train(…, stream="original")``).

Harness (learner_scores.json ``protocol.training``): ``Math.random := mulberry32(seed)``; the brain
is built (weight draws); v1: ``doEvalRun(⌈numRuns⌉, ⌈frames⌉)`` with learning on, then its
trailing ``reset()`` (60 draws). **No engine-construction draws** come between the build and the
first v1 run: the harness's engine existed before ``Math.random`` was seeded. The recorded data
decide this (with the 60 construction draws of evaluate.js no run matches; without them every
training run, every draw count and every evaluation score of learner_scores.json does), and the
same holds for its evaluations (``evaluate_net(…, engine_load=False)``), which also inherit the
training's Gaussian cache flag (same process). v2: the engine load (20 draws), the training-mode
seeding, the runs, the trailing ``reset()`` (20 draws).

The platform's ``log`` / ``exp`` may differ from V8's in the last bit: the initial weights then
differ by one ulp now and then (3 % of values), tanh/sigmoid nets drift at the 1e-13 level. For
relu nets that has not changed a single decision (every learner_scores*.json run reproduces).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from autotune.convnet.random import gauss_skip as fast_gauss_skip
from autotune.convnet.spec import FC, ConvNet, Input, Regression, Relu, Sigmoid, Tanh, fc_bias_prefs
from autotune.learner.config import TrainConfig
from sim import engine
from sim.config import ConfigError
from sim.grid import js_max, js_min
from sim.layout import F_LAST_REWARD, I_DONE, I_FRAME, K_FRAMES
from sim.rng import mrand, mulberry32_advance
from sim.simulator import Simulator

__all__ = ["ExactTrainResult", "OriginalStream", "train_exact", "draws_between"]

ACT_NONE, ACT_RELU, ACT_TANH, ACT_SIGMOID = range(4)
_ACTS = {Relu: ACT_RELU, Tanh: ACT_TANH, Sigmoid: ACT_SIGMOID}

# int64 hyperparameters / counters (``hp``)
(H_TW, H_NS, H_D, H_WINDOW, H_EXP_SIZE, H_START, H_BATCH, H_BURNIN, H_TOTAL, H_AGE,
 H_FP, H_N_EXP, H_HEAD, H_CACHE, H_UPDATES, H_LOSS_N, H_REWARD_N, H_LOSS_I, H_REWARD_I, H_V2) = range(20)  # fmt: skip
N_HP = 20
# float64 hyperparameters / state (``hf``)
(F_GAMMA, F_LR, F_MOMENTUM, F_L2, F_L1, F_EPS_MIN, F_EPSILON, F_LOSS_SUM, F_REWARD_SUM) = range(9)  # fmt: skip
N_HF = 9
RESET_DRAWS = {"v1": 60, "v2": 20}  # Math.random draws of reset(): v1 20 cars × 3, v2 one per car construction
WINDOW_SIZE = 1000  # cnnutil.Window(1000, 10): deepqlearn's average reward / loss windows
WINDOW_MIN = 10
_MUL_INV = pow(0x6D2B79F5, -1, 2**32)  # mulberry32 adds 0x6D2B79F5 per draw


def draws_between(state0: int, state1: int) -> int:
    """Number of mulberry32 draws that lead from ``state0`` to ``state1`` (the state is a counter)."""
    return ((state1 - state0) * _MUL_INV) % 2**32


# --------------------------------------------------------------------------------------------
# Gaussians (convnetjs gaussRandom / randn)
# --------------------------------------------------------------------------------------------


@njit(cache=True, error_model="numpy", inline="always")
def gauss_skip(mr: np.ndarray, w: int, cache: int, n: int) -> int:
    """The replica's own ``n`` discarded ``gaussRandom()`` calls (the fast paths' copy is
    ``autotune.convnet.random.gauss_skip``; tests hold it to this one); returns the new cache flag."""
    if n <= 0:
        return cache
    m = n - 1 if cache != 0 else n  # values still needed after using a cached one
    for _ in range((m + 1) // 2):
        while True:
            u = 2.0 * mrand(mr, w) - 1.0
            v = 2.0 * mrand(mr, w) - 1.0
            r = u * u + v * v
            if r == 0.0 or r > 1.0:
                continue
            break
    return 1 if m % 2 == 1 else 0


@njit(cache=True, error_model="numpy")
def _init_weights(mr: np.ndarray, cache: np.ndarray, lay: np.ndarray, P: np.ndarray) -> None:
    """``new Vol(1, 1, n_in)`` per neuron, layer by layer: ``w = 0 + gaussRandom()·√(1/n_in)``.

    ``cache`` = [flag, cached value] of convnetjs's global polar-method cache, updated in place.
    """
    for li in range(lay.shape[0]):
        n_in = lay[li, 0]
        n_out = lay[li, 1]
        off = lay[li, 2]
        scale = math.sqrt(1.0 / n_in)
        for i in range(n_out):
            for d in range(n_in):
                if cache[0] != 0.0:
                    cache[0] = 0.0
                    g = cache[1]
                else:
                    while True:
                        u = 2.0 * mrand(mr, 0) - 1.0
                        v = 2.0 * mrand(mr, 0) - 1.0
                        r = u * u + v * v
                        if r == 0.0 or r > 1.0:
                            continue
                        break
                    c = math.sqrt(-2.0 * math.log(r) / r)
                    cache[1] = v * c
                    cache[0] = 1.0
                    g = u * c
                P[off + i * n_in + d] = 0.0 + g * scale


@njit(cache=True, error_model="numpy")
def _uniform(mr: np.ndarray) -> float:
    return mrand(mr, 0)


@njit(cache=True, error_model="numpy")
def _batch_indices(mr: np.ndarray, cache: np.ndarray, n: int, D: int, out: np.ndarray) -> None:
    """deepqlearn's per-sample draws: ``⌊n·u⌋``, then the s₀ Vol and the s₁ ``policy()`` Vol (2·D Gaussians).
    The torch learner's draws take the fast skip; the replica's own loop keeps the one-draw-at-a-time copy."""
    for k in range(out.shape[0]):
        out[k] = int(math.floor(mrand(mr, 0) * n))
        cache[0] = fast_gauss_skip(mr, 0, cache[0], D)
        cache[0] = fast_gauss_skip(mr, 0, cache[0], D)


@njit(cache=True, error_model="numpy")
def _vol(mr: np.ndarray, cache: np.ndarray, D: int) -> None:
    cache[0] = fast_gauss_skip(mr, 0, cache[0], D)


class OriginalStream:
    """The original's ``Math.random`` stream as the torch learner's source of draws.

    The original learner draws from ``Math.random := mulberry32(seed)`` (spec §10.6): the weight
    initialisation, the replacement slot, the replay indices, ``rf``, the random actions — and the
    discarded Gaussians of every ``new Vol`` — interleaved with the engine's draws (v1: the
    traffic; v2: the load, the training-mode seeds and the car constructions of every reset).
    ``autotune.learner.DeepQLearner(…, stream=OriginalStream(seed))`` takes every draw from here
    in that order, so with ``dtype="float64"`` the torch learner follows the original's training
    run decision for decision for as long as BLAS's summation order does not flip a greedy choice
    (network_basic, seeds 1–8 of both engines: to the end of training). ``attach`` hands the
    state to the simulator's array once the engine exists, after the weights were drawn.
    """

    def __init__(self, seed: int) -> None:
        self.mr = np.array([int(seed) & 0xFFFFFFFF], dtype=np.int64)
        self.cache = np.zeros(1, dtype=np.int64)  # convnetjs's Gaussian cache flag

    @property
    def state(self) -> int:
        return int(self.mr[0])

    def init_weights(self, shapes: list[tuple[int, int]]) -> list[np.ndarray]:
        """fc weights (out, in) as ``new deepqlearn.Brain`` draws them, layer by layer, neuron by neuron."""
        lay = np.zeros((len(shapes), 4), dtype=np.int64)
        off = 0
        for li, (n_out, n_in) in enumerate(shapes):
            lay[li] = (n_in, n_out, off, ACT_NONE)
            off += n_in * n_out + n_out
        P = np.zeros(off)
        gauss = np.array([float(self.cache[0]), 0.0])
        _init_weights(self.mr, gauss, lay, P)
        self.cache[0] = int(gauss[0] != 0.0)
        return [P[o : o + n_in * n_out].reshape(n_out, n_in).copy() for n_in, n_out, o, _a in lay]

    def attach(self, mr: np.ndarray) -> None:
        """Continue in ``mr``: the simulator's ``Math.random`` array (one world), seeded from ``state``."""
        self.mr = mr

    def uniform(self) -> float:
        return float(_uniform(self.mr))

    def batch_indices(self, n: int, net_inputs: int, out: np.ndarray) -> None:
        _batch_indices(self.mr, self.cache, n, net_inputs, out)

    def vol(self, net_inputs: int) -> None:
        """The Gaussians of a discarded ``new Vol(1, 1, net_inputs)`` (``policy()``'s input Vol)."""
        _vol(self.mr, self.cache, net_inputs)


# --------------------------------------------------------------------------------------------
# the network: fc (+ activation) layers, convnetjs arithmetic
# --------------------------------------------------------------------------------------------
#
# ``lay`` int64 (n_fc, 4): n_in, n_out, offset of the weights in P (row-major (out, in), i.e.
# convnetjs's filters[i].w[d]; the biases follow), activation code. ``Y`` float64
# (n_fc + 1, width): Y[0] the input, Y[l + 1] the output of fc l after its activation.


@njit(cache=True, error_model="numpy", inline="always")
def _forward(lay: np.ndarray, P: np.ndarray, x: np.ndarray, Y: np.ndarray) -> int:
    """Forward ``x`` (training and prediction mode are identical for these layers); returns the last row of Y."""
    n0 = lay[0, 0]
    for d in range(n0):
        Y[0, d] = x[d]
    n_l = lay.shape[0]
    for li in range(n_l):
        n_in = lay[li, 0]
        n_out = lay[li, 1]
        off = lay[li, 2]
        act = lay[li, 3]
        boff = off + n_in * n_out
        for i in range(n_out):
            a = 0.0
            wo = off + i * n_in
            for d in range(n_in):
                a += Y[li, d] * P[wo + d]
            a += P[boff + i]
            if act == ACT_RELU:
                if a < 0.0:
                    a = 0.0
            elif act == ACT_TANH:
                e = math.exp(2.0 * a)
                a = (e - 1.0) / (e + 1.0)
            elif act == ACT_SIGMOID:
                a = 1.0 / (1.0 + math.exp(-a))
            Y[li + 1, i] = a
    return n_l


@njit(cache=True, error_model="numpy", inline="always")
def _backward(lay: np.ndarray, P: np.ndarray, G: np.ndarray, Y: np.ndarray, dA: np.ndarray, dB: np.ndarray) -> None:
    """convnetjs backward from the output gradient in ``dA[:n_out]`` (regression: only the taken action ≠ 0).

    Per fc (from the last): its activation's backward turns d(output) into d(fc output), then
    ``dx_d = Σ_i w_id·g_i`` (i in order, from 0) and ``dw_id += x_d·g_i``, ``db_i += g_i``.
    """
    src = dA
    dst = dB
    for li in range(lay.shape[0] - 1, -1, -1):
        n_in = lay[li, 0]
        n_out = lay[li, 1]
        off = lay[li, 2]
        act = lay[li, 3]
        boff = off + n_in * n_out
        if act == ACT_RELU:
            for i in range(n_out):
                if Y[li + 1, i] <= 0.0:
                    src[i] = 0.0
        elif act == ACT_TANH:
            for i in range(n_out):
                y = Y[li + 1, i]
                src[i] = (1.0 - y * y) * src[i]
        elif act == ACT_SIGMOID:
            for i in range(n_out):
                y = Y[li + 1, i]
                src[i] = y * (1.0 - y) * src[i]
        need_dx = li > 0
        if need_dx:
            for d in range(n_in):
                dst[d] = 0.0
        for i in range(n_out):
            g = src[i]
            wo = off + i * n_in
            if need_dx:
                for d in range(n_in):
                    dst[d] += P[wo + d] * g
            for d in range(n_in):
                G[wo + d] += Y[li, d] * g
            G[boff + i] += g
        tmp = src
        src = dst
        dst = tmp


@njit(cache=True, error_model="numpy", inline="always")
def _policy(lay: np.ndarray, P: np.ndarray, s: np.ndarray, Y: np.ndarray) -> tuple[int, float]:
    """deepqlearn ``policy(s)`` after its Vol allocation: (argmax with strict ``>`` from 0, its value)."""
    k = _forward(lay, P, s, Y)
    best = 0
    val = Y[k, 0]
    for j in range(1, 5):
        if Y[k, j] > val:
            best = j
            val = Y[k, j]
    return best, val


@njit(cache=True, error_model="numpy", inline="always")
def _window_add(win: np.ndarray, hp: np.ndarray, hf: np.ndarray, n_key: int, i_key: int, s_key: int, x: float) -> None:
    """cnnutil.Window.add: push, ``sum += x``, and past 1000 entries ``sum -= shift()``."""
    n = hp[n_key]
    i = hp[i_key]
    hf[s_key] += x
    if n < WINDOW_SIZE:
        win[n] = x
        hp[n_key] = n + 1
    else:
        old = win[i]
        win[i] = x
        hp[i_key] = (i + 1) % WINDOW_SIZE
        hf[s_key] -= old


@njit(cache=True, error_model="numpy")
def _learn(
    state, reward, mr, hp, hf, lay, P, G, M, Y, dA, dB, netw, statew, actw, rewardw, E0, E1, EA, ER, lwin, rwin, xin
):  # noqa: ANN001, ANN202, E501
    """``brain.backward(reward); return brain.forward(state)`` with learning on (spec §10.3, §10.4)."""
    tw = hp[H_TW]
    ns = hp[H_NS]
    D = hp[H_D]
    n = hp[H_WINDOW]
    head = hp[H_HEAD]  # ring position of window index n − 1 (the latest entry)
    # ---- backward(reward) ----
    prev = (head - 1) % n  # window index n − 2
    newest = (head + 1) % n  # the push below overwrites the oldest entry (shift + push)
    rewardw[newest] = reward
    _window_add(rwin, hp, hf, H_REWARD_N, H_REWARD_I, F_REWARD_SUM, reward)
    hp[H_AGE] += 1
    if hp[H_FP] > tw + 1:
        # (net_window[n−2], action_window[n−2], reward_window[n−2], net_window[n−1]) — after the
        # reward push, reward_window[n−2] is the previous call's reward: ring slot ``head``
        n_exp = hp[H_N_EXP]
        if n_exp < hp[H_EXP_SIZE]:
            slot = n_exp
            hp[H_N_EXP] = n_exp + 1
        else:
            slot = int(math.floor(mrand(mr, 0) * hp[H_EXP_SIZE]))
        for d in range(D):
            E0[slot, d] = netw[prev, d]
            E1[slot, d] = netw[head, d]
        EA[slot] = actw[prev]
        ER[slot] = rewardw[head]
    n_exp = hp[H_N_EXP]
    if n_exp > hp[H_START]:
        B = hp[H_BATCH]
        gamma = hf[F_GAMMA]
        avcost = 0.0
        for _k in range(B):
            re = int(math.floor(mrand(mr, 0) * n_exp))
            hp[H_CACHE] = gauss_skip(mr, 0, hp[H_CACHE], D)  # x = new Vol(1, 1, net_inputs)
            hp[H_CACHE] = gauss_skip(mr, 0, hp[H_CACHE], D)  # policy(state1): new Vol
            _a, maxval = _policy(lay, P, E1[re], Y)
            y = ER[re] + gamma * maxval
            k = _forward(lay, P, E0[re], Y)
            n_out = lay[lay.shape[0] - 1, 1]
            for j in range(n_out):
                dA[j] = 0.0
            a0 = EA[re]
            dy = Y[k, a0] - y
            dA[a0] = dy
            cost = 0.5 * dy * dy
            _backward(lay, P, G, Y, dA, dB)
            if _k == B - 1:
                cost = cost + 0.0 + _update(lay, P, G, M, hf, B)  # cost + l1 loss + l2 loss
            avcost += cost
        avcost = avcost / B
        _window_add(lwin, hp, hf, H_LOSS_N, H_LOSS_I, F_LOSS_SUM, avcost)
        hp[H_UPDATES] += 1
    # ---- forward(state) ----
    fp = hp[H_FP] + 1
    hp[H_FP] = fp
    if fp > tw:
        for d in range(ns):
            xin[d] = state[d]
        pos = ns
        for k in range(tw):
            idx = (head - k) % n  # state_window[n−1−k] before this call's push
            for d in range(ns):
                xin[pos + d] = statew[idx, d]
            pos += ns
            a = actw[idx]
            for q in range(5):
                xin[pos + q] = 0.0
            xin[pos + a] = 1.0 * ns
            pos += 5
        age = hp[H_AGE]
        eps = js_min(1.0, js_max(hf[F_EPS_MIN], 1.0 - (age - hp[H_BURNIN]) / (hp[H_TOTAL] - hp[H_BURNIN])))
        hf[F_EPSILON] = eps
        rf = mrand(mr, 0)
        if rf < eps:
            action = int(math.floor(mrand(mr, 0) * 5.0))
        else:
            hp[H_CACHE] = gauss_skip(mr, 0, hp[H_CACHE], D)
            action, _v = _policy(lay, P, xin, Y)
    elif hp[H_V2] != 0:
        action = 0  # v2 warm-up: ⌊nextFloat()⌋·5 from the brain's own generator, no Math.random draw
    else:
        action = int(math.floor(mrand(mr, 0) * 5.0))
    for d in range(D):
        netw[newest, d] = xin[d] if fp > tw else 0.0
    for d in range(ns):
        statew[newest, d] = state[d]
    actw[newest] = action
    hp[H_HEAD] = newest
    return action


@njit(cache=True, error_model="numpy", inline="always")
def _update(lay: np.ndarray, P: np.ndarray, G: np.ndarray, M: np.ndarray, hf: np.ndarray, B: int) -> float:
    """SGDTrainer's update of every parameter set (filters, then biases, per fc); returns the l2 decay loss."""
    l2 = hf[F_L2]
    l1 = hf[F_L1]
    lr = hf[F_LR]
    mom = hf[F_MOMENTUM]
    l2_loss = 0.0
    for li in range(lay.shape[0]):
        n_in = lay[li, 0]
        n_out = lay[li, 1]
        off = lay[li, 2]
        for part in range(2):  # weights (l2_decay_mul 1, l1_decay_mul 0), then biases (both 0)
            if part == 0:
                lo = off
                hi = off + n_in * n_out
                l2d = l2 * 1.0
                l1d = l1 * 0.0
            else:
                lo = off + n_in * n_out
                hi = lo + n_out
                l2d = l2 * 0.0
                l1d = l1 * 0.0
            for j in range(lo, hi):
                p = P[j]
                l2_loss += l2d * p * p / 2.0
                l1grad = l1d * (1.0 if p > 0.0 else -1.0)
                l2grad = l2d * p
                gij = (l2grad + l1grad + G[j]) / B
                if mom > 0.0:
                    dx = mom * M[j] - lr * gij
                    M[j] = dx
                    P[j] = p + dx
                else:
                    P[j] = p + -lr * gij
                G[j] = 0.0
    return l2_loss


@njit(cache=True, error_model="numpy")
def _run(cars, grid, fs, ints, cfg, mr, obs, scores, ego, run_seeds, learn_args):  # noqa: ANN001, ANN202
    """The training doEvalRun: every frame of every run, ``learn`` at the ego's decisions."""
    frames = cfg[K_FRAMES]
    (hp, hf, lay, P, G, M, Y, dA, dB, netw, statew, actw, rewardw, E0, E1, EA, ER, lwin, rwin, xin) = learn_args
    while ints[0, I_DONE] == 0:
        for _ in range(frames - ints[0, I_FRAME]):
            car = engine.frame_pre(cars, grid, fs, ints, mr, cfg, 0)
            action = -1
            if car == 0:
                engine.observe(cars, grid, cfg, 0, car, obs)
                action = _learn(
                    obs, fs[0, F_LAST_REWARD], mr, hp, hf, lay, P, G, M, Y, dA, dB, netw, statew, actw,
                    rewardw, E0, E1, EA, ER, lwin, rwin, xin,
                )  # fmt: skip
            engine.frame_post(cars, grid, fs, ints, cfg, 0, action)
        engine.end_run(cars, fs, ints, mr, cfg, 0, scores, ego, run_seeds)
    return 0


# --------------------------------------------------------------------------------------------
# Python entry point
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass
class ExactTrainResult:
    """A replicated train.js run: the trained net and the original harness's counters."""

    seed: int
    convnet: ConvNet
    training_run_scores: list[float]
    """Scores of the training runs, in run order (doEvalRun's list before its lexicographic sort)."""
    brain_age: int
    forward_passes: int
    updates: int
    final_epsilon: float
    experience_size_final: int
    avg_loss_window: float
    """deepqlearn's ``average_loss_window.get_average()`` at the end (last 1000 batch losses, −1 if < 10)."""
    avg_reward_window: float
    """``average_reward_window.get_average()`` at the end (last 1000 rewards)."""
    random_draws: int
    """``Math.random`` calls from ``mulberry32(seed)`` to the end (build, load, runs, trailing reset)."""
    frames: int
    final_gauss_cache: int
    """convnetjs's Gaussian cache flag at the end: what a brain built next in the same process starts from."""


def _check(config: TrainConfig) -> tuple[np.ndarray, int]:
    if config.method != "sgd":
        raise ConfigError(f"method: the exact replica implements convnetjs's sgd trainer, not '{config.method}'")
    if config.other_agents:
        raise ConfigError("other_agents: the exact replica trains without other agents; use 0")
    layers = config.expanded_layers
    rows: list[list[int]] = []
    off = 0
    for i, layer in enumerate(layers):
        if isinstance(layer, Input):
            continue
        if isinstance(layer, FC):
            if layer.l1_decay_mul != 0.0 or layer.l2_decay_mul != 1.0:
                raise ConfigError(f"layers[{i}]: per-layer decay multipliers are outside the exact replica's scope")
            n_out = layer.num_neurons
            n_in = rows[-1][1] if rows else config.net_inputs
            rows.append([n_in, n_out, off, ACT_NONE])
            off += n_in * n_out + n_out
        elif type(layer) in _ACTS and rows and rows[-1][3] == ACT_NONE:
            rows[-1][3] = _ACTS[type(layer)]
        elif isinstance(layer, Regression) and i == len(layers) - 1:
            continue
        else:
            raise ConfigError(
                f"layers[{i}]: {type(layer).__name__} is outside the exact replica's scope "
                "(fc layers with relu/tanh/sigmoid and the regression output)"
            )
    if not rows or rows[-1][1] != 5 or rows[-1][3] != ACT_NONE:
        raise ConfigError("layers: the net must end in the 5-output regression layer")
    return np.array(rows, dtype=np.int64), off


def train_exact(config: TrainConfig, seed: int) -> ExactTrainResult:
    """Run train.js for ``config`` from ``Math.random := mulberry32(seed)``, exactly as the original does."""
    lay, n_params = _check(config)
    seed32 = int(seed) & 0xFFFFFFFF
    mr = np.array([seed32], dtype=np.int64)
    cache = np.zeros(2)
    P = np.zeros(n_params)
    for li, pref in enumerate(fc_bias_prefs(config.expanded_layers)):  # 0.1 for relu fc layers, else 0
        n_in, n_out, off, _act = (int(v) for v in lay[li])
        P[off + n_in * n_out : off + n_in * n_out + n_out] = pref
    _init_weights(mr, cache, lay, P)
    runs, frames = config.schedule
    width = max(int(lay[:, 0].max()), int(lay[:, 1].max()))
    D = config.net_inputs
    ns = config.num_states
    tw = config.temporal_window
    n = max(tw, 2)
    hp = np.zeros(N_HP, dtype=np.int64)
    hp[H_TW], hp[H_NS], hp[H_D], hp[H_WINDOW] = tw, ns, D, n
    hp[H_EXP_SIZE], hp[H_START], hp[H_BATCH] = config.experience_size, config.start_learn_threshold, config.batch_size
    hp[H_BURNIN], hp[H_TOTAL] = config.learning_steps_burnin, config.learning_steps_total
    hp[H_HEAD] = n - 1
    hp[H_CACHE] = int(cache[0] != 0.0)
    hp[H_V2] = int(config.ruleset == "v2")
    hf = np.zeros(N_HF)
    hf[F_GAMMA], hf[F_LR], hf[F_MOMENTUM] = config.gamma, config.learning_rate, config.momentum
    hf[F_L2], hf[F_L1], hf[F_EPS_MIN], hf[F_EPSILON] = config.l2_decay, config.l1_decay, config.epsilon_min, 1.0
    size = config.experience_size
    learn_args = (
        hp, hf, lay, P, np.zeros(n_params), np.zeros(n_params), np.zeros((lay.shape[0] + 1, width)),
        np.zeros(width), np.zeros(width), np.zeros((n, D)), np.zeros((n, ns)), np.zeros(n, dtype=np.int64),
        np.full(n, math.nan), np.zeros((size, D)), np.zeros((size, D)), np.zeros(size, dtype=np.int64),
        np.zeros(size), np.zeros(WINDOW_SIZE), np.zeros(WINDOW_SIZE), np.zeros(D),
    )  # fmt: skip
    if runs > 0:
        sim = Simulator(config.engine_config, 1, frames, runs)
        if config.ruleset == "v2":  # engine load (20 draws), brain.reset_seed, r, t (spec v2 §12)
            sim.seed_training(int(mr[0]), brain_draws=1)
        else:  # no engine-load draws between the build and the runs (see the module doc)
            sim.seed_stream(int(mr[0]))
        obs = np.zeros(ns)
        _run(sim.cars, sim.grid, sim.fs, sim.ints, sim.cfg, sim.mrand, obs, sim.scores, sim.ego_scores,
             sim.run_seeds, learn_args)  # fmt: skip
        end_state = mulberry32_advance(int(sim.mrand[0]), RESET_DRAWS[config.ruleset])  # doEvalRun's trailing reset()
        scores = sim.scores.reshape(-1).tolist()
    else:  # trainIterations 0: train.js skips doEvalRun
        end_state = int(mr[0])
        scores = []
    params = []
    for li in range(lay.shape[0]):
        n_in, n_out, off, _act = (int(v) for v in lay[li])
        w = P[off : off + n_in * n_out].reshape(n_out, n_in).copy()
        b = P[off + n_in * n_out : off + n_in * n_out + n_out].copy()
        params.append((w, b))
    net = ConvNet(layers=config.expanded_layers, params=tuple(params))
    loss_n, reward_n = int(hp[H_LOSS_N]), int(hp[H_REWARD_N])
    return ExactTrainResult(
        seed=int(seed),
        convnet=net,
        training_run_scores=scores,
        brain_age=int(hp[H_AGE]),
        forward_passes=int(hp[H_FP]),
        updates=int(hp[H_UPDATES]),
        final_epsilon=float(hf[F_EPSILON]),
        experience_size_final=int(hp[H_N_EXP]),
        avg_loss_window=float(hf[F_LOSS_SUM] / loss_n) if loss_n >= WINDOW_MIN else -1.0,
        avg_reward_window=float(hf[F_REWARD_SUM] / reward_n) if reward_n >= WINDOW_MIN else -1.0,
        random_draws=draws_between(seed32, end_state),
        frames=runs * frames,
        final_gauss_cache=int(hp[H_CACHE]),
    )
