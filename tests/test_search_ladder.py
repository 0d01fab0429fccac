"""Issue 14's search machinery: the budget ladder, the cost model and gate, the crowd prior, the seed race.

Fast tests (no Ray): a rung equals a standalone training at its budget; refused draws never become
trials; the crowd prior lands inside the space with no claimed score as a value; the race's rounds;
resuming with a changed space is refused.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import optuna
import pytest

from autotune import TrainConfig, dumps_net, evaluate_official
from autotune.learner import train
from autotune.search import keys, racing, space
from autotune.search.cost import FEATURES, CostModel, Observation, features, plan, plan_one
from autotune.search.driver import Driver, WarmConfig, clip_params, make_pruner, make_sampler
from autotune.search.gate import MAX_DRAWS, CostGatedSampler, distributions
from autotune.search.ladder import START_LEARN_CAP, Ladder, rung_config, rung_seed
from autotune.search.objective import COMPLETE, PRUNED, TrialOutcome, TrialTask, run_trial, static_policy
from autotune.search.spec import SpecError, StudySpec, load_spec, parse_spec
from autotune.search.storage import open_storage
from tests.conftest import ROOT, FakePool, forward_cost_model

optuna.logging.set_verbosity(optuna.logging.WARNING)
CONFIGS = ROOT / "study_configs"

TINY = TrainConfig(
    ruleset="v2", lanes_side=0, patches_ahead=2, other_agents=1, train_iterations=1200, temporal_window=0,
    experience_size=500, start_learn_threshold=100, learning_steps_burnin=120, learning_steps_total=600,
    layers="fc:4:relu", batch_size=8,
)  # fmt: skip


def _spec(**study: Any) -> StudySpec:
    return parse_spec({
        "study": {"name": "lad", "n_trials": 10, "timeout_s": 60, **study},
        "ladder": {"rungs": [400, 1200]},
        "fixed": {"otherAgents": 1, "temporal_window": 0, "experience_size": 500, "batch_size": 8},
        "space": {
            "lanes_side": {"low": 0, "high": 2}, "patches_ahead": {"low": 1, "high": 4},
            "learning_steps_burnin_fraction": {"low": 0.01, "high": 0.2, "log": True},
            "method": {"choices": ["sgd", "adagrad"]},
            "n_layers": {"low": 0, "high": 2}, "neurons": {"low": 2, "high": 8},
            "activation": {"choices": ["relu", "tanh"]},
        },
    })  # fmt: skip


# -- the ladder -----------------------------------------------------------------------------


def test_ladder_steps_and_top() -> None:
    ladder = Ladder((10_000, 30_000, 90_000, 270_000))
    assert ladder.steps == (1, 3, 9, 27) and ladder.reduction_factor == 3
    assert [ladder.top_for(t) for t in (5_000, 10_000, 50_000, 100_000, 10**6)] == [0, 0, 2, 3, 3]
    for bad in ((), (10, 5), (10, 25), (0, 10)):
        with pytest.raises(ValueError, match="rungs"):
            Ladder(bad)


def test_rung_config_scales_the_length_bound_settings() -> None:
    top = TINY.replace(train_iterations=90_000, learning_steps_burnin=9_000, learning_steps_total=45_000,
                       experience_size=50_000, start_learn_threshold=20_000)  # fmt: skip
    r0 = rung_config(top, 10_000)
    assert (r0.train_iterations, r0.learning_steps_burnin, r0.learning_steps_total) == (10_000, 1_000, 5_000)
    assert r0.start_learn_threshold == int(START_LEARN_CAP * 10_000)  # learning starts within the first quarter
    assert rung_config(top, 90_000) == top
    assert r0.replace(train_iterations=1) != r0 and r0.layers == top.layers and r0.gamma == top.gamma


def test_a_rung_is_a_standalone_training_exactly() -> None:
    """Every rung of a ladder trial equals training its rung config alone from the trial's seed, net and score."""
    reports: list[tuple[int, float]] = []
    outcome = run_trial(
        TrialTask(number=0, config=TINY.to_mapping(), seed=7, rungs=(400, 1200)),
        lambda step, frames, score: bool(reports.append((step, score))),  # type: ignore[func-returns-value]
    )
    assert outcome.state == COMPLETE, outcome.cause
    rungs = outcome.attrs["rungs"]
    assert [r["budget"] for r in rungs] == [400, 1200] and [s for s, _ in reports] == [1, 3]
    for rung in rungs:
        alone = rung_config(TINY, rung["budget"])
        result = train(alone, 7, quick_eval=False)
        score = evaluate_official(result.convnet(), alone).median_site
        assert score == rung["score"]
        assert dumps_net(result.convnet()) == outcome.rung_nets[rung["budget"]]
    assert outcome.value == rungs[-1]["score"] and outcome.net_js is not None


def test_a_reseeded_rung_is_a_standalone_training_from_its_own_seed() -> None:
    """Under [ladder] reseed every rung below the top trains from its own seed, recorded with the rung, and still
    equals a standalone training from it; the top rung trains from the trial's seed (its value reproduces)."""
    task = TrialTask(number=0, config=TINY.to_mapping(), seed=7, rungs=(400, 1200), reseed_rungs=True)
    outcome = run_trial(task, lambda *a: False)
    assert outcome.state == COMPLETE, outcome.cause
    rungs = outcome.attrs["rungs"]
    seeds = [r["seed"] for r in rungs]
    assert seeds == [rung_seed(7, 400, 1200, True), 7] and seeds[0] != 7
    assert rung_seed(7, 400, 1200, True) == rung_seed(7, 400, 1200, True) != rung_seed(8, 400, 1200, True)
    assert rung_seed(7, 400, 1200, False) == 7 and rung_seed(7, 400, 400, True) == 7
    for rung in rungs:
        alone = rung_config(TINY, rung["budget"])
        result = train(alone, rung["seed"], quick_eval=False)
        assert evaluate_official(result.convnet(), alone).median_site == rung["score"]
        assert dumps_net(result.convnet()) == outcome.rung_nets[rung["budget"]]
    same = run_trial(dataclasses.replace(task, reseed_rungs=False), lambda *a: False)
    assert [r["seed"] for r in same.attrs["rungs"]] == [7, 7]
    assert same.rung_nets[1200] == outcome.rung_nets[1200] and same.rung_nets[400] != outcome.rung_nets[400]


def test_reseed_is_a_ladder_key_the_driver_passes_on(tmp_path: Path) -> None:
    """``[ladder] reseed``: off when left out (a study stored before the key resumes as it ran), stored only when
    on, a bool or a one-line error; the driver hands it to every trial; paper.toml turns it on."""
    spec = _spec().with_overrides(storage=str(tmp_path / "j.log"))
    assert not spec.ladder_reseed and "reseed" not in spec.to_dict()["ladder"]
    data = spec.to_dict()
    data["ladder"]["reseed"] = "yes"
    with pytest.raises(SpecError, match=r"\[ladder\] reseed: must be true or false, got 'yes'; write reseed = true"):
        parse_spec(data, source="bad.toml")
    data["ladder"]["reseed"] = True
    on = parse_spec(data, source="on.toml")
    assert on.ladder_reseed and on.to_dict()["ladder"]["reseed"] is True
    assert parse_spec(on.to_dict(), source="on.toml") == on
    assert load_spec(CONFIGS / "paper.toml").ladder_reseed
    driver = Driver(on, open_storage(on.study.storage, on.study.name))
    driver.open_study()
    driver.pool = FakePool()
    driver._t0 = time.perf_counter()  # noqa: SLF001
    assert driver._launch_next(0) and driver.pool.tasks[0].reseed_rungs  # noqa: SLF001


def test_a_pruned_ladder_keeps_its_finished_rungs() -> None:
    outcome = run_trial(TrialTask(number=0, config=TINY.to_mapping(), seed=3, rungs=(400, 1200)), lambda *a: True)
    assert outcome.state == PRUNED and "pruned after rung 0" in (outcome.cause or "")
    assert [r["budget"] for r in outcome.attrs["rungs"]] == [400] and set(outcome.rung_nets) == {400}
    assert outcome.value is None


def test_a_static_policy_is_pruned_and_told_infeasible(tmp_path: Path) -> None:
    """A rung whose net always picks one action, or that scores exactly as the rung before (median and mean),
    prunes the trial with its cause; a net that learns climbs on; the driver tells samplers the constraint, and
    TPE ranks the trial below every feasible pruned one; a race run is never pruned so."""

    def climb(config: TrainConfig, prune: bool = True) -> Any:
        task = TrialTask(number=0, config=config.to_mapping(), seed=3, rungs=(400, 1200), prune_static=prune)
        return run_trial(task, lambda *a: False)

    one_action = climb(TINY)  # this tiny net turns right at every greedy decision
    assert one_action.state == PRUNED and set(one_action.rung_nets) == {400}
    assert one_action.cause == ("static policy at rung 0 (400 iterations, 53.90 mph): the net chose right in 100.00% "
                                "of its 67,000 greedy decisions (the policy ignores its input)")  # fmt: skip
    assert one_action.attrs["rungs"][0][keys.GREEDY_CHOICES] == [0, 0, 0, 0, 67_000]
    frozen = TINY.replace(learning_rate=0.0)  # sgd at rate 0: every rung's net is the initial one (91 % right)
    outcome = climb(frozen)
    assert outcome.state == PRUNED and (outcome.cause or "").startswith("static policy at rung 1 (1,200 iterations")
    assert "the same official score as at 400 iterations, to the digit" in (outcome.cause or "")
    assert outcome.attrs[keys.STATIC_POLICY] is True and set(outcome.rung_nets) == {400, 1200}
    off = climb(frozen, prune=False)
    assert off.state == COMPLETE and keys.STATIC_POLICY not in off.attrs  # the key turns it off
    climbed = climb(TINY.replace(lanes_side=1, patches_ahead=4))  # left and right, the mix changing with training
    assert climbed.state == COMPLETE, climbed.cause
    assert [sum(r[keys.GREEDY_CHOICES]) > 0 for r in climbed.attrs["rungs"]] == [True, True]

    def rung(greedy: list[int], score: float = 70.0, mean: float = 69.5) -> dict[str, Any]:
        return {keys.BUDGET: 1, keys.SCORE: score, keys.OFFICIAL_MEAN: mean, keys.GREEDY_CHOICES: greedy}

    assert static_policy([rung([0, 99, 0, 1, 0])]) is not None  # 99 %: static
    assert static_policy([rung([0, 98, 0, 1, 1])]) is None and static_policy([rung([])]) is None
    assert static_policy([rung([1, 50, 0, 49, 0]), rung([1, 50, 0, 49, 0], mean=69.6)]) is None  # mean moved

    spec = _spec().with_overrides(storage=str(tmp_path / "j.log"))
    assert spec.ladder_prune_static and "prune_static" not in spec.to_dict()["ladder"]
    driver = Driver(spec, open_storage(spec.study.storage, spec.study.name))
    study = driver.open_study()
    driver.pool = FakePool()
    driver._t0 = time.perf_counter()  # noqa: SLF001
    assert driver._launch_next(0) and driver.pool.tasks[0].prune_static  # noqa: SLF001
    study.enqueue_trial({}, user_attrs={keys.RACE_OF: 0, keys.CONFIG: TINY.to_mapping(), keys.SEED: 5})
    assert driver._launch_next(1) and not driver.pool.tasks[1].prune_static  # noqa: SLF001 - a race run
    told = []
    for result in (outcome, dataclasses.replace(outcome, attrs={k: v for k, v in outcome.attrs.items()
                                                                 if k != keys.STATIC_POLICY})):  # fmt: skip
        trial = study.ask()
        for step, value in ((1, 52.0), (3, 52.0)):
            trial.report(value, step)
        driver._finish(trial, result)  # noqa: SLF001
        told.append(trial.number)
    frozen_t, plain_t = (study.trials[n] for n in told)
    assert frozen_t.constraints == {keys.POLICY_LEARNS: 1.0} and plain_t.constraints == {}
    from optuna.samplers._tpe.sampler import _split_trials

    below, above = _split_trials(study, [frozen_t, plain_t], n_below=1)
    assert [t.number for t in below] == [plain_t.number] and frozen_t.number in [t.number for t in above]

    data = _spec().to_dict()
    data["ladder"]["prune_static"] = "yes"
    with pytest.raises(SpecError, match=r"\[ladder\] prune_static: must be true or false"):
        parse_spec(data, source="bad.toml")
    data["ladder"]["prune_static"] = False
    off_spec = parse_spec(data)
    assert not off_spec.ladder_prune_static and off_spec.to_dict()["ladder"]["prune_static"] is False


def test_weight_change_is_how_far_training_moved_the_net() -> None:
    """``TrainResult.weight_change`` is ‖θ − θ₀‖ / ‖θ₀‖ against the initialisation from the run's seed; a rate of
    0 leaves it at 0."""
    import numpy as np

    from autotune.learner.brain import DeepQLearner

    config = rung_config(TINY, 400)
    result = train(config, 3, quick_eval=False)
    init = DeepQLearner(config, np.random.SeedSequence(3).spawn(4)[0]).module  # train's brain seed
    flat = [
        np.concatenate([p.detach().double().numpy().ravel() for p in m.parameters()]) for m in (init, result.module)
    ]
    assert result.weight_change == pytest.approx(np.linalg.norm(flat[1] - flat[0]) / np.linalg.norm(flat[0]))
    assert 0.1 < result.weight_change < 10 and result.summary()["weight_change"] == result.weight_change
    assert train(config.replace(learning_rate=0.0), 3, quick_eval=False).weight_change == 0.0


def test_a_net_that_does_not_learn_is_pruned_and_told_infeasible(tmp_path: Path) -> None:
    """A rung whose training left the weights within ``min_weight_change`` of their initialisation prunes the
    trial with its cause (kept, but neither scored nor reported: no evaluation is spent on it, and its cost
    observation is its training alone); a net that learns climbs on; the driver passes the spec's threshold (never
    to race runs), tells samplers the constraint, and keeps the trial out of the race."""
    from autotune.search.driver import _observations
    from autotune.search.records import kept_rungs

    inert = TINY.replace(method="adagrad", learning_rate=1e-8)  # moves ~3e-7 of its norm in 400 decisions
    reports: list[int] = []

    def climb(config: TrainConfig, threshold: float) -> Any:
        task = TrialTask(number=0, config=config.to_mapping(), seed=3, rungs=(400, 1200), min_weight_change=threshold)
        return run_trial(task, lambda step, *a: bool(reports.append(step)))  # type: ignore[func-returns-value]

    outcome = climb(inert, 0.01)
    assert outcome.state == PRUNED and outcome.attrs[keys.DOES_NOT_LEARN] is True and reports == []
    rung = outcome.attrs["rungs"][0]
    assert rung[keys.WEIGHT_CHANGE] < 1e-6 and set(outcome.rung_nets) == {400}
    assert outcome.cause == (
        "does not learn at rung 0 (400 iterations): training moved its weights 0.000% from "
        "their initialisation, under [ladder] min_weight_change = 1.00% (not scored)"
    )
    assert rung[keys.SCORE] is None and keys.OFFICIAL_MEAN not in rung and rung[keys.GREEDY_CHOICES] == [0] * 5
    assert outcome.attrs[keys.FRAMES_SIMULATED] == rung[keys.FRAMES]  # trained, never evaluated
    with_net = {**outcome.attrs, keys.ARTIFACT_RUNG_NETS: {"400": "id"}}
    assert kept_rungs(with_net) == []  # not a net the best single net can be
    stored = optuna.trial.create_trial(state=optuna.trial.TrialState.PRUNED, user_attrs=outcome.attrs)
    (obs,) = _observations(stored)
    want = features(rung_config(inert, 400), evaluated=False)
    assert obs.features == tuple(want) and not any(want[FEATURES.index("eval_fixed") :])
    assert climb(inert, 0.0).state == COMPLETE and reports == [1, 3]  # 0 turns it off
    learns = climb(TINY.replace(lanes_side=1, patches_ahead=4), 0.01)
    assert learns.state == COMPLETE and keys.DOES_NOT_LEARN not in learns.attrs
    assert all(r[keys.WEIGHT_CHANGE] > 0.1 for r in learns.attrs["rungs"])

    spec = _spec().with_overrides(storage=str(tmp_path / "j.log"))
    assert spec.ladder_min_weight_change == 0.01 and "min_weight_change" not in spec.to_dict()["ladder"]
    driver = Driver(spec, open_storage(spec.study.storage, spec.study.name))
    study = driver.open_study()
    driver.pool = FakePool()
    driver._t0 = time.perf_counter()  # noqa: SLF001
    assert driver._launch_next(0) and driver.pool.tasks[0].min_weight_change == 0.01  # noqa: SLF001
    study.enqueue_trial({}, user_attrs={keys.RACE_OF: 0, keys.CONFIG: TINY.to_mapping(), keys.SEED: 5})
    assert driver._launch_next(1) and driver.pool.tasks[1].min_weight_change == 0.0  # noqa: SLF001 - a race run
    trial = study.ask()
    driver._finish(trial, outcome)  # noqa: SLF001
    told = study.trials[trial.number]
    assert told.constraints == {keys.POLICY_LEARNS: 1.0} and told.state == optuna.trial.TrialState.PRUNED
    from autotune.search.driver import race_entry

    assert race_entry(told) is None  # its kept 400 rung has no score
    flagged = copy.deepcopy(told)  # as stored before such rungs went unscored: the flag alone keeps it out
    flagged.user_attrs[keys.RUNGS][0][keys.SCORE] = 60.0
    assert race_entry(flagged) is None  # the race measures configurations that learn
    kept = copy.deepcopy(flagged)
    kept.user_attrs = {k: v for k, v in flagged.user_attrs.items() if k != keys.DOES_NOT_LEARN}
    assert race_entry(kept) is not None

    data = _spec().to_dict()
    for bad in ("1%", -0.1, 1.5, True):
        data["ladder"]["min_weight_change"] = bad
        with pytest.raises(SpecError, match=r"\[ladder\] min_weight_change \(a fraction of the weights' norm"):
            parse_spec(data, source="bad.toml")
    data["ladder"]["min_weight_change"] = 0
    off = parse_spec(data)
    assert off.ladder_min_weight_change == 0.0 and parse_spec(off.to_dict()) == off


def test_the_study_deadline_stops_a_trial_without_a_truncated_score() -> None:
    import time

    outcome = run_trial(
        TrialTask(number=0, config=TINY.to_mapping(), seed=3, rungs=(400, 1200), deadline=time.time() - 1),
        lambda *a: False,
    )
    assert outcome.state == PRUNED and outcome.cause is not None and outcome.cause.startswith("deadline")
    assert outcome.value is None and outcome.attrs["rungs"] == []


def test_the_official_evaluation_honours_the_deadline() -> None:
    """A limit passing during the official evaluation stops it (PRUNED), it does not finish the 500 runs."""
    import time

    calls: list[int] = []

    def report(step: int, frames: int, score: float) -> bool:
        calls.append(step)
        return False

    t0 = time.perf_counter()
    # a trial limit shorter than one official evaluation of a wide net: the check between chunks of runs bites
    wide = TINY.replace(layers="fc:256:relu|fc:256:relu", other_agents=10, train_iterations=400)
    outcome = run_trial(TrialTask(number=0, config=wide.to_mapping(), seed=3, rungs=(400,), timeout_s=1.0), report)
    assert outcome.state == PRUNED and "timeout" in (outcome.cause or "") and calls == []
    assert time.perf_counter() - t0 < 30


# -- sampler, pruner, space -----------------------------------------------------------------


def test_ladder_pruner_promotes_at_the_rungs() -> None:
    pruner = make_pruner(_spec(pruner="sha"))
    assert isinstance(pruner, optuna.pruners.SuccessiveHalvingPruner)
    with pytest.raises(Exception, match="does not fit a budget ladder"):
        make_pruner(_spec(pruner="wilcoxon"))


def test_sampler_startup_count_is_the_specs() -> None:
    sampler = make_sampler(_spec(sampler="tpe", sampler_startup_trials=3), 0)
    assert isinstance(sampler, optuna.samplers.TPESampler) and sampler._n_startup_trials == 3  # noqa: SLF001


def test_refused_draws_never_become_trials() -> None:
    """The gate redraws over-cap draws: every trial is affordable, no extra trial exists, refusals are counted."""
    spec = _spec()

    def price(params: dict[str, Any]) -> float:
        return 10.0 if params["lanes_side"] > 0 else 1.0  # lanes_side > 0 is "too expensive"

    sampler = CostGatedSampler(optuna.samplers.TPESampler(seed=1, n_startup_trials=4), spec, price, 5.0, seed=1)
    study = optuna.create_study(direction="maximize", sampler=sampler)
    refused = 0
    for _ in range(12):
        trial = study.ask()
        params = space.sample(trial, spec)
        assert params["lanes_side"] == 0
        refused += sampler.refused(trial.number)
        study.tell(trial, float(params["patches_ahead"]))
    assert len(study.trials) == 12 and refused > 0  # refusals used no trial (budget, startup phase)


def test_the_gated_sampler_models_draws_not_race_runs() -> None:
    """Race runs retrain configurations already in the history: the wrapped sampler never sees them (the
    incumbent's many fresh runs before the race would fill TPE's good tenth with one configuration)."""
    spec = _spec()
    seen: list[list[int]] = []

    class Recording(optuna.samplers.RandomSampler):
        def infer_relative_search_space(self, study: Any, trial: Any) -> dict[str, Any]:
            seen.append([t.number for t in study.get_trials(deepcopy=False)])
            return super().infer_relative_search_space(study, trial)

        def sample_independent(self, study: Any, trial: Any, name: str, dist: Any) -> Any:
            seen.append([t.number for t in study.get_trials(deepcopy=False)])
            return super().sample_independent(study, trial, name, dist)

    sampler = CostGatedSampler(Recording(seed=0), spec, lambda _p: 1.0, 5.0, seed=0)
    study = optuna.create_study(direction="maximize", sampler=sampler)
    dists = distributions(spec)
    params = space.encode(spec, TINY)
    for attrs in ({}, {keys.RACE_OF: 0, keys.RACE_SEED: 0}, {keys.RACE_OF: 0, keys.RACE_SEED: 1}):
        study.add_trial(optuna.trial.create_trial(params=params, distributions=dists, value=74.0, user_attrs=attrs))
    trial = study.ask()
    space.sample(trial, spec)  # the gate's relative draw asks its base for its search space
    frozen = study._storage.get_trial(trial._trial_id)  # noqa: SLF001
    sampler.sample_independent(study, frozen, "lanes_side", dists["lanes_side"])
    assert len(seen) == 2 and all(numbers == [0, 3] for numbers in seen)  # no race run; the draw itself runs


def test_the_gate_prices_a_draws_whole_ladder(tmp_path: Path) -> None:
    """A sampled draw is priced at every rung it would climb: one whose first rung fits the cap but whose ladder
    does not is refused (its value would be a short rung's score, not comparable with the others')."""
    spec = _spec().with_overrides(storage=str(tmp_path / "j.log"))
    driver = Driver(spec, open_storage(spec.study.storage, spec.study.name))
    driver.cost_model = forward_cost_model(1e-6)  # cost ∝ weights × iterations

    def price(params: dict[str, Any]) -> float:
        cost = driver._price(params)  # noqa: SLF001 - the gate's question, as the driver asks it
        assert cost is not None
        return cost

    params = space.encode(spec, TINY.replace(layers="fc:8:relu|fc:8:tanh"))
    configs = driver._rung_configs(params)  # noqa: SLF001
    assert [c.train_iterations for c in configs] == [400, 1200]
    assert price(params) == pytest.approx(sum(driver.cost_model.predict(c) for c in configs))
    draws = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=5))
    prices = []
    for _ in range(40):
        p = space.sample(draws.ask(), spec)
        prices.append((price(p), driver.cost_model.predict(driver._rung_configs(p)[0])))  # noqa: SLF001
    cap = sorted(full for full, _ in prices)[len(prices) // 2]
    assert any(first <= cap < full for full, first in prices)  # the draws the old rule (first rung) let through
    sampler = CostGatedSampler(optuna.samplers.RandomSampler(seed=3), spec, price, cap, seed=3)
    study = optuna.create_study(direction="maximize", sampler=sampler)
    refused = 0
    for _ in range(10):
        trial = study.ask()
        assert price(space.sample(trial, spec)) <= cap
        refused += sampler.refused(trial.number)
        study.tell(trial, 0.0)
    assert refused > 0


def test_min_top_gates_the_ladder_below_it_and_cheap_draws_climb_above(tmp_path: Path) -> None:
    """With ``[ladder] min_top`` the gate prices a draw up to that rung only; a trial then climbs while its
    predicted cost fits the cap: a cheap configuration trains the whole ladder, a dearer one stops at
    ``min_top`` (not refused), and one whose ladder to ``min_top`` is over the cap never becomes a trial."""
    data = _spec().to_dict()
    data["ladder"] = {"rungs": [400, 1200, 3600], "min_top": 1200}
    spec = parse_spec(data, source="min_top.toml").with_overrides(storage=str(tmp_path / "j.log"))
    assert spec.gated_rungs == 2 and parse_spec(spec.to_dict()) == dataclasses.replace(spec, source="spec")
    driver = Driver(spec, open_storage(spec.study.storage, spec.study.name))
    study = driver.open_study()
    driver.cost_model = forward_cost_model(1e-6)  # cost ∝ weights × iterations
    driver._fitted_on = 0  # noqa: SLF001 - keep the model above (no finished trial to refit on)
    small, large = (space.encode(spec, TINY.replace(layers=layers)) for layers in ("fc:2:relu", "fc:8:relu|fc:8:tanh"))
    price = {}
    for name, params in (("small", small), ("large", large)):
        configs = driver._rung_configs(params)  # noqa: SLF001
        costs = [driver.cost_model.predict(c) for c in configs]
        assert driver._price(params) == pytest.approx(sum(costs[:2]))  # noqa: SLF001 - the gate's question
        price[name] = costs
    cap = (sum(price["large"][:2]) + sum(price["large"])) / 2  # large affords min_top, not the whole ladder
    assert sum(price["small"]) < cap
    driver.spec = spec = dataclasses.replace(spec, study=dataclasses.replace(spec.study, max_trial_cost_s=cap))
    driver.pool = FakePool()
    driver._t0 = time.perf_counter()  # noqa: SLF001 - the study just started: the cap, not the time left, binds
    for params in (small, large):
        study.enqueue_trial(params)
    assert driver._launch_next(0) and driver._launch_next(1)  # noqa: SLF001
    assert [t.rungs for t in driver.pool.tasks] == [(400, 1200, 3600), (400, 1200)]
    assert [TrainConfig.from_mapping(t.config).train_iterations for t in driver.pool.tasks] == [3600, 1200]

    gated = optuna.create_study(sampler=make_sampler(spec, 0, driver._price, driver._draw_cap))  # noqa: SLF001
    tops = set()
    for _ in range(12):
        trial = gated.ask()
        params = space.sample(trial, spec)
        gated_cost = driver._price(params)  # noqa: SLF001
        assert gated_cost is not None and gated_cost <= cap
        total = sum(driver.cost_model.predict(c) for c in driver._rung_configs(params))  # noqa: SLF001
        tops.add(total <= cap)
        gated.tell(trial, 0.0)
    assert tops == {True, False}  # some draws climb the whole ladder, some stop at min_top


def test_min_top_must_be_a_rung() -> None:
    data = _spec().to_dict()
    data["ladder"] = {"rungs": [400, 1200], "min_top": 800}
    with pytest.raises(SpecError, match=r"\[ladder\] min_top: must be one of the rungs \[400, 1200\], got 800"):
        parse_spec(data, source="bad.toml")
    data["ladder"]["min_top"] = 1200  # the last rung: the default, stored as such
    assert parse_spec(data).ladder_min_top == 0 and "min_top" not in parse_spec(data).to_dict()["ladder"]


def test_the_prior_cost_model_predicts_measured_rungs() -> None:
    """On 80 measured rungs of the benchmark studies (tests/data/cost_rungs.json.gz) the prior's median error is
    within 15 %, and a wide view evaluated greedily costs more than the same view with ε_test 0.9 (the Gaussian
    fill of every greedy decision's input Vol, replayed by the exact evaluation)."""
    from tests.conftest import load_json

    rungs = load_json(ROOT / "tests" / "data" / "cost_rungs.json.gz")["rungs"]
    prior = CostModel.prior()
    errors = sorted(abs(prior.predict(TrainConfig.from_mapping(r["config"])) - r["seconds"]) / r["seconds"]
                    for r in rungs)  # fmt: skip
    assert len(errors) == 80 and errors[40] < 0.15
    wide = TINY.replace(lanes_side=10, patches_ahead=60, patches_behind=20, temporal_window=3, other_agents=10)
    greedy, mostly_random = (prior.predict(wide.replace(epsilon_test_time=e)) for e in (0.0, 0.9))
    assert greedy - mostly_random == pytest.approx(
        0.9 * 11 * wide.net_inputs * prior.coef[FEATURES.index("eval_inputs")]
    )
    assert greedy > 1.5 * mostly_random


def test_the_prior_prices_a_linear_net_on_the_whole_road() -> None:
    """A linear net's batch update is no larger than gathering its batch's input rows from the replay memory, so
    without ``gather_work`` the prior prices the whole road's 810k linear training (46 measured, 222–289 s:
    tests/data/cost_wide_linear.json.gz) at about half its time; with it, within 10 % (median)."""
    from tests.conftest import load_json

    rungs = load_json(ROOT / "tests" / "data" / "cost_wide_linear.json.gz")["rungs"]
    configs = [TrainConfig.from_mapping(r["config"]) for r in rungs]
    seconds = [r["seconds"] for r in rungs]
    prior = CostModel.prior()
    without = list(prior.coef)
    without[FEATURES.index("gather_work")] = 0.0

    def median_error(model: CostModel) -> float:
        return statistics.median(abs(model.predict(c) - s) / s for c, s in zip(configs, seconds, strict=True))

    assert len(rungs) == 46 and all(not c.layers and c.lanes_side == 6 and c.train_iterations == 810_000
                                    for c in configs)  # fmt: skip
    assert median_error(prior) < 0.10 < 0.45 < median_error(CostModel(tuple(without)))


def test_cost_model_fits_rungs() -> None:
    """Fitted to rungs that follow a known cost law, the model predicts a new config within 35 %."""
    truth = CostModel(tuple(3 * c for c in CostModel.prior().coef))
    configs = [rung_config(TINY.replace(layers=f"fc:{n}:relu", batch_size=b, other_agents=k), budget)
               for n in (4, 64, 256) for b in (8, 64) for k in (0, 5) for budget in (400, 1200)]  # fmt: skip
    obs = [Observation(tuple(features(c)), truth.predict(c)) for c in configs]
    fitted = CostModel.prior().fit(obs)
    new = TINY.replace(layers="fc:128:tanh|fc:32:relu", batch_size=32, other_agents=3, train_iterations=5000)
    assert abs(fitted.predict(new) - truth.predict(new)) / truth.predict(new) < 0.35
    assert len(fitted.coef) == len(FEATURES) and all(c >= 0 for c in fitted.coef)
    with pytest.raises(ValueError, match=r"CostModel: 9 coefficients for the 10 work terms of FEATURES \(decisions, "):
        CostModel(fitted.coef[:9])  # a model of fewer terms (as before gather_work) is an error, not a misalignment


def test_plan_lowers_the_top_rung_to_the_cap() -> None:
    model = CostModel.prior()
    configs = [rung_config(TINY.replace(train_iterations=270_000), b) for b in (10_000, 30_000, 90_000, 270_000)]
    costs = [model.predict(c) for c in configs]
    full = plan(configs, model, cap_s=math.inf)
    assert full is not None and full.budgets == (10_000, 30_000, 90_000, 270_000)
    capped = plan(configs, model, cap_s=sum(costs[:2]) + 1e-9)
    assert capped is not None and capped.budgets == (10_000, 30_000)
    assert plan(configs, model, cap_s=costs[0] / 2) is None
    assert plan(configs, model, cap_s=math.inf, top=1).budgets == (10_000, 30_000)  # type: ignore[union-attr]


def test_a_single_rung_is_priced_alone() -> None:
    """A twin trains one rung: the highest ≤ top whose own cost fits the cap, however much the rungs below add."""
    model = CostModel.prior()
    configs = [rung_config(TINY.replace(train_iterations=270_000), b) for b in (10_000, 30_000, 90_000, 270_000)]
    costs = [model.predict(c) for c in configs]
    assert sum(costs) > costs[3] + 1e-6
    one = plan_one(configs, model, cap_s=costs[3] + 1e-9)  # the ladder would stop below it
    assert one is not None and one.budgets == (270_000,) and one.costs == (costs[3],)
    assert plan(configs, model, cap_s=costs[3] + 1e-9).budgets[-1] < 270_000  # type: ignore[union-attr]
    assert plan_one(configs, model, cap_s=costs[3] - 1e-6).budgets == (90_000,)  # type: ignore[union-attr]
    assert plan_one(configs, model, cap_s=math.inf, top=1).budgets == (30_000,)  # type: ignore[union-attr]
    assert plan_one(configs, model, cap_s=costs[0] / 2) is None


# -- warm start, resume ---------------------------------------------------------------------


def test_crowd_prior_lands_inside_the_space_and_claims_are_not_values(tmp_path: Path) -> None:
    from dashboards.crowd_prior import prior_settings

    spec = load_spec(CONFIGS / "quick.toml").with_overrides(storage=str(tmp_path / "j.log"))
    storages = open_storage(spec.study.storage, spec.study.name)
    prior = prior_settings("v2")
    assert len(prior) >= 10 and prior == sorted(prior, key=lambda p: -p.claimed)
    assert len({p.source for p in prior}) == len(prior)
    driver = Driver(spec, storages, warm_configs=tuple(WarmConfig(p.source, p.config) for p in prior))
    study = driver.open_study()
    driver._warm_start()  # noqa: SLF001 - what run() does first
    waiting = study.get_trials(states=(optuna.trial.TrialState.WAITING,))
    assert 10 <= len(waiting) <= len(prior) and any("skipped" in n for n in driver.warm_notes)
    claims = {p.claimed for p in prior}
    for t in waiting:
        params = t.system_attrs["fixed_params"]
        assert not space.outside(spec, params), t.user_attrs[keys.WARM_START]
        assert t.value is None and not claims & {v for v in t.user_attrs.values() if isinstance(v, float)}
    driver._warm_start()  # once per study: a resumed run enqueues nothing more  # noqa: SLF001
    assert len(study.get_trials(states=(optuna.trial.TrialState.WAITING,))) == len(waiting)


def test_clip_params_says_what_moved() -> None:
    spec = load_spec(CONFIGS / "paper.toml")
    params = space.encode(spec, TrainConfig(lanes_side=50, layers="fc:1:softmax"))
    clipped, notes = clip_params(spec, params)
    assert clipped["lanes_side"] == 10 and clipped["neurons_0"] == 2 and clipped["activation_0"] == "relu"
    assert any(n.startswith("lanes_side 50 → 10") for n in notes) and not space.outside(spec, clipped)


def test_resuming_with_a_changed_space_is_refused(tmp_path: Path) -> None:
    spec = _spec().with_overrides(storage=str(tmp_path / "j.log"))
    Driver(spec, open_storage(spec.study.storage, spec.study.name)).open_study()
    Driver(spec, open_storage(spec.study.storage, spec.study.name)).open_study()  # the same spec resumes
    data = spec.to_dict()
    data["space"]["lanes_side"] = {"low": 0, "high": 3, "log": False}
    changed = parse_spec(data, source="changed.toml")
    with pytest.raises(SpecError, match=r"\[space\] lanes_side: the study 'lad' was created with") as err:
        Driver(changed, open_storage(spec.study.storage, spec.study.name)).open_study()
    assert "\n" not in str(err.value)
    reseeded = dataclasses.replace(spec, ladder_reseed=not spec.ladder_reseed)  # rungs' seeds: incomparable too
    with pytest.raises(SpecError, match=r"\[ladder\] reseed: the study 'lad' was created with"):
        Driver(reseeded, open_storage(spec.study.storage, spec.study.name)).open_study()


# -- the seed race ----------------------------------------------------------------------------


def test_race_entrants_are_distinct_configurations() -> None:
    a, b = {"x": 1}, {"x": 2}
    field = racing.entrants([(0, 70.0, a), (1, 75.0, a), (2, 72.0, b), (3, math.nan, b)], 3)
    assert [e.number for e in field] == [1, 2]


def test_configurations_measured_on_fresh_seeds_join_the_race_by_their_mean() -> None:
    """``field_order``: the provisional leader (the best mean over 3+ fresh seeds) first; then a measured
    configuration by its fresh mean, one measured less by its selecting score less the measured ones' median
    optimism: none enters on its luckiest seed once its fresh seeds measured it (seed 1's hour: 75.10 selecting,
    150 seeds at 70.9)."""
    cfg = {n: {"x": n} for n in range(7)}
    values = (74.0, 75.1, 74.3, 73.25, 74.6, 74.4, 74.9)
    candidates = [(n, v, cfg[2 if n == 6 else n]) for n, v in enumerate(values)]  # 6: trial 2's configuration
    results: dict[tuple[int, int], float | None] = {(1, s): 70.9 + (s % 3 - 1) for s in range(150)}  # mean 70.9
    results |= {(2, s): v for s, v in enumerate((72.5, 72.9, 72.6, 74.3, 73.9))}  # mean 73.24
    results |= {(3, s): v for s, v in enumerate((74.0, 72.6, 72.6, None))}  # 3 scores: mean 73.07
    results |= {(0, 0): 76.0, (0, 1): 75.0, (5, 0): None}  # 2 seeds: not yet measured, ranks by its 74.0
    assert [e.number for e in racing.entrants(candidates, 4)] == [1, 6, 4, 5]  # by selecting score alone
    # optimism: the median of 4.2, 1.06 and 0.18 = 1.06, so 4 ranks at 73.54, 5 at 73.34 and 0 at 72.94
    order = racing.field_order(candidates, results)
    assert [e.number for e in order] == [2, 4, 5, 3, 0, 1]  # 6 is trial 2's configuration: it races as 2
    results |= {(3, s): 74.5 for s in range(4, 8)}  # 3's mean 73.89 now leads; 2 (73.24) ranks below 4 and 5
    assert [e.number for e in racing.field_order(candidates, results)] == [3, 4, 5, 2, 0, 1]
    assert [e.number for e in racing.field_order(candidates, {})] == [1, 6, 4, 5, 0, 3]  # nothing measured


def test_the_best_unmeasured_configuration_joins_the_race_second() -> None:
    """``field_order``: after the measured leader, the best-scored configuration with fewer than 3 fresh seeds,
    though its selecting score less the optimism ranks below measured ones (a 30-minute crowd-prior study raced
    three of gsurma's settings, not its best net's configuration, 75.56 and not yet reseeded)."""
    cfg = {n: {"x": n} for n in range(5)}
    values = (75.5, 75.6, 75.4, 75.56, 74.5)
    candidates = [(n, v, cfg[n]) for n, v in enumerate(values)]
    results: dict[tuple[int, int], float | None] = {}
    for number, scores in {0: (73.2, 73.4, 73.0), 1: (73.0, 73.1, 72.9), 2: (72.8, 72.9, 72.7)}.items():
        results |= {(number, s): v for s, v in enumerate(scores)}
    # optimism: the median of 2.3, 2.6, 2.6 = 2.6: 3 would rank at 72.96, below 1 (73.0); 4 at 71.9
    assert [e.number for e in racing.field_order(candidates, results)] == [0, 3, 1, 2, 4]
    results |= {(3, s): v for s, v in enumerate((70.0, 70.5, 71.0))}  # measured now: by its mean, last
    assert [e.number for e in racing.field_order(candidates, results)] == [0, 4, 1, 2, 3]
    optimistic = {**results, (0, 3): 65.0, (0, 4): 65.0}  # 0 falls to 69.92: 1 leads, 4 is still unmeasured
    assert [e.number for e in racing.field_order(candidates, optimistic)] == [1, 4, 2, 3, 0]


def test_race_halves_the_field_each_round() -> None:
    field = [10, 11, 12, 13]
    runs, over = racing.next_runs(field, {}, set(), 1)
    assert not over and [(r.race_of, r.seed_index) for r in runs] == [(10, 0), (11, 0), (12, 0), (13, 0)]
    results: dict[tuple[int, int], float | None] = {(10, 0): 70.0, (11, 0): 74.0, (12, 0): None, (13, 0): 72.0}
    runs, over = racing.next_runs(field, results, set(results), 1)
    assert not over and sorted((r.race_of, r.seed_index) for r in runs) == [(11, 1), (13, 1)]  # the better half
    results.update({(11, 1): 71.0, (13, 1): 75.0})
    runs, over = racing.next_runs(field, results, set(results), 1)
    assert over and runs == []
    top = racing.standings(field, results)[0]
    assert top.number == 13 and top.scores == (72.0, 75.0) and top.mean == 73.5  # the selecting seed left out
    assert racing.race_seed(0, 1) == racing.race_seed(0, 1) != racing.race_seed(0, 2)


def test_the_race_winner_is_paired_on_the_seeds_every_finalist_has() -> None:
    """A finalist whose last round the deadline stopped is compared on the seeds all finalists finished, not
    beaten for having fewer runs; a failed run on a shared seed ranks its configuration last."""
    deadline = "deadline: the study's time budget ended (training at 80 %)"
    assert racing.run_result("COMPLETE", 72.5, None) == (True, 72.5)
    assert racing.run_result("PRUNED", None, deadline) == (False, None)  # no result: the seed is not compared
    assert racing.run_result("FAIL", None, "worker died", retryable=True) == (False, None)  # its retry stands for it
    assert racing.run_result("RUNNING", None, None) == (False, None)
    assert racing.run_result("PRUNED", None, "timeout: trial wall time exceeded") == (True, None)  # ranks last
    assert racing.run_result("FAIL", None, "ValueError") == (True, None)
    field = [10, 11, 12, 13]
    results: dict[tuple[int, int], float | None] = {
        (10, 0): 66.7, (10, 1): 70.4, (11, 0): 72.3, (11, 1): 72.5, (12, 0): 65.0, (12, 1): 66.0,
        (13, 0): 60.0, (13, 1): None, (10, 2): 71.0, (10, 3): 72.0,
    }  # fmt: skip
    ranked = racing.standings(field, results, 2)
    assert [st.number for st in ranked] == [11, 10, 12, 13]  # 11's seeds 2, 3 were stopped: 72.4 > 68.55
    assert ranked[0].finalist and ranked[1].finalist and not ranked[2].finalist
    assert ranked[0].paired_mean == pytest.approx(72.4) and ranked[1].paired_mean == pytest.approx(68.55)
    assert ranked[1].scores == (66.7, 70.4, 71.0, 72.0) and ranked[2].paired is None
    results[(11, 2)] = None  # failed on a seed 10 finished: last among the finalists
    assert [st.number for st in racing.standings(field, results, 2)][:2] == [10, 11]
    del results[(11, 2)]
    results.update({(11, 2): 66.0, (11, 3): 65.0})  # both finished: all four seeds count
    assert racing.standings(field, results, 2)[0].number == 10  # 70.03 against 68.95
    assert [racing.standings(field, {}, 2)[i].number for i in range(4)] == field  # no result: the field's order
    # round 0 still running and two entrants not yet run: they do not block the pairing of the others
    early = {(10, 0): 64.8, (10, 1): 64.5, (11, 0): 70.4}
    assert [st.number for st in racing.standings(field, early, 2)] == [11, 10, 12, 13]


def test_signed_rank_is_wilcoxons_statistic_of_the_paired_differences() -> None:
    assert racing.signed_rank([3.0, 1.0, 4.0], [1.0, 2.0, 0.0]) == 3 - 1 + 2  # d = 2, −1, 4: ranks 2, 1, 3
    assert racing.signed_rank([1.0, 5.0], [1.0, 4.0]) == 1  # a zero difference is dropped
    assert racing.signed_rank([2.0, 0.0, 3.0], [1.0, 1.0, 1.5]) == 1.5 - 1.5 + 3  # |d| 1, 1 tied: rank 1.5 each
    assert racing.signed_rank([74.1, 73.3], [73.1, 73.5]) == -racing.signed_rank([73.1, 73.5], [74.1, 73.3]) == 1
    assert racing.signed_rank([], []) == 0


def results_of(results: dict[tuple[int, int], float | None], number: int) -> list[float]:
    return [v for (n, _s), v in sorted(results.items()) if n == number and v is not None]


def test_one_collapsed_race_seed_does_not_decide_the_race() -> None:
    """The race of a crowd-prior benchmark study (trial numbers and scores as recorded): 25 won three of its four
    seeds against 105 and collapsed on one. By the mean 105 won (73.09 against 72.28), and averaged 70.81 on three
    fresh seeds; by the signed ranks 25 wins, which scored 74.08–75.44 on 11 of 12 fresh seeds at 90k."""
    field = [105, 25, 1, 51]
    results: dict[tuple[int, int], float | None] = {
        (105, 0): 73.32, (105, 1): 73.32, (25, 0): 74.77, (25, 1): 74.79, (1, 0): 73.32, (1, 1): 70.76,
        (51, 0): 72.39, (51, 1): 61.18,
    }  # fmt: skip
    runs, over = racing.next_runs(field, results, set(results), 2)
    assert not over and sorted((r.race_of, r.seed_index) for r in runs) == [(25, 2), (25, 3), (105, 2), (105, 3)]
    results.update({(105, 2): 73.36, (105, 3): 72.37, (25, 2): 64.41, (25, 3): 75.16})
    assert racing.next_runs(field, results, set(results), 2) == ([], True)
    ranked = racing.standings(field, results, 2)
    assert [st.number for st in ranked] == [25, 105, 1, 51]
    assert ranked[0].mean < ranked[1].mean  # the mean alone would have crowned 105
    assert racing.signed_rank(results_of(results, 25), results_of(results, 105)) == 1 + 2 + 3 - 4  # one seed lost
    assert ranked[0].finalist and not any(st.finalist for st in ranked[1:])  # the halving's last survivor
    # a second collapse is no longer one seed among four: 105 wins back
    results[(25, 1)] = 65.0
    assert racing.standings(field, results, 2)[0].number == 105


def _tiny_adder(study: optuna.Study, spec: StudySpec) -> Callable[..., None]:
    """add(state, value, **user_attrs): a trial of TINY's parameters with that state, value and attributes."""
    dists, params = distributions(spec), space.encode(spec, TINY)

    def add(state: optuna.trial.TrialState, value: float | None, **attrs: Any) -> None:
        study.add_trial(optuna.trial.create_trial(params=params, distributions=dists, value=value, state=state,
                                                  user_attrs={keys.CONFIG: TINY.to_mapping(), **attrs}))  # fmt: skip

    return add


def test_a_race_run_the_deadline_stopped_is_run_again_and_not_held_against_it(tmp_path: Path) -> None:
    """The driver's race state and ``race_summary`` classify race runs with ``racing.run_result``: a run the
    deadline stopped is neither launched nor a result (a resumed race runs it again), and the summary's winner
    is the paired one."""
    from autotune.search.records import race_summary

    spec = _spec(race_configs=2, race_seeds=2).with_overrides(storage=str(tmp_path / "j.log"))
    storages = open_storage(spec.study.storage, spec.study.name)
    driver = Driver(spec, storages)
    study = driver.open_study()
    done, pruned = optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED

    add = _tiny_adder(study, spec)

    add(done, 74.0)
    add(done, 73.0)
    study.set_user_attr(keys.RACE_FIELD, [0, 1])
    add(done, 70.0, **{keys.RACE_OF: 0, keys.RACE_SEED: 0})
    add(done, 72.0, **{keys.RACE_OF: 1, keys.RACE_SEED: 0})
    add(pruned, None, **{keys.RACE_OF: 1, keys.RACE_SEED: 1, keys.CAUSE: "deadline: the study's time budget ended"})
    add(done, 71.0, **{keys.RACE_OF: 0, keys.RACE_SEED: 1})
    field, results, launched = driver._race_state()  # noqa: SLF001
    assert field == [0, 1] and results == {(0, 0): 70.0, (1, 0): 72.0, (0, 1): 71.0}
    assert launched == {(0, 0), (1, 0), (0, 1)}
    runs, over = racing.next_runs(field, results, launched, 2)
    assert not over and [(r.race_of, r.seed_index) for r in runs] == [(1, 1)]  # a resumed race reruns it
    summary = race_summary(storages, spec.study.name)
    assert summary is not None and summary["winner"]["trial"] == 1  # 72.0 against 70.0 on seed 0
    assert (summary["winner"]["n"], summary["winner"]["ranked_on"], summary["winner"]["paired_mean"]) == (1, 1, 72.0)
    assert summary["standings"][1]["n"] == 2 and summary["standings"][1]["finalist"]


def test_before_the_race_the_best_configuration_is_the_best_mean_over_three_fresh_seeds(tmp_path: Path) -> None:
    """``race_summary`` before the race (no field stored): a provisional standing of the configurations with
    ``racing.PROVISIONAL_SEEDS`` fresh seed runs, by their mean, not the lucky best trial; ``autotune best`` says
    so. None while no configuration has that many."""
    import subprocess
    import sys

    from autotune.search.records import race_summary

    spec = _spec().with_overrides(storage=str(tmp_path / "j.log"))
    storages = open_storage(spec.study.storage, spec.study.name)
    study = Driver(spec, storages).open_study()
    done, failed = optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.FAIL

    add = _tiny_adder(study, spec)

    add(done, 76.0)  # a lucky seed
    add(done, 74.0)
    for i, v in enumerate((71.0, 72.0)):
        add(done, v, **{keys.RACE_OF: 0, keys.RACE_SEED: i, keys.SEED_SOUP_RUN: True})
    for i, v in enumerate((73.0, 74.0)):
        add(done, v, **{keys.RACE_OF: 1, keys.RACE_SEED: i, keys.SEED_SOUP_RUN: True})
    add(failed, None, **{keys.RACE_OF: 1, keys.RACE_SEED: 2, keys.SEED_SOUP_RUN: True})
    assert race_summary(storages, spec.study.name) is None  # 2 fresh seeds each (a failed run is no score)
    add(done, 73.0, **{keys.RACE_OF: 0, keys.RACE_SEED: 2, keys.SEED_SOUP_RUN: True})
    summary = race_summary(storages, spec.study.name)
    assert summary is not None and summary["provisional"] and summary["entrants"] == []
    assert [r["trial"] for r in summary["standings"]] == [0]
    assert (summary["winner"]["mean"], summary["winner"]["n"], summary["winner"]["selecting_value"]) == (72.0, 3, 76.0)
    add(done, 75.0, **{keys.RACE_OF: 1, keys.RACE_SEED: 3, keys.SEED_SOUP_RUN: True})
    summary = race_summary(storages, spec.study.name)
    assert summary is not None and [r["trial"] for r in summary["standings"]] == [1, 0]  # 74.0 over 72.0
    assert summary["winner"]["sd"] == pytest.approx(1.0) and summary["winner"]["scores"] == [73.0, 74.0, 75.0]
    best = subprocess.run([sys.executable, "-m", "autotune.cli", "best", spec.study.name, "--storage",
                           spec.study.storage], cwd=tmp_path, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert best.returncode == 0, best.stderr
    assert "best configuration over fresh seeds so far (before the seed race): trial 1's settings: 74.00 ± 1.00" in (
        best.stdout
    )
    assert "also: trial 0: 72.00 mph over 3 fresh seeds" in best.stdout
    study.set_user_attr(keys.RACE_FIELD, [0, 1])  # the race started: its standings, not the provisional one
    summary = race_summary(storages, spec.study.name)
    assert summary is not None and not summary["provisional"] and summary["entrants"] == [0, 1]


def test_best_names_the_rival_the_winners_tail_fell_below(tmp_path: Path) -> None:
    """``race_summary`` and ``autotune best`` once the tail overturned the halving (``racing.tail_leader``): the
    rival is the winner row, not a finalist, and ``best`` says why; the halving's winner follows as a finalist."""
    import subprocess
    import sys

    from autotune.search.records import race_summary

    spec = _spec(race_seeds=1).with_overrides(storage=str(tmp_path / "j.log"))
    storages = open_storage(spec.study.storage, spec.study.name)
    study = Driver(spec, storages).open_study()
    done = optuna.trial.TrialState.COMPLETE
    add = _tiny_adder(study, spec)
    add(done, 76.0)
    add(done, 75.0)
    study.set_user_attr(keys.RACE_FIELD, [0, 1])
    for number, index, value in ((0, 0, 75.0), (1, 0, 74.5), (0, 1, 74.0)):
        add(done, value, **{keys.RACE_OF: number, keys.RACE_SEED: index})
    summary = race_summary(storages, spec.study.name)
    assert summary is not None and summary["winner"]["trial"] == 0  # 74.5 over 2 ties 74.5: the winner keeps it
    add(done, 62.0, **{keys.RACE_OF: 0, keys.RACE_SEED: 2})  # a collapse in the tail: 70.33 over 3
    summary = race_summary(storages, spec.study.name)
    assert summary is not None and summary["winner"]["trial"] == 1 and not summary["winner"]["finalist"]
    assert summary["standings"][1]["trial"] == 0 and summary["standings"][1]["finalist"]
    best = subprocess.run([sys.executable, "-m", "autotune.cli", "best", spec.study.name, "--storage",
                           spec.study.storage], cwd=tmp_path, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert best.returncode == 0, best.stderr
    assert "best configuration over fresh seeds (the seed race): trial 1's settings: 74.50 mph (n = 1" in best.stdout
    assert "the halving's winner's mean over all its fresh seeds fell below this one's" in best.stdout
    assert "raced: trial 0: 70.33 mph over 3 fresh seed(s) (finalist)" in best.stdout


def test_the_race_winner_gets_more_seeds_only_once_the_halving_is_over() -> None:
    """``tail_run``: nothing while the halving runs; then the winner's first seed index not yet started (a running
    one counts); a field of one takes its tail after its first round. ``tail_reaches``: within the reach of the
    study's best single net, not below it, never without a finite run."""
    field = [105, 25, 1, 51]
    results: dict[tuple[int, int], float | None] = {
        (105, 0): 73.32, (105, 1): 73.32, (25, 0): 74.77, (25, 1): 74.79, (1, 0): 73.32, (1, 1): 70.76,
        (51, 0): 72.39, (51, 1): 61.18,
    }  # fmt: skip
    assert racing.tail_run(field, results, set(results), 2) is None  # round 1 of the halving not run yet
    results.update({(105, 2): 73.36, (105, 3): 72.37, (25, 2): 64.41, (25, 3): 75.16})
    assert racing.next_runs(field, results, set(results), 2) == ([], True)
    assert racing.tail_run(field, results, set(results), 2) == racing.RaceRun(25, 4)
    assert racing.tail_run(field, results, set(results) | {(25, 4)}, 2) == racing.RaceRun(25, 5)  # 4 is running
    assert racing.tail_run([7], {(7, 0): 70.0}, {(7, 0), (7, 1)}, 2) is None  # its first round still runs
    assert racing.tail_run([7], {(7, 0): 70.0, (7, 1): 71.0}, {(7, 0), (7, 1)}, 2) == racing.RaceRun(7, 2)
    assert racing.tail_reaches([74.77, 64.41, 75.16], 75.16) and racing.tail_reaches([74.7], 75.16)
    assert not racing.tail_reaches([74.12, 74.09], 74.96)  # a cold hour's winner: 0.84 below its study's best
    assert not racing.tail_reaches([None], 70.0) and racing.tail_reaches([70.0], None)


def test_a_rival_of_the_last_round_leads_once_the_winners_tail_falls_below_its_mean() -> None:
    """``tail_leader``: the halving's winner (signed ranks) until its tail brings its mean over all its seeds below
    that of a configuration it beat in the last round; then that one takes the tail's seeds and heads the
    standings, and back again when its own mean falls; a failed run is no mean. Study seed 3's race, in short."""
    field = [1, 2, 3, 4]
    results: dict[tuple[int, int], float | None] = {
        (1, 0): 75.46, (1, 1): 75.13, (2, 0): 74.52, (2, 1): 75.09, (3, 0): 73.0, (3, 1): 73.5, (4, 0): 72.0,
        (4, 1): 72.5, (1, 2): 75.33, (1, 3): 74.15, (2, 2): 75.13, (2, 3): 75.11,
    }  # fmt: skip
    assert racing.next_runs(field, results, set(results), 2) == ([], True)
    assert racing.tail_leader(field, results, 2) == 1  # 3 of 4 seeds: signed ranks +2, though its mean is 75.02
    assert racing.tail_run(field, results, set(results), 2) == racing.RaceRun(1, 4)
    results.update({(1, 4): 74.54, (1, 5): 75.3})  # 74.99 over 6 seeds > 74.96: the verdict stands
    assert racing.tail_leader(field, results, 2) == 1 and racing.standings(field, results, 2)[0].number == 1
    results[(1, 6)] = 64.91  # a collapse: 73.55 over 7 seeds
    assert racing.tail_leader(field, results, 2) == 2
    assert racing.tail_run(field, results, set(results), 2) == racing.RaceRun(2, 4)  # a seed 1 ran: paired
    ranked = racing.standings(field, results, 2)
    assert [st.number for st in ranked][:2] == [2, 1] and ranked[0].mean == pytest.approx(74.9625)
    assert racing.tail_leader([3, 4, 1, 2], results, 2) == 2  # 3 and 4, cut in round 0, never lead
    results[(2, 4)] = 60.0  # its own collapse: 71.97 over 5
    assert racing.tail_leader(field, results, 2) == 1
    assert racing.tail_run(field, results, set(results), 2) == racing.RaceRun(1, 7)
    results[(1, 7)] = None  # a failed run ranks its configuration last
    assert racing.tail_leader(field, results, 2) == 2
    assert racing.tail_leader([7], {(7, 0): 70.0, (7, 1): 71.0}, 2) == 7  # a field of one: no rival


def _driver_on_journal(spec: StudySpec) -> tuple[Driver, Any, Any, dict[str, Any], dict[str, Any]]:
    """(driver, its opened study, the storages, the space's distributions, TINY's params) on ``spec``'s storage."""
    storages = open_storage(spec.study.storage, spec.study.name)
    driver = Driver(spec, storages)
    return driver, driver.open_study(), storages, distributions(spec), space.encode(spec, TINY)


def test_a_race_run_queued_behind_other_enqueued_trials_still_starts(tmp_path: Path) -> None:
    """Optuna's queue pops the oldest waiting trial: race runs enqueued behind two linear neighbours (enqueued just
    before the race window) have the neighbours start in their place. Once those finish, the waiting race runs
    start (``_race_slot``), where the race used to keep both slots for them, idle, to the study's end."""
    spec = _spec(race_configs=2, race_seeds=1, n_trials=50, timeout_s=3600).with_overrides(
        storage=str(tmp_path / "j.log"))  # fmt: skip
    driver, study, storages, dists, params = _driver_on_journal(spec)
    done = optuna.trial.TrialState.COMPLETE
    for value in (74.0, 73.0):
        study.add_trial(optuna.trial.create_trial(params=params, distributions=dists, value=value, state=done,
                                                  user_attrs={keys.CONFIG: TINY.to_mapping()}))  # fmt: skip
    study.set_user_attr(keys.RACE_FIELD, [0, 1])
    for _ in range(2):
        study.enqueue_trial(params, user_attrs={keys.NEIGHBOUR_OF: 0})
    driver._t0 = time.perf_counter() - 0.9 * 3600  # noqa: SLF001 - in the race window
    driver.pool = pool = FakePool()
    assert driver._race_window()  # noqa: SLF001
    assert driver._race_slot(0) and driver._race_slot(1)  # noqa: SLF001 - each enqueues a race run, starts a neighbour
    started = [study.trials[task.number] for task in pool.tasks]
    assert [t.user_attrs.get(keys.NEIGHBOUR_OF) for t in started] == [0, 0]
    assert driver._race_runs() == ([], False)  # noqa: SLF001 - both race runs count as launched: none left to start
    for task in pool.tasks:
        study.tell(task.number, 73.5)
    assert driver._race_slot(0) and driver._race_slot(1)  # noqa: SLF001
    raced = [study.trials[task.number].user_attrs.get(keys.RACE_OF) for task in pool.tasks[2:]]
    assert sorted(raced) == [0, 1]
    assert not study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.WAITING,))
    assert driver._race_slot(0) and not pool.tasks[4:]  # noqa: SLF001 - nothing waits: kept for the round under way


def test_the_race_winner_takes_the_time_left_while_its_runs_reach_the_best_net(tmp_path: Path) -> None:
    """The driver's ``_race_runs``: after the halving, the winner's next seed while its best run reaches the study's
    best single net (kept rungs count), one run of it fits the time left and the trial budget is not spent."""
    spec = _spec(race_configs=2, race_seeds=1, n_trials=5, timeout_s=3600).with_overrides(
        storage=str(tmp_path / "j.log"))  # fmt: skip
    driver, study, storages, dists, params = _driver_on_journal(spec)
    done = optuna.trial.TrialState.COMPLETE

    def add(value: float, **attrs: Any) -> None:
        study.add_trial(optuna.trial.create_trial(params=params, distributions=dists, value=value, state=done,
                                                  user_attrs={keys.CONFIG: TINY.to_mapping(), **attrs}))  # fmt: skip

    add(74.0)
    add(73.0)
    study.set_user_attr(keys.RACE_FIELD, [0, 1])
    add(73.6, **{keys.RACE_OF: 0, keys.RACE_SEED: 0})
    add(72.0, **{keys.RACE_OF: 1, keys.RACE_SEED: 0})
    driver._t0 = time.perf_counter()  # noqa: SLF001
    assert driver._race_runs() == ([racing.RaceRun(0, 1)], False)  # noqa: SLF001 - 73.6 is within 0.5 of 74.0
    driver.pool = FakePool()
    assert driver._launch_race(0)  # noqa: SLF001
    (run,) = [t for t in study.trials if t.user_attrs.get(keys.RACE_SEED) == 1]
    assert run.user_attrs[keys.RACE_OF] == 0 and run.user_attrs[keys.SEED] == racing.race_seed(spec.study.seed, 1)
    assert driver._race_runs() == ([racing.RaceRun(0, 2)], False)  # noqa: SLF001 - the other worker's
    study.add_trial(optuna.trial.create_trial(
        params=params, distributions=dists, state=optuna.trial.TrialState.PRUNED,
        user_attrs={keys.CONFIG: TINY.to_mapping(), keys.OFFICIAL_PROTOCOL: "v2-official",
                    keys.RUNGS: [{keys.BUDGET: 400, keys.SCORE: 74.5}], keys.ARTIFACT_RUNG_NETS: {"400": "id"}},
    ))  # fmt: skip
    assert driver._race_runs() == ([], True)  # noqa: SLF001 - a kept 74.5 rung: 73.6 no longer reaches it
    assert not driver._launch_race(1) and driver._race_over  # noqa: SLF001
    driver._race_over = False  # noqa: SLF001
    add(74.3, **{keys.RACE_OF: 0, keys.RACE_SEED: 2})  # the winner's tail reaches it again
    assert driver._race_runs()[1] is False  # noqa: SLF001
    driver._t0 = time.perf_counter() - 3600 + 0.01  # noqa: SLF001 - no run fits the time left
    assert driver._race_runs() == ([], True)  # noqa: SLF001
    driver._t0 = time.perf_counter()  # noqa: SLF001
    spent = Driver(spec.with_overrides(n_trials=3), storages)
    spent.open_study()
    spent._t0 = time.perf_counter()  # noqa: SLF001
    assert spent._race_runs() == ([], True)  # noqa: SLF001 - 3 original trials used the budget of 3


def test_a_round_that_would_not_finish_before_the_deadline_ends_the_race(tmp_path: Path) -> None:
    """The halving's next round starts only when each of its runs fits the time left (padded by RACE_MARGIN): a
    round the deadline cuts ranks no one, so the race is over and the workers go back to the search."""
    from autotune.search.driver import RACE_MARGIN

    spec = _spec(race_configs=3, race_seeds=1, n_trials=50, timeout_s=3600).with_overrides(
        storage=str(tmp_path / "j.log"))  # fmt: skip
    driver, study, _storages, dists, params = _driver_on_journal(spec)
    done = optuna.trial.TrialState.COMPLETE
    for value, attrs in (
        (74.0, {}),
        (73.0, {}),
        (72.0, {}),
        (73.5, {keys.RACE_OF: 0, keys.RACE_SEED: 0}),
        (73.1, {keys.RACE_OF: 1, keys.RACE_SEED: 0}),
        (70.0, {keys.RACE_OF: 2, keys.RACE_SEED: 0}),
    ):
        study.add_trial(optuna.trial.create_trial(params=params, distributions=dists, value=value, state=done,
                                                  user_attrs={keys.CONFIG: TINY.to_mapping(), **attrs}))  # fmt: skip
    study.set_user_attr(keys.RACE_FIELD, [0, 1, 2])
    cost = driver._race_cost(TINY.to_mapping())  # noqa: SLF001
    _left(driver, cost * RACE_MARGIN * 1.01)
    assert driver._race_runs() == ([racing.RaceRun(0, 1), racing.RaceRun(1, 1)], False)  # noqa: SLF001
    _left(driver, cost * RACE_MARGIN * 0.99)
    assert driver._race_runs() == ([], True)  # noqa: SLF001 - the second round would not finish


def test_the_incumbent_is_the_best_candidate_whose_runs_reach_the_best_net() -> None:
    """``incumbent_run``: the first candidate whose selecting score and finished fresh runs reach the study's best
    single net; its first seed index not started (a running one counts); none once every candidate trails."""
    a, b, c = (racing.Entrant(n, v, str(n)) for n, v in ((25, 75.11), (79, 74.9), (3, 73.0)))
    assert racing.incumbent_run([a, b, c], {}, set(), 75.11) == racing.RaceRun(25, 0)
    assert racing.incumbent_run([a, b, c], {}, set(), None) == racing.RaceRun(25, 0)  # no best yet: the first
    results: dict[tuple[int, int], float | None] = {(25, 0): 74.77}
    assert racing.incumbent_run([a, b, c], results, {(25, 0), (25, 1)}, 75.11) == racing.RaceRun(25, 2)
    results = {(25, 0): 74.12, (25, 1): 74.09}  # its fresh seeds trail by 0.99: the next candidate's turn
    assert racing.incumbent_run([a, b, c], results, set(results), 75.11) == racing.RaceRun(79, 0)
    assert racing.incumbent_run([a, b, c], {(25, 0): None}, {(25, 0)}, 75.11) == racing.RaceRun(79, 0)  # failed
    assert racing.incumbent_run([a, b, c], results, set(results), 75.5) is None  # 74.9 trails a 75.5 rung
    results = {(25, 0): 75.7}  # its own fresh seed set the study's best: it stays the incumbent
    assert racing.incumbent_run([a, b, c], results, set(results), 75.7) == racing.RaceRun(25, 1)
    assert racing.incumbent_run([c], {}, set(), 75.11) is None


def test_the_incumbent_runs_at_most_max_runs_before_the_race() -> None:
    """``max_runs`` bounds one configuration's fresh runs before the race (a running one counts): then the next
    candidate that reaches the best, else none; None leaves the incumbent unbounded."""
    a, b = racing.Entrant(25, 75.11, "a"), racing.Entrant(79, 74.9, "b")
    results = {(25, 0): 75.7, (25, 1): 75.2}  # its own runs set the best: unbounded, it would go on
    assert racing.incumbent_run([a, b], results, set(results), 75.7) == racing.RaceRun(25, 2)
    assert racing.incumbent_run([a, b], results, set(results), 75.7, max_runs=3) == racing.RaceRun(25, 2)
    assert racing.incumbent_run([a, b], results, {*results, (25, 2)}, 75.7, max_runs=3) is None  # 74.9 trails 75.7
    assert racing.incumbent_run([a, b], results, set(results), 75.3, max_runs=2) == racing.RaceRun(79, 0)
    assert racing.incumbent_run([a, b], {}, set(), 75.11, max_runs=1) == racing.RaceRun(25, 0)


def test_intensify_runs_bounds_the_incumbent_and_needs_intensify_share() -> None:
    assert _spec().study.intensify_runs is None
    assert _spec(intensify_share=0.5, intensify_runs=8).study.intensify_runs == 8
    with pytest.raises(SpecError, match=r"\[study\] intensify_runs: .*intensify_share = 0; set intensify_share"):
        _spec(intensify_runs=8)
    with pytest.raises(SpecError, match=r"\[study\] intensify_runs"):
        _spec(intensify_share=0.5, intensify_runs=0)


def test_intensify_share_is_a_share_of_the_workers_and_needs_a_race() -> None:
    assert _spec().study.intensify_share == 0.0
    assert _spec(intensify_share=0.5).study.intensify_share == 0.5
    with pytest.raises(SpecError, match=r"\[study\] intensify_share: 1.5 is out of range; use \[0, 1\]"):
        _spec(intensify_share=1.5)
    with pytest.raises(SpecError, match=r"intensify_share: .*race_fraction = 0; set race_fraction"):
        _spec(intensify_share=0.5, race_fraction=0.0)
    with pytest.raises(SpecError, match=r"intensify_shar.*did you mean 'intensify_share'"):
        _spec(intensify_shar=0.5)


def test_the_search_retrains_its_incumbent_on_the_race_seeds_before_the_race(tmp_path: Path) -> None:
    """The driver's ``_launch_incumbent``: before the race, the incumbent's next race seed on its share of the
    workers — an ordinary race run at the ε_test and budget that selected it, marked ``incumbent_run`` — after the
    queue, never in the race window, never with ``intensify_share`` 0; the race then runs only the seeds it lacks."""
    spec = _spec(race_configs=2, race_seeds=2, n_trials=20, timeout_s=3600, intensify_share=0.5).with_overrides(
        storage=str(tmp_path / "j.log"), workers=2)  # fmt: skip
    driver, study, storages, dists, params = _driver_on_journal(spec)
    done = optuna.trial.TrialState.COMPLETE
    chosen = TINY.replace(epsilon_test_time=0.05).to_mapping()

    def add(value: float, config: dict[str, Any] = chosen, **attrs: Any) -> None:
        study.add_trial(optuna.trial.create_trial(params=params, distributions=dists, value=value, state=done,
                                                  user_attrs={keys.CONFIG: config, **attrs}))  # fmt: skip

    def finish(slot: int, value: float) -> None:
        study.tell(driver._running.pop(slot).trial, value)  # noqa: SLF001

    add(74.0)
    add(73.0, TINY.replace(batch_size=4).to_mapping())
    driver._t0 = time.perf_counter()  # noqa: SLF001
    driver.pool = FakePool()
    assert driver._launch_incumbent(0)  # noqa: SLF001
    run = study.trials[-1]
    assert run.user_attrs[keys.RACE_OF] == 0 and run.user_attrs[keys.RACE_SEED] == 0
    assert run.user_attrs[keys.INCUMBENT_RUN] is True and run.user_attrs[keys.CONFIG] == chosen
    assert run.user_attrs[keys.SEED] == racing.race_seed(spec.study.seed, 0)
    task = driver.pool.tasks[-1]
    assert task.rungs == (TINY.train_iterations,) and not task.prune_static and task.epsilon_test_grid == ()
    assert not driver._launch_incumbent(1)  # noqa: SLF001 - half of the 2 workers: one such run at a time
    finish(0, 73.7)
    assert driver._launch_incumbent(0)  # noqa: SLF001 - 73.7 reaches 74.0: its next seed
    assert study.trials[-1].user_attrs[keys.RACE_SEED] == 1
    finish(0, 72.0)
    study.enqueue_trial(params)  # the queue (a crowd setting, a retry) comes first
    assert not driver._launch_incumbent(0)  # noqa: SLF001
    assert driver._launch_next(0)  # noqa: SLF001
    finish(0, 70.0)
    add(74.5, TINY.replace(batch_size=16).to_mapping())  # a new best: trial 0's seeds (73.7, 72.0) trail it
    assert driver._launch_incumbent(0) and study.trials[-1].user_attrs[keys.RACE_OF] == 5  # noqa: SLF001
    finish(0, 74.4)
    bounded = Driver(dataclasses.replace(spec, study=dataclasses.replace(spec.study, intensify_runs=1)), storages)
    bounded.open_study()
    bounded._t0, bounded.pool = time.perf_counter(), FakePool()  # noqa: SLF001
    assert not bounded._launch_incumbent(0)  # noqa: SLF001 - trial 5 (74.4) had its one run; trial 0's trail
    idle = Driver(dataclasses.replace(spec, study=dataclasses.replace(spec.study, intensify_share=0.0)), storages)
    idle.open_study()
    idle._t0, idle.pool = time.perf_counter(), FakePool()  # noqa: SLF001
    assert not idle._launch_incumbent(0)  # noqa: SLF001
    alone = Driver(spec.with_overrides(workers=1), storages)
    alone.open_study()
    alone._t0, alone.pool = time.perf_counter(), FakePool()  # noqa: SLF001
    assert not alone._launch_incumbent(0)  # noqa: SLF001 - never the last worker: the search goes on
    driver._race_over = True  # noqa: SLF001 - the race has run: no incumbent runs after it
    assert not driver._launch_incumbent(0)  # noqa: SLF001
    driver._race_over = False  # noqa: SLF001
    driver._t0 = time.perf_counter() - 0.8 * 3600  # noqa: SLF001 - the race window: the race takes over
    assert not driver._launch_incumbent(0)  # noqa: SLF001
    field, results, launched = driver._race_state()  # noqa: SLF001
    assert field == [5, 0] and results[(5, 0)] == 74.4 and results[(0, 1)] == 72.0
    runs, over = racing.next_runs(field, results, launched, 2)
    assert not over and runs == [racing.RaceRun(5, 1)]  # trial 0 ran both seeds of round 0 before the race


def test_warm_start_from_a_study_copies_measured_trials(tmp_path: Path) -> None:
    """--warm-start STUDY: the earlier study's COMPLETE trials enter the sampler's history, once, using no budget."""
    from autotune.search.gate import distributions

    spec = _spec().with_overrides(storage=str(tmp_path / "j.log"))
    storages = open_storage(spec.study.storage, spec.study.name)
    dists = distributions(spec)
    earlier = optuna.create_study(study_name="earlier", storage=storages.storage, direction="maximize")
    params = {name: (d.choices[0] if isinstance(d, optuna.distributions.CategoricalDistribution)
                     else d.low)  # type: ignore[attr-defined]
              for name, d in dists.items()}  # fmt: skip
    earlier.add_trial(optuna.trial.create_trial(params=params, distributions=dists, value=71.5,
                                                user_attrs={"config": {"x": 1}, "seed": 9}))  # fmt: skip
    earlier.add_trial(optuna.trial.create_trial(state=optuna.trial.TrialState.FAIL))
    warm = spec.with_overrides(warm_start="earlier")
    driver = Driver(warm, storages)
    study = driver.open_study()
    driver._warm_start()  # noqa: SLF001
    driver._warm_start()  # noqa: SLF001 - once per study
    copied = study.get_trials()
    assert len(copied) == 1 and copied[0].value == 71.5 and copied[0].user_attrs["copied_from"] == "earlier:0"
    driver._refresh_counts()  # noqa: SLF001
    assert driver.counts.started == 0 and driver.counts.complete == 0  # history, not this study's trials
    with pytest.raises(SpecError, match="--warm-start nosuch: no such study"):
        d = Driver(spec.with_overrides(warm_start="nosuch", name="other"), storages)
        d.open_study()
        d._warm_start()  # noqa: SLF001


def test_warm_start_from_a_study_in_other_coordinates_encodes_its_configs(tmp_path: Path) -> None:
    """An earlier study that sampled ε_test directly, this one ε_test + 0.005 on a log scale: its trials enter with
    their stored configurations encoded into this space, ε_test 0.02 as 0.025; one without a config does not."""
    from autotune.search import space as search_space
    from autotune.search.gate import distributions

    def with_eps(name: str) -> StudySpec:
        data = _spec(name=name, storage=str(tmp_path / "j.log")).to_dict()
        data["space"] = {**data["space"], name_of[name]: ranges[name]}
        return parse_spec(data)

    name_of = {"old": "epsilon_test_time", "new": "epsilon_test_time_shifted"}
    ranges = {"old": {"low": 0.0, "high": 0.9}, "new": {"low": 0.005, "high": 0.905, "log": True}}
    old, new = with_eps("old"), with_eps("new")
    storages = open_storage(new.study.storage, new.study.name)
    earlier = optuna.create_study(study_name="old", storage=storages.storage, direction="maximize")
    old_params = {"lanes_side": 1, "patches_ahead": 3, "learning_steps_burnin_fraction": 0.05, "method": "sgd",
                  "n_layers": 1, "neurons_0": 4, "activation_0": "tanh", "neurons_1": 2, "activation_1": "relu",
                  "epsilon_test_time": 0.02}  # fmt: skip
    config = search_space.to_config(old, old_params)
    for user in ({"config": config.to_mapping()}, {}):
        earlier.add_trial(optuna.trial.create_trial(params=old_params, distributions=distributions(old),
                                                    value=73.5, user_attrs=user))  # fmt: skip
    driver = Driver(new.with_overrides(warm_start="old"), storages)
    study = driver.open_study()
    driver._warm_start()  # noqa: SLF001
    (copied,) = study.get_trials()
    assert copied.params["epsilon_test_time_shifted"] == 0.025 and "epsilon_test_time" not in copied.params
    assert search_space.to_config(new, copied.params) == config and copied.value == 73.5


def _race_driver(tmp_path: Path, name: str, workers: int, min_top: int = 0) -> tuple[Driver, dict[int, float]]:
    """A driver over four finished trials (values 70, 72, 60, 65) whose race cost grows with their weights."""
    data = _spec(race_configs=2, race_seeds=1, name=name).to_dict()
    if min_top:
        data["ladder"]["min_top"] = min_top
    spec = parse_spec(data, source="race.toml").with_overrides(storage=str(tmp_path / "j.log"), workers=workers)
    driver = Driver(spec, open_storage(spec.study.storage, spec.study.name))
    study = driver.open_study()
    driver.cost_model = forward_cost_model(1e-3)  # cost ∝ weights × iterations
    dists = distributions(spec)
    layouts = {"fc:8:relu": 70.0, "fc:8:relu|fc:8:tanh": 72.0, "": 60.0, "fc:4:relu": 65.0}
    for layers, value in layouts.items():
        cfg = TINY.replace(layers=layers, train_iterations=1200)
        study.add_trial(optuna.trial.create_trial(
            params=space.encode(spec, cfg), distributions=dists, value=value,
            user_attrs={keys.CONFIG: cfg.to_mapping(), keys.SEED: 1},
        ))  # fmt: skip
    driver._fitted_on = len(study.trials)  # noqa: SLF001 - keep the model above (no refit on these trials)
    cost = {n: driver._race_cost(t.user_attrs[keys.CONFIG]) for n, t in enumerate(study.trials)}  # noqa: SLF001
    assert cost[1] > cost[0] > cost[3] > cost[2] > 0
    return driver, cost


def _left(driver: Driver, seconds: float) -> None:
    timeout = driver.spec.study.timeout_s
    assert timeout is not None
    driver._t0 = time.perf_counter() - timeout + seconds  # noqa: SLF001


def _add_seed_runs(driver: Driver, number: int, values: tuple[float, ...]) -> None:
    """Finished seed runs of trial ``number``'s configuration on race seeds 0, 1, …, scored ``values``."""
    assert driver.study is not None
    source = driver.study.trials[number]
    for seed, value in enumerate(values):
        driver.study.add_trial(optuna.trial.create_trial(
            params=source.params, distributions=source.distributions, value=value,
            user_attrs={keys.CONFIG: source.user_attrs[keys.CONFIG], keys.SEED: 100 + seed, keys.RACE_OF: number,
                        keys.RACE_SEED: seed, keys.SEED_SOUP_RUN: True},
        ))  # fmt: skip


def test_the_race_field_holds_only_runs_that_fit_the_time_left(tmp_path: Path) -> None:
    """A configuration one run of which (padded by RACE_MARGIN) the deadline would stop is not raced (it would
    score nothing after taking a worker); the others join best first while the first round, spread over the
    workers, fits the time left; a round starts its longest run first."""
    from autotune.search.driver import RACE_MARGIN

    driver, cost = _race_driver(tmp_path, "two", workers=2)
    _left(driver, cost[0] * RACE_MARGIN * 1.01)  # trial 0's run fits, the best (trial 1, 72.0) does not
    field, _results, _launched = driver._race_state()  # noqa: SLF001
    assert field == [0, 3]  # 0 and 3 side by side on the two workers
    runs, over = racing.next_runs(field, {}, set(), 1)
    assert not over and max(runs, key=lambda r: cost[r.race_of]).race_of == 0

    one, cost = _race_driver(tmp_path, "one", workers=1)
    _left(one, cost[0] * RACE_MARGIN * 1.01)
    assert one._race_state()[0] == [0]  # noqa: SLF001 - on one worker 3 would run after 0, past the deadline
    _left(one, (cost[0] + cost[2]) * RACE_MARGIN * 1.01)
    assert one._race_field()[0] == [0, 2]  # noqa: SLF001 - 3 (65.0) does not fit after 0, the cheaper 2 does


def test_the_provisional_leader_enters_the_race_though_its_selecting_score_is_lower(tmp_path: Path) -> None:
    """The driver's field: trial 2 (selected at 60.0), whose three fresh seed runs average 71.0, enters first, then
    the best selecting score (trial 1, 72.0); before its seeds it did not enter at all."""
    driver, _cost = _race_driver(tmp_path, "lead", workers=2)
    _left(driver, 3600.0)
    assert driver._race_field()[0] == [1, 0]  # noqa: SLF001
    assert driver.study is not None
    _add_seed_runs(driver, 2, (70.0, 71.5, 71.5))
    assert driver._race_field()[0] == [2, 1]  # noqa: SLF001


def test_the_race_field_counts_only_the_first_rounds_runs_not_yet_launched(tmp_path: Path) -> None:
    """The leader's seed runs are the race's first seeds: they take no more of the time left, so on one worker the
    next entrant joins in the time one leader's run would take (counted in full, only the cheapest could)."""
    from autotune.search.driver import RACE_MARGIN

    driver, cost = _race_driver(tmp_path, "seeded", workers=1)
    assert driver.study is not None
    _add_seed_runs(driver, 1, (71.0, 71.5, 71.5))  # the dearest configuration, 72.0; race seed 0 among them
    driver._fitted_on = len(driver.study.trials)  # noqa: SLF001 - keep the cost model (no refit on the seed runs)
    _left(driver, cost[1] * RACE_MARGIN * 1.01)  # a run of the leader fits; with one run of 0 beside it, not
    assert cost[1] + cost[0] > cost[1] * 1.01
    assert driver._race_field()[0] == [1, 0]  # noqa: SLF001


def test_an_entrant_too_long_for_the_time_left_races_at_a_lower_rung(tmp_path: Path) -> None:
    """An entrant whose own run would not fit the time left races at the highest rung from min_top up that does
    (stored in ``race_budgets``, so its runs train ``rung_config`` at that budget), not at all when none does."""
    from autotune.search.driver import RACE_MARGIN

    driver, cost = _race_driver(tmp_path, "low", workers=2, min_top=400)
    assert driver.spec.race_min_budget == 400
    _left(driver, cost[1] * 400 / 1200 * RACE_MARGIN * 1.01)  # trial 1's 400 run fits, its 1,200 one does not
    field, _results, _launched = driver._race_state()  # noqa: SLF001
    assert driver.study is not None
    assert field == [1, 0] and driver.study.user_attrs[keys.RACE_BUDGETS] == {"1": 400, "0": 400}
    driver.pool = FakePool()
    assert driver._launch_race(0)  # noqa: SLF001
    run = driver.pool.tasks[0]
    top = TrainConfig.from_mapping(driver.study.trials[1].user_attrs[keys.CONFIG])
    assert run.config == rung_config(top, 400).to_mapping() and run.rungs == (400,)
    gated, _cost = _race_driver(tmp_path, "gated", workers=2)  # the whole ladder gated: 400 only screens
    _left(gated, cost[2] * RACE_MARGIN * 0.5)
    assert gated._race_field()[0] == []  # noqa: SLF001


def test_a_draw_the_deadline_overtakes_is_pruned_at_the_deadline_not_failed(tmp_path: Path) -> None:
    """A trial whose cheapest rung no longer fits the time left when the driver prices it (the deadline came
    nearer while it was drawn) is not trained and ends PRUNED with a 'deadline' cause, like a trial the deadline
    stops while it trains, not FAIL; one over the study's cost cap is refused as before."""
    driver, cost = _race_driver(tmp_path, "late", workers=1)
    study = driver.study
    assert study is not None
    driver.pool = FakePool()
    cfg = TINY.replace(layers="fc:8:relu|fc:8:tanh")
    study.enqueue_trial(space.encode(driver.spec, cfg))
    _left(driver, cost[1] / 1200 * 400 / 10)  # a tenth of its 400 rung
    assert driver._launch_next(0)  # noqa: SLF001
    late = study.trials[-1]
    assert late.state == optuna.trial.TrialState.PRUNED and driver.pool.tasks == []
    assert late.user_attrs[keys.CAUSE].startswith("deadline: the study's time budget ended (before training: ")
    assert racing.run_result("PRUNED", None, late.user_attrs[keys.CAUSE]) == (False, None)
    capped = dataclasses.replace(driver.spec.study, max_trial_cost_s=cost[1] / 1200 * 400 / 10)
    driver.spec = dataclasses.replace(driver.spec, study=capped)
    driver._fitted_on += 1  # noqa: SLF001 - the pruned trial above: keep the test's model, no refit
    _left(driver, 60)
    study.enqueue_trial(space.encode(driver.spec, cfg))
    assert driver._launch_next(0)  # noqa: SLF001
    over = study.trials[-1]
    assert over.state == optuna.trial.TrialState.FAIL and driver.pool.tasks == []
    assert over.user_attrs[keys.CAUSE].startswith("refused: its cheapest rung is predicted to take")
    assert over.user_attrs[keys.CAUSE].endswith("s ([study] max_trial_cost_s)")  # the key to raise
    assert dataclasses.replace(capped, max_trial_cost_s=None).cap_key() == "trial_timeout_s"  # the cap without it


def test_a_kept_rung_that_beat_its_top_races_at_its_budget(tmp_path: Path) -> None:
    """An entrant is a trial's best scored net at min_top or above (here 400): a kept rung that beat its trial's
    top races at its own budget (``rung_config``: what the rung trained), a pruned trial's kept rung may enter, a
    static policy may not; ``race_summary`` names the budget and the rung's score, and a resumed driver races
    the same configs."""
    from autotune.search.driver import race_entry
    from autotune.search.records import race_summary

    data = _spec(race_configs=3, race_seeds=1).to_dict()
    data["ladder"]["min_top"] = 400
    spec = parse_spec(data, source="race.toml").with_overrides(storage=str(tmp_path / "j.log"))
    assert spec.race_min_budget == 400
    storages = open_storage(spec.study.storage, spec.study.name)
    driver = Driver(spec, storages)
    study = driver.open_study()
    driver.cost_model = forward_cost_model(1e-9)
    driver._fitted_on = 10**6  # noqa: SLF001 - keep the model above
    dists = distributions(spec)

    def add(layers: str, state: optuna.trial.TrialState, value: float | None, rungs: dict[int, float],
            **attrs: Any) -> None:  # fmt: skip
        cfg = TINY.replace(layers=layers)
        study.add_trial(optuna.trial.create_trial(
            params=space.encode(spec, cfg), distributions=dists, value=value, state=state,
            user_attrs={keys.CONFIG: cfg.to_mapping(), keys.SEED: 1, keys.OFFICIAL_PROTOCOL: "v2-official",
                        keys.RUNGS: [{keys.BUDGET: b, keys.SCORE: v} for b, v in rungs.items()],
                        keys.ARTIFACT_RUNG_NETS: {str(b): f"id{b}" for b in rungs}, **attrs},
        ))  # fmt: skip

    done, pruned = optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED
    add("fc:8:relu", done, 70.0, {400: 74.0, 1200: 70.0})  # 0: its 400-iteration net beat its top
    add("fc:8:tanh", done, 72.0, {400: 71.0, 1200: 72.0})  # 1: its top is its best
    add("fc:4:relu", pruned, None, {400: 73.0})  # 2: pruned after a good rung
    add("fc:2:relu", pruned, None, {400: 80.0}, **{keys.STATIC_POLICY: True})  # 3: always one action
    add("fc:2:tanh", done, 71.5, {400: 71.5, 1200: 71.5})  # 4: a tie goes to the value (no budget)
    trials = study.trials
    at_400 = rung_config(TrainConfig.from_mapping(trials[0].user_attrs[keys.CONFIG]), 400)
    assert race_entry(trials[0], 400) == (74.0, 400, at_400.to_mapping()) and at_400.train_iterations == 400
    assert race_entry(trials[1], 400) == race_entry(trials[1]) == (72.0, None, trials[1].user_attrs[keys.CONFIG])
    assert race_entry(trials[3], 400) is None and race_entry(trials[4], 400)[1] is None  # type: ignore[index]
    # with the whole ladder gated (no min_top) the 400 rungs only screen: trial 0 enters with its top, trial 2
    # (pruned after its 400 rung) not at all
    assert _spec().race_min_budget == 1200
    assert race_entry(trials[0], 1200) == (70.0, None, trials[0].user_attrs[keys.CONFIG])
    assert race_entry(trials[2], 1200) is None

    driver._t0 = time.perf_counter()  # noqa: SLF001
    field, _results, _launched = driver._race_state()  # noqa: SLF001
    assert field == [0, 2, 1] and study.user_attrs[keys.RACE_BUDGETS] == {"0": 400, "2": 400}
    driver.pool = FakePool()
    assert driver._launch_race(0)  # noqa: SLF001
    (run,) = [t for t in study.trials if keys.RACE_OF in t.user_attrs]
    assert run.user_attrs[keys.RACE_OF] == 1  # the longest run first: trial 1 races at its own 1,200 iterations
    assert run.user_attrs[keys.CONFIG] == trials[1].user_attrs[keys.CONFIG] == driver.pool.tasks[0].config

    resumed = Driver(spec, open_storage(spec.study.storage, spec.study.name))
    resumed.open_study()
    assert resumed._raced_config(trials[0]) == at_400.to_mapping()  # noqa: SLF001
    assert resumed._raced_config(trials[2]) == rung_config(  # noqa: SLF001
        TrainConfig.from_mapping(trials[2].user_attrs[keys.CONFIG]), 400).to_mapping()  # fmt: skip
    assert resumed._raced_config(trials[1]) == trials[1].user_attrs[keys.CONFIG]  # noqa: SLF001
    summary = race_summary(storages, spec.study.name)
    assert summary is not None
    assert [(r["trial"], r["budget"], r["selecting_value"]) for r in summary["standings"]] == [
        (0, 400, 74.0), (2, 400, 73.0), (1, None, 72.0)]  # fmt: skip


def test_near_the_deadline_draws_must_fit_the_time_left(tmp_path: Path) -> None:
    """The gate's cap is the study's cost cap or the time left, whichever is less; once the time left is below
    the fewest seconds a sampled trial took through the gated rungs, no sampled trial starts (the deadline would
    stop it before it had a value) and the seed race takes the time left."""
    spec = _spec(max_trial_cost_s=20).with_overrides(storage=str(tmp_path / "j.log"))
    driver = Driver(spec, open_storage(spec.study.storage, spec.study.name))
    study = driver.open_study()
    timeout = spec.study.timeout_s
    assert timeout is not None
    driver._t0 = time.perf_counter()  # noqa: SLF001 - the study just started
    assert driver._draw_cap() == 20  # noqa: SLF001 - 60 s left: the cost cap
    driver._t0 = time.perf_counter() - timeout + 10  # noqa: SLF001 - 10 s left
    assert 9 < driver._draw_cap() <= 10  # noqa: SLF001
    assert driver._worth_starting()  # noqa: SLF001 - no complete trial yet: nothing known to be too long
    driver._cheapest_gated_s = 15.0  # noqa: SLF001 - the cheapest ladder up to min_top took 15 s
    assert not driver._worth_starting()  # noqa: SLF001
    assert driver._launch_next(0) is False and study.trials == []  # noqa: SLF001 - nothing asked, nothing made

    # the race takes the time no draw could use, even before its own part of the time (the last 25 %: 15 s)
    driver._t0 = time.perf_counter() - timeout + 30  # noqa: SLF001 - 30 s left: the race starts at 15 s left
    driver._cheapest_gated_s = 35.0  # noqa: SLF001
    assert driver._race_window()  # noqa: SLF001 - no ladder fits in 30 s
    driver._cheapest_gated_s = 20.0  # noqa: SLF001
    assert not driver._race_window()  # noqa: SLF001 - a 20 s ladder fits: the search goes on

    # the cheapest ladder: the time through the gated rungs (min_top), from any sampled trial that got there
    def outcome(state: str, *seconds: float) -> TrialOutcome:
        rungs = [{keys.BUDGET: b, keys.SECONDS: x} for b, x in zip((400, 1200), seconds, strict=False)]
        return TrialOutcome(0, state, None, None, {keys.RUNGS: rungs}, wall_seconds=sum(seconds) + 1)

    at_min_top = dataclasses.replace(spec, ladder_min_top=400)
    assert at_min_top.gated_rungs == 1 and spec.gated_rungs == 2
    driver.spec = at_min_top
    assert driver._gated_seconds(outcome(PRUNED, 3.0, 50.0)) == 3.0  # noqa: SLF001 - climbed on past min_top
    assert driver._gated_seconds(outcome(PRUNED)) is None  # noqa: SLF001 - stopped before its first rung
    driver.spec = spec
    assert driver._gated_seconds(outcome(COMPLETE, 3.0, 50.0)) == 53.0  # noqa: SLF001
    assert driver._gated_seconds(outcome(PRUNED, 3.0)) is None  # noqa: SLF001

    cap = [5.0]
    sampler = CostGatedSampler(optuna.samplers.RandomSampler(seed=0), spec, lambda _p: 4.0, lambda: cap[0], seed=0)
    gated = optuna.create_study(sampler=sampler)
    first = gated.ask()
    space.sample(first, spec)
    assert sampler.refused(first.number) == 0  # 4 s fits a cap of 5 s
    cap[0] = 3.0  # the deadline came closer: the cap is asked again for the next trial
    second = gated.ask()
    space.sample(second, spec)
    assert sampler.refused(second.number) == MAX_DRAWS
