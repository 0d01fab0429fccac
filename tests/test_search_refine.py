"""Refinement (``[study] refine_share``): runs that train on from the study's best single net.

The pure rules (the parent, the config, the seed), the spec keys, and the driver on a journal study: which net
each run starts from, on which share of the workers, after what, and that the runs use no budget and never reach
the sampler or the race.
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from pathlib import Path
from typing import Any

import optuna
import pytest

from autotune.convnet.netjson import dumps_net
from autotune.learner.training import train
from autotune.search import keys, racing, refine
from autotune.search.driver import Driver, StudyCounts, trial_seed
from autotune.search.history import DrawsView
from autotune.search.ladder import trained_rung_config
from autotune.search.records import RecordError, best_net, lineage, read_study
from autotune.search.spec import REFINE_ITERATIONS, REFINE_LEARNING_RATE, REFINE_RUNS, SpecError
from tests.conftest import FakePool
from tests.test_search_ladder import TINY, _driver_on_journal, _spec

COMPLETE, PRUNED = optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED


def test_a_refinement_config_is_its_parents_with_a_short_schedule_and_a_smaller_rate() -> None:
    parent = TINY.replace(learning_rate=0.01, epsilon_min=0.02, epsilon_test_time=0.05)
    c = refine.refine_config(parent, 20_000, 0.1)
    assert c.train_iterations == 20_000 and c.learning_rate == pytest.approx(0.001)
    assert c.learning_steps_total == refine.EXPLORE_DECISIONS and c.learning_steps_burnin == refine.BURNIN
    assert c.start_learn_threshold == min(refine.START_LEARN, parent.start_learn_threshold)  # 100: its own
    same = {f.name for f in dataclasses.fields(c)} - {
        "train_iterations", "learning_rate", "learning_steps_total", "learning_steps_burnin", "start_learn_threshold",
    }  # fmt: skip
    assert all(getattr(c, name) == getattr(parent, name) for name in same)  # inputs, layers, ε_min, ε_test, …
    late = parent.replace(learning_steps_burnin=50, start_learn_threshold=400, experience_size=1000)
    c = refine.refine_config(late, 5_000, 1.0)
    assert c.learning_steps_burnin == 50 and c.start_learn_threshold == 400 and c.learning_rate == 0.01


def test_the_parent_is_the_best_single_net_refinement_runs_included() -> None:
    rung: dict[str, Any] = {keys.OFFICIAL_PROTOCOL: "v2-official", keys.RUNGS: [{keys.BUDGET: 400, keys.SCORE: 74.8}],
            keys.ARTIFACT_RUNG_NETS: {"400": "id"}}  # fmt: skip
    net = {keys.ARTIFACT_NET_JSON: "id"}
    assert refine.choose_parent([], [], 0) is None
    assert refine.choose_parent([(0, net, 74.0, True), (1, rung, None, False)], [], 0) == refine.Parent(1, 400, 74.8)
    refined: dict[str, Any] = {keys.REFINE_OF: {"trial": 1, "budget": 400, "score": 74.8}, **net}
    trials: list[tuple[int, dict[str, Any], float | None, bool]] = [
        (0, net, 74.0, True), (1, rung, None, False), (2, refined, 75.1, True),
    ]  # fmt: skip
    assert refine.choose_parent(trials, [], 0) == refine.Parent(2, None, 75.1)
    assert refine.choose_parent([(0, net, 74.0, False)], [], 0) is None  # a value only counts when COMPLETE
    copied = {keys.COPIED_FROM: "other:3"}  # another study's history: no net stored here
    assert refine.choose_parent([(0, net, 74.0, True), (1, copied, 76.0, True)], [], 0) == refine.Parent(0, None, 74.0)
    parent = refine.Parent(1, 400, 74.8)
    assert refine.Parent.from_attr(parent.to_attr()) == parent


def test_once_the_best_net_had_its_runs_the_next_best_near_it_is_the_parent() -> None:
    def net(score: float) -> tuple[dict[str, Any], float, bool]:
        return {keys.ARTIFACT_NET_JSON: "id"}, score, True

    trials = [(i, *net(score)) for i, score in enumerate((74.0, 75.2, 74.9, 74.6, 75.2))]
    ranked = refine.ranked_parents(trials)
    assert [p.trial for p in ranked] == [1, 4, 2, 3, 0]  # ties: the earlier trial first
    of = [{"trial": 1, "budget": None, "score": 75.2}] * 2 + [None]
    assert refine.choose_parent(trials, [], 2) == refine.Parent(1, None, 75.2)
    assert refine.choose_parent(trials, of, 2) == refine.Parent(4, None, 75.2)
    assert refine.choose_parent(trials, of, 0) == refine.Parent(1, None, 75.2)  # no bound: always the best
    assert refine.choose_parent(trials, of, 3) == refine.Parent(1, None, 75.2)
    spent = of + [{"trial": 4, "budget": None, "score": 75.2}] * 2 + [{"trial": 2, "budget": None, "score": 74.9}] * 2
    assert refine.choose_parent(trials, spent, 2) is None  # 74.6 is more than PARENT_SPAN below the best
    assert 75.2 - 74.6 > refine.PARENT_SPAN >= 75.2 - 74.9
    assert refine.choose_parent([], [], 2) is None
    # a refinement run is a parent only when it beat its own: else that parent is the better start
    worse = {keys.ARTIFACT_NET_JSON: "id", keys.REFINE_OF: {"trial": 1, "budget": None, "score": 75.2}}
    better = {keys.ARTIFACT_NET_JSON: "id", keys.REFINE_OF: {"trial": 2, "budget": None, "score": 74.9}}
    climbed = refine.ranked_parents([*trials, (5, worse, 75.1, True), (6, better, 75.0, True), (7, worse, None, False)])
    assert [p.trial for p in climbed] == [1, 4, 6, 2, 3, 0]
    # a COMPLETE ladder trial's top rung is the net of its value: one parent
    ladder = {keys.ARTIFACT_NET_JSON: "id", keys.OFFICIAL_PROTOCOL: "v2-official",
              keys.RUNGS: [{keys.BUDGET: 100, keys.SCORE: 74.5}, {keys.BUDGET: 300, keys.SCORE: 75.0}],
              keys.ARTIFACT_RUNG_NETS: {"100": "a", "300": "b"}}  # fmt: skip
    assert refine.ranked_parents([(0, ladder, 75.0, True)]) == [refine.Parent(0, None, 75.0),
                                                               refine.Parent(0, 100, 74.5)]  # fmt: skip
    assert refine.ranked_parents([(0, ladder, None, False)]) == [refine.Parent(0, 300, 75.0),
                                                                refine.Parent(0, 100, 74.5)]  # fmt: skip


def test_a_fresh_net_below_the_race_floor_is_no_parent() -> None:
    """``min_budget`` (the driver's ``race_min_budget``): a rung below it screens; its best scores are often luck.
    A trial's value counts at its top rung's budget; a refinement run or soup of an eligible net is eligible."""
    ladder = {keys.ARTIFACT_NET_JSON: "id", keys.OFFICIAL_PROTOCOL: "v2-official",
              keys.RUNGS: [{keys.BUDGET: 100, keys.SCORE: 75.5}, {keys.BUDGET: 300, keys.SCORE: 74.0}],
              keys.ARTIFACT_RUNG_NETS: {"100": "a", "300": "b"}}  # fmt: skip
    short = {keys.ARTIFACT_NET_JSON: "id", keys.RUNGS: [{keys.BUDGET: 100, keys.SCORE: 76.0}]}
    child = {keys.ARTIFACT_NET_JSON: "id", keys.REFINE_OF: {"trial": 0, "budget": None, "score": 74.0}}
    trials: list[tuple[int, dict[str, Any], float | None, bool]] = [
        (0, ladder, 74.0, True), (1, short, 76.0, True), (2, child, 74.2, True),
    ]  # fmt: skip
    assert [(p.trial, p.budget) for p in refine.ranked_parents(trials)] == [(1, None), (0, 100), (2, None), (0, None)]
    assert [(p.trial, p.budget) for p in refine.ranked_parents(trials, 300)] == [(2, None), (0, None)]
    assert refine.choose_parent(trials, [], 0, min_budget=300) == refine.Parent(2, None, 74.2)
    plain = {keys.ARTIFACT_NET_JSON: "id"}  # no ladder: nothing to measure it by
    assert refine.ranked_parents([(0, plain, 70.0, True)], 300) == [refine.Parent(0, None, 70.0)]


def test_refinement_seeds_are_their_own() -> None:
    seeds = [refine.refine_seed(0, i) for i in range(50)]
    assert len(set(seeds)) == 50 and seeds == [refine.refine_seed(0, i) for i in range(50)]
    others = {trial_seed(0, i) for i in range(50)} | {racing.race_seed(0, i) for i in range(50)}
    assert not others & set(seeds)
    assert refine.refine_seed(1, 0) != seeds[0]


def test_refine_keys_are_checked() -> None:
    st = _spec().study
    assert (st.refine_share, st.refine_iterations, st.refine_learning_rate) == (0.0, REFINE_ITERATIONS,
                                                                                 REFINE_LEARNING_RATE)  # fmt: skip
    st = _spec(refine_share=0.5, refine_iterations=5000, refine_learning_rate=0.5).study
    assert (st.refine_share, st.refine_iterations, st.refine_learning_rate) == (0.5, 5000, 0.5)
    with pytest.raises(SpecError, match=r"\[study\] refine_share: 2 is out of range; use \[0, 1\]"):
        _spec(refine_share=2)
    with pytest.raises(SpecError, match=r"\[study\] refine_iterations: .*refine_share = 0; set refine_share"):
        _spec(refine_iterations=5000)
    with pytest.raises(SpecError, match=r"\[study\] refine_learning_rate: must be above 0, got 0.0"):
        _spec(refine_share=0.5, refine_learning_rate=0.0)
    with pytest.raises(SpecError, match=r"refine_iterations: 10 is out of range"):
        _spec(refine_share=0.5, refine_iterations=10)
    with pytest.raises(SpecError, match=r"refine_shares.*did you mean 'refine_share'"):
        _spec(refine_shares=0.5)
    assert st.refine_runs == REFINE_RUNS and _spec(refine_share=0.5, refine_runs=0).study.refine_runs == 0
    with pytest.raises(SpecError, match=r"\[study\] refine_runs: -1 is out of range"):
        _spec(refine_share=0.5, refine_runs=-1)
    with pytest.raises(SpecError, match=r"\[study\] refine_runs: .*refine_share = 0"):
        _spec(refine_runs=8)
    assert st.refine_start == 0.0 and _spec(refine_share=0.5, refine_start=0.25).study.refine_start == 0.25
    with pytest.raises(SpecError, match=r"\[study\] refine_start: 1 is out of range; use \[0, 0.99\]"):
        _spec(refine_share=0.5, refine_start=1)
    with pytest.raises(SpecError, match=r"\[study\] refine_start: .*refine_share = 0"):
        _spec(refine_start=0.25)


def test_a_run_counts_for_its_parents_trial_and_rung() -> None:
    nets = [(4, {keys.ARTIFACT_NET_JSON: "id", keys.OFFICIAL_PROTOCOL: "v2-official",
                 keys.RUNGS: [{keys.BUDGET: 90_000, keys.SCORE: 75.0}], keys.ARTIFACT_RUNG_NETS: {"90000": "a"}},
             None, False)]  # fmt: skip
    ofs = [None, {"trial": 4, "budget": 90_000, "score": 75.0}, {"trial": 4, "budget": None, "score": 74.0},
           {"trial": 4, "budget": 90_000, "score": 75.0}, {"trial": 7, "budget": 90_000, "score": 75.0}]  # fmt: skip
    assert refine.choose_parent(nets, ofs, 3) == refine.Parent(4, 90_000, 75.0)  # 2 of its 3 runs
    assert refine.choose_parent(nets, ofs, 2) is None


def _net_text(seed: int) -> str:
    return dumps_net(train(TINY.replace(train_iterations=0), seed=seed, quick_eval=False).convnet())


def _upload(storages: Any, study: optuna.Study, text: str) -> str:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "net.json"
        path.write_text(text)
        return optuna.artifacts.upload_artifact(artifact_store=storages.artifacts, file_path=str(path),
                                                study_or_trial=study)  # fmt: skip


def test_the_driver_refines_the_best_net_on_its_share_of_the_workers(tmp_path: Path) -> None:
    """``_launch_refine``: each run trains on from the best single net stored when it starts (its net sent with the
    task, its config ``refine_config`` of what that net trained with, its seed the study's next refinement seed); on
    ``refine_share`` of the workers (at least one, never all); after the queue, not in the race's rounds, not once
    the trial budget is spent or when one run would not fit the time left; using no budget, never shown to the
    sampler."""
    spec = _spec(race_configs=2, race_seeds=1, n_trials=20, timeout_s=3600, refine_share=0.5,
                 refine_iterations=3000).with_overrides(storage=str(tmp_path / "j.log"), workers=2)  # fmt: skip
    driver, study, storages, dists, params = _driver_on_journal(spec)
    texts = [_net_text(seed) for seed in range(4)]
    chosen = TINY.replace(epsilon_test_time=0.05)

    def add(value: float | None, state: Any = COMPLETE, net: str | None = None, **attrs: Any) -> int:
        if net is not None:  # its net, as the driver stores a finished trial's (or its kept rung's)
            artifact = _upload(storages, study, net)
            rung = keys.RUNGS in attrs
            kept = {str(r[keys.BUDGET]): artifact for r in attrs.get(keys.RUNGS, ())}
            attrs[keys.ARTIFACT_RUNG_NETS if rung else keys.ARTIFACT_NET_JSON] = kept if rung else artifact
        study.add_trial(optuna.trial.create_trial(params=params, distributions=dists, value=value, state=state,
                                                  user_attrs={keys.CONFIG: chosen.to_mapping(), **attrs}))  # fmt: skip
        return len(study.trials) - 1

    driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001
    assert not driver._launch_refine(0)  # noqa: SLF001 - no net scored yet
    add(74.0, net=texts[0])
    add(73.0)
    assert driver._launch_refine(0)  # noqa: SLF001
    run = study.trials[-1]
    assert run.user_attrs[keys.REFINE_OF] == {"trial": 0, "budget": None, "score": 74.0}
    assert run.user_attrs[keys.CONFIG] == refine.refine_config(chosen, 3000, 0.1).to_mapping()
    assert run.user_attrs[keys.SEED] == refine.refine_seed(spec.study.seed, 0)
    task = driver.pool.tasks[-1]
    assert task.init_net == texts[0] and task.rungs == (3000,) and task.epsilon_test_grid == ()
    assert not task.prune_static and task.min_weight_change == 0.0 and driver._running[0].silent  # noqa: SLF001
    assert not driver._launch_refine(1)  # noqa: SLF001 - half of the 2 workers: one such run at a time
    # it beats its parent: the next run trains on from it (the runs climb)
    running = driver._running.pop(0).trial  # noqa: SLF001
    running.set_user_attr(keys.ARTIFACT_NET_JSON, _upload(storages, study, texts[1]))
    study.tell(running, 74.6)
    assert driver._launch_refine(0)  # noqa: SLF001
    nxt = study.trials[-1]
    assert nxt.user_attrs[keys.REFINE_OF] == {"trial": 2, "budget": None, "score": 74.6}
    assert nxt.user_attrs[keys.SEED] == refine.refine_seed(spec.study.seed, 1)
    # at its parent's rate, already a tenth of the fresh training's: not a hundredth
    assert nxt.user_attrs[keys.CONFIG] == refine.refine_config(chosen, 3000, 0.1).to_mapping()
    assert driver.pool.tasks[-1].init_net == texts[1]
    study.tell(driver._running.pop(0).trial, 73.9)  # noqa: SLF001 - worse: the parent stays
    # a kept rung below the race's floor (1200, the ladder's top here) is no parent, however it scored
    low = [{keys.BUDGET: 400, keys.SCORE: 76.0}]
    add(None, PRUNED, net=texts[3], **{keys.OFFICIAL_PROTOCOL: "v2-official", keys.RUNGS: low})
    # a kept rung that beats every value is the next parent, at the settings that rung trained with
    rungs = [{keys.BUDGET: 1200, keys.SCORE: 75.2, keys.EPSILON_TEST: 0.02}]
    kept = add(None, PRUNED, net=texts[2], **{keys.OFFICIAL_PROTOCOL: "v2-official", keys.RUNGS: rungs})
    assert driver._launch_refine(0)  # noqa: SLF001
    run = study.trials[-1]
    assert run.user_attrs[keys.REFINE_OF] == {"trial": kept, "budget": 1200, "score": 75.2}
    expected = refine.refine_config(trained_rung_config(chosen, 1200, rungs), 3000, 0.1)
    assert run.user_attrs[keys.CONFIG] == expected.to_mapping() and expected.epsilon_test_time == 0.02
    assert driver.pool.tasks[-1].init_net == texts[2]
    study.tell(driver._running.pop(0).trial, 75.0)  # noqa: SLF001
    bounded = Driver(dataclasses.replace(spec, study=dataclasses.replace(spec.study, refine_runs=1)), storages)
    bounded.open_study()
    bounded._t0, bounded.pool = time.perf_counter(), FakePool()  # noqa: SLF001
    assert not bounded._launch_refine(0)  # noqa: SLF001 - the nets within PARENT_SPAN had their run: the search
    # the search's share of the budget first: of the time, else of the trials
    late = Driver(dataclasses.replace(spec, study=dataclasses.replace(spec.study, refine_start=0.25)), storages)
    late.open_study()
    late._t0, late.pool = time.perf_counter(), FakePool()  # noqa: SLF001
    assert not late._launch_refine(0)  # noqa: SLF001
    late._t0 -= 0.25 * 3600  # noqa: SLF001
    assert late._refine_open()  # noqa: SLF001
    untimed = dataclasses.replace(spec.study, refine_start=0.25, timeout_s=None, n_trials=12)
    late = Driver(dataclasses.replace(spec, study=untimed), storages)
    late.open_study()
    assert late.counts.started == 4 and late._refine_open()  # noqa: SLF001 - 4 of the 12 trials started
    late.spec = dataclasses.replace(spec, study=dataclasses.replace(untimed, n_trials=17))
    assert not late._refine_open()  # noqa: SLF001
    # a crowd-prior study opens once its crowd settings are enqueued (the queue check then waits for each to start)
    study.set_user_attr(f"{keys.WARM_STARTED}crowd", 3)
    assert late._refine_open()  # noqa: SLF001
    study.set_user_attr(f"{keys.WARM_STARTED}crowd", 0)  # none enqueued (none fit the space): refine_start holds
    assert not late._refine_open()  # noqa: SLF001
    # no budget used, never shown to the sampler, never a race entrant
    driver._refresh_counts()  # noqa: SLF001
    refined = [t for t in study.trials if keys.REFINE_OF in t.user_attrs]
    assert driver.counts.started == 4 and driver.counts.refine_runs == len(refined) == 3
    shown = DrawsView(study).get_trials(deepcopy=False)
    assert not any(keys.REFINE_OF in t.user_attrs for t in shown) and len(shown) == 4
    assert not {t.number for t in refined} & set(driver._race_field()[0])  # noqa: SLF001
    # the queue first; a spent budget, a single worker, share 0, the race's rounds, no time: none
    study.enqueue_trial(params)
    assert not driver._launch_refine(0)  # noqa: SLF001
    assert driver._launch_next(0)  # noqa: SLF001
    study.tell(driver._running.pop(0).trial, 70.0)  # noqa: SLF001
    for other in (spec.with_overrides(n_trials=4), spec.with_overrides(workers=1),
                  dataclasses.replace(spec, study=dataclasses.replace(spec.study, refine_share=0.0))):  # fmt: skip
        d = Driver(other, storages)
        d.open_study()
        d._t0, d.pool = time.perf_counter(), FakePool()  # noqa: SLF001
        assert not d._launch_refine(0)  # noqa: SLF001
    driver._t0 = time.perf_counter() - 0.8 * 3600  # noqa: SLF001 - the race window: its rounds come first
    assert not driver._launch_refine(0)  # noqa: SLF001
    driver._race_over = True  # noqa: SLF001 - the race has run: the time left is the search's and refinement's
    assert driver._launch_refine(0)  # noqa: SLF001
    study.tell(driver._running.pop(0).trial, 74.0)  # noqa: SLF001
    driver._t0 = time.perf_counter() - 3600 + 0.01  # noqa: SLF001 - no run fits the time left
    assert not driver._launch_refine(0)  # noqa: SLF001


def test_a_refined_best_net_names_its_lineage_and_a_missing_parent_net_is_one_line(tmp_path: Path) -> None:
    spec = _spec(refine_share=0.5).with_overrides(storage=str(tmp_path / "j.log"), workers=2)
    driver, study, storages, dists, params = _driver_on_journal(spec)
    refined = {"trial": 0, "budget": 400, "score": 74.2}
    for value, attrs in ((74.0, {}), (74.6, {keys.REFINE_OF: refined}),
                         (75.1, {keys.REFINE_OF: {"trial": 1, "budget": None, "score": 74.6}})):  # fmt: skip
        study.add_trial(optuna.trial.create_trial(params=params, distributions=dists, value=value, state=COMPLETE,
                                                  user_attrs={keys.CONFIG: TINY.to_mapping(), **attrs}))  # fmt: skip
    record = read_study(storages, "lad")
    net = best_net(record)
    assert net is not None and net["trial"] == 2
    assert net["lineage"] == [{"trial": 1, "budget": None, "score": 74.6}, refined]
    assert lineage(record, 0) == []
    driver._t0, driver.pool = time.perf_counter(), FakePool()  # noqa: SLF001
    assert not driver._launch_refine(0)  # noqa: SLF001 - no trial stores its net: nothing to train on from
    study.add_trial(optuna.trial.create_trial(params=params, distributions=dists, value=75.3, state=COMPLETE,
                                              user_attrs={keys.CONFIG: TINY.to_mapping(),
                                                          keys.ARTIFACT_NET_JSON: "gone"}))  # fmt: skip
    assert driver._launch_refine(0)  # noqa: SLF001 - its net is not in the artifact store: the run fails, saying so
    run = study.trials[-1]
    assert run.state == optuna.trial.TrialState.FAIL and not driver.pool.tasks
    assert run.user_attrs[keys.CAUSE].startswith("refinement: trial 3: artifact user attr artifact_net_json=gone "
                                                 "not found in ")  # fmt: skip
    with pytest.raises(RecordError, match="trial 0: no trained network stored"):
        from autotune.search.records import parent_net

        parent_net(storages, record, refined)


def test_refinement_runs_use_no_budget() -> None:
    counts = StudyCounts(budget=5, complete=9, pruned=2, retries=1, race_runs=2, refine_runs=4)
    assert counts.finished == 4
    assert counts.reruns == "1 retries, 2 race runs, 4 refinement runs"
