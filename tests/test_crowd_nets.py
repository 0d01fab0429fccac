"""CI parity: the crowd's trained nets reproduce the original JS engines' per-run scores exactly.

Reference: ``shared/reference/crowd_net_scores.json`` (15 nets × v2 official, v1 distribution and,
for v1 nets, 3 repetitions of v1 evaluate.js), computed by running the original JS. Every listed
evaluation is replayed in full (every run, every frame) and must match run for run.

The one input that is not a property of the net is convnetjs's global Gaussian-cache flag when
the reference harness built each brain (``tests/data/crowd_gauss_cache.json`` explains it): it
matters only for nets with an odd number of inputs, through the draw count of each greedy step.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

import pytest

from autotune.convnet.netjson import load
from autotune.learner.brain_policy import evaluate_net

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
REFERENCE = SHARED / "reference" / "crowd_net_scores.json"
NETS = SHARED / "crowd" / "nets"
CACHE_FLAGS = Path(__file__).resolve().parent / "data" / "crowd_gauss_cache.json"


def test_reference_data_present() -> None:
    if not REFERENCE.exists() or not NETS.is_dir():
        pytest.fail(f"reference data not found at {SHARED} (CI keeps ../shared beside the checkout)")


@functools.lru_cache(maxsize=1)
def _reference() -> dict:
    return json.loads(REFERENCE.read_text())["nets"]


@functools.lru_cache(maxsize=1)
def _flags() -> dict:
    return json.loads(CACHE_FLAGS.read_text())["start_flag"]


@functools.lru_cache(maxsize=4)
def _net(nid: str):  # noqa: ANN202
    return load(NETS / f"{nid}.json")


def _cases() -> list[tuple[str, str, int]]:
    if not REFERENCE.exists():
        return []
    cases = []
    for nid, entry in json.loads(REFERENCE.read_text())["nets"].items():
        for key in entry["results"]:
            if key == "v1_original":
                cases += [(nid, key, rep) for rep in range(3)]
            else:
                cases.append((nid, key, -1))
    return cases


def _diff(got: list[float], want: list[float]) -> str:
    bad = [i for i, (a, b) in enumerate(zip(got, want, strict=False)) if a != b]
    return f"{len(bad)} of {len(want)} runs differ; first: " + ", ".join(
        f"run {i}: {got[i]} vs JS {want[i]}" for i in bad[:5]
    )


@pytest.mark.slow
@pytest.mark.parametrize(("nid", "key", "rep"), _cases(), ids=lambda v: str(v))
def test_crowd_net_scores_exact(nid: str, key: str, rep: int) -> None:
    net, settings = _net(nid)
    ref = _reference()[nid]["results"][key]
    flags = _flags()[nid]
    if key.startswith("v2_official"):
        result = evaluate_net(net, settings, "v2-official", other_agents=ref["other_agents"], gauss_cache=flags[key])
        want = ref["scores"]
        assert result.scores == want, _diff(result.scores, want)
        assert result.ego_scores == ref["ego_only_scores"]
        assert result.median_site == ref["median_site"]
    elif key == "v1_dist":
        result = evaluate_net(net, settings, "v1-distribution", gauss_cache=flags[key])
        want = ref["scores"]
        assert result.scores == want, _diff(result.scores, want)
    else:
        repetition = ref["repetitions"][rep]
        result = evaluate_net(net, settings, "v1-original", seed=repetition["seed"], gauss_cache=flags[f"rep{rep}"])
        want = repetition["scores"]
        assert result.scores == want, _diff(result.scores, want)
        assert result.median_site == repetition["median"]


def test_cache_flag_matters_for_odd_inputs() -> None:
    """With an odd net_inputs the flag changes every greedy step's draw count, hence the traffic."""
    nid = "dt-anuj-dimri25-deep-traffic-v00"  # 55 inputs, v1, temporal window 3
    net, settings = _net(nid)
    want = _reference()[nid]["results"]["v1_original"]["repetitions"][0]["scores"]
    assert _flags()[nid]["rep0"] == 1
    fresh = evaluate_net(net, settings, "v1-original", seed=2000, runs=1, gauss_cache=0)
    inherited = evaluate_net(net, settings, "v1-original", seed=2000, runs=1, gauss_cache=1)
    assert inherited.scores == want[:1]
    assert fresh.scores != want[:1]


def test_protocol_api_paths_agree() -> None:
    """The policy object also works through ``sim.protocols.evaluate``: compiled twin and Python batches."""
    from autotune.learner.brain_policy import BrainPolicy, engine_config
    from sim.protocols import evaluate

    nid = "dt-m-quadra-deeptraffic-v04"  # svm + maxout, 9 agents: copies, staggered decisions
    net, settings = _net(nid)
    want = _reference()[nid]["results"]["v2_official_otherAgents9"]["scores"][:3]
    config = engine_config(settings, "v2")
    brain = settings.filled()  # the file's temporal window and ε_test, or deepqlearn's defaults
    policy = BrainPolicy(net, config, brain.temporal_window, brain.epsilon_test_time)
    stream = policy.prepare("v2-official", 1)
    compiled = evaluate(config, policy, "v2-official", runs=3, stream_state=stream)
    assert compiled.scores == want

    class PythonOnly:  # no compiled twin: sim calls __call__ once per decision batch
        stateful = True
        name = "python"

        def __call__(self, obs):  # noqa: ANN001, ANN204
            return policy(obs)

    stream = policy.prepare("v2-official", 1)
    python = evaluate(config, PythonOnly(), "v2-official", runs=3, stream_state=stream)
    assert python.scores == want


def test_custom_protocol_batched_worlds() -> None:
    nid = "dt-anirudhrbhat-deep-learning-for-self-driving-v00"  # tw 1, ε 0.01, 4 agents
    net, settings = _net(nid)
    a = evaluate_net(net, settings, "custom", runs=4, frames=600, seed=7)
    b = evaluate_net(net, settings, "custom", runs=4, frames=600, seed=7)
    assert a.scores == b.scores and len(a.scores) == 4 and a.other_agents == 4


def test_v2_heldout_is_the_official_harness_on_other_runs() -> None:
    """``v2-heldout`` at seed 0 is the site's evaluation to the digit (the JS's recorded runs of a net whose
    temporal window carries from run to run); at other seeds it plays other runs with that harness, where the
    ``custom`` protocol's fresh world per run scores the same net apart."""
    nid = "dt-anirudhrbhat-deep-learning-for-self-driving-v00"  # temporal window 1, ε_test 0.01, 4 agents
    net, settings = _net(nid)
    ref = _reference()[nid]["results"]["v2_official_otherAgents4"]
    flag = _flags()[nid]["v2_official_otherAgents4"]
    kw = {"other_agents": ref["other_agents"], "gauss_cache": flag, "runs": 6}
    at_zero = evaluate_net(net, settings, "v2-heldout", seed=0, **kw)
    assert at_zero.scores == ref["scores"][:6] and at_zero.seed == 0
    other = evaluate_net(net, settings, "v2-heldout", **kw)
    assert other.seed == 1_000_000 and other.scores != at_zero.scores
    assert evaluate_net(net, settings, "v2-heldout", seed=1_000_000, **kw).scores == other.scores
