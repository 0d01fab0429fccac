"""Per-run scores of the fixed policies, digit for digit, in every protocol of the reference data."""

from __future__ import annotations

import pytest

from sim.config import EngineConfig
from sim.policies import BUILTINS
from sim.protocols import evaluate
from tests.conftest import REFERENCE, load_json

# Loaded at collection: missing reference data is an error, never a silently empty parametrisation.
V1 = load_json(REFERENCE / "policy_scores.json")
V2 = load_json(REFERENCE / "policy_scores_v2.json")


def _config(entry: dict, ruleset: str, agents: int = 0) -> EngineConfig:
    ic = entry["input_config"]
    return EngineConfig(
        ruleset=ruleset,
        lanes_side=ic["lanesSide"],
        patches_ahead=ic["patchesAhead"],
        patches_behind=ic["patchesBehind"],
        other_agents=agents,
    )


@pytest.mark.parametrize("agents", [0, 10])
@pytest.mark.parametrize("name", sorted(V2["policies"]))
def test_v2_official(name, agents):
    entry = V2["policies"][name]
    ref = entry[f"otherAgents_{agents}"]
    config = _config(entry, "v2", agents)
    result = evaluate(config, BUILTINS[name].bind(config), "v2-official")
    assert result.scores == ref["scores"]
    assert result.ego_scores == ref["ego_only_scores"]
    assert result.median_site == ref["median_site"]


@pytest.mark.parametrize("name", sorted(V2["policies"]))
def test_v2_official_through_python_policy(name):
    """The same protocol with the policy called from Python (no compiled twin) gives the same runs."""
    entry = V2["policies"][name]
    ref = entry["otherAgents_10"]
    config = _config(entry, "v2", 10)
    bound = BUILTINS[name].bind(config)
    result = evaluate(config, lambda obs: bound(obs), "v2-official", runs=20)
    assert result.scores == ref["scores"][:20]


@pytest.mark.parametrize("name", sorted(V1["policies"]))
def test_v1_distribution(name):
    entry = V1["policies"][name]
    config = _config(entry, "v1")
    result = evaluate(config, BUILTINS[name].bind(config), "v1-distribution")
    assert result.scores == entry["distribution"]["scores"]


@pytest.mark.parametrize("name", sorted(V1["policies"]))
def test_v1_original(name):
    entry = V1["policies"][name]
    config = _config(entry, "v1")
    policy = BUILTINS[name].bind(config)
    for rep in entry["original_protocol"]["repetitions"]:
        result = evaluate(config, policy, "v1-original", seed=rep["seed"])
        assert result.scores == rep["scores"]
        assert result.median_site == rep["median"]


def test_custom_protocol_is_v1_distribution_for_memoryless_policies():
    entry = V1["policies"]["heuristic_a"]
    config = _config(entry, "v1")
    result = evaluate(config, BUILTINS["heuristic_a"].bind(config), "custom", seed=1000, runs=200, frames=10_000)
    assert result.scores == entry["distribution"]["scores"]
