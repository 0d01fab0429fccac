"""The deepqlearn-faithful learner: schedule, replay, alignment, the convnetjs update, training protocol."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import torch

from autotune.convnet import spec
from autotune.convnet.deepqlearn import BLOCK, BlockUniform, js_argmax_rows, js_epsilon
from autotune.learner.brain import DeepQLearner
from autotune.learner.config import ConfigError, TrainConfig
from autotune.learner.quick_eval import GreedyPolicy
from autotune.learner.training import (
    StopTraining,
    train,
)
from sim.layout import CA, CC
from sim.simulator import Simulator


def tiny(**kw) -> TrainConfig:
    base: dict[str, Any] = dict(
        lanes_side=0, patches_ahead=2, temporal_window=0, layers="fc:3:relu", batch_size=4,
        experience_size=50, start_learn_threshold=49, learning_steps_total=30, learning_steps_burnin=10,
    )  # fmt: skip
    base.update(kw)
    return TrainConfig(**base)


class Draws:
    """Scripted replacement for the learner's uniform draws, counting them."""

    def __init__(self, values=None, default=0.999):
        self.values = list(values or [])
        self.default = default
        self.n = 0

    def __call__(self) -> float:
        self.n += 1
        return self.values.pop(0) if self.values else self.default


# -- ε schedule ---------------------------------------------------------------------------------


def test_js_epsilon_formula():
    assert js_epsilon(0, 1000, 10000, 0.0) == 1.0  # burn-in: capped at 1
    assert js_epsilon(1000, 1000, 10000, 0.0) == 1.0
    assert js_epsilon(5500, 1000, 10000, 0.0) == 1.0 - 4500 / 9000
    assert js_epsilon(10000, 1000, 10000, 0.05) == 0.05  # floor
    assert js_epsilon(20000, 1000, 10000, 0.05) == 0.05
    assert js_epsilon(5, 5, 5, 0.1) != js_epsilon(5, 5, 5, 0.1)  # 0/0 → NaN (then never explores)
    assert js_epsilon(6, 5, 5, 0.1) == 0.1 and js_epsilon(4, 5, 5, 0.1) == 1.0  # x/0 = ±∞


def test_epsilon_per_decision_and_rf_always_drawn():
    c = tiny(epsilon_min=0.1, learning_steps_burnin=5, learning_steps_total=15)
    b = DeepQLearner(c, 0)
    draws = Draws(default=0.999)  # rf = 0.999: explores (2nd draw) only while ε = 1
    b._uniform = draws
    x = np.array([0.5, 0.25])
    expected = 0
    for t in range(1, 31):
        b.learn(x, 0.0)
        assert b.age == t and b.forward_passes == t
        eps = min(1.0, max(0.1, 1.0 - (t - 5) / (15 - 5)))
        assert b.epsilon == eps
        expected += 2 if 0.999 < eps else 1
        assert draws.n == expected  # rf drawn even when ε is at its floor; no replacement (memory not full)


def test_block_uniform_is_the_generator_stream_across_refills():
    u = BlockUniform(np.random.default_rng(7))
    assert [u() for _ in range(BLOCK + 3)] == np.random.default_rng(7).random(BLOCK + 3).tolist()


def test_exploration_draws_a_second_uniform():
    b = DeepQLearner(tiny(), 0)
    b._uniform = Draws([0.3, 0.61], default=0.999)  # rf = 0.3 < ε = 1 → action ⌊5·0.61⌋ = 3
    assert b.learn(np.zeros(2), 0.0) == 3


# -- warm-up, input window and experience alignment ---------------------------------------------


@pytest.mark.parametrize("ruleset", ["v1", "v2"])
@pytest.mark.parametrize("tw", [0, 2])
def test_stored_transitions_are_aligned(ruleset, tw):
    c = tiny(ruleset=ruleset, temporal_window=tw, experience_size=100, start_learn_threshold=99)
    b = DeepQLearner(c, 3)
    S, A = c.num_states, 5
    T = 12
    states = [np.array([0.01 * t, 0.5 + 0.01 * t]) for t in range(1, T + 1)]
    rewards = [float(t) for t in range(1, T + 1)]
    actions = []
    for x, r in zip(states, rewards, strict=True):
        actions.append(b.learn(x, r))
    if ruleset == "v2":
        assert actions[:tw] == [0] * tw  # v2 warm-up: ⌊nextFloat()⌋·5 = 0

    def net_input(u: int) -> np.ndarray:  # decision u (1-based), u > tw
        parts = [states[u - 1]]
        for k in range(1, tw + 1):
            e = np.zeros(A)
            e[actions[u - 1 - k]] = S  # one-hot scaled by num_states
            parts += [states[u - 1 - k], e]
        return np.concatenate(parts)

    # storage starts at the decision t with forward_passes (= t − 1) > tw + 1
    first = tw + 3
    assert b.n_exp == T - first + 1
    for j in range(b.n_exp):
        t = first + j  # (S_{t−2}, A_{t−2}, R_{t−1}, S_{t−1})
        np.testing.assert_allclose(b._SS[0, j], net_input(t - 2), rtol=1e-6)
        np.testing.assert_allclose(b._SS[1, j], net_input(t - 1), rtol=1e-6)
        assert b._OH[j].argmax() == actions[t - 3] and b._OH[j].sum() == 1.0
        assert b._R[j] == rewards[t - 2]


def test_replay_appends_then_replaces_random_slots():
    c = tiny(experience_size=4, start_learn_threshold=3, learning_steps_burnin=0, learning_steps_total=1)
    b = DeepQLearner(c, 0)
    b._uniform = Draws(default=0.999)
    x = np.array([0.1, 0.2])
    for t in range(5):  # learn calls 1…5 with rewards 0…4; calls 3, 4, 5 store R = 1, 2, 3 in slots 0, 1, 2
        b.learn(x, float(t))
    assert b.n_exp == 3 and list(b._R[:3]) == [1.0, 2.0, 3.0]
    b.learn(x, 6.0)  # 4th store fills slot 3 (append, no draw for the slot)
    assert b.n_exp == 4 and b._R[3] == 4.0
    # memory full: slot = ⌊experience_size·u⌋, u the next draw (before this decision's rf)
    for u, r, slot in [(0.6, 7.0, 2), (0.1, 8.0, 0), (0.6, 9.0, 2), (0.99, 10.0, 3)]:
        b._uniform = Draws([u], default=0.999)
        before = b._R.copy()
        b.learn(x, r)
        changed = np.flatnonzero(b._R != before)
        assert list(changed) == [slot] and b._R[slot] == r - 1.0 and b.n_exp == 4


def test_replay_memory_holds_what_the_schedule_can_fill_and_grows_if_driven_longer():
    """The replay memory is allocated for ``replay_rows`` = min(experience_size, the schedule's ego decisions) —
    allocated whole, one draw asked for 20 GB at its 10k rung — and a brain driven past its schedule grows it:
    the same seeds and inputs give the same decisions, memory and weights as a brain allocated for all of it."""
    c = tiny(experience_size=500, start_learn_threshold=20, train_iterations=10)
    assert c.ego_decisions == c.schedule[0] * -(-c.schedule[1] // 30) and c.replay_rows == min(500, c.ego_decisions)
    assert c.replay_bytes == c.replay_rows * (2 * c.net_inputs + 6) * 4
    assert c.replace(dtype="float64").replay_bytes == 2 * c.replay_bytes
    assert tiny(experience_size=5, start_learn_threshold=2, train_iterations=10).replay_rows == 5
    small, whole = DeepQLearner(c, 3), DeepQLearner(c.replace(train_iterations=100_000), 3)
    assert small.SS.shape[1] == c.replay_rows < whole.SS.shape[1] == 500
    rng = np.random.default_rng(0)
    for t in range(4 * c.replay_rows):
        x, r = rng.normal(size=2), float(rng.normal())
        assert small.learn(x, r) == whole.learn(x, r), t
    n = small.n_exp
    assert n > c.replay_rows and small.SS.shape[1] >= n
    assert torch.equal(small.SS[:, :n], whole.SS[:, :n]) and np.array_equal(small._R[:n], whole._R[:n])
    for a, b in zip(small.module.parameters(), whole.module.parameters(), strict=True):
        assert torch.equal(a, b)


def test_learning_starts_above_threshold_one_update_per_decision():
    c = tiny(experience_size=20, start_learn_threshold=5)
    b = DeepQLearner(c, 0)
    x = np.array([0.1, 0.2])
    for t in range(1, 15):
        b.learn(x, 0.0)
        stored = max(0, t - 2)
        assert b.n_exp == stored
        assert b.updates == max(0, stored - 5)  # from the call where the memory holds 6 > 5


def test_weight_init():
    c = TrainConfig(
        lanes_side=6, patches_ahead=30, patches_behind=0, temporal_window=0, layers="fc:300:relu|fc:20:tanh"
    )
    b = DeepQLearner(c, 0)
    l1, l2, l3 = b.module.fc_layers
    assert l1.weight.shape == (300, 390)
    assert abs(float(l1.weight.std()) - math.sqrt(1 / 390)) < 0.002 and abs(float(l1.weight.mean())) < 0.002
    assert torch.all(l1.bias == 0.1) and torch.all(l2.bias == 0.0) and torch.all(l3.bias == 0.0)
    assert abs(float(l2.weight.std()) - math.sqrt(1 / 300)) < 0.005


# -- the convnetjs update, by hand ----------------------------------------------------------------


def _set_tiny_net(b: DeepQLearner) -> tuple[np.ndarray, ...]:
    W1 = np.array([[0.5, -0.3], [0.2, 0.8], [-0.6, 0.1]])
    b1 = np.array([0.1, 0.1, 0.1])
    W2 = np.arange(15, dtype=float).reshape(5, 3) / 20 - 0.3
    b2 = np.array([0.0, 0.01, -0.02, 0.03, 0.0])
    lin1, lin2 = b.module.fc_layers
    for t, v in ((lin1.weight, W1), (lin1.bias, b1), (lin2.weight, W2), (lin2.bias, b2)):
        t.data.copy_(torch.from_numpy(v))
    return W1, b1, W2, b2


def _hand_gradients(W1, b1, W2, b2, s0, a0, r0, s1, gamma):
    """Σ over the batch of ∂½(Q(s₀)_a₀ − (r + γ·max Q(s₁)))², computed by hand with the pre-update weights."""
    dW1, db1, dW2, db2 = (np.zeros_like(W1), np.zeros_like(b1), np.zeros_like(W2), np.zeros_like(b2))
    for k in range(len(a0)):
        h1 = np.maximum(0.0, W1 @ s1[k] + b1)
        y = r0[k] + gamma * np.max(W2 @ h1 + b2)
        h0 = np.maximum(0.0, W1 @ s0[k] + b1)
        q0 = W2 @ h0 + b2
        dq = np.zeros(5)
        dq[a0[k]] = q0[a0[k]] - y
        dW2 += np.outer(dq, h0)
        db2 += dq
        dh = (W2.T @ dq) * (h0 > 0)
        dW1 += np.outer(dh, s0[k])
        db1 += dh
    return dW1, db1, dW2, db2


@pytest.mark.parametrize("momentum", [0.0, 0.9])
def test_sgd_momentum_l2_update_by_hand(momentum):
    lr, l2, gamma, B = 0.05, 0.01, 0.7, 3
    c = tiny(
        layers="fc:3:relu", batch_size=B, learning_rate=lr, l2_decay=l2, gamma=gamma, momentum=momentum, dtype="float64"
    )
    b = DeepQLearner(c, 0)
    params = list(_set_tiny_net(b))
    s0 = np.array([[0.3, 0.9], [1.0, 0.2], [0.5, 0.5], [0.0, 1.0]])
    s1 = np.array([[0.4, 0.7], [0.9, 0.1], [0.2, 0.6], [1.0, 1.0]])
    a0 = np.array([1, 3, 0, 4])
    r0 = np.array([0.5, -1.0, 2.0, 0.0])
    b._SS[0, :4], b._SS[1, :4], b._R[:4] = s0, s1, r0
    b._OH[np.arange(4), a0] = 1.0
    idx = torch.tensor([2, 0, 2])  # with replacement
    velocity = [np.zeros_like(p) for p in params]
    for _step in range(2):
        grads = _hand_gradients(*params, s0[idx], a0[idx], r0[idx], s1[idx], gamma)
        new = []
        for i, (p, g) in enumerate(zip(params, grads, strict=True)):
            decay = l2 if i in (0, 2) else 0.0  # weights only (biases: l2_decay_mul = 0)
            gij = (decay * p + g) / B
            if momentum > 0:
                velocity[i] = momentum * velocity[i] - lr * gij
                new.append(p + velocity[i])
            else:
                new.append(p - lr * gij)
        params = new
        b.kernel.step(b.SS, b.OH, b.R, idx)
        lin1, lin2 = b.module.fc_layers
        got = [lin1.weight, lin1.bias, lin2.weight, lin2.bias]
        for exp, t in zip(params, got, strict=True):
            np.testing.assert_allclose(t.numpy(), exp, rtol=1e-12, atol=1e-14)


LAYERS = [
    "fc:4:relu",
    "fc:4:tanh|fc:3:sigmoid",
    "fc:6:maxout",
    "fc:4:relu|svm:3|fc:2:relu",
    "fc:4:relu|softmax:3",
    "fc:3:relu|lrn",
    "",
]


@pytest.mark.parametrize("layers", LAYERS)
@pytest.mark.parametrize(
    "method, momentum",
    [("sgd", 0.0), ("sgd", 0.9), ("adagrad", 0.0), ("windowgrad", 0.0), ("adadelta", 0.0), ("nesterov", 0.5)],
)
def test_kernel_matches_autograd_and_trainer_formulas(layers, method, momentum):
    """The hand-written backward pass (every crowd layer type) against torch autograd on netspec's module,
    and the first step of every trainer method against its convnetjs formula (spec §10.9)."""
    lr, l2, B = 0.01, 0.01, 5
    c = tiny(
        patches_ahead=3,
        layers=layers,
        batch_size=B,
        dtype="float64",
        method=method,
        momentum=momentum,
        learning_rate=lr,
        l2_decay=l2,
    )
    b = DeepQLearner(c, 3)
    rng = np.random.default_rng(1)
    b._SS[:, :20] = rng.random((2, 20, 3))
    a0 = rng.integers(0, 5, 20)
    b._OH[np.arange(20), a0] = 1.0
    b._R[:20] = rng.random(20)
    idx = torch.tensor([0, 3, 3, 7, 19])
    mod = b.module
    names = [n for n, _ in mod.named_parameters()]
    p0 = [p.detach().clone() for p in mod.parameters()]
    ps = [p.clone().requires_grad_(True) for p in p0]

    def fwd(x):
        return torch.func.functional_call(mod, dict(zip(names, ps, strict=True)), (x,))

    s0, s1, r = b.SS[0, idx], b.SS[1, idx], b.R[idx]
    a = torch.from_numpy(a0)[idx]
    with torch.enable_grad():
        y = r + c.gamma * fwd(s1).detach().max(1).values
        loss = 0.5 * ((fwd(s0)[torch.arange(B), a] - y) ** 2).sum()
        grads = torch.autograd.grad(loss, ps, allow_unused=True)
    b.kernel.step(b.SS, b.OH, b.R, idx)
    for name, p, g, p1 in zip(names, p0, grads, mod.parameters(), strict=True):
        g = torch.zeros_like(p) if g is None else g
        gij = ((l2 if name.endswith("weight") else 0.0) * p + g) / B
        if method == "sgd":
            exp = p - lr * gij
        elif method == "adagrad":
            exp = p - lr / torch.sqrt(gij * gij + 1e-6) * gij
        elif method == "windowgrad":
            exp = p - lr / torch.sqrt(0.05 * gij * gij + 1e-6) * gij
        elif method == "adadelta":
            exp = p - torch.sqrt(1e-6 / (0.05 * gij * gij + 1e-6)) * gij
        else:  # nesterov, V = 0 before: V = lr·g; w += μ·0 − (1 + μ)·V
            exp = p - (1 + momentum) * lr * gij
        torch.testing.assert_close(p1, exp, rtol=1e-10, atol=1e-12, msg=f"{layers} {method} {name}")


def test_dropout_kernel_modes():
    c = tiny(layers="fc:6:relu:drop_prob=0.5", batch_size=8, dtype="float64")
    b = DeepQLearner(c, 0)
    k = b.kernel
    drop = next(op for op in k.ops if type(op).__name__ == "_DropoutOp")
    k.x.uniform_(0.5, 1.0)
    for op in k.ops:
        op.fwd()
    x0, x1, o0, o1 = drop.x0, drop.x1, drop.o0, drop.o1
    torch.testing.assert_close(o1, x1 * 0.5)  # prediction mode (targets): × drop_prob
    kept = drop.keep
    assert torch.all(o0[~kept] == 0) and torch.equal(o0[kept], x0[kept]) and 0 < int(kept.sum()) < kept.numel()
    d = torch.ones_like(o0)
    assert torch.equal(drop.bwd(d), kept.to(d.dtype))


# -- greedy policy helpers ----------------------------------------------------------------------


def test_js_argmax_rows():
    q = np.array([[1.0, 3.0, 3.0, 0.0, 2.0], [np.nan, 5.0, 1.0, 0.0, 0.0], [1.0, np.nan, 2.0, 0.0, 0.0], [np.nan] * 5])
    assert js_argmax_rows(q).tolist() == [1, 0, 2, 0]


def test_greedy_policy_window_and_warmup():
    c = tiny(ruleset="v2", temporal_window=2)
    b = DeepQLearner(c, 0)
    pol = GreedyPolicy(b.module, c)

    class Obs:
        def __init__(self, inputs):
            self.inputs = inputs
            self.world = np.array([0, 1])
            self.car = np.array([0, 0])

        def __len__(self):
            return 2

    x = np.array([[0.2, 0.4], [0.6, 0.8]])
    assert pol(Obs(x)).tolist() == [0, 0] and pol(Obs(x)).tolist() == [0, 0]  # v2 warm-up
    a = pol(Obs(x))
    hist = pol._hist[[0, 1]]
    for w in range(2):
        net_in = np.concatenate([x[w], hist[w]])
        # the window shifted after the decision: hist = [x, e(a), x, e(0)]
        assert hist[w, 2 + a[w]] == 2.0 and np.allclose(hist[w, :2], x[w])
    assert np.isfinite(net_in).all()


# -- simulator driving and the training protocol --------------------------------------------------


def test_single_world_fast_path_matches_public_api():
    config = tiny(ruleset="v2", other_agents=2, lanes_side=1, patches_ahead=3)
    actions = np.random.default_rng(0).integers(0, 5, 400)

    def run(fast: bool):
        sim = Simulator(config.engine_config, 1, 900, 2)
        sim.seed_training(12345, 3)
        trace = []
        if fast:
            car = sim.start_single()
            k = 0
            while car >= 0:
                trace.append((car, sim.obs_inputs[0].copy(), float(sim.obs_reward[0]) if car == 0 else None))
                car = sim.step_single(int(actions[k % 400]))
                k += 1
        else:
            obs = sim.start()
            k = 0
            while obs is not None:
                trace.append((int(obs.car[0]), obs.inputs[0].copy(), float(obs.reward[0]) if obs.car[0] == 0 else None))
                obs = sim.step(np.array([actions[k % 400]]))
                k += 1
        return trace, sim.scores.copy(), sim.frames_simulated

    (t1, s1, f1), (t2, s2, f2) = run(True), run(False)
    assert len(t1) == len(t2) and f1 == f2 == 1800
    for (c1, x1, r1), (c2, x2, r2) in zip(t1, t2, strict=True):
        assert c1 == c2 and np.array_equal(x1, x2) and r1 == r2
    assert np.array_equal(s1, s2)


@pytest.mark.parametrize("supply", [10_000, 7])
def test_agents_answered_inline_match_stepping_them_one_by_one(supply):
    """``step_single_agents``: the other cars' decisions answered inside the simulator from a given list are the
    frames ``step_single`` plays answering them one by one; with the list used up, the next agent's decision
    comes back observed, as ``step_single`` leaves it."""
    config = tiny(ruleset="v2", other_agents=4, lanes_side=1, patches_ahead=3)
    rng = np.random.default_rng(3)
    ego_actions, agent_actions = rng.integers(0, 5, 200), rng.integers(0, 5, supply)

    def run(inline: bool):
        sim = Simulator(config.engine_config, 1, 900, 2)
        sim.seed_training(4321, 5)
        trace, k, pos = [], 0, 0
        car = sim.start_single()
        while car >= 0:
            trace.append((car, sim.obs_inputs[0].copy(), float(sim.obs_reward[0]) if car == 0 else None))
            if car == 0:
                action = int(ego_actions[k % 200])
                k += 1
                if inline:
                    car, pos = sim.step_single_agents(action, agent_actions, pos)
                    continue
            else:
                action = int(agent_actions[pos]) if pos < supply else 2
                pos += 1
            car = sim.step_single(action)
        return trace, pos, sim.scores.copy(), sim.frames_simulated, [a.copy() for a in sim.state_arrays]

    (t1, p1, s1, f1, a1), (t2, p2, s2, f2, a2) = run(True), run(False)
    assert p1 == p2 > 100 and f1 == f2 == 1800 and np.array_equal(s1, s2)
    assert all(np.array_equal(x, y) for x, y in zip(a1, a2, strict=True))
    agent_index = np.cumsum([c > 0 for c, _, _ in t2]) - 1  # the k-th agent decision stepped one by one
    seen = [row for row, k in zip(t2, agent_index, strict=True) if row[0] == 0 or k >= supply]
    assert len(t1) == len(seen) >= 60 and (supply > p2 or sum(c > 0 for c, _, _ in t1) == p2 - supply > 0)
    for (c1, x1, r1), (c2, x2, r2) in zip(t1, seen, strict=True):
        assert c1 == c2 and np.array_equal(x1, x2) and r1 == r2


@pytest.mark.parametrize("ruleset", ["v1", "v2"])
def test_bogus_first_reward_and_transition_across_reset(ruleset):
    """Each run's first reward covers one frame (≈ −2.9); the transition spanning the reset is stored as is."""
    c = tiny(ruleset=ruleset, lanes_side=1, patches_ahead=3, experience_size=200, start_learn_threshold=199)
    b = DeepQLearner(c, 0)
    sim = Simulator(c.engine_config, 1, 600, 2)  # 20 decisions per run
    sim.seed_stream(7) if ruleset == "v1" else sim.seed_training(7, 1)
    car = sim.start_single()
    rewards, inputs, single = [], [], []
    while car >= 0:
        reward = float(sim.obs_reward[0])
        rewards.append(reward)
        inputs.append(sim.obs_inputs[0].astype(np.float32))
        single.append((sim.cars[0, CC, 0] * sim.cars[0, CA, 0] - 60.0) / 20.0)  # one frame's (c·a − 60)/20
        car = sim.step_single(b.learn(sim.obs_inputs[0], reward))
    assert len(rewards) == 40
    for first in (0, 20):
        assert rewards[first] == single[first] and -3.0 <= rewards[first] <= -2.79
    # stored at decision 22 (0-based 21): (S_19, A_19, R_20 = run 2's bogus reward, S_20 = run 2's first state)
    j = 21 - 2
    assert b._R[j] == np.float32(rewards[20])
    np.testing.assert_array_equal(b._SS[0, j], inputs[19])
    np.testing.assert_array_equal(b._SS[1, j], inputs[20])


def _small_training_config(**kw) -> TrainConfig:
    base: dict[str, Any] = dict(
        ruleset="v2", lanes_side=1, patches_ahead=4, temporal_window=0, layers="fc:4:relu", train_iterations=400,
        experience_size=200, start_learn_threshold=50, learning_steps_total=300, learning_steps_burnin=50, batch_size=8,
    )  # fmt: skip
    base.update(kw)
    return TrainConfig(**base)


def test_tiny_training_reports_on_schedule():
    config = _small_training_config()
    assert config.schedule == (2, 10715)
    calls = []
    result = train(
        config,
        seed=5,
        reporter=lambda k, f, s: calls.append((k, f, s)),
        report_points=4,
        quick_eval_runs=2,
        quick_eval_frames=300,
    )
    assert [k for k, _f, _s in calls] == [0, 1, 2, 3]
    frames = [f for _k, f, _s in calls]
    assert frames == sorted(frames) and frames[-1] == result.frames == 2 * 10715
    assert all(isinstance(s, float) and 0 < s < 100 for _k, _f, s in calls)
    assert result.decisions == 2 * 358 and result.runs_completed == 2 and len(result.training_run_scores) == 2
    assert result.updates == result.decisions - 2 - 50  # storage from decision 3, learning once > 50 stored
    assert len(result.curve) == 4 and result.curve[-1].decisions == result.decisions
    assert not result.stopped and not result.diverged
    net = result.convnet()
    assert net.fc_shapes == [(4, 12), (5, 4)]


def test_training_is_deterministic_per_seed():
    config = _small_training_config(train_iterations=200)
    a = train(config, seed=11, quick_eval=False)
    b = train(config, seed=11, quick_eval=False)
    c = train(config, seed=12, quick_eval=False)
    pa, pb, pc = (r.module.flat_params for r in (a, b, c))
    assert torch.equal(pa, pb) and not torch.equal(pa, pc)
    assert a.training_run_scores == b.training_run_scores


def test_reporter_stops_training():
    config = _small_training_config()
    calls = []

    def stop_at_1(k, frames, score):
        calls.append(k)
        return k == 1

    r = train(config, seed=1, reporter=stop_at_1, report_points=4, quick_eval_runs=2, quick_eval_frames=300)
    assert calls == [0, 1] and r.stopped and "report 1" in r.stop_reason and r.decisions < 2 * 358

    def raise_stop(k, frames, score):
        raise StopTraining("pruned by the study")

    r = train(config, seed=1, reporter=raise_stop, report_points=4, quick_eval_runs=2, quick_eval_frames=300)
    assert r.stopped and r.stop_reason == "pruned by the study" and len(r.curve) == 1

    def broken(k, frames, score):
        raise KeyError("boom")

    with pytest.raises(KeyError):
        train(config, seed=1, reporter=broken, report_points=4, quick_eval_runs=2, quick_eval_frames=300)


def test_divergence_is_reported():
    config = _small_training_config(
        learning_rate=10.0, gamma=1.0, l2_decay=0.0, train_iterations=600, layers="fc:16:relu|fc:16:relu"
    )
    r = train(config, seed=0, quick_eval=False)
    assert r.diverged and ("non-finite" in r.diverged_reason or "loss became" in r.diverged_reason)
    assert r.decisions < 2 * 536


def test_v2_agents_during_training():
    config = _small_training_config(other_agents=3, temporal_window=1, train_iterations=200)
    r = train(config, seed=2, quick_eval=False)
    per_run = -(-config.schedule[1] // 30)
    assert r.decisions == config.schedule[0] * per_run and r.agent_decisions > 2 * r.decisions
    assert not r.diverged


def test_blind_agents_are_answered_inside_the_simulator_with_the_same_draws():
    """Agents at ε = 1 (burnin > tw + 1) take their two draws per decision a block ahead and are answered inside
    the simulator: the training run is the one deciding them one by one gave (pinned before the change: agent
    decisions and training-run scores exactly; the trained float32 weights to 1e-5, since torch's CPU kernels round
    the last bits by the machine's vector unit: the digest pinned first, fe305255b07aa7e2, came out 8bc20ce8ca28c6d2
    on an AVX-512 machine with the same decisions and scores)."""
    from autotune.learner.agents import TrainingAgents

    config = _small_training_config(other_agents=10, temporal_window=2, layers="", method="adagrad",
                                    train_iterations=1500)  # fmt: skip
    assert TrainingAgents(config, DeepQLearner(config, 0), np.random.SeedSequence(1)).blind
    r = train(config, seed=7, quick_eval=False)
    weights = np.concatenate([p.detach().numpy().ravel() for p in r.module.parameters()])
    assert (r.agent_decisions, r.decisions, r.frames) == (18620, 2070, 62070)
    assert r.training_run_scores == [56.57, 59.28]
    summary = [float(weights.sum()), float(np.abs(weights).sum()), float((weights * weights).sum())]
    np.testing.assert_allclose(summary, [-3.5407606, 27.722958, 4.9283082], rtol=1e-5)
    greedy = _small_training_config(other_agents=2, temporal_window=1, learning_steps_burnin=0, learning_steps_total=4)
    assert not TrainingAgents(greedy, DeepQLearner(greedy, 0), np.random.SeedSequence(1)).blind


def test_zero_iterations():
    r = train(_small_training_config(train_iterations=0), seed=0, quick_eval=False)
    assert r.frames == 0 and r.decisions == 0 and r.curve == []
    assert isinstance(r.convnet(), spec.ConvNet)


def test_v2_agents_greedy_snapshot_when_burnin_is_tiny():
    """burnin ≤ tw + 1: the frozen copies' ε = 1 − (tw + 1 − burnin)/(total − burnin) < 1, so they act
    greedily (on the net frozen when they were copied) with probability 1 − ε."""
    from autotune.learner.agents import TrainingAgents

    config = _small_training_config(other_agents=2, temporal_window=1, learning_steps_burnin=0, learning_steps_total=4)
    brain = DeepQLearner(config, 0)
    agents = TrainingAgents(config, brain, np.random.SeedSequence(1))
    assert agents.epsilon == 0.5  # 1 − (2 − 0)/(4 − 0)
    x = np.full(config.num_states, 0.5)
    assert agents.act(1, x) == 0  # the ego has made no decision yet: load-time copies, warm-up
    brain.learn(x, 0.0)
    brain.learn(x, 0.0)
    acts = [agents.act(1 + k % 2, x) for k in range(200)]
    assert agents.frozen is not None and set(acts) <= set(range(5))
    frozen_q = agents.frozen[0](np.concatenate([x, agents._hist[1]]).astype(np.float32)).copy()
    with torch.no_grad():
        brain.module.fc_layers[0].weight.add_(1.0)  # later training does not change the frozen copy
    assert np.array_equal(agents.frozen[0](np.concatenate([x, agents._hist[1]]).astype(np.float32)), frozen_q)


def test_training_on_from_loaded_weights():
    """``init_net``: the site's train-on from ``value_net.fromJSON`` weights — loaded, then trained from them."""
    config = _small_training_config(train_iterations=200)
    parent = train(config, seed=3, quick_eval=False).convnet()
    # no update (start_learn_threshold above what 200 decisions store): the net comes back as loaded, bit for bit
    no_update = config.replace(experience_size=1000, start_learn_threshold=999)
    frozen = train(no_update, seed=4, quick_eval=False, init_net=parent)
    assert frozen.updates == 0 and frozen.convnet().same_as(parent) and frozen.weight_change == 0.0
    fresh = train(no_update, seed=4, quick_eval=False)
    assert not fresh.convnet().same_as(parent)  # without it, the seed's own initial weights
    # trained on: moved from the loaded weights, deterministic per (net, seed), and every draw as without init_net
    a = train(config, seed=4, quick_eval=False, init_net=parent)
    b = train(config, seed=4, quick_eval=False, init_net=parent)
    c = train(config, seed=4, quick_eval=False)
    assert a.updates == c.updates > 0 and 0.0 < a.weight_change and a.convnet().same_as(b.convnet())
    assert not a.convnet().same_as(parent) and not a.convnet().same_as(c.convnet())


def test_loaded_weights_must_be_the_configs_net():
    parent = train(_small_training_config(train_iterations=0), seed=0, quick_eval=False).convnet()
    with pytest.raises(ConfigError, match=r"init_net: its layers \(12 inputs, hidden 'fc:4:relu'\) are not the "
                                          r"config's \(12 inputs, hidden 'fc:5:relu'\)"):  # fmt: skip
        train(_small_training_config(layers="fc:5:relu"), seed=0, quick_eval=False, init_net=parent)
    with pytest.raises(ConfigError, match="init_net: .*load a net trained with the same inputs and layers"):
        train(_small_training_config(patches_ahead=5), seed=0, quick_eval=False, init_net=parent)
