"""Seed soups (``[study] seed_soups``, ``seed_soup_runs``): a linear configuration's fresh-seed nets averaged.

Why it is exact for linear nets (and not for others), the grouping and the two choices as pure rules, the spec keys,
and the driver on a journal study: which soup it scores, what the soup records, the fresh seeds it trains for it."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import optuna
import pytest

from autotune.convnet import stack
from autotune.convnet.forward import forward
from autotune.convnet.netjson import dumps_net, loads_net
from autotune.learner.training import train
from autotune.search import ensemble, keys, racing, refine, soup
from autotune.search.racing import Entrant, RaceRun
from autotune.search.spec import SpecError
from tests.conftest import FakePool
from tests.test_search_ladder import TINY, _driver_on_journal, _spec
from tests.test_search_refine import _upload

COMPLETE = optuna.trial.TrialState.COMPLETE
LINEAR = TINY.replace(layers="")


def _linear_text(seed: int) -> str:
    return dumps_net(train(LINEAR.replace(train_iterations=0), seed=seed, quick_eval=False).convnet())


def test_a_soup_of_linear_nets_is_the_mean_of_their_q_values_and_of_hidden_ones_is_not() -> None:
    linear = [loads_net(_linear_text(seed)) for seed in range(3)]
    xs = np.random.default_rng(0).normal(size=(16, linear[0].input_size))
    mean = soup.average_nets(linear)
    for x in xs:
        expected = np.mean([forward(n, x) for n in linear], axis=0)
        np.testing.assert_allclose(forward(mean, x), expected, rtol=0, atol=1e-12)
    hidden = [loads_net(dumps_net(train(TINY.replace(train_iterations=0), seed=s, quick_eval=False).convnet()))
              for s in range(3)]  # fmt: skip
    xh = np.random.default_rng(1).normal(size=hidden[0].input_size)
    gap = np.abs(forward(soup.average_nets(hidden), xh) - np.mean([forward(n, xh) for n in hidden], axis=0))
    assert gap.max() > 1e-6  # a hidden layer: the soup is not the ensemble
    assert ensemble.is_linear(LINEAR.to_mapping()) and not ensemble.is_linear(TINY.to_mapping())
    assert not ensemble.is_linear(None) and not ensemble.is_linear({"layers": "fc:x"})


def _attrs(config: Any = None, **more: Any) -> dict[str, Any]:
    return {keys.CONFIG: (LINEAR if config is None else config).to_mapping(), keys.ARTIFACT_NET_JSON: "id", **more}


def test_seed_nets_are_a_linear_configurations_value_and_its_race_runs() -> None:
    trials = [
        (0, _attrs(), 74.0, True),
        (1, _attrs(**{keys.RACE_OF: 0, keys.RACE_SEED: 0}), 74.5, True),
        (2, _attrs(TINY), 75.0, True),  # hidden layers: none
        (3, _attrs(**{keys.RACE_OF: 0, keys.RACE_SEED: 1}), None, False),  # unfinished
        (4, _attrs(**{keys.REFINE_OF: {"trial": 0, "budget": None, "score": 74.0}}), 74.8, True),
        (5, _attrs(**{keys.RACE_OF: 0, keys.RACE_SEED: 2, keys.RETRY_OF: 3}), 73.0, True),
        (6, {keys.CONFIG: LINEAR.to_mapping(), keys.RACE_OF: 0, keys.RACE_SEED: 3}, 73.5, True),  # no stored net
        (7, _attrs(), 72.0, True),
        (8, _attrs(), 71.0, False),  # pruned: its value is no net
    ]
    assert ensemble.seed_nets(trials) == {0: [(0, 74.0), (1, 74.5)], 7: [(7, 72.0)]}


def test_with_families_linear_configurations_that_see_and_are_scored_alike_are_one_group() -> None:
    """A linear twin (same view, traffic, temporal window and ε_test, another trainer) joins its sibling's group,
    keyed by the first of them; another view, another ε_test or hidden layers do not."""
    adagrad = LINEAR.replace(method="adagrad", learning_rate=0.01, gamma=0.8, batch_size=4)
    trials = [
        (0, _attrs(), 74.0, True),
        (1, _attrs(**{keys.RACE_OF: 0, keys.RACE_SEED: 0}), 74.5, True),
        (2, _attrs(TINY), 75.0, True),
        (3, _attrs(adagrad), 74.2, True),  # a twin of 0: the same inputs and scoring
        (4, _attrs(adagrad.replace(patches_ahead=LINEAR.patches_ahead + 1)), 73.0, True),  # another view
        (5, _attrs(adagrad.replace(epsilon_test_time=0.05)), 73.5, True),  # scored with another ε_test
        (6, _attrs(adagrad, **{keys.RACE_OF: 3, keys.RACE_SEED: 0}), 73.9, True),
    ]
    assert ensemble.seed_nets(trials, families=True) == {
        0: [(0, 74.0), (1, 74.5), (3, 74.2), (6, 73.9)], 4: [(4, 73.0)], 5: [(5, 73.5)]}  # fmt: skip
    assert ensemble.seed_groups(trials)[1] == {0: 0, 3: 0, 4: 4, 5: 5}
    assert ensemble.seed_nets(trials) == {0: [(0, 74.0), (1, 74.5)], 3: [(3, 74.2), (6, 73.9)], 4: [(4, 73.0)],
                                          5: [(5, 73.5)]}  # fmt: skip
    assert ensemble.family_key(TINY.to_mapping()) is None and ensemble.family_key(None) is None
    longer = adagrad.replace(train_iterations=9).to_mapping()
    assert ensemble.family_key(LINEAR.to_mapping()) == ensemble.family_key(longer)


def test_the_next_seed_soup_is_the_best_k_seeds_of_the_best_configuration_near_the_best_net() -> None:
    groups = {0: [(0, 74.0), (1, 74.5), (2, 74.3), (3, 73.0)], 5: [(5, 74.9), (6, 74.8)], 9: [(9, 72.0), (10, 71.9)]}
    assert ensemble.next_seed_soup(groups, {}, (2, 3), 0.5, 75.0, 1.0) == (5, (5, 6))
    tried = {5: [[5, 6]]}
    assert ensemble.next_seed_soup(groups, tried, (2, 3), 0.5, 75.0, 1.0) == (0, (1, 2))  # 5 has no 3 seeds
    tried[0] = [[1, 2]]
    assert ensemble.next_seed_soup(groups, tried, (2, 3), 0.5, 75.0, 1.0) == (0, (0, 1, 2))
    tried[0].append([0, 1, 2])  # 73.0 is over the span below 74.5: no soup of 4, and 9 is over 1 mph below 75
    assert ensemble.next_seed_soup(groups, tried, (2, 3, 4), 0.5, 75.0, 1.0) is None
    assert ensemble.next_seed_soup(groups, tried, (2, 3, 4), 2.0, 75.0, 1.0) == (0, (0, 1, 2, 3))
    assert ensemble.next_seed_soup(groups, tried, (2,), 0.5, 75.0, 5.0) == (9, (9, 10))
    assert ensemble.next_seed_soup(groups, tried, (2,), 0.5, None, 1.0) == (9, (9, 10))


def test_the_greedy_soup_adds_the_best_net_not_yet_tried_to_the_best_set_so_far() -> None:
    nets = [(1, 75.3), (2, 75.2), (3, 75.0), (4, 74.9), (5, 74.0)]
    # no soup yet: the best single net is the set, plus the next best
    assert ensemble.greedy_step(nets, [], [], 74.5) == (1, 2)
    # {1, 2} souped below net 1: net 1 stays the set; its next union is with 3
    assert ensemble.greedy_step(nets, [[1, 2]], [([1, 2], 75.1)], 74.5) == (1, 3)
    # {1, 3} beat it: the next steps add to {1, 3}, best net first ({1, 2, 3}), every net tried once against it
    tried, scored = [[1, 2], [1, 3]], [([1, 2], 75.1), ([1, 3], 75.5)]
    assert ensemble.greedy_step(nets, tried, scored, 74.5) == (1, 2, 3)
    tried.append([1, 2, 3])  # still running: no score, but tried
    assert ensemble.greedy_step(nets, tried, scored, 74.5) == (1, 3, 4)
    tried.append([1, 3, 4])
    assert ensemble.greedy_step(nets, tried, scored, 74.5) is None  # net 5 is below the floor
    assert ensemble.greedy_step(nets, tried, scored, 73.0) == (1, 3, 5)
    # a tie keeps the smaller set; a new seed is tried against the current set
    assert ensemble.greedy_step(nets + [(6, 75.25)], tried, scored + [([1, 2, 3], 75.5)], 74.5) == (1, 3, 6)
    assert ensemble.greedy_step([(5, 74.0)], [], [], 74.5) is None
    # next_seed_soup: the sizes first, then the greedy step (only given the scored soups)
    groups = {1: nets}
    assert ensemble.next_seed_soup(groups, {1: [[1, 2]]}, (2,), 0.5, 75.3, 1.0) is None
    assert ensemble.next_seed_soup(groups, {1: [[1, 2]]}, (2,), 0.5, 75.3, 1.0, {1: [([1, 2], 75.1)]}) == (1, (1, 3))
    assert ensemble.next_seed_soup(groups, {}, (2,), 0.5, 75.3, 1.0, {}) == (1, (1, 2))


def test_the_next_seed_run_is_the_highest_linear_candidate_near_the_best_with_seeds_left() -> None:
    a, b = Entrant(3, 74.9, "a"), Entrant(8, 74.2, "b")
    assert ensemble.next_seed_run([a, b], [], {}, 75.0, 0.5, 2) == RaceRun(3, 0)
    assert ensemble.next_seed_run([a, b], [(3, 0), (3, 1)], {}, 75.0, 0.5, 2) is None  # b is 0.8 below the best
    assert ensemble.next_seed_run([a, b], [(3, 0), (3, 1)], {8: 74.7}, 75.0, 0.5, 2) == RaceRun(8, 0)  # its soup
    assert ensemble.next_seed_run([a, b], [(3, 1)], {3: 74.0, 8: 74.6}, 75.0, 0.5, 4) == RaceRun(8, 0)
    assert ensemble.next_seed_run([a], [(3, 1)], {3: 75.2}, 75.2, 0.5, 4) == RaceRun(3, 0)  # the first free index
    assert ensemble.next_seed_run([a], [(3, 1)], {3: 74.0}, 75.2, 0.5, 4) is None  # its seeds trail the best
    assert ensemble.next_seed_run([b], [], {}, None, 0.5, 1) == RaceRun(8, 0)
    assert ensemble.next_seed_run([a, b], [], {3: 74.6, 8: 74.9}, 75.0, 0.5, 4) == RaceRun(8, 0)  # the higher level
    assert ensemble.next_seed_run([a, b], [], {3: 73.1, 8: 72.9}, 75.0, 2.0, 4) == RaceRun(3, 0)  # a wider reach


def test_seed_soups_and_seed_soup_runs_are_checked() -> None:
    assert _spec().study.seed_soups == () and _spec().study.seed_soup_runs == 0
    assert _spec(seed_soups=[2, 3]).study.seed_soups == (2, 3)  # evaluations only: no refinement needed
    assert _spec(seed_soups=[2], refine_soup_span=1.0).study.refine_soup_span == 1.0
    with pytest.raises(SpecError, match=r"\[study\] seed_soups: sizes must be distinct and in \[2, 64\], got \[1\]"):
        _spec(seed_soups=[1])
    with pytest.raises(SpecError, match=r"\[study\] seed_soups: must be a list of integers, got 'x'"):
        _spec(seed_soups="x")
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_runs: .*seed_soups is empty.*set seed_soups"):
        _spec(refine_share=0.5, seed_soup_runs=4)
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_runs: .*refine_share = 0"):
        _spec(seed_soups=[2], seed_soup_runs=4)
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_runs: -1 is out of range"):
        _spec(refine_share=0.5, seed_soups=[2], seed_soup_runs=-1)
    assert _spec(refine_share=0.5, seed_soups=[2], seed_soup_runs=4).study.seed_soup_runs == 4
    assert not _spec().study.seed_soup_greedy and _spec(seed_soups=[2], seed_soup_greedy=True).study.seed_soup_greedy
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_greedy: .*seed_soups is empty.*set seed_soups"):
        _spec(seed_soup_greedy=True)
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_greedy: must be true or false, got 1"):
        _spec(seed_soups=[2], seed_soup_greedy=1)
    assert not _spec().study.seed_soup_families and "seed_soup_families" not in _spec().to_dict()["study"]
    assert _spec(seed_soups=[2], seed_soup_families=True).to_dict()["study"]["seed_soup_families"] is True
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_families: .*seed_soups is empty.*set seed_soups"):
        _spec(seed_soup_families=True)
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_families: must be true or false, got 'yes'"):
        _spec(seed_soups=[2], seed_soup_families="yes")


def test_the_driver_trains_seeds_of_a_linear_configuration_and_soups_them(tmp_path: Path) -> None:
    """``_launch_refine`` first trains fresh race seeds of a linear configuration within ``refine.PARENT_SPAN`` of the
    study's best net (up to ``seed_soup_runs``); ``_launch_seed_soup`` then scores the soup of its best seeds on any
    slot: a refinement trial of its best net, ``soup_of`` the seeds, ``seed_soup_of`` the configuration. A soup that
    is the best net is refined at the refinement's rate (its config is a fresh training's)."""
    spec = _spec(race_configs=2, race_seeds=1, n_trials=20, timeout_s=3600, refine_share=0.5, refine_runs=3,
                 refine_iterations=3000, seed_soups=[2], seed_soup_runs=2).with_overrides(
                     storage=str(tmp_path / "j.log"), workers=2)  # fmt: skip
    driver, study, storages, dists, params = _driver_on_journal(spec)
    texts = [_linear_text(seed) for seed in range(3)]
    config = LINEAR.replace(train_iterations=1200).to_mapping()
    study.add_trial(optuna.trial.create_trial(
        params=params, distributions=dists, value=74.0, state=COMPLETE,
        user_attrs={keys.CONFIG: config, keys.ARTIFACT_NET_JSON: _upload(storages, study, texts[0]),
                    keys.RUNGS: [{keys.BUDGET: 1200, keys.SCORE: 74.0}]},
    ))  # fmt: skip
    driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001
    assert not driver._launch_seed_soup(1)  # noqa: SLF001 - one net: nothing to soup

    def finish(value: float, text: str) -> Any:
        run = driver._running.pop(0).trial  # noqa: SLF001
        run.set_user_attr(keys.ARTIFACT_NET_JSON, _upload(storages, study, text))
        study.tell(run, value)
        return study.trials[run.number]

    assert driver._launch_refine(0)  # noqa: SLF001 - a fresh seed of the linear configuration, not a refinement
    seed_run = study.trials[-1]
    assert seed_run.user_attrs[keys.RACE_OF] == 0 and seed_run.user_attrs[keys.RACE_SEED] == 0
    assert seed_run.user_attrs[keys.SEED] == racing.race_seed(spec.study.seed, 0)
    assert seed_run.user_attrs[keys.SEED_SOUP_RUN] is True and keys.REFINE_OF not in seed_run.user_attrs
    assert driver._running[0].ensemble and not driver.pool.tasks[-1].init_net  # noqa: SLF001
    assert not driver._launch_refine(1)  # noqa: SLF001 - the refinement's share (one of 2) is busy
    first = finish(73.8, texts[1])
    assert driver._launch_seed_soup(1)  # noqa: SLF001
    made = study.trials[-1]
    assert made.user_attrs[keys.SOUP_OF] == [0, first.number] and made.user_attrs[keys.SEED_SOUP_OF] == 0
    assert made.user_attrs[keys.REFINE_OF] == {"trial": 0, "budget": None, "score": 74.0}
    task = driver.pool.tasks[-1]
    assert task.evaluate_only and task.init_net == dumps_net(soup.average_nets([loads_net(texts[0]),
                                                                                loads_net(texts[1])]))  # fmt: skip
    run = driver._running.pop(1).trial  # noqa: SLF001
    run.set_user_attr(keys.ARTIFACT_NET_JSON, _upload(storages, study, task.init_net))
    study.tell(run, 74.6)
    assert not driver._launch_seed_soup(1)  # noqa: SLF001 - that set had its soup
    assert driver._launch_refine(0)  # noqa: SLF001 - the second seed (seed_soup_runs = 2)
    assert study.trials[-1].user_attrs[keys.RACE_SEED] == 1
    finish(74.2, texts[2])
    assert driver._launch_seed_soup(1)  # noqa: SLF001 - a new best pair: 74.2 and 74.0
    assert study.trials[-1].user_attrs[keys.SOUP_OF] == [0, study.trials[-2].number]
    study.tell(driver._running.pop(1).trial, 74.1)  # noqa: SLF001
    # both seeds trained: the refinement worker refines the best net, the 74.6 soup, at the refinement's rate
    assert driver._launch_refine(0)  # noqa: SLF001
    nxt = study.trials[-1]
    assert nxt.user_attrs[keys.REFINE_OF]["trial"] == made.number and keys.SOUP_OF not in nxt.user_attrs
    assert nxt.user_attrs[keys.CONFIG]["learning_rate"] == pytest.approx(
        LINEAR.learning_rate * spec.study.refine_learning_rate
    )
    assert nxt.user_attrs[keys.SEED] == refine.refine_seed(spec.study.seed, 0)


def test_with_a_swap_floor_the_greedy_soup_goes_on_by_swaps_once_no_addition_is_left() -> None:
    nets = [(1, 75.3), (2, 75.2), (3, 75.0), (4, 74.9), (5, 74.0)]
    tried = [[1, 2], [1, 3], [1, 2, 3], [1, 3, 4]]
    scored = [([1, 2], 75.1), ([1, 3], 75.5), ([1, 2, 3], 75.4), ([1, 3, 4], 75.45)]
    assert ensemble.greedy_step(nets, tried, scored, 74.5) is None  # additions within the floor: all tried
    # the swap floor's nets are added first (net 5), then members swapped, the weakest (3) first, best net first
    assert ensemble.greedy_step(nets, tried, scored, 74.5, swap_floor=73.5) == (1, 3, 5)
    tried.append([1, 3, 5])
    assert ensemble.greedy_step(nets, tried, scored, 74.5, swap_floor=73.5) == (1, 4)  # 3 → 2 is {1, 2}: tried
    tried.append([1, 4])
    assert ensemble.greedy_step(nets, tried, scored, 74.5, swap_floor=73.5) == (1, 5)
    assert ensemble.greedy_step(nets, tried, scored, 74.5, swap_floor=74.5) == (2, 3)  # 1 → 2; net 5 below
    # a swap that scores higher is the set the next steps start from: additions to it first
    scored.append(([1, 4], 75.6))
    assert ensemble.greedy_step(nets, tried, scored, 74.5, swap_floor=73.5) == (1, 2, 4)
    # a set of three: a member left out (the weakest first) before any swap; never below two nets
    tried += [[1, 2, 4], [1, 3, 4, 5]]
    scored += [([1, 2, 4], 75.7)]
    steps = []
    for _ in range(4):
        step = ensemble.greedy_step(nets, tried, scored, 74.5, swap_floor=73.5)
        assert step is not None
        steps.append(step)
        tried.append(list(step))
    assert steps == [(1, 2, 3, 4), (1, 2, 4, 5), (2, 4), (1, 2, 5)]  # {1, 2}, {1, 4} tried; 4 → 3 tried, 4 → 5
    # at most 3 nets: no additions; the next swap is the next member's (2 → 3 tried, 2 → 5)
    assert ensemble.greedy_step(nets, tried, scored, 74.5, most=3, swap_floor=73.5) == (1, 4, 5)
    # next_seed_soup swaps only unbounded configurations (a stack's neighbours take tens of seconds each)
    groups = {1: nets}
    full = [[1, 2], [1, 3], [1, 2, 3], [1, 3, 4]]
    done = [([1, 2], 75.1), ([1, 3], 75.5), ([1, 2, 3], 75.4), ([1, 3, 4], 75.45)]
    assert ensemble.next_seed_soup(groups, {1: full}, (2,), 0.5, 75.3, 1.0, {1: done}) is None
    assert ensemble.next_seed_soup(groups, {1: full}, (2,), 0.5, 75.3, 1.0, {1: done}, swap_span=1.5) == (1, (1, 3, 5))
    assert ensemble.next_seed_soup(groups, {1: full}, (2,), 0.5, 75.3, 1.0, {1: done}, {1: 4}, swap_span=1.5) is None


def test_a_stacks_members_come_from_within_the_stack_span_of_its_best_net() -> None:
    """A configuration with hidden layers (given a cap, ``most``) takes seeds down to ``STACK_SPAN`` below its best
    into its stacks; a linear one only within ``span``."""
    nets = [(1, 75.0), (2, 74.9), (3, 74.2), (4, 73.9), (5, 73.5)]
    assert ensemble.next_seed_soup({1: nets}, {1: [[1, 2]]}, (2, 4), 0.5, 75.0, 1.0) is None
    assert ensemble.next_seed_soup({1: nets}, {1: [[1, 2]]}, (2, 4), 0.5, 75.0, 1.0, most={1: 8}) == (1, (1, 2, 3, 4))
    assert ensemble.next_seed_soup({1: nets}, {1: [[1, 2]]}, (2, 4), 0.5, 75.0, 1.0, most={1: 3}) is None
    done = {1: [([1, 2], 75.2)]}
    assert ensemble.next_seed_soup({1: nets}, {1: [[1, 2]]}, (2,), 0.5, 75.0, 1.0, done, {1: 8}) == (1, (1, 2, 3))
    assert ensemble.STACK_SPAN > 0.5 and 75.0 - ensemble.STACK_SPAN > 73.5  # net 5 is out of every stack


def test_seed_soup_swap_span_is_checked() -> None:
    assert _spec().study.seed_soup_swap_span == 0.0 and "seed_soup_swap_span" not in _spec().to_dict()["study"]
    on = _spec(seed_soups=[2], seed_soup_greedy=True, seed_soup_swap_span=1.25)
    assert on.study.seed_soup_swap_span == 1.25 and on.to_dict()["study"]["seed_soup_swap_span"] == 1.25
    with pytest.raises(SpecError, match=r"seed_soup_swap_span: .*seed_soup_greedy is off.*seed_soup_greedy = "):
        _spec(seed_soups=[2], seed_soup_swap_span=1.0)
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_swap_span: -1.0 is out of range"):
        _spec(seed_soups=[2], seed_soup_greedy=True, seed_soup_swap_span=-1.0)


def test_the_driver_grows_a_greedy_seed_soup_from_the_best_set_so_far(tmp_path: Path) -> None:
    """With ``seed_soup_greedy`` the driver scores, after the best-k soups, the best set so far plus the next net:
    while the soup of the best 2 is scored, a free worker tries the best net with the third; the best 2 beat the best
    net, so the third is then tried with both."""
    spec = _spec(n_trials=20, timeout_s=3600, seed_soups=[2], seed_soup_greedy=True).with_overrides(
        storage=str(tmp_path / "j.log"), workers=2)  # fmt: skip
    driver, study, storages, dists, params = _driver_on_journal(spec)
    config = LINEAR.replace(train_iterations=1200).to_mapping()
    for seed, value in enumerate((74.0, 73.9, 73.8)):
        extra = {keys.RACE_OF: 0, keys.RACE_SEED: seed - 1} if seed else {}
        study.add_trial(optuna.trial.create_trial(
            params=params, distributions=dists, value=value, state=COMPLETE,
            user_attrs={keys.CONFIG: config, keys.ARTIFACT_NET_JSON: _upload(storages, study, _linear_text(seed)),
                        **extra},
        ))  # fmt: skip
    driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001
    assert driver._launch_seed_soup(0)  # noqa: SLF001 - the best 2
    assert study.trials[-1].user_attrs[keys.SOUP_OF] == [0, 1]
    assert driver._launch_seed_soup(1)  # noqa: SLF001 - meanwhile the next step from the best net so far
    assert study.trials[-1].user_attrs[keys.SOUP_OF] == [0, 2]
    study.tell(driver._running.pop(0).trial, 74.3)  # noqa: SLF001
    study.tell(driver._running.pop(1).trial, 73.9)  # noqa: SLF001
    assert driver._launch_seed_soup(1)  # noqa: SLF001 - {0, 1} beat net 0: the greedy soup adds net 2 to it
    made = study.trials[-1]
    assert made.user_attrs[keys.SOUP_OF] == [0, 1, 2] and made.user_attrs[keys.SEED_SOUP_OF] == 0
    study.tell(driver._running.pop(1).trial, 74.1)  # noqa: SLF001
    assert not driver._launch_seed_soup(0)  # noqa: SLF001 - every net was tried with the best set {0, 1}


def test_with_seed_soup_swap_span_the_driver_swaps_the_best_sets_members(tmp_path: Path) -> None:
    """Once every net was added to the best set {0, 1}, the driver goes on with ``seed_soup_swap_span``: its weakest
    member (1) swapped for net 2 was tried ({0, 2}), so net 0 swapped for net 2, {1, 2}."""
    spec = _spec(n_trials=20, timeout_s=3600, seed_soups=[2], seed_soup_greedy=True,
                 seed_soup_swap_span=1.0).with_overrides(storage=str(tmp_path / "j.log"), workers=2)  # fmt: skip
    driver, study, storages, dists, params = _driver_on_journal(spec)
    config = LINEAR.replace(train_iterations=1200).to_mapping()
    for seed, value in enumerate((74.0, 73.9, 73.8)):
        extra = {keys.RACE_OF: 0, keys.RACE_SEED: seed - 1} if seed else {}
        study.add_trial(optuna.trial.create_trial(
            params=params, distributions=dists, value=value, state=COMPLETE,
            user_attrs={keys.CONFIG: config, keys.ARTIFACT_NET_JSON: _upload(storages, study, _linear_text(seed)),
                        **extra},
        ))  # fmt: skip
    driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001
    for slot, value in ((0, 74.3), (1, 73.9), (0, 74.1)):  # {0, 1}, {0, 2}, {0, 1, 2}
        assert driver._launch_seed_soup(slot)  # noqa: SLF001
        study.tell(driver._running.pop(slot).trial, value)  # noqa: SLF001
    assert driver._launch_seed_soup(0)  # noqa: SLF001
    made = study.trials[-1]
    assert made.user_attrs[keys.SOUP_OF] == [1, 2] and made.user_attrs[keys.SEED_SOUP_OF] == 0


def test_the_driver_soups_a_family_of_linear_twins_and_seeds_its_members_by_the_family_soup(tmp_path: Path) -> None:
    """With ``seed_soup_families`` two linear configurations that differ only in their trainer are souped together
    (``seed_soup_of`` the first); the family soup's score is each member's level for its seeds. Without, neither
    configuration has two nets: nothing to soup."""
    for families in (False, True):
        spec = _spec(n_trials=20, timeout_s=3600, seed_soups=[2], seed_soup_families=families, refine_share=0.5,
                     seed_soup_runs=2, seed_soup_reach=1.0).with_overrides(
                         storage=str(tmp_path / f"{families}.log"), workers=2)  # fmt: skip
        driver, study, storages, dists, params = _driver_on_journal(spec)
        configs = [LINEAR.replace(train_iterations=1200), LINEAR.replace(train_iterations=1200, method="adagrad",
                                                                          learning_rate=0.01)]  # fmt: skip
        for seed, (config, value) in enumerate(zip(configs, (73.8, 74.0), strict=True)):
            study.add_trial(optuna.trial.create_trial(
                params=params, distributions=dists, value=value, state=COMPLETE,
                user_attrs={keys.CONFIG: config.to_mapping(), keys.RUNGS: [{keys.BUDGET: 1200, keys.SCORE: value}],
                            keys.ARTIFACT_NET_JSON: _upload(storages, study, _linear_text(seed))},
            ))  # fmt: skip
        driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001
        if not families:
            assert not driver._launch_seed_soup(0)  # noqa: SLF001
            continue
        assert driver._launch_seed_soup(0)  # noqa: SLF001
        made = study.trials[-1]
        assert made.user_attrs[keys.SOUP_OF] == [0, 1] and made.user_attrs[keys.SEED_SOUP_OF] == 0
        assert made.user_attrs[keys.CONFIG] == configs[1].to_mapping()  # scored as its best ingredient
        study.tell(driver._running.pop(0).trial, 75.0)  # noqa: SLF001
        # the family soup (75.0) is the level of both: 0's own best (73.8) lies 1.2 below it, out of reach alone
        for expected in (1, 1, 0, 0):
            assert driver._launch_seed_run(1, 1.0)  # noqa: SLF001
            assert study.trials[-1].user_attrs[keys.RACE_OF] == expected
            run = driver._running.pop(1).trial  # noqa: SLF001
            study.tell(run, 60.0)
        assert not driver._launch_seed_run(1, 1.0)  # noqa: SLF001 - both had their seed_soup_runs


def test_a_soup_scored_before_an_earlier_twin_joined_its_family_counts_for_the_family(tmp_path: Path) -> None:
    """A family is keyed by its first configuration; one whose first net comes late (its only net a later seed)
    takes over the key, and the soups its siblings scored before stay tried: none is scored twice."""
    spec = _spec(n_trials=20, timeout_s=3600, seed_soups=[2], seed_soup_families=True).with_overrides(
        storage=str(tmp_path / "j.log"), workers=2)  # fmt: skip
    driver, study, storages, dists, params = _driver_on_journal(spec)
    sgd = LINEAR.replace(train_iterations=1200).to_mapping()
    adagrad = LINEAR.replace(train_iterations=1200, method="adagrad", learning_rate=0.01).to_mapping()
    study.add_trial(optuna.trial.create_trial(params=params, distributions=dists, state=optuna.trial.TrialState.PRUNED,
                                              user_attrs={keys.CONFIG: sgd}))  # fmt: skip
    for seed, (value, extra) in enumerate(((74.0, {}), (73.9, {keys.RACE_OF: 1, keys.RACE_SEED: 0}))):
        study.add_trial(optuna.trial.create_trial(
            params=params, distributions=dists, value=value, state=COMPLETE,
            user_attrs={keys.CONFIG: adagrad, keys.ARTIFACT_NET_JSON: _upload(storages, study, _linear_text(seed)),
                        **extra},
        ))  # fmt: skip
    driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001
    assert driver._launch_seed_soup(0)  # noqa: SLF001
    assert study.trials[-1].user_attrs[keys.SEED_SOUP_OF] == 1 and study.trials[-1].user_attrs[keys.SOUP_OF] == [1, 2]
    study.tell(driver._running.pop(0).trial, 74.3)  # noqa: SLF001
    study.add_trial(optuna.trial.create_trial(  # trial 0's first net: the family's key is now 0
        params=params, distributions=dists, value=73.0, state=COMPLETE,
        user_attrs={keys.CONFIG: sgd, keys.ARTIFACT_NET_JSON: _upload(storages, study, _linear_text(5)),
                    keys.RACE_OF: 0, keys.RACE_SEED: 0},
    ))  # fmt: skip
    assert ensemble.seed_groups((t.number, t.user_attrs, t.value, t.state == COMPLETE) for t in study.trials)[1] == {
        0: 0, 1: 0}  # fmt: skip
    assert not driver._launch_seed_soup(0)  # noqa: SLF001 - {1, 2} had its soup (under 1); 73.0 is out of the span


def test_seed_soup_reach_is_checked() -> None:
    assert _spec().study.seed_soup_reach == 0.5
    assert _spec(refine_share=0.5, seed_soups=[2], seed_soup_runs=4, seed_soup_reach=2.0).study.seed_soup_reach == 2.0
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_reach: must be 0.5 mph or more, got 0.2"):
        _spec(refine_share=0.5, seed_soups=[2], seed_soup_runs=4, seed_soup_reach=0.2)
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_reach: .*seed_soup_runs = 0; set seed_soup_runs"):
        _spec(seed_soups=[2], seed_soup_reach=2.0)


def test_a_wider_seed_soup_reach_shares_the_refinement_worker(tmp_path: Path) -> None:
    """A linear configuration 1.5 mph below the best net: outside the seed runs' own reach (0.5), it gets no seed; with
    ``seed_soup_reach = 2.0`` it first gets its ``PROBE_SEEDS`` seeds, then every other run of the refinement's worker
    (refinement of the best net the others), and all of them once the best net had its refinement runs."""
    for reach in (0.5, 2.0):
        spec = _spec(race_configs=2, race_seeds=1, n_trials=40, timeout_s=3600, refine_share=0.5, refine_runs=6,
                     refine_iterations=3000, seed_soups=[2], seed_soup_runs=8, seed_soup_reach=reach).with_overrides(
                         storage=str(tmp_path / f"{reach}.log"), workers=2)  # fmt: skip
        driver, study, storages, dists, params = _driver_on_journal(spec)
        hidden = TINY.replace(train_iterations=1200)
        study.add_trial(optuna.trial.create_trial(
            params=params, distributions=dists, value=75.0, state=COMPLETE,
            user_attrs={keys.CONFIG: hidden.to_mapping(), keys.ARTIFACT_NET_JSON: _upload(storages, study, dumps_net(
                train(hidden.replace(train_iterations=0), seed=0, quick_eval=False).convnet()))},
        ))  # fmt: skip
        study.add_trial(optuna.trial.create_trial(
            params=params, distributions=dists, value=73.5, state=COMPLETE,
            user_attrs={keys.CONFIG: LINEAR.replace(train_iterations=1200).to_mapping(),
                        keys.ARTIFACT_NET_JSON: _upload(storages, study, _linear_text(0))},
        ))  # fmt: skip
        driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001
        kinds = ""
        while driver._launch_refine(0):  # noqa: SLF001
            run = driver._running.pop(0).trial  # noqa: SLF001
            attrs = study.trials[run.number].user_attrs
            kinds += "S" if attrs.get(keys.SEED_SOUP_RUN) else "R" if keys.REFINE_OF in attrs else "?"
            assert kinds[-1] != "S" or attrs[keys.RACE_OF] == 1
            study.tell(run, 70.0)
        # 0.5: the best net's 6 runs, then nothing near enough (back to the search); 2.0: 4 probe seeds, then
        # refinement until it has as many runs, then every other run, then the seeds alone (8 in all)
        assert kinds == ("RRRRRR" if reach == 0.5 else "SSSSRRRRSRSRSS")


def test_probe_seeds_rank_a_configuration_by_its_own_nets_not_its_familys_soup(tmp_path: Path) -> None:
    """Probe seeds go to a configuration by its own nets: one whose net is 74.9 but whose family has no soup comes
    before a member (73.8 alone) of the family whose soup is the best net (75.6); the seeds near the best
    (``SEED_RUN_REACH``, not probes) still rank by the family's soup."""
    spec = _spec(n_trials=40, timeout_s=3600, refine_share=0.5, seed_soups=[2], seed_soup_runs=8,
                 seed_soup_reach=2.0, seed_soup_families=True).with_overrides(
                     storage=str(tmp_path / "j.log"), workers=2)  # fmt: skip
    driver, study, storages, dists, params = _driver_on_journal(spec)
    net = _upload(storages, study, _linear_text(0))
    head, member, apart = (LINEAR.to_mapping(), LINEAR.replace(gamma=0.8).to_mapping(),
                           LINEAR.replace(temporal_window=2).to_mapping())  # fmt: skip
    assert ensemble.family_key(member) == ensemble.family_key(head) != ensemble.family_key(apart)
    _add_seed_rows(study, params, dists, net, [head, member, apart], [
        (75.0, 0, {}),
        *((74.9, 0, {keys.RACE_OF: 0, keys.RACE_SEED: i}) for i in range(ensemble.PROBE_SEEDS)),
        (75.6, 0, {keys.SOUP_OF: [0, 1], keys.SEED_SOUP_OF: 0, keys.REFINE_OF: refine.Parent(0, None, 75.0).to_attr()}),
        (73.8, 1, {}),
        (74.9, 2, {}),
    ])  # fmt: skip
    member_n, apart_n = len(study.trials) - 2, len(study.trials) - 1
    driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001
    assert driver._launch_seed_run(1, 2.0, ensemble.PROBE_SEEDS, own=True)  # noqa: SLF001
    assert study.trials[driver._running.pop(1).trial.number].user_attrs[keys.RACE_OF] == apart_n  # noqa: SLF001
    assert driver._launch_seed_run(1, 2.0, ensemble.PROBE_SEEDS)  # noqa: SLF001 - by the family's soup
    assert study.trials[driver._running.pop(1).trial.number].user_attrs[keys.RACE_OF] == member_n  # noqa: SLF001


def test_with_seed_ensembles_configurations_with_hidden_layers_have_seed_nets_of_their_own() -> None:
    """``hidden`` (``[study] seed_ensembles``): a configuration with hidden layers groups its seeds too — never with
    a linear family, whose soups are means of weights — and a cap on a stack's members bounds its soups."""
    trials = [
        (0, _attrs(), 74.0, True),
        (1, _attrs(TINY), 75.0, True),
        (2, _attrs(TINY, **{keys.RACE_OF: 1, keys.RACE_SEED: 0}), 74.6, True),
        (3, _attrs(LINEAR.replace(method="adagrad")), 73.0, True),
        (4, {keys.RACE_OF: 1, keys.ARTIFACT_NET_JSON: "id"}, 74.0, True),  # no config: not a seed net
    ]
    assert ensemble.seed_nets(trials) == {0: [(0, 74.0)], 3: [(3, 73.0)]}
    assert ensemble.seed_nets(trials, hidden=True) == {0: [(0, 74.0)], 1: [(1, 75.0), (2, 74.6)], 3: [(3, 73.0)]}
    groups, family = ensemble.seed_groups(trials, families=True, hidden=True)
    assert groups == {0: [(0, 74.0), (3, 73.0)], 1: [(1, 75.0), (2, 74.6)]} and family == {0: 0, 1: 1, 3: 0}
    nets = {1: [(1, 75.0), (2, 74.9), (5, 74.8), (6, 74.7)]}
    assert ensemble.next_seed_soup(nets, {}, (2, 3), 0.5, 75.0, 1.0, most={1: 2}) == (1, (1, 2))
    assert ensemble.next_seed_soup(nets, {1: [[1, 2]]}, (2, 3), 0.5, 75.0, 1.0, most={1: 2}) is None
    scored = {1: [([1, 2], 75.2)]}
    assert ensemble.next_seed_soup(nets, {1: [[1, 2]]}, (2,), 0.5, 75.0, 1.0, scored, most={1: 3}) == (1, (1, 2, 5))
    assert ensemble.next_seed_soup(nets, {1: [[1, 2]]}, (2,), 0.5, 75.0, 1.0, scored, most={1: 2}) is None
    # seeds: a configuration capped by ``most`` stops there, the others go on to max_runs
    a, b = Entrant(1, 75.0, "a"), Entrant(0, 74.9, "b")
    assert ensemble.next_seed_run([a, b], [(1, 0), (1, 1)], {}, 75.0, 0.5, 4, {1: 2}) == RaceRun(0, 0)
    assert ensemble.next_seed_run([a], [(1, 0)], {}, 75.0, 0.5, 4, {1: 2}) == RaceRun(1, 1)
    # a capped configuration near the best fresh training is near enough when soups lifted the best net past it
    c = Entrant(2, 74.7, "c")
    assert ensemble.next_seed_run([c], [], {}, 75.6, 0.5, 4, {2: 2}) is None
    assert ensemble.next_seed_run([c], [], {}, 75.6, 0.5, 4, {2: 2}, 74.8) == RaceRun(2, 0)
    assert ensemble.next_seed_run([c], [], {}, 75.6, 0.5, 4, {2: 2}, 75.3) is None  # its net trails that one
    assert ensemble.next_seed_run([c], [], {}, 75.6, 0.5, 4, {}, 74.8) is None  # a linear one: by its soups alone


def test_seed_ensembles_is_checked() -> None:
    assert not _spec().study.seed_ensembles and "seed_ensembles" not in _spec().to_dict()["study"]
    assert _spec(seed_soups=[2], seed_ensembles=True).to_dict()["study"]["seed_ensembles"] is True
    with pytest.raises(SpecError, match=r"\[study\] seed_ensembles: .*seed_soups is empty.*set seed_soups"):
        _spec(seed_ensembles=True)
    with pytest.raises(SpecError, match=r"\[study\] seed_ensembles: must be true or false, got 1"):
        _spec(seed_soups=[2], seed_ensembles=1)


def test_the_driver_seeds_a_configuration_with_hidden_layers_and_stacks_its_seeds(tmp_path: Path) -> None:
    """With ``seed_ensembles`` the best configuration, with a hidden layer, gets fresh seeds on the refinement's worker
    (at most ``STACK_SEED_RUNS``) and its seed soups are stacks: the init net is the members side by side, the
    config records every hidden width × k (so the stack refines as stored), and a stack over ``MAX_STACK_NEURONS``
    units is never made. Without the key the configuration gets neither."""
    for on in (False, True):
        spec = _spec(n_trials=40, timeout_s=3600, refine_share=0.5, refine_runs=3, refine_iterations=3000,
                     seed_soups=[2, 3], seed_soup_greedy=True, seed_soup_runs=20,
                     seed_ensembles=on).with_overrides(storage=str(tmp_path / f"{on}.log"), workers=2)  # fmt: skip
        driver, study, storages, dists, params = _driver_on_journal(spec)
        hidden = TINY.replace(train_iterations=1200)
        texts = [dumps_net(train(hidden.replace(train_iterations=0), seed=s, quick_eval=False).convnet())
                 for s in range(3)]  # fmt: skip
        study.add_trial(optuna.trial.create_trial(
            params=params, distributions=dists, value=75.0, state=COMPLETE,
            user_attrs={keys.CONFIG: hidden.to_mapping(), keys.ARTIFACT_NET_JSON: _upload(storages, study, texts[0]),
                        keys.RUNGS: [{keys.BUDGET: 1200, keys.SCORE: 75.0}]},
        ))  # fmt: skip
        driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001
        assert driver._launch_refine(0)  # noqa: SLF001
        first = study.trials[-1]
        if not on:
            assert keys.REFINE_OF in first.user_attrs and keys.RACE_OF not in first.user_attrs  # a refinement run
            continue
        assert first.user_attrs[keys.RACE_OF] == 0 and first.user_attrs[keys.SEED_SOUP_RUN] is True
        run = driver._running.pop(0).trial  # noqa: SLF001
        run.set_user_attr(keys.ARTIFACT_NET_JSON, _upload(storages, study, texts[1]))
        study.tell(run, 74.8)
        assert driver._launch_seed_soup(1)  # noqa: SLF001
        made = study.trials[-1]
        assert made.user_attrs[keys.SOUP_OF] == [0, run.number] and made.user_attrs[keys.SEED_SOUP_OF] == 0
        assert made.user_attrs[keys.CONFIG]["layers"] == "fc:8:relu"  # 2 × fc:4:relu
        stacked = stack.stack_nets([loads_net(texts[0]), loads_net(texts[1])])
        assert driver.pool.tasks[-1].evaluate_only and driver.pool.tasks[-1].init_net == dumps_net(stacked)
        soup_run = driver._running.pop(1).trial  # noqa: SLF001
        soup_run.set_user_attr(keys.ARTIFACT_NET_JSON, _upload(storages, study, dumps_net(stacked)))
        study.tell(soup_run, 75.2)
        seeds = 1
        while driver._launch_refine(0):  # noqa: SLF001 - the rest of its seeds, then refinement of the best net
            run = driver._running.pop(0).trial  # noqa: SLF001
            if keys.RACE_OF not in study.trials[run.number].user_attrs:
                break
            seeds += 1
            run.set_user_attr(keys.ARTIFACT_NET_JSON, _upload(storages, study, texts[2]))
            study.tell(run, 60.0)
        assert seeds == ensemble.STACK_SEED_RUNS
        assert study.trials[run.number].user_attrs[keys.REFINE_OF]["trial"] == made.number  # the stack refines
        assert study.trials[run.number].user_attrs[keys.CONFIG]["layers"] == "fc:8:relu"


def test_a_stacked_seed_soup_trial_scores_the_stack_with_its_widened_config() -> None:
    """The trial the driver makes of a stack (``evaluate_only``, its config every hidden width × k) scores exactly
    the stack's official score and stores the stack; its config builds the stack's layers."""
    from autotune.learner.config import TrainConfig
    from autotune.learner.official import evaluate_official
    from autotune.search.objective import COMPLETE as DONE
    from autotune.search.objective import TrialTask, run_trial

    nets = [loads_net(dumps_net(train(TINY.replace(train_iterations=0), seed=s, quick_eval=False).convnet()))
            for s in range(3)]  # fmt: skip
    stacked = stack.stack_nets(nets)
    config = TrainConfig.from_mapping({**TINY.to_mapping(), "layers": "fc:12:relu"})
    task = TrialTask(number=5, config=config.to_mapping(), seed=1, init_net=dumps_net(stacked), evaluate_only=True,
                     final_protocol="v2-official")  # fmt: skip
    out = run_trial(task, lambda step, frames, score: False)
    assert out.state == DONE and out.net_json == dumps_net(stacked)
    assert out.value == float(evaluate_official(stacked, config, protocol="v2-official").median_site)
    assert out.attrs[keys.PARAM_COUNT] == sum(w.size + b.size for w, b in stacked.params)


def test_a_configuration_with_hidden_layers_gets_seeds_only_near_the_best(tmp_path: Path) -> None:
    """With ``seed_ensembles`` and a wide ``seed_soup_reach``, a configuration with hidden layers 1 mph below the best
    net gets no probe seed (a seed of one trains for longer); the best one gets its ``STACK_SEED_RUNS`` seeds."""
    spec = _spec(n_trials=40, timeout_s=3600, refine_share=0.5, seed_soups=[2], seed_soup_runs=20,
                 seed_soup_reach=2.0, seed_ensembles=True).with_overrides(
                     storage=str(tmp_path / "j.log"), workers=2)  # fmt: skip
    driver, study, storages, dists, params = _driver_on_journal(spec)
    hidden = TINY.replace(train_iterations=1200)
    text = dumps_net(train(hidden.replace(train_iterations=0), seed=0, quick_eval=False).convnet())
    for value, layers in ((75.0, "fc:4:relu"), (74.0, "fc:3:relu")):
        study.add_trial(optuna.trial.create_trial(
            params=params, distributions=dists, value=value, state=COMPLETE,
            user_attrs={keys.CONFIG: hidden.replace(layers=layers).to_mapping(),
                        keys.ARTIFACT_NET_JSON: _upload(storages, study, text)},
        ))  # fmt: skip
    driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001
    assert not driver._launch_seed_run(1, 2.0, ensemble.PROBE_SEEDS)  # noqa: SLF001
    owners = []
    while driver._launch_seed_run(1, 0.5):  # noqa: SLF001
        run = driver._running.pop(1).trial  # noqa: SLF001
        owners.append(study.trials[run.number].user_attrs[keys.RACE_OF])
        study.tell(run, 60.0)
    assert owners == [0] * ensemble.STACK_SEED_RUNS


def test_a_configuration_with_hidden_layers_near_the_best_training_gets_seeds_when_soups_lead(tmp_path: Path) -> None:
    """A linear configuration's soup 0.85 mph above a configuration with hidden layers does not keep that one from
    its seeds: its net is within ``SEED_RUN_REACH`` of the best fresh training (74.8), member against member. A
    third, 0.8 below that training, gets none. The linear one takes its seeds first (its soup is the higher)."""
    spec = _spec(n_trials=40, timeout_s=3600, refine_share=0.5, seed_soups=[2], seed_soup_runs=3,
                 seed_ensembles=True).with_overrides(storage=str(tmp_path / "j.log"), workers=2)  # fmt: skip
    driver, study, storages, dists, params = _driver_on_journal(spec)
    hidden = TINY.replace(train_iterations=1200)
    linear = _upload(storages, study, _linear_text(0))
    text = _upload(storages, study, dumps_net(train(hidden.replace(train_iterations=0), seed=0,
                                                    quick_eval=False).convnet()))  # fmt: skip
    rows: list[tuple[float, dict[str, Any]]] = [
        (74.8, {keys.CONFIG: LINEAR.to_mapping(), keys.ARTIFACT_NET_JSON: linear}),
        (75.65, {keys.CONFIG: LINEAR.to_mapping(), keys.ARTIFACT_NET_JSON: linear, keys.SOUP_OF: [0, 0],
                 keys.SEED_SOUP_OF: 0, keys.REFINE_OF: refine.Parent(0, None, 74.8).to_attr()}),
        (74.7, {keys.CONFIG: hidden.replace(layers="fc:4:relu").to_mapping(), keys.ARTIFACT_NET_JSON: text}),
        (74.0, {keys.CONFIG: hidden.replace(layers="fc:3:relu").to_mapping(), keys.ARTIFACT_NET_JSON: text}),
    ]  # fmt: skip
    for value, attrs in rows:
        study.add_trial(optuna.trial.create_trial(params=params, distributions=dists, value=value, state=COMPLETE,
                                                  user_attrs=attrs))  # fmt: skip
    driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001
    owners = []
    while driver._launch_seed_run(1, 0.5):  # noqa: SLF001
        run = driver._running.pop(1).trial  # noqa: SLF001
        owners.append(study.trials[run.number].user_attrs[keys.RACE_OF])
        study.tell(run, 60.0)
    assert owners == [0] * 3 + [2] * 3  # seed_soup_runs caps both


def test_a_configuration_whose_nets_cannot_stack_gets_no_seeds_and_no_stack(tmp_path: Path) -> None:
    """A maxout layer of 3 units in groups of 2 (a stack would split a group across members: the refusal failed a
    crowd-prior hour's soup trial) or an LRN layer: ``stackable`` says no, so the configuration gets no seed runs and
    its nets no stack, where an even maxout layer gets both."""
    from autotune.learner.config import parse_layers

    assert stack.stackable(parse_layers("fc:4:maxout|fc:3:tanh")) and stack.stackable(())
    assert not stack.stackable(parse_layers("fc:3:maxout")) and not stack.stackable(parse_layers("fc:4:relu|lrn"))
    for layers, stacks in (("fc:3:maxout", False), ("fc:4:maxout", True)):
        spec = _spec(n_trials=40, timeout_s=3600, refine_share=0.5, seed_soups=[2], seed_soup_runs=3,
                     seed_ensembles=True).with_overrides(storage=str(tmp_path / f"{layers[3]}.log"),
                                                         workers=2)  # fmt: skip
        driver, study, storages, dists, params = _driver_on_journal(spec)
        config = TINY.replace(train_iterations=1200, layers=layers)
        text = _upload(storages, study, dumps_net(train(config.replace(train_iterations=0), seed=0,
                                                        quick_eval=False).convnet()))  # fmt: skip
        study.add_trial(optuna.trial.create_trial(params=params, distributions=dists, value=75.0, state=COMPLETE,
                        user_attrs={keys.CONFIG: config.to_mapping(), keys.ARTIFACT_NET_JSON: text}))  # fmt: skip
        driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001
        assert driver._launch_seed_run(1, 0.5) is stacks  # noqa: SLF001
        study.add_trial(optuna.trial.create_trial(params=params, distributions=dists, value=74.9, state=COMPLETE,
                        user_attrs={keys.CONFIG: config.to_mapping(), keys.ARTIFACT_NET_JSON: text,
                                    keys.RACE_OF: 0, keys.RACE_SEED: 1}))  # fmt: skip
        assert driver._launch_seed_soup(0) is stacks  # noqa: SLF001


def _add_seed_rows(
    study: Any, params: Any, dists: Any, net: str, configs: list[Any], rows: list[tuple[float, int, dict[str, Any]]]
) -> None:
    """Each row (value, configuration index, user attrs) as a COMPLETE trial of that configuration with ``net``."""
    for value, which, attrs in rows:
        attrs = {keys.CONFIG: configs[which], keys.ARTIFACT_NET_JSON: net, **attrs}
        study.add_trial(optuna.trial.create_trial(params=params, distributions=dists, value=value, state=COMPLETE,
                                                  user_attrs=attrs))  # fmt: skip


def _refine_runs(driver: Any, study: Any, n: int, value: Any) -> list[tuple[int, int, bool]]:
    """(race_of, race seed, a seed turn?) of the next ``n`` runs of the refinement's worker, each told
    ``value(its user attrs, its index)``."""
    driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001
    runs = []
    for i in range(n):
        assert driver._launch_refine(0)  # noqa: SLF001
        run = driver._running.pop(0).trial  # noqa: SLF001
        attrs = study.trials[run.number].user_attrs
        runs.append((attrs[keys.RACE_OF], attrs[keys.RACE_SEED], bool(attrs.get(keys.SEED_LEADER_RUN))))
        study.tell(run, value(attrs, i))
    return runs


def test_the_leader_by_seed_mean_takes_every_other_run_of_the_refinement(tmp_path: Path) -> None:
    """With ``seed_soup_leader`` the configuration with the best mean over its fresh seeds (3 or more) takes turns
    with the rest of the refinement's runs: here with the probe seeds of two new linear configurations, which alone
    take every run first (a crowd-prior hour's stream of neighbours held the worker so until the race). The leader
    is chosen by mean, not level (trial 0's own net is the best, yet trial 1 leads once 0's mean falls), and a probed
    configuration whose seeds average higher leads in turn, its probes counted among its seeds."""
    got = {}
    for on in (False, True):
        spec = _spec(n_trials=80, timeout_s=3600, refine_share=0.5, seed_soups=[2], seed_soup_runs=8,
                     seed_soup_reach=2.0, seed_soup_leader=on).with_overrides(
                         storage=str(tmp_path / f"{on}.log"), workers=2)  # fmt: skip
        driver, study, storages, dists, params = _driver_on_journal(spec)
        net = _upload(storages, study, _linear_text(0))
        configs = [LINEAR.replace(train_iterations=1200, patches_ahead=2 + i).to_mapping() for i in range(4)]
        rows: list[tuple[float, int, dict[str, Any]]] = [
            (value, i, {}) for i, value in enumerate((75.0, 74.9, 74.5, 74.4))
        ]
        for owner, scores in ((0, (74.0, 74.2, 74.4, 74.2)), (1, (73.8,) * 4)):  # means 74.2 and 73.8
            rows += [(score, owner, {keys.RACE_OF: owner, keys.RACE_SEED: i, keys.SEED_SOUP_RUN: True})
                     for i, score in enumerate(scores)]  # fmt: skip
        _add_seed_rows(study, params, dists, net, configs, rows)
        got[on] = _refine_runs(driver, study, 8, lambda attrs, _i: 70.0 if attrs.get(keys.SEED_LEADER_RUN) else 74.0)
        # (each leader's run lowers its mean)
    assert got[False] == [(2, i, False) for i in range(4)] + [(3, i, False) for i in range(4)]
    assert got[True] == [(0, 4, True), (2, 0, False), (1, 4, True), (2, 1, False), (0, 5, True), (2, 2, False),
                         (2, 3, True), (3, 0, False)]  # fmt: skip


def test_seed_soup_leader_is_checked() -> None:
    assert not _spec().study.seed_soup_leader and "seed_soup_leader" not in _spec().to_dict()["study"]
    spec = _spec(refine_share=0.5, seed_soups=[2], seed_soup_runs=8, seed_soup_leader=True)
    assert spec.to_dict()["study"]["seed_soup_leader"] is True
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_leader: .*seed_soup_runs = 0.*set seed_soup_runs"):
        _spec(seed_soups=[2], seed_soup_leader=True)
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_leader: must be true or false, got 1"):
        _spec(refine_share=0.5, seed_soups=[2], seed_soup_runs=8, seed_soup_leader=1)


def test_best_net_configs_are_the_configurations_whose_seeds_make_the_best_net() -> None:
    attrs: list[dict[str, Any]] = [{}, {}, {}, {keys.RACE_OF: 0}, {keys.RACE_OF: 2}, {keys.RACE_OF: 2}]
    attrs.append({keys.SOUP_OF: [3, 4, 5], keys.SEED_SOUP_OF: 0, keys.REFINE_OF: {"trial": 0, "budget": None}})
    attrs.append({keys.REFINE_OF: {"trial": 6, "budget": None}})
    attrs.append({keys.SOUP_OF: [7, 7], keys.REFINE_OF: {"trial": 6, "budget": None}})
    assert ensemble.best_net_configs(6, attrs) == [0, 2]  # a family soup: two configurations
    assert ensemble.best_net_configs(4, attrs) == [2]  # a fresh seed: its configuration
    assert ensemble.best_net_configs(1, attrs) == [1]
    assert ensemble.best_net_configs(7, attrs) == [] == ensemble.best_net_configs(8, attrs)  # trained on from a net


@pytest.mark.parametrize("leader", [False, True])
def test_the_best_nets_configurations_take_every_other_run_of_the_refinement(tmp_path: Path, leader: bool) -> None:
    """With ``seed_soup_best`` the configurations whose seeds make the best net take turns with the rest of the
    refinement's runs (here a new linear configuration's probe seeds), the best of them by mean over its nets first.
    The best net is a soup of configurations 1 and 2 (twins by their rate; 2's nets average higher), so
    configuration 0 gets no turn though it leads by mean and has the best fresh net; once a seed of 1 beats the
    soup, 1 alone takes them. With ``seed_soup_leader`` too (and 5 seeds a configuration), the leader by mean (0)
    takes the turn once the best net's configurations have all their seeds."""
    spec = _spec(n_trials=80, timeout_s=3600, refine_share=0.5, seed_soups=[2], seed_soup_runs=5 if leader else 8,
                 seed_soup_reach=2.0, seed_soup_best=True, seed_soup_leader=leader).with_overrides(
                     storage=str(tmp_path / "best.log"), workers=2)  # fmt: skip
    driver, study, storages, dists, params = _driver_on_journal(spec)
    net = _upload(storages, study, _linear_text(0))
    base = LINEAR.replace(train_iterations=1200)
    configs = [
        base.replace(patches_ahead=2),
        base.replace(patches_ahead=3),
        base.replace(patches_ahead=3, learning_rate=base.learning_rate * 2),
        base.replace(patches_ahead=5),
    ]
    rows: list[tuple[float, int, dict[str, Any]]] = [(value, i, {}) for i, value in enumerate((75.0, 74.2, 74.6, 74.5))]
    for owner, score in ((0, 74.9), (1, 73.5), (2, 74.0)):  # means 74.92, 73.64, 74.12
        rows += [(score, owner, {keys.RACE_OF: owner, keys.RACE_SEED: i, keys.SEED_SOUP_RUN: True}) for i in range(4)]
    soup = {keys.SOUP_OF: [1, 2, 12], keys.SEED_SOUP_OF: 1, keys.REFINE_OF: {"trial": 2, "budget": None}}
    rows.append((75.3, 2, soup))  # trials 1 (configuration 1), 2 and 12 (configuration 2): the best net
    _add_seed_rows(study, params, dists, net, [c.to_mapping() for c in configs], rows)
    runs = _refine_runs(driver, study, 6, lambda _attrs, i: 75.5 if i == 2 else 70.0)  # the third (1's) beats the soup
    fifth = (0, 4, True) if leader else (1, 5, True)
    assert runs == [(2, 4, True), (3, 0, False), (1, 4, True), (3, 1, False), fifth, (3, 2, False)]


def test_seed_soup_best_is_checked() -> None:
    assert "seed_soup_best" not in _spec().to_dict()["study"]
    spec = _spec(refine_share=0.5, seed_soups=[2], seed_soup_runs=8, seed_soup_best=True)
    assert spec.study.seed_soup_best and spec.to_dict()["study"]["seed_soup_best"] is True
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_best: .*seed_soup_runs = 0.*set seed_soup_runs"):
        _spec(seed_soups=[2], seed_soup_best=True)
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_best: must be true or false, got 'yes'"):
        _spec(refine_share=0.5, seed_soups=[2], seed_soup_runs=8, seed_soup_best="yes")


def test_contender_configs_are_each_familys_best_nets_configurations_fewest_seeds_first() -> None:
    """Every family whose best net is at the floor or above, by the configurations that make that net: a family soup
    by its ingredients' configurations, a fresh seed by its own; refinement runs, nets below the floor and the
    configurations skipped count for nothing; the family with fewer seeds first, then the higher best net."""
    base = LINEAR.replace(train_iterations=1200)
    a, b, c = (base.replace(patches_ahead=k).to_mapping() for k in (2, 3, 4))
    a2 = base.replace(patches_ahead=2, learning_rate=base.learning_rate * 2).to_mapping()  # a's twin: one family
    attrs: list[dict[str, Any]] = [
        {keys.CONFIG: a}, {keys.CONFIG: a2}, {keys.CONFIG: b}, {keys.CONFIG: c},
        {keys.CONFIG: a, keys.RACE_OF: 0}, {keys.CONFIG: b, keys.RACE_OF: 2},
        {keys.CONFIG: a, keys.SOUP_OF: [1, 4], keys.SEED_SOUP_OF: 0, keys.REFINE_OF: {"trial": 4, "budget": None}},
        {keys.CONFIG: c, keys.REFINE_OF: {"trial": 3, "budget": None}},
    ]  # fmt: skip
    values: list[float | None] = [75.0, 74.0, 74.9, 73.0, 75.1, 75.2, 75.6, 76.0]
    assert ensemble.contender_configs(attrs, values, 75.0, {}) == [[0, 1], [2]]  # a's soup 75.6, then b's seed 75.2
    assert ensemble.contender_configs(attrs, values, 75.0, {2: 5, 0: 3, 1: 3}) == [[2], [0, 1]]  # 5 seeds before 6
    assert ensemble.contender_configs(attrs, values, 75.0, {}, skip=[0, 1]) == [[2]]
    assert ensemble.contender_configs(attrs, values, 75.3, {}) == [[0, 1]]  # the refinement run (76.0) makes none
    values[6] = None  # the soup not COMPLETE: a's best is its seed 75.1 (trial 4, configuration 0's)
    assert ensemble.contender_configs(attrs, values, 75.0, {}) == [[2], [0]]


def test_other_families_near_the_best_share_the_best_nets_turns(tmp_path: Path) -> None:
    """With ``seed_soup_best_span`` the best net's configurations and the other families whose best net is within
    the span take the seed turns in turn (the rest of the refinement's runs between them): configuration 0 makes
    the best net (75.3); configurations 1 (75.1, 1 seed) and 2 (a seed at 75.2, 4 seeds) are within 0.25, the one
    with fewer seeds first; configuration 3 (74.9) is not. Without the span only configuration 0 takes the turns."""
    got = {}
    for span in (0.0, 0.25):
        spec = _spec(n_trials=80, timeout_s=3600, refine_share=0.5, seed_soups=[2], seed_soup_runs=8,
                     seed_soup_reach=2.0, seed_soup_best=True, seed_soup_best_span=span).with_overrides(
                         storage=str(tmp_path / f"{span}.log"), workers=2)  # fmt: skip
        driver, study, storages, dists, params = _driver_on_journal(spec)
        net = _upload(storages, study, _linear_text(0))
        configs = [LINEAR.replace(train_iterations=1200, patches_ahead=2 + i) for i in range(5)]
        rows: list[tuple[float, int, dict[str, Any]]] = [
            (value, i, {}) for i, value in enumerate((75.3, 75.1, 74.0, 74.9, 74.5))
        ]
        for owner, scores in ((0, (74.0,) * 4), (1, (74.0,)), (2, (75.2, 74.0, 74.0, 74.0))):
            rows += [(score, owner, {keys.RACE_OF: owner, keys.RACE_SEED: i, keys.SEED_SOUP_RUN: True})
                     for i, score in enumerate(scores)]  # fmt: skip
        _add_seed_rows(study, params, dists, net, [c.to_mapping() for c in configs], rows)
        got[span] = [owner for owner, _i, turn in _refine_runs(driver, study, 8, lambda _a, _i: 70.0) if turn]
    assert got[0.0] == [0, 0, 0, 0]
    turns = got[0.25]
    assert turns[0::2] == [0, 0] and turns[1] == 1  # 1 (1 seed) before 2 (4 seeds, a better net): fewest first
    assert set(turns[1::2]) <= {1, 2}  # the rest's probe seeds also count: either may come next, never 3 or 4


def test_seed_soup_best_span_is_checked() -> None:
    assert "seed_soup_best_span" not in _spec().to_dict()["study"]
    spec = _spec(refine_share=0.5, seed_soups=[2], seed_soup_runs=8, seed_soup_best=True, seed_soup_best_span=0.25)
    assert spec.study.seed_soup_best_span == 0.25 and spec.to_dict()["study"]["seed_soup_best_span"] == 0.25
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_best_span: .*seed_soup_best is off.*set seed_soup_best"):
        _spec(refine_share=0.5, seed_soups=[2], seed_soup_runs=8, seed_soup_best_span=0.25)
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_best_span: must be a number"):
        _spec(refine_share=0.5, seed_soups=[2], seed_soup_runs=8, seed_soup_best=True, seed_soup_best_span="wide")


def test_with_seed_soup_views_linear_configurations_of_two_views_soup_on_their_union(tmp_path: Path) -> None:
    """With ``seed_soup_views`` (and families) two linear configurations that differ only in their view are one
    family: their soup is scored with the union of their views, each net moved onto it (``widen``), so the soup's
    Q-values are the mean of theirs. Without it each is its own family of one net: nothing to soup."""
    narrow = LINEAR.replace(train_iterations=1200, lanes_side=0, patches_ahead=2)
    wide = LINEAR.replace(train_iterations=1200, lanes_side=1, patches_ahead=1, patches_behind=1)
    texts = [dumps_net(train(c.replace(train_iterations=0), seed=s, quick_eval=False).convnet())
             for s, c in enumerate((narrow, wide))]  # fmt: skip
    for views in (False, True):
        spec = _spec(n_trials=20, timeout_s=3600, seed_soups=[2], seed_soup_families=True, seed_soup_views=views)
        spec = spec.with_overrides(storage=str(tmp_path / f"{views}.log"), workers=2)
        driver, study, storages, dists, params = _driver_on_journal(spec)
        for config, value, text in zip((narrow, wide), (74.0, 73.8), texts, strict=True):
            study.add_trial(optuna.trial.create_trial(
                params=params, distributions=dists, value=value, state=COMPLETE,
                user_attrs={keys.CONFIG: config.to_mapping(), keys.RUNGS: [{keys.BUDGET: 1200, keys.SCORE: value}],
                            keys.ARTIFACT_NET_JSON: _upload(storages, study, text)},
            ))  # fmt: skip
        driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001
        if not views:
            assert not driver._launch_seed_soup(0)  # noqa: SLF001
            continue
        assert driver._launch_seed_soup(0)  # noqa: SLF001
        made = study.trials[-1]
        assert made.user_attrs[keys.SOUP_OF] == [0, 1] and made.user_attrs[keys.SEED_SOUP_OF] == 0
        union = narrow.replace(lanes_side=1, patches_ahead=2, patches_behind=1)  # the best's settings, the union view
        assert made.user_attrs[keys.CONFIG] == union.to_mapping()
        net = loads_net(driver.pool.tasks[-1].init_net)
        assert net.input_size == union.net_inputs == 9
        x_union = np.random.default_rng(1).normal(size=(3, 3))  # rows -2…0 (ahead 2, behind 1) × lanes -1…1
        members = [loads_net(t) for t in texts]
        expected = np.mean([forward(members[0], x_union[:2, 1]), forward(members[1], x_union[1:, :].ravel())], axis=0)
        np.testing.assert_allclose(forward(net, x_union.ravel()), expected, rtol=0, atol=1e-12)


def test_seed_soup_views_is_checked() -> None:
    assert not _spec().study.seed_soup_views and "seed_soup_views" not in _spec().to_dict()["study"]
    on = _spec(seed_soups=[2], seed_soup_families=True, seed_soup_views=True)
    assert on.study.seed_soup_views and on.to_dict()["study"]["seed_soup_views"] is True
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_views: .*seed_soup_families is off.*set seed_soup_famil"):
        _spec(seed_soups=[2], seed_soup_views=True)
    with pytest.raises(SpecError, match=r"\[study\] seed_soup_views: must be true or false, got 1"):
        _spec(seed_soups=[2], seed_soup_families=True, seed_soup_views=1)


def test_family_key_with_views_leaves_out_only_the_view() -> None:
    a = LINEAR.replace(lanes_side=0, patches_ahead=2).to_mapping()
    b = LINEAR.replace(lanes_side=2, patches_ahead=5, patches_behind=3).to_mapping()
    assert ensemble.family_key(a) != ensemble.family_key(b)
    assert ensemble.family_key(a, views=True) == ensemble.family_key(b, views=True)
    for other in ({"other_agents": 3}, {"temporal_window": 1}, {"epsilon_test_time": 0.05}):
        assert ensemble.family_key(LINEAR.replace(**other).to_mapping(), views=True) != ensemble.family_key(a, True)
    assert ensemble.family_key(TINY.to_mapping(), views=True) is None  # hidden layers: no family
