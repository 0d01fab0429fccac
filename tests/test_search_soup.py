"""Weight soups (``[study] refine_soups``): the mean of a parent's best refinement runs, scored with no training.

The average and the choice of the next soup as pure rules, the spec key, the objective's evaluation-only path,
and the driver on a journal study: when a soup replaces a training run, what it records, and that it uses
neither a seed, a net's runs nor the cost model."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import optuna
import pytest

from autotune.convnet.netjson import dumps_net, loads_net
from autotune.convnet.spec import NetSpecError
from autotune.learner.official import evaluate_official
from autotune.learner.training import train
from autotune.search import keys, refine, soup
from autotune.search.driver import _observations
from autotune.search.objective import COMPLETE as DONE
from autotune.search.objective import FAILED, TrialTask, run_trial
from autotune.search.spec import SpecError
from tests.conftest import FakePool
from tests.test_search_ladder import TINY, _driver_on_journal, _spec
from tests.test_search_refine import _net_text, _upload

COMPLETE = optuna.trial.TrialState.COMPLETE


def test_a_soup_is_the_mean_of_its_ingredients_weights() -> None:
    a, b, c = (loads_net(_net_text(seed)) for seed in range(3))
    mean = soup.average_nets([a, b, c])
    assert mean.layers == a.layers
    for k, (w, bias) in enumerate(mean.params):
        np.testing.assert_allclose(w, (a.params[k][0] + b.params[k][0] + c.params[k][0]) / 3, rtol=0, atol=1e-15)
        np.testing.assert_allclose(bias, (a.params[k][1] + b.params[k][1] + c.params[k][1]) / 3, rtol=0, atol=1e-15)
    assert all(np.array_equal(x[0], y[0]) for x, y in zip(soup.average_nets([a, a]).params, a.params, strict=True))
    other = loads_net(dumps_net(train(TINY.replace(train_iterations=0, layers="fc:6:relu"), seed=0,
                                      quick_eval=False).convnet()))  # fmt: skip
    with pytest.raises(NetSpecError, match="soup ingredient 1: its layers differ"):
        soup.average_nets([a, other])
    with pytest.raises(NetSpecError, match="at least one net"):
        soup.average_nets([])


def test_the_next_soup_is_the_best_k_runs_not_tried_yet() -> None:
    runs = [(10, 74.0), (11, 75.0), (12, 74.5), (13, 74.5), (14, 60.0)]
    assert soup.next_soup(runs, (2, 4), []) == (11, 12)  # ties: the earlier trial
    assert soup.next_soup(runs, (2, 4), [[12, 11]]) == (10, 11, 12, 13)
    assert soup.next_soup(runs, (2, 4), [(11, 12), (10, 11, 12, 13)]) is None
    assert soup.next_soup(runs[:3], (4, 2), []) == (11, 12)  # too few for 4: the next size
    assert soup.next_soup(runs[:1], (2,), []) is None
    assert soup.next_soup(runs + [(15, 76.0)], (2,), [(11, 12)]) == (11, 15)  # a new best: a new set
    assert soup.next_soup(runs, (2, 4), [], floor=74.4) == (11, 12)
    assert soup.next_soup(runs, (4,), [], floor=74.4) is None  # 3 runs within the span: no soup of 4


def test_refine_soups_is_checked() -> None:
    assert _spec(refine_share=0.5).study.refine_soups == ()
    assert _spec(refine_share=0.5, refine_soups=[2, 4]).study.refine_soups == (2, 4)
    for bad, message in ((3, "must be a list of integers, got 3"), ([2, 2], "sizes must be distinct"),
                         ([1], r"sizes must be distinct and in \[2, 64\], got \[1\]"),
                         ([2.5], r"must be a list of integers, got \[2.5\]")):  # fmt: skip
        with pytest.raises(SpecError, match=rf"\[study\] refine_soups: {message}"):
            _spec(refine_share=0.5, refine_soups=bad)
    with pytest.raises(SpecError, match=r"\[study\] refine_soups: .*refine_share = 0"):
        _spec(refine_soups=[2])
    assert _spec(refine_share=0.5).study.refine_soup_span == soup.SOUP_SPAN == 0.5
    assert _spec(refine_share=0.5, refine_soups=[2], refine_soup_span=1).study.refine_soup_span == 1.0
    spans: tuple[tuple[object, str], ...] = ((0, "must be above 0, got 0.0"), ("1", "must be a number"),
                                             (-1, r"-1 is out of range; use \[0, 100\]"))  # fmt: skip
    for span, message in spans:
        with pytest.raises(SpecError, match=rf"\[study\] refine_soup_span: {message}"):
            _spec(refine_share=0.5, refine_soups=[2], refine_soup_span=span)
    with pytest.raises(SpecError, match=r"refine_soup_span: .*refine_soups and seed_soups are empty.*set refine_soups"):
        _spec(refine_share=0.5, refine_soup_span=1.0)


def test_a_soup_trial_scores_its_net_officially_and_trains_nothing() -> None:
    net = _net_text(5)
    config = TINY.replace(epsilon_test_time=0.05)
    task = TrialTask(number=3, config=config.to_mapping(), seed=1, init_net=net, evaluate_only=True,
                     final_protocol="v2-official")  # fmt: skip
    out = run_trial(task, lambda step, frames, score: False)
    assert out.state == DONE and out.net_json == net and out.net_js
    assert out.value == float(evaluate_official(loads_net(net), config, protocol="v2-official").median_site)
    assert out.attrs[keys.TRAIN_SECONDS] == 0.0 and keys.RUNGS not in out.attrs and keys.CURVE not in out.attrs
    failed = run_trial(TrialTask(number=4, config=config.to_mapping(), seed=1, evaluate_only=True), lambda *a: False)
    assert failed.state == FAILED and "needs its net" in (failed.cause or "")


def test_the_driver_soups_a_parents_best_runs_before_its_next_run(tmp_path: Path) -> None:
    """With ``refine_soups``, a refinement worker scores the soup of the parent's best k finished runs when that set
    is new, else trains the parent's next run; a soup keeps its ingredients' config, records them, gets no seed of
    the refinement runs', no predicted cost and no count against ``refine_runs``, and is a parent once it beats
    its own."""
    spec = _spec(race_configs=2, race_seeds=1, n_trials=20, timeout_s=3600, refine_share=0.5, refine_runs=3,
                 refine_iterations=3000, refine_soups=[2], refine_soup_span=0.6).with_overrides(
                     storage=str(tmp_path / "j.log"), workers=2)  # fmt: skip
    driver, study, storages, dists, params = _driver_on_journal(spec)
    texts = [_net_text(seed) for seed in range(4)]
    study.add_trial(optuna.trial.create_trial(
        params=params, distributions=dists, value=74.0, state=COMPLETE,
        user_attrs={keys.CONFIG: TINY.to_mapping(), keys.ARTIFACT_NET_JSON: _upload(storages, study, texts[0])},
    ))  # fmt: skip
    driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001

    def finish(value: float, text: str | None) -> Any:
        run = driver._running.pop(0).trial  # noqa: SLF001
        if text is not None:
            run.set_user_attr(keys.ARTIFACT_NET_JSON, _upload(storages, study, text))
        study.tell(run, value)
        return study.trials[run.number]

    assert driver._launch_refine(0)  # noqa: SLF001 - one run: no pair to soup yet
    first = finish(73.5, texts[1])
    assert driver._launch_refine(0)  # noqa: SLF001
    second = finish(73.45, texts[2])  # within the study's refine_soup_span (0.6), not the default 0.5
    assert driver._launch_refine(0)  # noqa: SLF001 - two runs of trial 0: their soup
    made = study.trials[-1]
    assert made.user_attrs[keys.SOUP_OF] == [first.number, second.number]
    assert made.user_attrs[keys.REFINE_OF] == {"trial": 0, "budget": None, "score": 74.0}
    assert made.user_attrs[keys.CONFIG] == first.user_attrs[keys.CONFIG]
    assert keys.PREDICTED_COST not in made.user_attrs
    task = driver.pool.tasks[-1]
    expected = dumps_net(soup.average_nets([loads_net(texts[1]), loads_net(texts[2])]))
    assert task.evaluate_only and task.init_net == expected
    soup_trial = finish(74.3, expected)  # beats its parent: the next run trains on from the soup, at its rate
    assert _observations(soup_trial) == []  # an evaluation, no training: never a cost observation
    assert driver._launch_refine(0)  # noqa: SLF001
    nxt = study.trials[-1]
    assert nxt.user_attrs[keys.REFINE_OF] == {"trial": soup_trial.number, "budget": None, "score": 74.3}
    assert keys.SOUP_OF not in nxt.user_attrs
    assert nxt.user_attrs[keys.SEED] == refine.refine_seed(spec.study.seed, 2)  # the third training run's seed
    assert nxt.user_attrs[keys.CONFIG] == first.user_attrs[keys.CONFIG]
    assert driver.pool.tasks[-1].init_net == expected and not driver.pool.tasks[-1].evaluate_only
    finish(74.0, texts[3])
    # trial 0 had 2 training runs of its 3 (the soup does not count): once the soup's line stalls, it has its third
    assert driver._launch_refine(0)  # noqa: SLF001
    assert study.trials[-1].user_attrs[keys.REFINE_OF]["trial"] == soup_trial.number
