"""The learners reproduce the original's training runs (learner_scores*.json) to the digit.

Two learners, two checks:

* ``js_learner.train_exact`` — the deepqlearn/SGDTrainer arithmetic in float64 with every draw
  taken from the original's ``Math.random`` stream — gives every training-run score, the count of
  random draws, deepqlearn's reward/loss windows and the evaluation scores of the reference runs;
* the torch learner (``learner.train``, float64, ``stream="original"``) takes the same draws and
  makes the same decisions, so it ends with the same training-run scores.

The v1 reference evaluations are v1-original with seed 100 + s, no engine-load draws
(``engine_load=False``) and, the harness having evaluated in the training's process, convnetjs's
Gaussian cache flag as the training left it (it matters for odd net_inputs: default_v1 seed 2).
The v2 ones are the official worker's, seed 100 + s.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from autotune.learner.brain_policy import evaluate_net
from autotune.learner.config import preset
from autotune.learner.js_learner import OriginalStream, draws_between, train_exact
from autotune.learner.official import evaluate_official
from autotune.learner.training import train
from sim.config import ConfigError
from sim.rng import mulberry32_advance
from tests.conftest import SHARED, load_json

REFERENCE = {
    "v1": load_json(SHARED / "reference" / "learner_scores.json"),
    "v2": load_json(SHARED / "reference" / "learner_scores_v2.json"),
}


def _reference(config_file: str, seed: int, ruleset: str = "v1") -> dict:
    for run in REFERENCE[ruleset]["runs"]:
        if run["config_file"] == config_file and run["train"]["seed"] == seed:
            return run
    raise KeyError((config_file, seed, ruleset))


CASES = [("v1", "default_v1", 1), ("v1", "default_v1", 2), ("v1", "network_basic", 1), ("v2", "network_basic", 1)]
# strong_lr1e-3 diverges to NaN around decision 5,000 and keeps training on NaN, as convnetjs does;
# its evaluation sees the NaN weights as 0 after the JSON round trip (spec §10.7)
EXACT_CASES = [*CASES, ("v1", "strong_lr1e-3", 1), ("v2", "network_basic", 2)]


@pytest.mark.parametrize(("ruleset", "name", "seed"), EXACT_CASES)
def test_exact_training_run_matches_the_original(ruleset: str, name: str, seed: int) -> None:
    ref = _reference(f"{name}.json", seed, ruleset)
    config = preset(name, ruleset=ruleset)
    result = train_exact(config, seed)
    t = ref["train"]
    assert sorted(result.training_run_scores) == t["training_run_mph_sorted"]
    assert result.random_draws == t["random_draws" if ruleset == "v1" else "math_random_draws"]
    assert result.brain_age == t["brain_age"]
    assert result.forward_passes == t["forward_passes"]
    assert result.experience_size_final == t["experience_size_final"]
    assert result.final_epsilon == t["final_epsilon"]
    assert result.avg_reward_window == t["avg_reward_window"]
    # the loss window differs from V8's in the last bits only (Math.log of the initial weights)
    if t["avg_loss_window"] is None:  # NaN in the original, null in its JSON
        assert math.isnan(result.avg_loss_window)
    else:
        assert result.avg_loss_window == pytest.approx(t["avg_loss_window"], rel=1e-12)
    if ruleset == "v1":
        ev = evaluate_official(
            result.convnet, config, seed=ref["eval"]["seed"], engine_load=False, gauss_cache=result.final_gauss_cache
        )
        assert ev.median_site == ref["eval"]["median_original"]
    else:  # the v2 worker evaluates in a fresh engine; its traffic does not depend on Math.random
        ev = evaluate_official(result.convnet, config, seed=ref["eval"]["seed"])
        assert ev.median_site == ref["eval"]["median_site"]
    assert ev.scores == ref["eval"]["scores_run_order"]


@pytest.mark.parametrize(("ruleset", "name", "seed"), CASES)
def test_torch_learner_on_the_original_stream_makes_the_same_run(ruleset: str, name: str, seed: int) -> None:
    ref = _reference(f"{name}.json", seed, ruleset)
    config = preset(name, ruleset=ruleset, dtype="float64")
    result = train(config, seed, quick_eval=False, stream="original")
    assert sorted(result.training_run_scores) == ref["train"]["training_run_mph_sorted"]
    assert result.decisions == ref["train"]["forward_passes"]


def test_evaluation_with_and_without_the_engine_load_differ() -> None:
    """Guard for the harness difference: evaluate.js's 60 construction draws change every run."""
    ref = _reference("default_v1.json", 1)
    config = preset("default_v1", ruleset="v1")
    result = train_exact(config, 1)
    settings = config.settings
    without = evaluate_net(result.convnet, settings, "v1-original", seed=101, runs=2, engine_load=False)
    assert without.scores == ref["eval"]["scores_run_order"][:2]
    with_load = evaluate_net(result.convnet, settings, "v1-original", seed=101, runs=2)
    assert with_load.scores != ref["eval"]["scores_run_order"][:2]


def test_original_stream_initialisation_matches_the_replica() -> None:
    config = preset("network_basic", ruleset="v1")
    replica = train_exact(config.replace(train_iterations=0), 7)
    stream = OriginalStream(7)
    shapes = [w.shape for w, _b in replica.convnet.params]
    for w, (w_ref, _b) in zip(stream.init_weights(shapes), replica.convnet.params, strict=True):
        np.testing.assert_array_equal(w, w_ref)
    assert draws_between(7, stream.state) == replica.random_draws
    assert replica.training_run_scores == []
    biases = [b for _w, b in replica.convnet.params]
    assert biases[0].tolist() == [0.1] * 10  # relu layers start at bias_pref 0.1
    assert biases[1].tolist() == [0.0] * 5


def test_draws_between_inverts_the_counter() -> None:
    assert draws_between(123, mulberry32_advance(123, 0)) == 0
    assert draws_between(123, mulberry32_advance(123, 1000)) == 1000
    assert draws_between(0xFFFFFFF0, mulberry32_advance(0xFFFFFFF0, 77)) == 77


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"ruleset": "v2", "other_agents": 2}, "other_agents"),
        ({"method": "adadelta"}, "method"),
        ({"layers": "fc:8:relu|dropout:0.5"}, r"layers\[\d+\]: Dropout"),
        ({"layers": "fc:8:maxout:group_size=2"}, r"layers\[\d+\]: Maxout"),
    ],
)
def test_exact_replica_names_what_it_does_not_cover(change: dict, field: str) -> None:
    config = preset("default_v1", ruleset="v1").replace(**change)
    with pytest.raises(ConfigError, match=r"^" + field):
        train_exact(config, 1)


def test_unknown_stream_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="^stream: 'js' is not a stream"):
        train(preset("default_v1", ruleset="v1"), 1, quick_eval=False, stream="js")


def test_momentum_update_follows_convnetjs() -> None:
    """sgd with momentum: v = μv − lr·g, w += v with g = (l2·w + dw)/B — checked on one short run.

    No reference run uses momentum; this pins the replica and the torch learner (same stream,
    float64) to each other on a momentum config over 2,000 decisions, which exercises the
    replacement rule (memory 300) and learning from decision 103 on.
    """
    config = preset(
        "default_v1",
        ruleset="v1",
        dtype="float64",
        momentum=0.9,
        train_iterations=2000,
        experience_size=300,
        start_learn_threshold=100,
        learning_steps_burnin=200,
        learning_steps_total=1500,
        layers="fc:6:relu|fc:4:relu",
        batch_size=8,
    )
    replica = train_exact(config, 11)
    torch_run = train(config, 11, quick_eval=False, stream="original")
    assert torch_run.training_run_scores == replica.training_run_scores
    torch_net = torch_run.convnet()
    for (w, b), (w_ref, b_ref) in zip(torch_net.params, replica.convnet.params, strict=True):
        np.testing.assert_allclose(w, w_ref, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(b, b_ref, rtol=1e-9, atol=1e-12)
    assert math.isfinite(replica.avg_loss_window)


def test_train_cli_reproduces_the_original_run(tmp_path) -> None:
    """``python -m autotune.train --stream original`` on default_v1 seed 2: the reference's training runs."""
    import json

    from autotune.cli import main

    out = tmp_path / "run"
    argv = ["--preset", "default_v1", "--set", "ruleset=v1", "--set", "dtype=float64", "--seed", "2"]
    assert (
        main(["train", *argv, "--stream", "original", "--no-quick-eval", "--no-eval", "--quiet", "--out", str(out)])
        == 0
    )
    result = json.loads((out / "result.json").read_text())
    assert sorted(result["training_run_scores"]) == _reference("default_v1.json", 2)["train"]["training_run_mph_sorted"]
    assert result["final_gauss_cache"] == 1
    assert json.loads((out / "config.json").read_text())["stream"] == "original"
    for name in ("net.json", "net.config.json", "net.js", "checkpoint.pt", "curve.csv"):
        assert (out / name).is_file()


def test_evaluate_cli_reproduces_the_reference_evaluation(tmp_path, capsys) -> None:
    """``python -m autotune.evaluate … --no-engine-load`` = the learner_scores.json evaluation."""
    import json

    from autotune.convnet.netjson import write_net
    from autotune.evaluate import main  # the python -m autotune.evaluate shim

    config = preset("default_v1", ruleset="v1")
    result = train_exact(config, 1)
    write_net(tmp_path / "net.json", result.convnet, config.settings)
    argv = ["--net", str(tmp_path / "net.json"), "--protocol", "v1-original", "--seed", "101"]
    assert main([*argv, "--no-engine-load", "--gauss-cache", str(result.final_gauss_cache), "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["scores"] == _reference("default_v1.json", 1)["eval"]["scores_run_order"]


def test_original_stream_with_agents_is_reproducible() -> None:
    """v2 agents draw their ε-greedy choices (and greedy Vols) from the same stream: same seed, same run."""
    config = preset(
        "network_basic", ruleset="v2", other_agents=3, train_iterations=2000, learning_steps_burnin=1, temporal_window=1
    )
    a = train(config, 5, quick_eval=False, stream="original")
    b = train(config, 5, quick_eval=False, stream="original")
    c = train(config, 6, quick_eval=False, stream="original")
    assert a.agent_decisions > 0
    assert a.training_run_scores == b.training_run_scores
    assert a.training_run_scores != c.training_run_scores


def test_fast_paths_hold_to_the_replicas_decision_rules():
    """The shared routines of the fast paths (``autotune.convnet.random`` / ``.deepqlearn``) against the
    replica's own copies: same draws consumed, same cache flags."""
    import numpy as np

    from autotune.convnet.random import gauss_skip as fast_skip
    from autotune.learner.js_learner import gauss_skip as replica_skip

    # the fast skip tests attempts in blocks of 64, 16 and 4: sizes at and around each block edge, states that wrap
    # past 2³², and a run of calls that carries the cache flag and the state on
    rng = np.random.default_rng(5)
    states = [1, 2000, 123456789, 2**32 - 1, 2**32 - 0x6D2B79F5, *rng.integers(0, 2**32, 6).tolist()]
    sizes = [0, 1, 2, 3, 7, 8, 9, 31, 32, 33, 63, 64, 127, 128, 129, 333, 1000, 4097]
    for state in states:
        for cache in (0, 1):
            for n in sizes:
                a, b = np.array([state], dtype=np.int64), np.array([state], dtype=np.int64)
                assert fast_skip(a, 0, cache, n) == replica_skip(b, 0, cache, n) and a[0] == b[0], (state, cache, n)
    a, b = np.array([77], dtype=np.int64), np.array([77], dtype=np.int64)
    fa = fb = 0
    for n in rng.integers(0, 300, 2000).tolist():
        fa, fb = fast_skip(a, 0, fa, n), replica_skip(b, 0, fb, n)
        assert fa == fb and a[0] == b[0], n


def _replica_decisions(config, seed: int, states: np.ndarray):
    """The replica's ``_learn`` per decision with learning off (memory below the threshold, never full):
    (action, net input or None during warm-up, ε, Math.random state after) per decision, and its net."""
    import autotune.learner.js_learner as js
    from autotune.convnet.spec import ConvNet, fc_bias_prefs

    lay, n_params = js._check(config)
    mr = np.array([seed], dtype=np.int64)
    cache = np.zeros(2)
    P = np.zeros(n_params)
    for li, pref in enumerate(fc_bias_prefs(config.expanded_layers)):
        n_in, n_out, off, _act = (int(v) for v in lay[li])
        P[off + n_in * n_out : off + n_in * n_out + n_out] = pref
    js._init_weights(mr, cache, lay, P)
    width = max(int(lay[:, 0].max()), int(lay[:, 1].max()))
    D, ns, tw = config.net_inputs, config.num_states, config.temporal_window
    n, size = max(tw, 2), config.experience_size
    hp = np.zeros(js.N_HP, dtype=np.int64)
    hp[js.H_TW], hp[js.H_NS], hp[js.H_D], hp[js.H_WINDOW] = tw, ns, D, n
    hp[js.H_EXP_SIZE], hp[js.H_START], hp[js.H_BATCH] = size, config.start_learn_threshold, config.batch_size
    hp[js.H_BURNIN], hp[js.H_TOTAL], hp[js.H_HEAD] = config.learning_steps_burnin, config.learning_steps_total, n - 1
    hp[js.H_CACHE], hp[js.H_V2] = int(cache[0] != 0.0), int(config.ruleset == "v2")
    hf = np.zeros(js.N_HF)
    hf[js.F_GAMMA], hf[js.F_LR], hf[js.F_EPS_MIN], hf[js.F_EPSILON] = config.gamma, 0.0, config.epsilon_min, 1.0
    args = (
        hp, hf, lay, P, np.zeros(n_params), np.zeros(n_params), np.zeros((lay.shape[0] + 1, width)),
        np.zeros(width), np.zeros(width), np.zeros((n, D)), np.zeros((n, ns)), np.zeros(n, dtype=np.int64),
        np.full(n, math.nan), np.zeros((size, D)), np.zeros((size, D)), np.zeros(size, dtype=np.int64),
        np.zeros(size), np.zeros(js.WINDOW_SIZE), np.zeros(js.WINDOW_SIZE), np.zeros(D),
    )  # fmt: skip
    start = (int(mr[0]), int(hp[js.H_CACHE]))
    out = []
    for t, x in enumerate(states):
        action = js._learn(x, 0.0, mr, *args)
        net_input = args[-1].copy() if t + 1 > tw else None
        out.append((action, net_input, float(hf[js.F_EPSILON]), int(mr[0])))
    assert hp[js.H_UPDATES] == 0 and hp[js.H_N_EXP] < size  # learning off: the weights stay the built ones
    params = []
    for li in range(lay.shape[0]):
        n_in, n_out, off, _act = (int(v) for v in lay[li])
        params.append((P[off : off + n_in * n_out].reshape(n_out, n_in).copy(), P[off + n_in * n_out :][:n_out].copy()))
    return start, out, ConvNet(layers=config.expanded_layers, params=tuple(params))


@pytest.mark.parametrize(
    ("ruleset", "tw", "burnin", "total"), [("v1", 3, 0, 1), ("v2", 2, 0, 1), ("v1", 1, 10, 60), ("v2", 4, 5, 40)]
)
def test_shared_decision_rules_make_the_replicas_decisions(ruleset: str, tw: int, burnin: int, total: int) -> None:
    """Same states, same Math.random stream → the shared rules (``autotune.convnet.deepqlearn``) give the
    replica's net inputs (window with the one-hot × num_states), ε, actions and draws — the Python
    rules (flat history, ``explore_action``, ``warmup_action``) and the compiled brain policy's
    (ring buffers, ``explore_action_mr``, ``warmup_action_mr``, ``argmax_js``)."""
    from autotune.convnet.deepqlearn import (
        GREEDY,
        explore_action,
        js_argmax_rows,
        js_epsilon,
        shift_window,
        warmup_action,
    )
    from autotune.convnet.forward import forward
    from autotune.convnet.random import gauss_skip
    from autotune.learner.brain_policy import BrainPolicy, brain_policy
    from autotune.learner.config import TrainConfig
    from sim.rng import mrand

    config = TrainConfig.from_mapping(dict(
        ruleset=ruleset, lanes_side=1, patches_ahead=2, patches_behind=1, temporal_window=tw, layers="fc:6:relu",
        experience_size=500, start_learn_threshold=400, learning_steps_burnin=burnin, learning_steps_total=total,
        epsilon_min=0.3, epsilon_test_time=0.3,
    ))  # fmt: skip
    states = np.random.default_rng(tw).random((120, config.num_states)) * 3.0
    (mr0, cache0), replica, net = _replica_decisions(config, 4242, states)
    greedy_at: set[int] = set()

    # Python rules: flat history, the torch learner's and the training agents' path
    ns = config.num_states
    hist = np.zeros(tw * (ns + 5))
    mr, cache = np.array([mr0], dtype=np.int64), cache0
    draw = lambda: mrand(mr, 0)  # noqa: E731
    for t, (x, (want, want_input, want_eps, want_mr)) in enumerate(zip(states, replica, strict=True)):
        if t + 1 <= tw:
            action = warmup_action(ruleset == "v2", draw)
        else:
            net_input = np.concatenate([x, hist])
            np.testing.assert_array_equal(net_input, want_input, err_msg=f"decision {t + 1}: net input")
            eps = js_epsilon(t + 1, burnin, total, config.epsilon_min)
            assert eps == want_eps, (t + 1, eps, want_eps)
            action = explore_action(draw, eps)
            if action == GREEDY:
                greedy_at.add(t)
                cache = gauss_skip(mr, 0, cache, config.net_inputs)  # policy()'s new Vol
                action = int(js_argmax_rows(forward(net, net_input)[None, :])[0])
        assert (action, int(mr[0])) == (want, want_mr), f"decision {t + 1}: action/draws"
        if tw:
            shift_window(hist, x, action, ns)
    assert len(greedy_at) > 10

    # compiled rules: the exact brain policy (ring buffers) — its ε is ε_test, so only where the schedule is flat
    if (burnin, total) == (0, 1):
        policy = BrainPolicy(net, config.engine_config, config.temporal_window, config.epsilon_test_time)
        policy.reset(1, np.array([cache0], dtype=np.int64))
        mr = np.array([mr0], dtype=np.int64)
        for t, (x, (want, want_input, _eps, want_mr)) in enumerate(zip(states, replica, strict=True)):
            action = brain_policy(x, 0, 0, math.nan, mr, 0, policy.pstate)
            assert (action, int(mr[0])) == (want, want_mr), f"decision {t + 1}: compiled action/draws"
            if t in greedy_at:  # the ring buffers built the input policy() saw
                np.testing.assert_array_equal(policy.netin, want_input, err_msg=f"decision {t + 1}: net input")
