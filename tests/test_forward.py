"""The compiled forward pass equals convnetjs's prediction-mode arithmetic bit for bit; torch bridges."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autotune.convnet.forward import flatten, forward, greedy_actions
from autotune.convnet.random import build_draws, gauss_skip, replay_build
from autotune.convnet.settings import Settings
from autotune.convnet.spec import (
    FC,
    LRN,
    SVM,
    ConvNet,
    Dropout,
    Input,
    Maxout,
    Regression,
    Relu,
    Sigmoid,
    Softmax,
    Tanh,
    expand,
    init_convnet,
)
from autotune.convnet.torch_bridge import build_torch, from_torch, to_torch
from autotune.learner.brain_policy import BrainPolicy
from sim.rng import mulberry32_advance, mulberry32_next, mulberry32_stream


def reference_forward(net: ConvNet, x: list[float]) -> list[float]:
    """Straight transcription of the spec's rules (engine_spec.md §10.5, §10.9), one value at a time."""
    v = [float(t) for t in x[: net.input_size]]
    fc = 0
    for layer in net.layers:
        if isinstance(layer, FC):
            w, b = net.params[fc]
            fc += 1
            out = []
            for i in range(w.shape[0]):
                a = 0.0
                for d in range(w.shape[1]):
                    a += v[d] * float(w[i, d])
                a += float(b[i])
                out.append(a)
            v = out
        elif isinstance(layer, Relu):
            v = [0.0 if t < 0 else t for t in v]
        elif isinstance(layer, Tanh):
            v = [(math.exp(2 * t) - 1) / (math.exp(2 * t) + 1) for t in v]
        elif isinstance(layer, Sigmoid):
            v = [1.0 / (1.0 + math.exp(-t)) for t in v]
        elif isinstance(layer, Maxout):
            g = layer.group_size
            out = []
            for i in range(len(v) // g):
                a = v[i * g]
                for j in range(1, g):
                    if v[i * g + j] > a:
                        a = v[i * g + j]
                out.append(a)
            v = out
        elif isinstance(layer, Dropout):
            v = [t * layer.drop_prob for t in v]
        elif isinstance(layer, Softmax):
            m = v[0]
            for t in v[1:]:
                if t > m:
                    m = t
            es = [math.exp(t - m) for t in v]
            s = 0.0
            for e in es:
                s += e
            v = [e / s for e in es]
        elif isinstance(layer, LRN):
            half = layer.n // 2
            out = []
            for i in range(len(v)):
                den = 0.0
                for j in range(max(0, i - half), min(len(v) - 1, i + half) + 1):
                    den += v[j] * v[j]
                den *= layer.alpha / layer.n
                den += layer.k
                out.append(v[i] / math.pow(den, layer.beta))
            v = out
    return v


ALL_TYPES = expand(
    [
        Input(23),
        FC(17, "tanh"),
        LRN(1.0, 3, 0.1, 0.75),
        FC(12, "sigmoid", drop_prob=0.3),
        SVM(9),
        FC(10, "maxout", group_size=3),
        Softmax(6),
        FC(8, "relu"),
        Regression(5),
    ]
)


def _random_net(layers: tuple, seed: int, scale: float = 1.0) -> ConvNet:
    net = init_convnet(layers, seed)
    rng = np.random.default_rng(seed + 100)
    return ConvNet(net.layers, tuple((w * scale, b + rng.normal(size=b.shape)) for w, b in net.params))


def test_expansion_rules() -> None:
    layers = expand([Input(4), SVM(3), FC(6, "maxout"), FC(2, "softmax"), FC(3, "relu", drop_prob=0.5), Regression(5)])
    kinds = [type(layer).__name__ for layer in layers]
    assert kinds == ["Input", "FC", "SVM", "FC", "Maxout", "FC", "FC", "Relu", "Dropout", "FC", "Regression"]
    fcs = [layer for layer in layers if isinstance(layer, FC)]
    assert [f.num_neurons for f in fcs] == [3, 6, 2, 3, 5]
    assert [f.bias_pref for f in fcs] == [0.0, 0.0, 0.0, 0.1, 0.0]  # 'softmax' as an activation adds nothing
    assert layers[4] == Maxout(2)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_forward_matches_reference_bitwise(seed: int) -> None:
    net = _random_net(ALL_TYPES, seed, scale=3.0)
    rng = np.random.default_rng(seed)
    xs = rng.normal(size=(20, 23)) * 4
    got = forward(net, xs)
    for x, row in zip(xs, got, strict=True):
        want = reference_forward(net, list(x))
        assert row.tolist() == want


def test_forward_dense_relu_tanh_nets() -> None:
    layers = expand([Input(61), FC(33, "relu"), FC(19, "tanh"), FC(7), Regression(5)])
    net = _random_net(layers, 5)
    xs = np.random.default_rng(5).random((50, 61))
    got = forward(net, xs)
    for x, row in zip(xs, got, strict=True):
        assert row.tolist() == reference_forward(net, list(x))


def test_quirks() -> None:
    # tanh is (e^{2x}-1)/(e^{2x}+1): NaN beyond x ≈ 354.9; dropout multiplies by drop_prob; NaN Q → action 0.
    eye = (np.eye(2), np.zeros(2))
    net = ConvNet((Input(2), FC(2, bias_pref=0.0), Tanh()), (eye,))
    out = forward(net, np.array([400.0, 0.5]))
    assert math.isnan(out[0]) and out[1] == (math.exp(1.0) - 1) / (math.exp(1.0) + 1)
    drop = ConvNet((Input(2), Dropout(0.25), FC(2, bias_pref=0.0)), (eye,))
    assert forward(drop, np.array([4.0, 8.0])).tolist() == [1.0, 2.0]
    q = ConvNet(expand([Input(5), Regression(5)]), ((np.eye(5), np.array([math.nan, 0, 9, 9, 0.0])),))
    assert greedy_actions(q, np.zeros(5)).tolist() == [0]  # NaN first: nothing beats it
    q2 = ConvNet(expand([Input(5), Regression(5)]), ((np.eye(5), np.array([1, math.nan, 9, 9, 0.0])),))
    assert greedy_actions(q2, np.zeros(5)).tolist() == [2]  # ties keep the lowest index


def test_maxout_ties_keep_lowest() -> None:
    net = ConvNet((Input(4), Maxout(2)), ())
    assert forward(net, np.array([1.0, 1.0, -0.0, 0.0])).tolist() == [1.0, -0.0]


def test_flatten_layout() -> None:
    net = _random_net(ALL_TYPES, 3)
    flat = flatten(net)
    assert flat.input_size == 23 and flat.output_size == 5
    assert flat.params.size == net.n_params + 1 + 3  # + dropout p + lrn (k, alpha, beta)


# -- torch bridges ------------------------------------------------------------------------------


def test_torch_roundtrip_and_outputs() -> None:
    torch = pytest.importorskip("torch")
    net = _random_net(ALL_TYPES, 7)
    module = to_torch(net)
    module.eval()
    assert len(module.fc_layers) == len(net.params)
    back = from_torch(module, net)
    assert back.same_as(net)
    xs = np.random.default_rng(7).normal(size=(16, 23))
    with torch.no_grad():
        got = module(torch.from_numpy(xs)).numpy()
    np.testing.assert_allclose(got, forward(net, xs), rtol=1e-12, atol=1e-12)
    m32 = to_torch(net, dtype=torch.float32)
    assert m32.fc_layers[0].weight.dtype == torch.float32
    back32 = from_torch(m32, net.layers)
    np.testing.assert_array_equal(back32.params[0][0], net.params[0][0].astype(np.float32).astype(np.float64))


def test_build_torch_and_errors() -> None:
    torch = pytest.importorskip("torch")
    layers = expand([Input(10), FC(8, "relu"), FC(4, "maxout"), Regression(5)])
    module = build_torch(layers, dtype=torch.float64)
    assert [type(m).__name__ for m in module] == ["Linear", "ReLU", "Linear", "ConvnetMaxout", "Linear", "Identity"]
    assert module(torch.zeros(3, 10, dtype=torch.float64)).shape == (3, 5)
    net = from_torch(module, layers)
    assert net.fc_shapes == [(8, 10), (4, 8), (5, 2)]
    wrong = build_torch(expand([Input(10), FC(7, "relu"), FC(4, "maxout"), Regression(5)]))
    with pytest.raises(ValueError, match="2 Linear layers"):
        from_torch(build_torch(expand([Input(10), FC(8), Regression(5)])), layers)
    with pytest.raises(ValueError, match="Linear #0"):
        from_torch(wrong, layers)


def test_convnet_dropout_modes() -> None:
    torch = pytest.importorskip("torch")
    module = build_torch((Input(3), FC(3, bias_pref=0.0), Dropout(0.5)), dtype=torch.float64)
    with torch.no_grad():
        module[0].weight.copy_(torch.eye(3, dtype=torch.float64))
        module[0].bias.zero_()
    module.eval()
    x = torch.tensor([[2.0, 4.0, 6.0]], dtype=torch.float64)
    assert module(x).tolist() == [[1.0, 2.0, 3.0]]  # prediction mode multiplies by drop_prob
    module.train()
    y = module(x)
    assert set(y.flatten().tolist()) <= {0.0, 2.0, 4.0, 6.0}  # training: zero or unscaled


# -- Gaussian draw accounting ---------------------------------------------------------------------


def _gauss_draws_python(seed: int, cache: bool, n: int) -> tuple[int, bool]:
    """Explicit gaussRandom emulation: (uniform draws used, cache flag after n calls)."""
    stream = iter(mulberry32_stream(seed, 10 * n + 10))
    used = 0
    for _ in range(n):
        if cache:
            cache = False
            continue
        while True:
            u = 2 * next(stream) - 1
            v = 2 * next(stream) - 1
            used += 2
            r = u * u + v * v
            if r == 0 or r > 1:
                continue
            break
        cache = True
    return used, cache


@pytest.mark.parametrize(("n", "cache"), [(0, 0), (1, 0), (1, 1), (7, 0), (7, 1), (260, 0), (355, 1)])
def test_gaussian_replay(n: int, cache: int) -> None:
    state, flag, draws = replay_build(12345, cache, n)
    used, want_flag = _gauss_draws_python(12345, bool(cache), n)
    assert draws == used and flag == int(want_flag)
    mr = np.array([12345], dtype=np.int64)
    assert gauss_skip(mr, 0, cache, n) == int(want_flag)
    assert mr[0] == state


def test_build_draws_counts_all_fc_weights() -> None:
    net = init_convnet(expand([Input(55), FC(50, "relu"), FC(50, "relu"), Regression(5)]))
    state, flag, draws = build_draws(net, 2000)
    used, want_flag = _gauss_draws_python(2000, False, 55 * 50 + 50 * 50 + 50 * 5)
    assert (draws, flag) == (used, int(want_flag))


class _Obs:
    """Minimal stand-in for sim.simulator.Observation (one ego row, world 0)."""

    def __init__(self, x: list[float], mr: np.ndarray, car: int = 0) -> None:
        self.inputs = np.array([x])
        self.world = np.array([0])
        self.car = np.array([car])
        self.mrand = mr

    def __len__(self) -> int:
        return 1


@pytest.mark.parametrize("ruleset", ["v1", "v2"])
def test_brain_policy_warmup_and_window(ruleset: str) -> None:
    # tw = 2: warm-up for 2 decisions (v2: action 0, no draw; v1: ⌊5u⌋, one draw), then the input is
    # [x_t, x_{t-1}, e(a_{t-1})·ns, x_{t-2}, e(a_{t-2})·ns] and a greedy step draws rf + ni Gaussians.
    settings = Settings(lanes_side=0, patches_ahead=2, patches_behind=0, temporal_window=2, epsilon_test_time=0.0)
    ni = settings.net_inputs
    assert ni == 2 + 2 * (2 + 5)
    w = np.zeros((5, ni))
    w[3, :] = 1.0  # Q_3 = Σ inputs > 0 = Q_others
    net = ConvNet(expand([Input(ni), Regression(5)]), ((w, np.zeros(5)),))
    pol = BrainPolicy.of_settings(net, settings, ruleset)
    pol.prepare("v2-official" if ruleset == "v2" else "v1-original", 1)
    mr = np.array([99], dtype=np.int64)
    a1 = int(pol(_Obs([0.25, 0.5], mr))[0])
    s1 = int(mr[0])
    if ruleset == "v2":
        assert a1 == 0 and s1 == 99
    else:
        s, u = mulberry32_next(99)
        assert s1 == s and a1 == math.floor(u * 5)
    a2 = int(pol(_Obs([0.75, 1.0], mr))[0])
    cache = int(pol.wstate[0, 0])
    s2 = int(mr[0])
    a3 = int(pol(_Obs([1.0, 1.0], mr))[0])
    assert a3 == 3
    expected = (
        [1.0, 1.0, 0.75, 1.0] + [2.0 * (k == a2) for k in range(5)] + [0.25, 0.5] + [2.0 * (k == a1) for k in range(5)]
    )
    assert pol.netin.tolist() == expected
    # one rf draw, then the Gaussians of a Vol(1, 1, ni)
    state, flag, _draws = replay_build(mulberry32_advance(s2, 1), cache, ni)
    assert int(mr[0]) == state and int(pol.wstate[0, 0]) == flag
    assert pol.bstate[0, 0, 0] == 3


def test_agents_copy_the_ego_brain_once() -> None:
    # v2: agents return 0 (load-time copies in warm-up) until the ego has made more than tw decisions,
    # then every agent starts from the ego's windows and counters.
    settings = Settings(
        lanes_side=0, patches_ahead=1, patches_behind=0, temporal_window=1, epsilon_test_time=0.0, other_agents=3
    )
    ni = settings.net_inputs
    w = np.zeros((5, ni))
    w[4, 1] = 1.0  # Q_4 = x_{t-1}[0]: the previous state seen by this brain
    w[2, 1] = -1.0
    net = ConvNet(expand([Input(ni), Regression(5)]), ((w, np.zeros(5)),))
    pol = BrainPolicy.of_settings(net, settings, "v2")
    pol.prepare("v2-official", 1)
    mr = np.array([5], dtype=np.int64)
    assert pol(_Obs([0.5], mr))[0] == 0  # ego warm-up
    assert pol(_Obs([0.9], mr, car=1))[0] == 0  # agent before the copy
    assert pol.wstate[0, 1] == 0
    assert pol(_Obs([0.7], mr))[0] == 4  # ego greedy: previous ego state 0.5 > 0
    assert pol(_Obs([-0.3], mr, car=2))[0] == 4  # agent 2: copy of the ego → previous state 0.7
    assert pol.wstate[0, 1] == 1
    assert pol.bstate[0, 2, 0] == pol.bstate[0, 0, 0] + 1
    assert pol(_Obs([0.1], mr, car=2))[0] == 2  # its own previous state −0.3 now
