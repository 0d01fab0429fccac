"""``[ladder] epsilon_test_grid``: ε_test chosen per trained net (screened on a prefix of the official runs), not
searched as a training setting.

ε_test acts only at test time, so one training serves every value: each rung screens its net at the grid's values
on the protocol's first runs and is scored officially at the best. Checked here: a screen is exactly the protocol's
first runs; a rung's choice is its best screen and its score a standalone training scored at that ε_test; the
trial's config, a kept rung's config (race entry, export) and a retrain carry the chosen value; race runs and
replays are measured at their own ε_test; the cost model prices the screens; the spec's refusals.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import optuna
import pytest

from autotune import TrainConfig, evaluate_official
from autotune.learner import train
from autotune.search import keys, space
from autotune.search.cost import FEATURES, CostModel, features
from autotune.search.driver import Driver, race_entry
from autotune.search.gate import distributions
from autotune.search.ladder import rung_config, trained_rung_config
from autotune.search.objective import COMPLETE, PRUNED, TrialTask, choose_epsilon, run_trial
from autotune.search.spec import EPSILON_SCREEN_RUNS, SpecError, default_screen_runs, parse_spec
from autotune.search.storage import open_storage
from tests.conftest import FakePool, forward_cost_model

FIXED, CARS, FILLS = (FEATURES.index(k) for k in ("eval_fixed", "eval_cars", "eval_inputs"))
TRAINING = FEATURES.index("eval_fixed")  # the work terms before it are the training's

optuna.logging.set_verbosity(optuna.logging.WARNING)

TINY = TrainConfig(
    ruleset="v2", lanes_side=0, patches_ahead=2, other_agents=1, train_iterations=1200, temporal_window=0,
    experience_size=500, start_learn_threshold=100, learning_steps_burnin=120, learning_steps_total=600,
    layers="fc:4:relu", batch_size=8,
)  # fmt: skip
GRID = (0.0, 0.2, 0.6)


def _data(**ladder: Any) -> dict[str, Any]:
    return {
        "study": {"name": "eps", "n_trials": 10, "timeout_s": 60, "race_configs": 2, "race_seeds": 1},
        "ladder": {"rungs": [400, 1200], "epsilon_test_grid": list(GRID), "epsilon_test_screen_runs": 50, **ladder},
        "fixed": {"otherAgents": 1, "temporal_window": 0, "experience_size": 500, "batch_size": 8},
        "space": {"lanes_side": {"low": 0, "high": 2}, "patches_ahead": {"low": 1, "high": 4},
                  "learning_steps_burnin_fraction": {"low": 0.01, "high": 0.2, "log": True}},
    }  # fmt: skip


def test_a_screen_is_the_official_protocols_first_runs() -> None:
    """The premise of screening: ``runs = n`` evaluates exactly the whole protocol's first n runs (same traffic,
    same draws), so a screen ranks ε_test on the very runs the official score starts with."""
    net = train(rung_config(TINY, 400), 3, quick_eval=False).convnet()
    for epsilon in (0.0, 0.3):
        config = TINY.replace(epsilon_test_time=epsilon)
        whole, first = evaluate_official(net, config), evaluate_official(net, config, runs=40)
        assert first.runs == 40 and list(first.scores) == list(whole.scores[:40])


def test_each_rung_is_scored_at_its_best_screen_and_is_a_standalone_training() -> None:
    """A grid trial's rung records its screens (one per grid value, each the protocol's first runs at that
    ε_test), chooses the best, and its score is the rung's standalone training scored officially at that ε_test;
    the trial's config carries its last rung's choice, so a retrain from config and seed gives its value."""
    task = TrialTask(number=0, config=TINY.to_mapping(), seed=7, rungs=(400, 1200), epsilon_test_grid=GRID,
                     epsilon_test_screen_runs=(50,))  # fmt: skip
    outcome = run_trial(task, lambda *a: False)
    assert outcome.state == COMPLETE, outcome.cause
    rungs = outcome.attrs[keys.RUNGS]
    assert outcome.attrs[keys.EPSILON_SCREEN_RUNS] == 50
    for rung in rungs:
        alone = rung_config(TINY, rung[keys.BUDGET])
        net = train(alone, rung[keys.SEED], quick_eval=False).convnet()
        screens = rung[keys.EPSILON_SCREEN]
        assert [s[0] for s in screens] == list(GRID)
        for epsilon, median, mean, runs in screens:
            ev = evaluate_official(net, alone.replace(epsilon_test_time=epsilon), runs=50)
            assert (median, mean, runs) == (ev.median_site, ev.mean, 50)
        best = max(screens, key=lambda s: (s[1], s[2], -s[0]))
        assert rung[keys.EPSILON_TEST] == best[0]
        assert evaluate_official(net, alone.replace(epsilon_test_time=best[0])).median_site == rung[keys.SCORE]
        assert trained_rung_config(TINY, rung[keys.BUDGET], rungs).epsilon_test_time == best[0]
    evaluated = len(rungs) * (len(GRID) * 50 + 500 - 50) * 2000  # the chosen screen's runs are not run again
    assert outcome.attrs[keys.FRAMES_SIMULATED] == sum(r[keys.FRAMES] for r in rungs) + evaluated
    top = TrainConfig.from_mapping(outcome.attrs[keys.CONFIG])
    assert top.epsilon_test_time == rungs[-1][keys.EPSILON_TEST]
    assert outcome.attrs[keys.SETTINGS]["opt"]["epsilon_test_time"] == top.epsilon_test_time
    again = run_trial(TrialTask(number=0, config=top.to_mapping(), seed=7), lambda *a: False)  # autotune's retrain
    assert again.value == outcome.value


def test_choose_epsilon_breaks_ties_by_the_mean_then_the_smaller_value() -> None:
    """The site's median ranks the screens, then the mean, then the smaller ε_test."""
    screens = [[0.0, 73.0, 72.0], [0.1, 74.0, 72.5], [0.2, 74.0, 72.9], [0.3, 74.0, 72.9], [0.5, 73.9, 73.5]]
    assert choose_epsilon(screens) == 2  # 74.0 at 0.1, 0.2 and 0.3: the higher mean (72.9) at 0.2 and 0.3, then 0.2
    assert choose_epsilon([[0.4, 70.0, 70.0], [0.0, 70.0, 70.0]]) == 1
    assert choose_epsilon([[0.0, 70.0, 71.0]]) == 0
    # a halving's screens carry their runs: only those screened on the most runs are candidates
    halved = [[0.0, 75.0, 74.0, 20], [0.1, 73.0, 72.0, 50], [0.2, 73.5, 72.0, 50], [0.4, 74.0, 73.0, 20]]
    assert choose_epsilon(halved) == 2


@pytest.mark.parametrize(("ruleset", "screen_runs"), [("v2", 50), ("v2", 37), ("v1", 3)])
def test_screens_are_the_protocols_first_runs_and_the_chosen_one_finishes_as_the_official_score(
    ruleset: str, screen_runs: int
) -> None:
    """``screen_epsilons``: each screen is ``evaluate_official(…, runs=n)`` at its ε_test, to the digit; ``finish``
    carries the chosen one on to exactly ``evaluate_official``'s whole evaluation (scores, greedy choices), so
    the screened runs are not run again; ``frames`` counts what was simulated."""
    from autotune import screen_epsilons

    if ruleset == "v2":
        config = TINY
    else:
        config = TrainConfig(
            ruleset="v1", lanes_side=0, patches_ahead=2, train_iterations=400, temporal_window=0,
            experience_size=200, start_learn_threshold=50, layers="fc:4:relu", batch_size=8,
        )  # fmt: skip
    net = train(rung_config(config, 400) if ruleset == "v2" else config, 3, quick_eval=False).convnet()
    screened = screen_epsilons(net, config, GRID, screen_runs)
    assert screened.grid == GRID and screened.runs == screen_runs
    for epsilon, screen in zip(GRID, screened.screens, strict=True):
        alone = evaluate_official(net, config.replace(epsilon_test_time=epsilon), runs=screen_runs)
        assert (screen.scores, screen.ego_scores) == (alone.scores, alone.ego_scores)
    frames = screened.screens[0].frames
    assert screened.frames == len(GRID) * screen_runs * frames
    greedy, want_greedy = np.zeros(5, dtype=np.int64), np.zeros(5, dtype=np.int64)
    whole = screened.finish(1, greedy_actions=greedy)
    want = evaluate_official(net, config.replace(epsilon_test_time=GRID[1]), greedy_actions=want_greedy)
    assert (whole.scores, whole.median_site, whole.official_size) == (want.scores, want.median_site, True)
    assert np.array_equal(greedy, want_greedy) and greedy.sum() > 0
    assert screened.frames == (len(GRID) * screen_runs + want.runs - screen_runs) * frames
    from autotune import dumps_net

    assert screened.net_json == dumps_net(net)


def test_screens_on_a_protocol_of_independent_worlds_evaluate_the_choice_from_the_start() -> None:
    """The custom protocol cannot pause: its screens and its finish are plain evaluations, the same numbers."""
    from autotune import screen_epsilons

    net = train(rung_config(TINY, 400), 3, quick_eval=False).convnet()
    screened = screen_epsilons(net, TINY, GRID, 20, protocol="custom")
    alone = evaluate_official(net, TINY.replace(epsilon_test_time=0.2), protocol="custom", runs=20)
    assert screened.screens[1].scores == alone.scores
    whole = screened.finish(1)
    assert whole.scores == evaluate_official(net, TINY.replace(epsilon_test_time=0.2), protocol="custom").scores
    assert screened.frames == (3 * 20 + whole.runs) * whole.frames
    with pytest.raises(Exception, match=r"runs: a screen runs 1 to 500 of v2-official's runs, in increasing "
                       r"stages; got 501"):  # fmt: skip
        screen_epsilons(net, TINY, GRID, 501)
    with pytest.raises(Exception, match=r"in increasing stages; got \[50, 50\]"):
        screen_epsilons(net, TINY, GRID, (50, 50))


HALVING_GRID = (0.0, 0.1, 0.2, 0.4, 0.6)


@pytest.mark.parametrize("protocol", ["v2-official", "custom"])
def test_a_halving_carries_the_better_half_on_and_the_best_finalist_finishes(protocol: str) -> None:
    """``runs=(20, 50)``: every value on the first 20 runs, the better two of five (``screen_survivors``, by
    ``screen_order``) on to 50; each screen is ``evaluate_official(…, runs=n)`` for the runs it reached, to the
    digit, ``best`` is the best finalist, and ``finish`` gives the whole evaluation; a screen carried on is
    continued (v2-official) or evaluated again (custom: its worlds are independent), and ``frames`` says which."""
    from autotune import screen_epsilons
    from autotune.learner.official import screen_order, screen_survivors

    assert screen_survivors(5, 2) == (5, 2) and screen_survivors(3, 3) == (3, 1, 1) and screen_survivors(2, 1) == (2,)
    net = train(rung_config(TINY, 400), 3, quick_eval=False).convnet()
    screened = screen_epsilons(net, TINY, HALVING_GRID, (20, 50), protocol=protocol)
    assert screened.stages == (20, 50) and screened.runs == 50
    first = {e: evaluate_official(net, TINY.replace(epsilon_test_time=e), protocol=protocol, runs=20)
             for e in HALVING_GRID}  # fmt: skip
    ranked = sorted(range(5), key=lambda i: screen_order(HALVING_GRID[i], first[HALVING_GRID[i]].median_site,
                                                         first[HALVING_GRID[i]].mean), reverse=True)  # fmt: skip
    assert screened.finalists == sorted(ranked[:2])
    for i, (epsilon, screen) in enumerate(zip(HALVING_GRID, screened.screens, strict=True)):
        runs = 50 if i in screened.finalists else 20
        alone = evaluate_official(net, TINY.replace(epsilon_test_time=epsilon), protocol=protocol, runs=runs)
        assert (screen.runs, screen.scores, screen.ego_scores) == (runs, alone.scores, alone.ego_scores)
    best = max(screened.finalists, key=lambda i: screen_order(HALVING_GRID[i], screened.screens[i].median_site,
                                                              screened.screens[i].mean))  # fmt: skip
    assert screened.best == best
    frames = screened.screens[0].frames
    continued = protocol == "v2-official"
    assert screened.frames == (5 * 20 + 2 * (30 if continued else 50)) * frames
    whole = screened.finish(best)
    want = evaluate_official(net, TINY.replace(epsilon_test_time=HALVING_GRID[best]), protocol=protocol)
    assert (whole.scores, whole.median_site) == (want.scores, want.median_site)
    assert screened.frames == (5 * 20 + 2 * (30 if continued else 50) + want.runs - (50 if continued else 0)) * frames


def test_a_halving_trial_records_each_screens_runs_and_the_cost_model_reads_them(tmp_path: Path) -> None:
    """A rung of a halving trial stores ``[ε, median, mean, runs]`` per value and is scored at the best finalist;
    its cost observation prices each screen by the runs it ran."""
    from autotune.search.driver import _observations

    task = TrialTask(number=0, config=TINY.to_mapping(), seed=7, rungs=(400,), epsilon_test_grid=HALVING_GRID,
                     epsilon_test_screen_runs=(20, 50))  # fmt: skip
    outcome = run_trial(task, lambda *a: False)
    assert outcome.state == COMPLETE, outcome.cause
    (rung,) = outcome.attrs[keys.RUNGS]
    screens = rung[keys.EPSILON_SCREEN]
    assert sorted(s[3] for s in screens) == [20, 20, 20, 50, 50] and outcome.attrs[keys.EPSILON_SCREEN_RUNS] == 50
    assert rung[keys.EPSILON_TEST] == screens[choose_epsilon(screens)][0]
    assert max((s for s in screens if s[3] == 50), key=lambda s: (s[1], s[2], -s[0]))[0] == rung[keys.EPSILON_TEST]
    net = train(rung_config(TINY, 400), rung[keys.SEED], quick_eval=False).convnet()
    chosen = rung_config(TINY, 400).replace(epsilon_test_time=rung[keys.EPSILON_TEST])
    assert evaluate_official(net, chosen).median_site == rung[keys.SCORE]
    frames = rung[keys.FRAMES] + (5 * 20 + 2 * 30 + 500 - 50) * 2000
    assert outcome.attrs[keys.FRAMES_SIMULATED] == frames
    trial = optuna.trial.create_trial(
        value=outcome.value, state=optuna.trial.TrialState.COMPLETE,
        user_attrs={k: v for k, v in outcome.attrs.items() if k in (keys.CONFIG, keys.RUNGS, keys.OFFICIAL_PROTOCOL,
                                                                   keys.EPSILON_SCREEN_RUNS)},
    )  # fmt: skip
    (obs,) = _observations(trial)
    config = trained_rung_config(TrainConfig.from_mapping(outcome.attrs[keys.CONFIG]), 400, [rung])
    shares = [s[3] / 500 for s in screens]
    want = features(config, screen=[s[0] for s in screens], screen_share=shares)
    assert np.allclose(obs.features, want)
    assert want[CARS] == pytest.approx(features(config)[CARS] * (0.9 + (3 * 20 + 2 * 50) / 500))  # cars: runs' worth


@pytest.mark.parametrize("protocol", ["v2-official", "custom"])
def test_screens_count_each_values_greedy_choices(protocol: str) -> None:
    """``EpsilonScreens.greedy[i]`` is what ``evaluate_official(…, runs=n, greedy_actions=…)`` counts for value i
    over the runs n its screen reached: the best finalist's are the first runs of the official evaluation."""
    from autotune import screen_epsilons

    net = train(rung_config(TINY, 400), 3, quick_eval=False).convnet()
    screened = screen_epsilons(net, TINY, HALVING_GRID, (20, 50), protocol=protocol)
    assert screened.greedy.shape == (5, 5) and screened.greedy.sum() > 0
    for i, (epsilon, screen) in enumerate(zip(HALVING_GRID, screened.screens, strict=True)):
        alone = np.zeros(5, dtype=np.int64)
        evaluate_official(net, TINY.replace(epsilon_test_time=epsilon), protocol=protocol, runs=screen.runs,
                          greedy_actions=alone)  # fmt: skip
        assert np.array_equal(screened.greedy[i], alone)


def test_a_net_static_on_its_screens_is_pruned_without_its_official_score() -> None:
    """With ``prune_static`` a rung whose chosen screen's greedy choices are one action is not scored: the trial is
    PRUNED with the cause, the rung keeps its net and screens but has no score, nothing is reported, no frames are
    spent past the screens, and its cost observation prices the screens without the evaluation."""
    from autotune.search.driver import _observations
    from autotune.search.records import kept_rungs

    reports: list[int] = []

    def climb(prune: bool) -> Any:
        task = TrialTask(number=0, config=TINY.to_mapping(), seed=3, rungs=(400, 1200), prune_static=prune,
                         epsilon_test_grid=HALVING_GRID, epsilon_test_screen_runs=(20, 50))  # fmt: skip
        return run_trial(task, lambda step, *a: bool(reports.append(step)))  # type: ignore[func-returns-value]

    outcome = climb(True)  # this tiny net turns right at every greedy decision (tests/test_search_ladder.py)
    assert outcome.state == PRUNED and outcome.attrs[keys.STATIC_POLICY] is True and reports == []
    (rung,) = outcome.attrs[keys.RUNGS]
    greedy = rung[keys.GREEDY_CHOICES]
    assert greedy[:4] == [0, 0, 0, 0] and greedy[4] > 0
    screens = rung[keys.EPSILON_SCREEN]
    chosen = choose_epsilon(screens)
    assert outcome.cause == (
        f"static policy at rung 0 (400 iterations): the net chose right in 100.00% of its {greedy[4]:,} greedy "
        f"decisions of the first 50 official runs at its ε_test {screens[chosen][0]:g} (not scored officially)"
    )
    assert rung[keys.SCORE] is None and keys.EPSILON_TEST not in rung and set(outcome.rung_nets) == {400}
    assert sorted(s[3] for s in screens) == [20, 20, 20, 50, 50]
    net = train(rung_config(TINY, 400), 3, quick_eval=False).convnet()
    first = np.zeros(5, dtype=np.int64)
    at = rung_config(TINY, 400).replace(epsilon_test_time=screens[chosen][0])
    evaluate_official(net, at, runs=50, greedy_actions=first)
    assert greedy == first.tolist()  # the chosen screen's: the official evaluation's first 50 runs
    assert outcome.attrs[keys.FRAMES_SIMULATED] == rung[keys.FRAMES] + (5 * 20 + 2 * 30) * 2000
    assert kept_rungs({**outcome.attrs, keys.ARTIFACT_RUNG_NETS: {"400": "id"}}) == []
    trial = optuna.trial.create_trial(state=optuna.trial.TrialState.PRUNED, user_attrs=outcome.attrs)
    (obs,) = _observations(trial)
    config = rung_config(TINY, 400)
    want = features(config, screen=HALVING_GRID, screen_share=[s[3] / 500 for s in screens], carried=1.0)
    assert np.allclose(obs.features, want)
    assert want[FIXED] == 1.0 and want[CARS] == pytest.approx(features(config)[CARS] * 160 / 500)  # the screens alone
    scored = climb(False)  # without the key the net is scored officially as before
    assert scored.state == COMPLETE and scored.attrs[keys.RUNGS][0][keys.SCORE] is not None and reports == [1, 3]


def test_the_spec_key_its_refusals_and_round_trip() -> None:
    spec = parse_spec(_data(), source="eps.toml")
    assert spec.ladder_epsilon_grid == GRID and spec.ladder_epsilon_screen_runs == (50,)
    assert parse_spec(spec.to_dict(), source="eps.toml") == spec
    assert spec.to_dict()["ladder"]["epsilon_test_screen_runs"] == 50  # one stage: stored as before the halving
    halving = parse_spec(_data(epsilon_test_screen_runs=[20, 50]), source="eps.toml")
    assert (
        halving.ladder_epsilon_screen_runs == (20, 50) and parse_spec(halving.to_dict(), source="eps.toml") == halving
    )
    off = _data()
    del off["ladder"]["epsilon_test_grid"], off["ladder"]["epsilon_test_screen_runs"]
    plain = parse_spec(off, source="off.toml")
    assert plain.ladder_epsilon_grid == () and "epsilon_test_grid" not in plain.to_dict()["ladder"]
    unsorted = _data(epsilon_test_grid=[0.5, 0.0, 0.5, 0.25])
    del unsorted["ladder"]["epsilon_test_screen_runs"]
    assert parse_spec(unsorted, source="u.toml").ladder_epsilon_grid == (0.0, 0.25, 0.5)
    assert parse_spec(unsorted, source="u.toml").ladder_epsilon_screen_runs == EPSILON_SCREEN_RUNS == (50, 100)
    assert default_screen_runs(500) == (50, 100) and default_screen_runs(10) == (5, 10)
    assert default_screen_runs(1) == (1,)

    def refused(data: dict[str, Any], match: str) -> None:
        with pytest.raises(SpecError, match=match):
            parse_spec(data, source="bad.toml")

    searched = _data()
    searched["space"]["epsilon_test_time"] = {"low": 0.0, "high": 0.9}
    refused(
        searched,
        r"bad.toml: \[space\] epsilon_test_time: is set, but \[ladder\] epsilon_test_grid chooses "
        r"ε_test per net; remove epsilon_test_time from \[space\] or epsilon_test_grid from \[ladder\]",
    )
    shifted = _data()
    shifted["space"]["epsilon_test_time_shifted"] = {"low": 0.005, "high": 0.905, "log": True}
    refused(shifted, r"\[space\] epsilon_test_time_shifted: is set")
    fixed = _data()
    fixed["fixed"]["epsilon_test_time"] = 0.1
    refused(fixed, r"\[fixed\] epsilon_test_time: is set, but")
    refused(
        _data(epsilon_test_grid=[0.2]),
        r"\[ladder\] epsilon_test_grid: one value \(0.2\) is no choice; fix it "
        r"with \[fixed\] epsilon_test_time = 0.2",
    )
    refused(_data(epsilon_test_grid=[0.0, 1.5]), r"\[ladder\] epsilon_test_grid")
    refused(_data(epsilon_test_grid="0, 0.1"), r"\[ladder\] epsilon_test_grid: must be a list of ε_test values")
    refused(_data(epsilon_test_grid=[0.0, True]), r"must be a list of ε_test values")
    refused(_data(epsilon_test_screen_runs=501), r"\[ladder\] epsilon_test_screen_runs")
    refused(_data(epsilon_test_screen_runs=0), r"\[ladder\] epsilon_test_screen_runs")
    refused(_data(epsilon_test_screen_runs=[]), r"epsilon_test_screen_runs .*: an empty list screens nothing")
    refused(_data(epsilon_test_screen_runs=[50, 20]), r"\[50, 20\] must increase .*e.g. \[50, 100\]")
    refused(_data(epsilon_test_screen_runs=[50, 50]), r"must increase")
    refused(_data(epsilon_test_screen_runs=[50, 600]), r"600 is out of range; use 1–500")
    refused(_data(epsilon_test_screen_runs=[50, "100"]), r"must be an integer")
    refused(_data(epsilon_test_gird=[0.0]), r"epsilon_test_grid")  # unknown key: the nearest valid one named


def test_resuming_with_another_grid_is_refused(tmp_path: Path) -> None:
    """The grid changes what a trial's value measures: like a changed [space], a resume with another is refused."""
    spec = parse_spec(_data(), source="eps.toml").with_overrides(storage=str(tmp_path / "j.log"))
    Driver(spec, open_storage(spec.study.storage, spec.study.name)).open_study()
    other = parse_spec(_data(epsilon_test_grid=[0.0, 0.5]), source="eps2.toml")
    other = other.with_overrides(storage=str(tmp_path / "j.log"))
    with pytest.raises(SpecError, match=r"eps2.toml: \[ladder\] epsilon_test_grid: the study 'eps' was created"):
        Driver(other, open_storage(other.study.storage, other.study.name)).open_study()
    # the screens' runs may change (a study from before the halving resumes with it): same grid, same values' meaning
    halved = parse_spec(_data(epsilon_test_screen_runs=[20, 50]), source="eps3.toml")
    halved = halved.with_overrides(storage=str(tmp_path / "j.log"))
    study = Driver(halved, open_storage(halved.study.storage, halved.study.name)).open_study()
    assert study.user_attrs[keys.STUDY_SPEC]["ladder"]["epsilon_test_screen_runs"] == [20, 50]


def test_sampled_trials_screen_and_race_runs_keep_their_own_epsilon(tmp_path: Path) -> None:
    """The driver hands the grid to every sampled ladder trial, never to a race run: a configuration's fresh
    seeds are measured at the ε_test its selecting rung chose (``trained_rung_config``), or the race would
    re-pick ε_test on every seed."""
    spec = parse_spec(_data(), source="eps.toml").with_overrides(storage=str(tmp_path / "j.log"))
    driver = Driver(spec, open_storage(spec.study.storage, spec.study.name))
    study = driver.open_study()
    driver.pool = FakePool()
    driver._t0 = time.perf_counter()  # noqa: SLF001
    assert driver._launch_next(0)  # noqa: SLF001
    task = driver.pool.tasks[0]
    assert task.epsilon_test_grid == GRID and task.epsilon_test_screen_runs == (50,)
    study.tell(study.trials[0].number, state=optuna.trial.TrialState.FAIL)

    dists = distributions(spec)
    cfg = TINY.replace(epsilon_test_time=0.2)  # the trial's config: its top rung chose 0.2
    rungs = [{keys.BUDGET: 400, keys.SCORE: 74.0, keys.EPSILON_TEST: 0.6},
             {keys.BUDGET: 1200, keys.SCORE: 70.0, keys.EPSILON_TEST: 0.2}]  # fmt: skip
    study.add_trial(optuna.trial.create_trial(
        params=space.encode(spec, cfg), distributions=dists, value=70.0, state=optuna.trial.TrialState.COMPLETE,
        user_attrs={keys.CONFIG: cfg.to_mapping(), keys.SEED: 1, keys.OFFICIAL_PROTOCOL: "v2-official",
                    keys.RUNGS: rungs, keys.ARTIFACT_RUNG_NETS: {"400": "a", "1200": "b"}},
    ))  # fmt: skip
    trial = study.trials[-1]
    score, budget, raced = race_entry(trial, 400)  # type: ignore[misc]
    assert (score, budget) == (74.0, 400)
    assert TrainConfig.from_mapping(raced).epsilon_test_time == 0.6  # what the 400 rung was scored with
    assert race_entry(trial, 1200)[2] == cfg.to_mapping()  # type: ignore[index]
    assert TrainConfig.from_mapping(driver._raced_config(trial)).epsilon_test_time == 0.2  # noqa: SLF001

    driver.cost_model = forward_cost_model(1e-9)
    driver._fitted_on = 10**6  # noqa: SLF001
    driver.pool = FakePool()
    driver._race_state()  # noqa: SLF001
    assert driver._launch_race(0)  # noqa: SLF001
    (run,) = [t for t in study.trials if keys.RACE_OF in t.user_attrs]
    raced = TrainConfig.from_mapping(driver.pool.tasks[0].config)
    assert driver.pool.tasks[0].epsilon_test_grid == ()  # the race measures the configuration, never re-chooses
    assert (raced.train_iterations, raced.epsilon_test_time) == (1200, 0.2)  # the top the gate priced, its choice
    assert run.user_attrs[keys.CONFIG] == driver.pool.tasks[0].config


def test_the_cost_model_prices_the_screens(tmp_path: Path) -> None:
    """Each screen adds its share of the runs' work, less the chosen screen's (the official evaluation carries it
    on) and no set-up (the screens share the evaluation's); the driver's model screens sampled rungs at the spec's
    grid, a race run (``screened=False``) not; a refit keeps the grid."""
    config = TINY.replace(epsilon_test_time=0.0)
    plain = features(config)
    screened = features(config, screen=(0.0, 0.5), screen_share=0.2)
    assert screened[FIXED] == plain[FIXED]  # one set-up
    assert screened[CARS] == pytest.approx(plain[CARS] * 1.2)  # cars: 0.8 + 2 × 0.2 evaluations' worth
    assert screened[FILLS] == pytest.approx(plain[FILLS] * (0.8 + 0.2 * (1.0 + 0.5)))  # input fills at each ε_test
    assert np.array_equal(screened[:TRAINING], plain[:TRAINING])  # training work unchanged
    model = CostModel.prior().screening((0.0, 0.5), 0.2)
    assert model.predict(config) > model.predict(config, screened=False) == CostModel.prior().predict(config)
    assert model.fit([]).screen == (0.0, 0.5) and model.fit([]).screen_share == 0.2
    driver = Driver(parse_spec(_data(), source="eps.toml"), open_storage(str(tmp_path / "j.log"), "eps"))
    model = driver._prior_model()  # noqa: SLF001
    assert model.screen == GRID and model.screen_share == 50 / 500 and model.screen_carried == 50 / 500
    # a halving: per value on average (3 × 20 + 1 × 30 of 500 runs over 3 values), the chosen one on 50
    spec = parse_spec(_data(epsilon_test_screen_runs=[20, 50]), source="eps.toml")
    assert spec.ladder_epsilon_screen_share == pytest.approx(90 / 3 / 500) and spec.ladder_epsilon_carried_share == 0.1
    halving = Driver(spec, open_storage(str(tmp_path / "k.log"), "eps"))._prior_model()  # noqa: SLF001
    assert halving.screen_carried == 0.1 and halving.screen_share == pytest.approx(0.06)
    expected = features(config, screen=GRID, screen_share=0.06, carried=0.1)  # which value goes on is not known
    assert halving.predict_features(expected) == pytest.approx(halving.predict(config))
    assert expected[CARS] == pytest.approx(features(config, screen=GRID, screen_share=[0.04, 0.04, 0.1])[CARS])  # runs
    assert features(config, screen=(0.0, 0.5), screen_share=[0.1, 0.2])[CARS] == pytest.approx(plain[CARS] * 1.1)


def test_a_spec_without_the_grid_searches_epsilon_test_as_before(tmp_path: Path) -> None:
    """Without the key ε_test stays a searched setting: no screens are priced or run, and the trial trains and is
    scored at the ε_test it drew."""
    data = _data()
    del data["ladder"]["epsilon_test_grid"], data["ladder"]["epsilon_test_screen_runs"]
    data["space"]["epsilon_test_time"] = {"low": 0.0, "high": 0.9}
    spec = parse_spec(data, source="plain.toml").with_overrides(storage=str(tmp_path / "j.log"))
    assert spec.ladder_epsilon_grid == () and spec.ladder_epsilon_screen_share == 0.0
    driver = Driver(spec, open_storage(spec.study.storage, spec.study.name))
    assert driver._prior_model().screen == ()  # noqa: SLF001
    study = driver.open_study()
    driver.pool = FakePool()
    driver._t0 = time.perf_counter()  # noqa: SLF001
    assert driver._launch_next(0)  # noqa: SLF001
    task = driver.pool.tasks[0]
    assert task.epsilon_test_grid == () and task.rungs
    drawn = study.trials[0].params["epsilon_test_time"]
    assert TrainConfig.from_mapping(task.config).epsilon_test_time == drawn
