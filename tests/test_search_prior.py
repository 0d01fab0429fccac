"""Draws free of the prior (``[study] prior_free_share``): the prior's lineage, the routing sampler, the halving
among their own kind, the spec key, and the driver's twins and neighbours of the prior-free sampler's best."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import optuna
import pytest

from autotune.search import keys, prior, space, twins
from autotune.search.driver import make_pruner, make_sampler
from autotune.search.gate import CostGatedSampler
from autotune.search.spec import LR_X_INPUTS, SpecError
from tests.test_search_twins import HIDDEN, _add, _driver, _spec

COMPLETE = optuna.trial.TrialState.COMPLETE
WAITING = optuna.trial.TrialState.WAITING


def _frozen(number: int, **attrs: Any) -> optuna.trial.FrozenTrial:
    t = optuna.trial.create_trial(value=70.0, user_attrs=attrs)
    t.number = number
    return t


def test_the_prior_is_its_roots_and_every_trial_made_from_them() -> None:
    trials = [
        _frozen(0, **{keys.WARM_START: "crowd:gsurma-v03"}),
        _frozen(1),  # a draw of the sampler's
        _frozen(2, **{keys.TWIN_OF: 0}),
        _frozen(3, **{keys.NEIGHBOUR_OF: 2}),
        _frozen(4, **{keys.RACE_OF: 3, keys.RACE_SEED: 0}),
        _frozen(5, **{keys.SEED_SOUP_OF: 3, keys.SOUP_OF: [3, 4]}),
        _frozen(6, **{keys.TWIN_OF: 1}),
        _frozen(7, **{keys.SEED_SOUP_OF: 6, keys.SOUP_OF: [6, 4]}),  # a family soup with a prior seed in it
        _frozen(8, **{keys.REFINE_OF: {"trial": 6, "budget": None, "score": 70.0}}),
        _frozen(9, **{keys.RETRY_OF: 2}),
        _frozen(10, **{keys.COPIED_FROM: "old:12"}),
        _frozen(11, **{keys.NEIGHBOUR_OF: 6}),
        _frozen(12, **{keys.SEED_SOUP_OF: 6, keys.SOUP_OF: [6, 11]}),
    ]
    assert prior.from_prior(trials) == {0, 2, 3, 4, 5, 7, 9, 10}
    assert prior.from_prior([t for t in trials if t.number in (1, 6, 8, 11, 12)]) == set()
    assert prior.prior_free(trials) == []  # no draw of the prior-free sampler's yet
    trials[1].set_user_attr(keys.PRIOR_FREE, True)  # 1 was its draw: it and what was made from it, less the mix
    assert [t.number for t in prior.prior_free(trials)] == [1, 6, 8, 11, 12]


def test_the_prior_free_turns_are_the_share_spread_evenly() -> None:
    assert [n for n in range(8) if prior.own_turn(n, 0.5)] == [1, 3, 5, 7]
    assert [n for n in range(8) if prior.own_turn(n, 0.25)] == [3, 7]
    assert all(prior.own_turn(n, 1.0) for n in range(8))


class _Recording(optuna.samplers.RandomSampler):
    """A random sampler that records, per trial it draws, the trial numbers of the history it was shown."""

    def __init__(self, seed: int) -> None:
        super().__init__(seed=seed)
        self.seen: dict[int, list[int]] = {}

    def sample_independent(self, study: Any, trial: Any, param_name: str, param_distribution: Any) -> Any:
        self.seen[trial.number] = [t.number for t in study.get_trials(deepcopy=False)]
        return super().sample_independent(study, trial, param_name, param_distribution)


def _routed_study(with_prior: bool) -> tuple[optuna.Study, _Recording, _Recording, prior.PriorFreeSampler]:
    base, own = _Recording(0), _Recording(1)
    sampler = prior.PriorFreeSampler(base, own, 0.5)
    study = optuna.create_study(direction="maximize", sampler=sampler)
    dist: dict[str, optuna.distributions.BaseDistribution] = {"x": optuna.distributions.FloatDistribution(0.0, 1.0)}
    crowd = {keys.WARM_START: "crowd:a"} if with_prior else {}
    study.add_trial(optuna.trial.create_trial(params={"x": 0.9}, distributions=dist, value=75.0, user_attrs=crowd))
    study.add_trial(optuna.trial.create_trial(params={"x": 0.8}, distributions=dist, value=74.0,
                                              user_attrs={keys.TWIN_OF: 0}))  # fmt: skip
    study.add_trial(optuna.trial.create_trial(params={"x": 0.1}, distributions=dist, value=70.0))
    for _ in range(4):  # trials 3, 4, 5, 6
        trial = study.ask()
        x = trial.suggest_float("x", 0.0, 1.0)
        if sampler.drew(trial.number):  # as the driver records it
            trial.set_user_attr(keys.PRIOR_FREE, True)
        study.tell(trial, x)
    return study, base, own, sampler


def test_the_prior_free_sampler_draws_its_share_from_the_history_without_the_prior() -> None:
    _, base, own, sampler = _routed_study(with_prior=True)
    assert sorted(own.seen) == [3, 5] and sorted(base.seen) == [4, 6]  # the odd numbers: the prior-free turns
    assert own.seen[3] == [] and own.seen[5] == [3]  # its own draws only: no crowd setting, twin, or base draw
    assert base.seen[4] == [0, 1, 2, 3, 4] and base.seen[6] == list(range(7))  # the whole history
    assert [sampler.drew(n) for n in range(7)] == [False] * 3 + [True, False, True, False]
    _, base, own, sampler = _routed_study(with_prior=False)  # a study without a prior: every draw the base's
    assert not own.seen and sorted(base.seen) == [3, 4, 5, 6]
    with pytest.raises(ValueError, match="share must lie in"):
        prior.PriorFreeSampler(base, own, 0.0)


def test_prior_free_share_is_checked_and_builds_the_sampler() -> None:
    assert _spec().study.prior_free_share == 0.0 and "prior_free_share" not in _spec().to_dict()["study"]
    spec = _spec(prior_free_share=0.5)
    assert spec.study.prior_free_share == 0.5 and spec.to_dict()["study"]["prior_free_share"] == 0.5
    for bad, match in ((1.5, r"\[study\] prior_free_share: 1.5 is out of range; use \[0, 1\]"),
                       ("half", r"\[study\] prior_free_share: must be a number in \[0, 1\]")):  # fmt: skip
        with pytest.raises(SpecError, match=match):
            _spec(prior_free_share=bad)
    with pytest.raises(SpecError, match=r"prior_fre_share.*prior_free_share"):  # a misspelt key names the right one
        _spec(prior_fre_share=0.5)
    gated = make_sampler(spec, 0, price=lambda params: 1.0)
    assert isinstance(gated, CostGatedSampler) and isinstance(gated.base, prior.PriorFreeSampler)
    assert not isinstance(make_sampler(_spec(), 0), prior.PriorFreeSampler)


def test_the_best_trial_made_without_the_prior_gets_twins_and_neighbours_too(tmp_path: Path) -> None:
    for share in (0.0, 0.5):
        driver, study, dists = _driver(tmp_path / str(share), seed_soups=[2], linear_neighbours=True,
                                       prior_free_share=share)  # fmt: skip
        hidden = space.encode(driver.spec, HIDDEN)
        crowd = _add(study, dists, hidden, 74.0, [(1200, 74.0)], **{keys.WARM_START: "crowd:a"})
        crowd_twin = _add(study, dists, {**hidden, "n_layers": 0, "method": "adagrad", LR_X_INPUTS: 3.0}, 74.5,
                          [(1200, 74.5)], **{keys.TWIN_OF: crowd})  # fmt: skip
        _add(study, dists, {**hidden, "patches_ahead": 2}, 73.5, [(1200, 73.5)])  # the other sampler's draw
        draw = _add(study, dists, {**hidden, "patches_ahead": 4}, 73.0, [(1200, 73.0)], **{keys.PRIOR_FREE: True})
        driver._enqueue_twins()  # noqa: SLF001
        waiting = study.get_trials(states=(WAITING,))
        twinned = [draw] * 3 if share else []  # the crowd's best has its twin: the search's best, with the share
        assert [t.user_attrs[keys.TWIN_OF] for t in waiting] == twinned
        driver._enqueue_twins()  # noqa: SLF001 - once per parent
        assert len(study.get_trials(states=(WAITING,))) == len(twinned)

        # neighbours: of the best soup, and of the best soup made without the prior
        linear = {**hidden, "n_layers": 0, "method": "adagrad", "lanes_side": 1, "patches_ahead": 4, LR_X_INPUTS: 1.0}
        own = _add(study, dists, linear, 72.5, [(1200, 72.5)], **{keys.NEIGHBOUR_OF: draw})
        seed = _add(study, dists, linear, 72.8, [(1200, 72.8)], **{keys.RACE_OF: own, keys.RACE_SEED: 0})
        _add(study, dists, linear, 73.4, [], **{keys.SEED_SOUP_OF: own, keys.SOUP_OF: [own, seed]})
        mixed = {keys.SEED_SOUP_OF: crowd_twin, keys.SOUP_OF: [crowd_twin, seed]}  # made from the prior too
        _add(study, dists, study.trials[crowd_twin].params, 75.0, [], **mixed)
        driver._enqueue_neighbours()  # noqa: SLF001
        moved = {t.user_attrs[keys.NEIGHBOUR_OF] for t in study.get_trials(states=(WAITING,))
                 if keys.NEIGHBOUR_OF in t.user_attrs}  # fmt: skip
        assert moved == ({crowd_twin, own} if share else {crowd_twin})
        if share:
            mine = [t.system_attrs["fixed_params"] for t in study.get_trials(states=(WAITING,))
                    if t.user_attrs.get(keys.NEIGHBOUR_OF) == own]  # fmt: skip
            assert mine == twins.neighbours(linear, driver.spec.space)


def _halving(pruner: optuna.pruners.BasePruner) -> list[bool]:
    """Whether each prior-free trial (scoring 70–73, then 60 and 69, at the first rung) is pruned, after nine others
    (crowd settings and draws near them, 74–76) reached that rung."""
    study = optuna.create_study(direction="maximize", sampler=optuna.samplers.RandomSampler(seed=0), pruner=pruner)
    for i in range(9):
        trial = study.ask()
        if i < 3:
            trial.set_user_attr(keys.WARM_START, f"crowd:{i}")
        trial.report(74.0 + i / 4, 1)
        trial.should_prune()
        study.tell(trial, 74.0 + i / 4)
    out = []
    for score in (70.0, 71.0, 72.0, 73.0, 60.0, 69.0):
        trial = study.ask()
        trial.set_user_attr(keys.PRIOR_FREE, True)
        trial.report(score, 1)
        out.append(trial.should_prune())
        study.tell(trial, state=optuna.trial.TrialState.PRUNED)
    return out


def test_prior_free_draws_are_halved_among_their_own_kind() -> None:
    sha = optuna.pruners.SuccessiveHalvingPruner(min_resource=1, reduction_factor=3, min_early_stopping_rate=0)
    assert _halving(sha) == [True] * 6  # among the crowd's: never in the top third
    # among their own kind: the first four each the best so far, then 60 and 69 below the top third
    assert _halving(prior.PriorFreePruner(sha)) == [False] * 4 + [True, True]
    spec = _spec(prior_free_share=0.5, pruner="sha")
    made = make_pruner(spec)
    assert isinstance(made, prior.PriorFreePruner) and isinstance(made.base, optuna.pruners.SuccessiveHalvingPruner)
    assert not isinstance(make_pruner(_spec(pruner="sha")), prior.PriorFreePruner)
