"""Simulator API: configs, seeding, batch stepping, generators, scoring helpers."""

from __future__ import annotations

import numpy as np
import pytest

from sim.config import ConfigError, EngineConfig
from sim.policies import BUILTINS
from sim.protocols import evaluate, js_number_to_string, site_median
from sim.rng import mulberry32_stream, pm_next, pm_seed_state
from sim.simulator import PolicyError, Simulator, check_actions


def test_mulberry32_test_vector():
    assert mulberry32_stream(1, 5) == [
        0.6270739405881613,
        0.002735721180215478,
        0.5274470399599522,
        0.9810509674716741,
        0.9683778982143849,
    ]


def test_park_miller():
    assert pm_seed_state(0) == 2147483646 and pm_seed_state(2147483647) == 2147483646
    assert pm_next(1) == 16807 and pm_next(16807) == 282475249


def test_config_validation_names_the_field():
    with pytest.raises(ConfigError, match="ruleset"):
        EngineConfig(ruleset="v9")
    with pytest.raises(ConfigError, match="other_agents"):
        EngineConfig(other_agents=11)
    with pytest.raises(ConfigError, match="patches_ahead"):
        EngineConfig(patches_ahead=0, patches_behind=0)
    with pytest.raises(ConfigError, match="did you mean 'lanes_side'"):
        EngineConfig.from_mapping({"lane_side": 1})
    cfg = EngineConfig.from_mapping({"lanesSide": 2, "patchesAhead": 5, "patchesBehind": 1, "otherAgents": 4})
    assert (cfg.lanes_side, cfg.num_inputs, cfg.other_agents) == (2, 30, 4)


def test_check_actions():
    assert check_actions([0, 4, 2], 3).tolist() == [0, 4, 2]
    with pytest.raises(PolicyError, match="shape"):
        check_actions([0, 1], 3)
    with pytest.raises(PolicyError, match="action 5"):
        check_actions([0, 5, 1], 3)
    with pytest.raises(PolicyError, match="non-integer"):
        check_actions([0.5], 1)


@pytest.mark.parametrize("ruleset,agents", [("v1", 0), ("v2", 0), ("v2", 10)])
def test_worlds_of_a_batch_are_independent(ruleset, agents):
    """World i of a batch equals the same seed simulated alone (no cross-talk between worlds)."""
    config = EngineConfig(ruleset=ruleset, lanes_side=1, patches_ahead=10, other_agents=agents)
    policy = BUILTINS["heuristic_a"].bind(config)
    batch = evaluate(config, policy, "custom", seed=40, runs=6, frames=900)
    alone = [evaluate(config, policy, "custom", seed=40 + i, runs=1, frames=900).scores[0] for i in range(6)]
    assert batch.scores == alone


def test_v2_agent_decisions_are_staggered():
    config = EngineConfig(ruleset="v2", other_agents=10)
    sim = Simulator(config, n_worlds=1, frames_per_run=60)
    sim.seed_independent(3)
    seen = []
    obs = sim.start()
    while obs is not None:
        seen.append(int(obs.car[0]))
        assert np.isnan(obs.reward[0]) == (obs.car[0] != 0)
        obs = sim.step(np.zeros(len(obs), dtype=int))
    # ego at frames 0 and 30; agents 1…9 at 3i and 30 + 3i; agent 10 never decides
    assert seen == [0, *range(1, 10), 0, *range(1, 10)]
    assert sim.done and np.isfinite(sim.scores[0, 0])


def test_single_world_fast_path_matches_batch():
    config = EngineConfig(ruleset="v2", lanes_side=1, patches_ahead=10)
    policy = BUILTINS["heuristic_a"].bind(config)
    sim = Simulator(config, 1, 2000, runs_per_world=3)
    sim.seed_stream(1)
    car = sim.start_single()
    while car >= 0:
        action = policy.compiled(sim.obs_inputs[0], 0, car, 0.0, sim.mrand, 0, policy.pstate)
        car = sim.step_single(action)
    official = evaluate(config, policy, "v2-official", runs=3)
    assert sim.scores[0].tolist() == official.scores
    assert sim.frames_simulated == 6000


def test_run_scores_are_truncated_and_sorted_like_js():
    assert js_number_to_string(70.0) == "70" and js_number_to_string(7.8) == "7.8"
    assert js_number_to_string(float("nan")) == "NaN"
    # one String(x) for the median's sort and the net JSON (autotune.convnet.netjson.js_num): JS's layout
    assert js_number_to_string(5e-5) == "0.00005" and js_number_to_string(1e-7) == "1e-7"
    assert site_median([5e-5, 1e-3]) == 1e-3  # "0.00005" < "0.001" (a Python repr would sort "5e-05" last)
    # "7.8" sorts after "10.5" as a string: the originals' median breaks below 10 mph
    assert site_median([7.8, 10.5, 9.9]) == 7.8
    assert site_median([71.2, 70.1, 72.3, 69.0]) == 71.2


def test_seeding_required():
    sim = Simulator(EngineConfig(), 2, 10)
    with pytest.raises(RuntimeError, match="seed"):
        sim.start()


@pytest.mark.parametrize("ruleset,agents", [("v1", 0), ("v2", 0), ("v2", 4)])
@pytest.mark.parametrize("name", sorted(BUILTINS))
def test_compiled_builtin_matches_python_batches(name, ruleset, agents):
    """The parallel compiled driver makes the same decisions and draws as the Python step loop."""
    config = EngineConfig(ruleset=ruleset, other_agents=agents, lanes_side=1, patches_ahead=10)
    policy = BUILTINS[name].bind(config)
    compiled = Simulator(config, 24, 300, 2)
    compiled.seed_independent(7)
    policy.run(compiled, 0, 10)
    policy.run(compiled, 10, 24, max_runs=1)
    policy.run(compiled, 10, 24, max_runs=1)
    stepped = Simulator(config, 24, 300, 2)
    stepped.seed_independent(7)
    obs = stepped.start()
    while obs is not None:
        obs = stepped.step(policy(obs))
    assert compiled.done
    np.testing.assert_array_equal(compiled.scores, stepped.scores)
    np.testing.assert_array_equal(compiled.mrand, stepped.mrand)
    np.testing.assert_array_equal(compiled.cars, stepped.cars)


def test_compiled_builtin_refuses_bad_arguments():
    policy = BUILTINS["noop"].bind(EngineConfig(ruleset="v1"))
    with pytest.raises(ValueError, match="configuration differs"):
        policy.run(Simulator(EngineConfig(ruleset="v2"), 1, 10))
    with pytest.raises(RuntimeError, match="seed the simulator"):
        policy.run(Simulator(EngineConfig(ruleset="v1"), 1, 10))
    sim = Simulator(EngineConfig(ruleset="v1"), 4, 10)
    sim.seed_independent(0)
    for first, last in ((0, 5), (-1, 2), (3, 2)):
        with pytest.raises(ValueError, match="first ≤ last ≤ n_worlds = 4"):
            policy.run(sim, first, last)
    with pytest.raises(ValueError, match="max_runs must be ≥ 1"):
        policy.run(sim, max_runs=0)
    assert np.isnan(sim.scores).all()  # nothing ran


def test_any_policy_with_a_compiled_twin_drives_the_sequential_protocols():
    """A user policy carrying ``compiled``/``pstate`` (not a built-in) goes through ``run_compiled``."""
    config = EngineConfig(ruleset="v2", other_agents=3, lanes_side=1, patches_ahead=10)
    bound = BUILTINS["heuristic_a"].bind(config)

    class Twin:
        compiled = staticmethod(bound.compiled)
        pstate = bound.pstate
        stateful = False

        def __call__(self, obs):  # noqa: ANN001, ANN204
            raise AssertionError("the sequential protocol must call the compiled twin")

    want = evaluate(config, bound, "v2-official", runs=4)
    got = evaluate(config, Twin(), "v2-official", runs=4)
    assert got.scores == want.scores
    assert got.ego_scores == want.ego_scores


def test_evaluate_sets_numba_threads_for_the_call_only() -> None:
    """``threads`` is scoped: numba's process-wide count is the same after the call (and after a failing one)."""
    import numba

    from sim.protocols import CUSTOM, numba_threads

    config = EngineConfig(ruleset="v2", lanes_side=0, patches_ahead=1, patches_behind=0)
    before = numba.get_num_threads()
    seen: list[int] = []

    def policy(obs):  # noqa: ANN001, ANN202 - a Python policy: records the count it runs under
        seen.append(numba.get_num_threads())
        return np.zeros(len(obs), dtype=np.int64)

    most = numba.config.NUMBA_NUM_THREADS
    with numba_threads(most):  # the caller's count, whatever the machine
        evaluate(config, policy, CUSTOM, runs=2, frames=20, threads=1)
        assert set(seen) == {1} and numba.get_num_threads() == most
        with pytest.raises(ConfigError, match="threads: must be ≥ 1"):
            evaluate(config, policy, CUSTOM, runs=2, frames=20, threads=0)
        with pytest.raises(RuntimeError), numba_threads(1):
            raise RuntimeError("the block fails")
        assert numba.get_num_threads() == most
    assert numba.get_num_threads() == before


@pytest.mark.parametrize(("ruleset", "protocol", "runs", "stops"), [
    ("v2", "v2-official", 260, (37, 1, 100, 0)),
    ("v1", "v1-original", 10, (3, 4)),
])  # fmt: skip
def test_a_paused_sequential_evaluation_is_the_whole_one(ruleset, protocol, runs, stops):  # noqa: ANN001
    """``SequentialEvaluation`` pauses between runs: its result after k runs is the whole evaluation's first k
    runs, and carried on to the end it is ``evaluate``'s result to the digit, wherever it paused (the world, the
    ``Math.random`` stream and the policy's state carry over; the random policy draws from that stream)."""
    from sim.protocols import SequentialEvaluation

    config = EngineConfig(ruleset=ruleset, other_agents=2 if ruleset == "v2" else 0, lanes_side=1, patches_ahead=10)
    policy = BUILTINS["random"].bind(config)
    want = evaluate(config, policy, protocol, runs=runs)
    paused = SequentialEvaluation(config, policy, protocol, runs=runs)
    done = 0
    for stop in stops:
        done = paused.advance(stop)
        if done:
            part = paused.result()
            assert part.runs == done and part.scores == want.scores[:done] and not part.official_size
    assert done == sum(stops)
    seen: list[tuple[int, int]] = []
    assert paused.advance(progress=lambda d, t: seen.append((d, t))) == runs and paused.done
    assert paused.advance(5) == runs  # never past the end
    got = paused.result()
    assert (got.scores, got.ego_scores, got.runs) == (want.scores, want.ego_scores, runs)
    assert seen[-1] == (runs * want.frames, runs * want.frames)


def test_a_paused_evaluation_needs_a_sequential_protocol_and_a_compiled_policy():
    from sim.protocols import SequentialEvaluation

    config = EngineConfig(ruleset="v2", lanes_side=1, patches_ahead=10)
    policy = BUILTINS["random"].bind(config)
    with pytest.raises(ConfigError, match="'custom' runs independent worlds; pausable evaluations are sequential"):
        SequentialEvaluation(config, policy, "custom")
    with pytest.raises(ConfigError, match="policy: a pausable evaluation drives a compiled policy"):
        SequentialEvaluation(config, lambda obs: np.zeros(len(obs), dtype=np.int64), "v2-official")
    paused = SequentialEvaluation(config, policy, "v2-official", runs=3)
    with pytest.raises(RuntimeError, match="no run done yet"):
        paused.result()
    with pytest.raises(ConfigError, match="runs: must be ≥ 0"):
        paused.advance(-1)


def test_v2_heldout_moves_only_the_runs_of_the_official_harness() -> None:
    """``v2-heldout``: the official evaluation (``Math.random := mulberry32(1)``, one world, runs coupled through
    ``reset()``) with the run counter starting at its seed, so run k uses Park–Miller seed seed + k + 1: seed 0 is
    ``v2-official`` exactly, and a seed whose runs would pass the generator's range is refused by name."""
    from sim.layout import I_RUN_COUNTER
    from sim.protocols import PROTOCOLS, V2_HELDOUT

    config = EngineConfig(ruleset="v2", other_agents=2, lanes_side=1, patches_ahead=10)
    policy = BUILTINS["random"].bind(config)  # draws from the Math.random stream the two protocols share
    official = evaluate(config, policy, "v2-official", runs=4)
    assert evaluate(config, policy, V2_HELDOUT, seed=0, runs=4).scores == official.scores
    held = evaluate(config, policy, V2_HELDOUT, runs=4)
    assert held.seed == PROTOCOLS[V2_HELDOUT].seed == 1_000_000 and held.scores != official.scores
    sim = Simulator(config, 1, 10, runs_per_world=2)
    sim.seed_stream(1, run_counter=41)
    assert sim.ints[0, I_RUN_COUNTER] == 42  # the first run's Park–Miller seed: counter + 1
    with pytest.raises(ConfigError, match=r"seed: v2-heldout's runs use Park–Miller seeds .* got -1"):
        evaluate(config, policy, V2_HELDOUT, seed=-1, runs=4)
    with pytest.raises(ConfigError, match=r"seed must be an integer in 0–2,147,483,642 for 4 runs"):
        evaluate(config, policy, V2_HELDOUT, seed=2**31 - 5, runs=4)
    with pytest.raises(ValueError, match="run_counter is a v2 evaluation's"):
        Simulator(EngineConfig(ruleset="v1"), 1, 10, runs_per_world=2).seed_stream(1, run_counter=3)
