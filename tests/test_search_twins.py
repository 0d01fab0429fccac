"""Linear twins (``[study] linear_twins``): the best configuration retried without hidden layers per method and rate.

The twins and the parent as pure rules, the spec key and its checks against the space, and the driver on a journal
study: which trial it twins, what a twin records and trains, once per parent."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import optuna
import pytest

from autotune import TrainConfig
from autotune.search import keys, space, twins
from autotune.search.cost import CostModel
from autotune.search.driver import Driver
from autotune.search.driver import next_side_entry as driver_next
from autotune.search.gate import distributions
from autotune.search.objective import TrialOutcome
from autotune.search.spec import LR_X_INPUTS, Dimension, SpecError, StudySpec, parse_spec
from autotune.search.storage import open_storage
from autotune.search.workers import Event
from tests.conftest import FakePool

COMPLETE = optuna.trial.TrialState.COMPLETE
PRUNED = optuna.trial.TrialState.PRUNED
HIDDEN = TrainConfig(
    ruleset="v2", lanes_side=1, patches_ahead=3, other_agents=1, train_iterations=1200, temporal_window=0,
    experience_size=500, start_learn_threshold=100, learning_steps_burnin=120, learning_steps_total=600,
    layers="fc:4:relu|fc:3:tanh", batch_size=8, learning_rate=0.001,
)  # fmt: skip
RATES = {"adagrad": [3.0, 10.0], "sgd": [0.03]}


def _data(**study: Any) -> dict[str, Any]:
    return {
        "study": {"name": "twins", "n_trials": 50, "timeout_s": 3600, "seed": 0, **study},
        "ladder": {"rungs": [400, 1200]},
        "fixed": {"otherAgents": 1, "temporal_window": 0, "experience_size": 500, "batch_size": 8},
        "space": {
            "lanes_side": {"low": 0, "high": 2}, "patches_ahead": {"low": 1, "high": 4},
            "learning_steps_burnin_fraction": {"low": 0.01, "high": 0.2, "log": True},
            LR_X_INPUTS: {"low": 1e-4, "high": 10.0, "log": True},
            "method": {"choices": ["sgd", "adagrad", "adadelta"]},
            "n_layers": {"low": 0, "high": 2}, "neurons": {"low": 2, "high": 8},
            "activation": {"choices": ["relu", "tanh"]},
        },
    }  # fmt: skip


def _spec(**study: Any) -> StudySpec:
    return parse_spec(_data(**study), source="twins.toml")


# -- the pure rules ---------------------------------------------------------------------------


def test_twins_are_the_params_without_hidden_layers_per_method_and_rate() -> None:
    params = {"n_layers": 2, "neurons_0": 4, "activation_0": "relu", "method": "sgd", LR_X_INPUTS: 0.1,
              "lanes_side": 1, "patches_ahead": 3}  # fmt: skip
    made = twins.twins(params, tuple(RATES.items()))
    assert [(t["method"], t[LR_X_INPUTS]) for t in made] == [("adagrad", 3.0), ("adagrad", 10.0), ("sgd", 0.03)]
    for t in made:  # the view and the unused layout keep their values: only the layer count, method and rate move
        assert t["n_layers"] == 0 and {k: v for k, v in t.items() if k not in ("n_layers", "method", LR_X_INPUTS)} == {
            k: v for k, v in params.items() if k not in ("n_layers", "method", LR_X_INPUTS)}  # fmt: skip
    linear = {**params, "n_layers": 0, "method": "adagrad", LR_X_INPUTS: 3.0}
    made = twins.twins(linear, tuple(RATES.items()))  # a linear parent is not its own twin
    assert [(t["method"], t[LR_X_INPUTS]) for t in made] == [("adagrad", 10.0), ("sgd", 0.03)]


def _frozen(number: int, value: float | None, n_layers: int = 1, **attrs: Any) -> optuna.trial.FrozenTrial:
    t = optuna.trial.create_trial(
        params={"n_layers": n_layers}, distributions={"n_layers": optuna.distributions.IntDistribution(0, 2)},
        value=value, state=COMPLETE if value is not None else PRUNED, user_attrs=attrs,
    )  # fmt: skip
    t.number = number
    return t


def test_the_parent_is_the_best_first_measure_of_a_configuration() -> None:
    score = lambda t: t.value  # noqa: E731
    assert twins.parent([], score) is None
    trials = [_frozen(0, 72.0), _frozen(1, 74.0), _frozen(2, 74.0), _frozen(3, None)]

    def number(trials: list[optuna.trial.FrozenTrial], score: Any = score) -> int | None:
        found = twins.parent(trials, score)
        return None if found is None else found.number

    assert number(trials) == 1  # the earlier on a tie; no score: no candidate
    for key in twins.TWIN_SKIP:  # a rerun, a soup, copied history or a twin is no parent, however good
        assert number([*trials, _frozen(4, 76.0, **{key: 0})]) == 1
    assert number([*trials, _frozen(4, 76.0, n_layers=0)]) == 4  # a linear one can be
    assert number(trials, lambda t: None if t.number == 1 else t.value) == 2


def test_the_parents_within_a_span_are_the_best_and_those_near_it_best_first() -> None:
    score = lambda t: t.value  # noqa: E731
    trials = [_frozen(0, 72.0), _frozen(1, 74.0), _frozen(2, 73.5), _frozen(3, None), _frozen(4, 73.0),
              _frozen(5, 75.0, **{keys.TWIN_OF: 1})]  # fmt: skip
    numbers = lambda span: [t.number for t in twins.parents(trials, score, span)]  # noqa: E731
    assert twins.parents([], score, 1.0) == [] and numbers(0.0) == [1]
    assert numbers(0.5) == [1, 2] and numbers(1.0) == [1, 2, 4] and numbers(2.0) == [1, 2, 4, 0]
    assert numbers(1.0) == numbers(1.0 + 1e-12)  # within: the bound itself is in


# -- the spec ---------------------------------------------------------------------------------


def test_linear_twins_are_checked_against_the_space() -> None:
    assert _spec().study.linear_twins == () and "linear_twins" not in _spec().to_dict()["study"]
    spec = _spec(linear_twins=RATES)
    assert spec.study.linear_twins == (("adagrad", (3.0, 10.0)), ("sgd", (0.03,)))
    assert spec.to_dict()["study"]["linear_twins"] == RATES and parse_spec(spec.to_dict(), source="twins.toml") == spec
    for bad, match in (
        ([3.0], r"\[study\] linear_twins: must be a table of trainer methods, got \[3.0\]; e.g. linear_twins ="),
        ({"adagrad": []}, r"linear_twins: adagrad: must be a non-empty list of positive learning rates per input"),
        ({"adagrad": [0.0]}, r"linear_twins: adagrad: must be a non-empty list"),
        ({"adagrad": [True]}, r"linear_twins: adagrad: must be a non-empty list"),
        ({"adagrad": [1.0, 1.0]}, r"linear_twins: adagrad names a rate twice"),
        ({"adagard": [1.0]}, r"linear_twins: 'adagard' is not among \[space\] method's choices.*adagrad"),
        ({"adagrad": [20.0]}, r"linear_twins: adagrad rate 20 is outside \[space\] learning_rate_x_inputs "
                              r"\(0.0001–10\)"),
    ):  # fmt: skip
        with pytest.raises(SpecError, match=match):
            _spec(linear_twins=bad)
    assert "linear_twin_span" not in spec.to_dict()["study"]  # 0 (each new best only) is left out, as stored before
    spread = _spec(linear_twins=RATES, linear_twin_span=1.0)
    assert spread.study.linear_twin_span == 1.0 and spread.to_dict()["study"]["linear_twin_span"] == 1.0
    assert parse_spec(spread.to_dict(), source="twins.toml") == spread
    with pytest.raises(SpecError, match=r"linear_twin_span: sets which configurations get linear twins, but "
                                        r"linear_twins is empty; set linear_twins"):  # fmt: skip
        _spec(linear_twin_span=1.0)
    with pytest.raises(SpecError, match=r"\[study\] linear_twin_span: -1 is out of range"):
        _spec(linear_twins=RATES, linear_twin_span=-1)
    data = _data(linear_twins=RATES)
    data["space"]["n_layers"] = {"low": 1, "high": 2}
    with pytest.raises(SpecError, match=r"linear_twins: .*n_layers does not reach 0; search n_layers = \{ low = 0"):
        parse_spec(data, source="x")
    data = _data(linear_twins=RATES)
    del data["space"][LR_X_INPUTS]
    data["space"]["learning_rate"] = {"low": 1e-5, "high": 0.1, "log": True}
    with pytest.raises(SpecError, match=r"linear_twins: its rates are per input, .*search learning_rate_x_inputs"):
        parse_spec(data, source="x")
    data = _data(linear_twins=RATES)
    del data["space"]["method"]
    with pytest.raises(SpecError, match=r"linear_twins: .*\[space\] does not search method"):
        parse_spec(data, source="x")


# -- the driver -------------------------------------------------------------------------------


def _driver(tmp_path: Path, **study: Any) -> tuple[Driver, optuna.Study, dict[str, Any]]:
    spec = _spec(linear_twins=RATES, **study).with_overrides(storage=str(tmp_path / "j.log"))
    driver = Driver(spec, open_storage(spec.study.storage, spec.study.name))
    study_ = driver.open_study()
    driver.pool, driver._t0 = FakePool(), time.perf_counter()  # noqa: SLF001
    return driver, study_, distributions(spec)


def _add(study: optuna.Study, dists: dict[str, Any], params: dict[str, Any], value: float | None,
         rungs: list[tuple[int, float]], **attrs: Any) -> int:  # fmt: skip
    config = space.to_config(_spec(), params, 1200 if value is not None else rungs[-1][0]).to_mapping()
    study.add_trial(optuna.trial.create_trial(
        params=params, distributions=dists, value=value, state=COMPLETE if value is not None else PRUNED,
        user_attrs={keys.CONFIG: config, keys.RUNGS: [{keys.BUDGET: b, keys.SCORE: s} for b, s in rungs], **attrs},
    ))  # fmt: skip
    return len(study.trials) - 1


def test_the_driver_enqueues_the_twins_of_each_new_best_configuration_once(tmp_path: Path) -> None:
    driver, study, dists = _driver(tmp_path)
    hidden = space.encode(driver.spec, HIDDEN)
    driver._enqueue_twins()  # noqa: SLF001 - no trial yet: nothing
    assert not study.trials
    _add(study, dists, {**hidden, "lanes_side": 0}, None, [(400, 76.0)])  # a 400-iteration screen: no parent
    driver._enqueue_twins()  # noqa: SLF001
    assert len(study.trials) == 1
    first = _add(study, dists, hidden, 73.0, [(400, 70.0), (1200, 73.0)], **{keys.LADDER_TOP: 1})
    driver._enqueue_twins()  # noqa: SLF001
    waiting = [t.system_attrs["fixed_params"] for t in study.get_trials(states=(optuna.trial.TrialState.WAITING,))]
    assert [(t["n_layers"], t["method"], t[LR_X_INPUTS]) for t in waiting] == [
        (0, "adagrad", 3.0), (0, "adagrad", 10.0), (0, "sgd", 0.03)]  # fmt: skip
    for t in study.get_trials(states=(optuna.trial.TrialState.WAITING,)):
        assert t.user_attrs == {keys.TWIN_OF: first, keys.LADDER_TOP: 1}
    for t in waiting:
        assert {k: v for k, v in t.items() if k not in ("n_layers", "method", LR_X_INPUTS)} == {
            k: v for k, v in hidden.items() if k not in ("n_layers", "method", LR_X_INPUTS)}  # fmt: skip
    driver._enqueue_twins()  # noqa: SLF001 - once per parent
    assert len(study.get_trials(states=(optuna.trial.TrialState.WAITING,))) == 3

    # the driver trains a twin once, at its parent's budget (no screening rung), its score kept from the pruner
    assert driver._launch_next(0)  # noqa: SLF001
    task = driver.pool.tasks[-1]
    assert task.config["layers"] == "" and task.config["method"] == "adagrad" and task.rungs == (1200,)
    assert task.config["train_iterations"] == 1200 and driver._running[0].silent  # noqa: SLF001
    twin = driver._running.pop(0).trial  # noqa: SLF001
    twin_number = twin.number
    # a better twin is no parent, and a finished trial (any state) triggers the check: nothing new
    rungs = [{keys.BUDGET: 400, keys.SCORE: 74.0}, {keys.BUDGET: 1200, keys.SCORE: 75.0}]
    driver._finish(twin, TrialOutcome(twin_number, "complete", 75.0, None, {  # noqa: SLF001
        keys.CONFIG: task.config, keys.RUNGS: rungs}))  # fmt: skip
    assert len(study.get_trials(states=(optuna.trial.TrialState.WAITING,))) == 2
    # a new best configuration with hidden layers: its twins, enqueued by the finish of any trial
    better = {**hidden, "patches_ahead": 4}
    second = _add(study, dists, better, 74.5, [(400, 76.0), (1200, 74.5)])  # its top: its twins at 1200
    assert driver._launch_next(0)  # noqa: SLF001 - the next twin, pruned at its first rung
    run = driver._running.pop(0).trial  # noqa: SLF001
    driver._finish(run, TrialOutcome(run.number, "pruned", None, "pruned", {  # noqa: SLF001
        keys.RUNGS: [{keys.BUDGET: 400, keys.SCORE: 60.0}]}))  # fmt: skip
    waiting_now = study.get_trials(states=(optuna.trial.TrialState.WAITING,))
    new = [t for t in waiting_now if t.user_attrs[keys.TWIN_OF] == second]
    assert [t.system_attrs["fixed_params"]["patches_ahead"] for t in new] == [4, 4, 4]
    assert len(waiting_now) == 1 + 3 and new[0].user_attrs[keys.LADDER_TOP] == 1


def test_with_a_span_the_driver_twins_each_configuration_near_the_best_once(tmp_path: Path) -> None:
    driver, study, dists = _driver(tmp_path, linear_twin_span=1.0)
    hidden = space.encode(driver.spec, HIDDEN)
    best = _add(study, dists, hidden, 74.0, [(1200, 74.0)])
    near = _add(study, dists, {**hidden, "patches_ahead": 4}, 73.2, [(1200, 73.2)])
    _add(study, dists, {**hidden, "patches_ahead": 2}, 72.9, [(1200, 72.9)])  # 1.1 below: not twinned
    driver._enqueue_twins()  # noqa: SLF001
    waiting = study.get_trials(states=(optuna.trial.TrialState.WAITING,))
    assert [t.user_attrs[keys.TWIN_OF] for t in waiting] == [best] * 3 + [near] * 3  # the best's first
    assert [t.system_attrs["fixed_params"]["patches_ahead"] for t in waiting[3:]] == [4, 4, 4]
    driver._enqueue_twins()  # noqa: SLF001 - once per parent
    assert len(study.get_trials(states=(optuna.trial.TrialState.WAITING,))) == 6
    late = _add(study, dists, {**hidden, "lanes_side": 2}, 73.5, [(1200, 73.5)])  # near the best later on
    driver._enqueue_twins()  # noqa: SLF001
    waiting = study.get_trials(states=(optuna.trial.TrialState.WAITING,))
    assert len(waiting) == 9 and {t.user_attrs[keys.TWIN_OF] for t in waiting[6:]} == {late}


def test_no_twins_without_the_key_or_in_the_race_window(tmp_path: Path) -> None:
    spec = _spec().with_overrides(storage=str(tmp_path / "j.log"))
    driver = Driver(spec, open_storage(spec.study.storage, spec.study.name))
    study = driver.open_study()
    driver._t0 = time.perf_counter()  # noqa: SLF001
    _add(study, distributions(spec), space.encode(spec, HIDDEN), 74.0, [(1200, 74.0)])
    driver._enqueue_twins()  # noqa: SLF001
    assert len(study.trials) == 1
    driver, study, dists = _driver(tmp_path / "race")
    _add(study, dists, space.encode(driver.spec, HIDDEN), 74.0, [(1200, 74.0)])
    driver._t0 = time.perf_counter() - 3600 * 0.8  # noqa: SLF001 - in the last quarter: the seed race's time
    driver._enqueue_twins()  # noqa: SLF001
    assert len(study.trials) == 1


def test_crowd_twins_are_checked_and_left_out_of_the_stored_spec_when_off() -> None:
    assert "crowd_twins" not in _spec(linear_twins=RATES).to_dict()["warm_start"]  # as stored before the key
    on = parse_spec({**_data(linear_twins=RATES), "warm_start": {"crowd": True, "crowd_twins": True}}, source="x")
    assert on.warm_start.crowd_twins and on.to_dict()["warm_start"]["crowd_twins"] is True
    with pytest.raises(SpecError, match=r"\[warm_start\] crowd_twins: .*linear_twins is empty"):
        parse_spec({**_data(), "warm_start": {"crowd_twins": True}}, source="x")
    with pytest.raises(SpecError, match=r"\[warm_start\] crowd_twins: must be true or false"):
        parse_spec({**_data(linear_twins=RATES), "warm_start": {"crowd_twins": 1}}, source="x")


@pytest.mark.parametrize("on", [True, False])
def test_a_linear_crowd_setting_gets_its_twins_at_the_ladders_top_whatever_its_own_score(
    tmp_path: Path, on: bool
) -> None:
    linear = {**space.encode(_spec(), HIDDEN), "n_layers": 0, "method": "adagrad", LR_X_INPUTS: 3.0}
    model = CostModel.prior()
    low, top = (model.predict(space.to_config(_spec(), linear, b)) for b in (400, 1200))
    data = {**_data(linear_twins=RATES, max_trial_cost_s=top + (low / 2)),  # the top alone fits, the ladder not
            "warm_start": {"crowd": True, "crowd_twins": on}}  # fmt: skip
    spec = parse_spec(data, source="x").with_overrides(storage=str(tmp_path / "j.log"))
    driver = Driver(spec, open_storage(spec.study.storage, spec.study.name))
    study = driver.open_study()
    driver.pool, driver._t0, driver.cost_model = FakePool(), time.perf_counter(), model  # noqa: SLF001
    dists = distributions(spec)
    linear = {**linear, LR_X_INPUTS: 1e-4}
    # the crowd's settings: a linear one at a fine-tuning rate (pruned at its screen), one with hidden layers
    crowd = _add(study, dists, linear, None, [(400, 40.0)], **{keys.WARM_START: "crowd:lin"})
    _add(study, dists, space.encode(spec, HIDDEN), None, [(400, 41.0)], **{keys.WARM_START: "crowd:deep"})
    driver._enqueue_twins()  # noqa: SLF001
    waiting = study.get_trials(states=(optuna.trial.TrialState.WAITING,))
    if not on:
        assert not waiting
        return
    assert [(t.system_attrs["fixed_params"]["method"], t.system_attrs["fixed_params"][LR_X_INPUTS])
            for t in waiting] == [("adagrad", 3.0), ("adagrad", 10.0), ("sgd", 0.03)]  # fmt: skip
    assert all(t.user_attrs == {keys.TWIN_OF: crowd, keys.LADDER_TOP: 1} for t in waiting)
    driver._enqueue_twins()  # noqa: SLF001 - once per crowd setting
    assert len(study.get_trials(states=(optuna.trial.TrialState.WAITING,))) == 3
    assert driver._launch_next(0)  # noqa: SLF001 - trained once, at the top rung the cap affords, priced alone
    assert driver.pool.tasks[-1].rungs == (1200,) and driver.pool.tasks[-1].config["learning_rate"] > 1e-4


@pytest.mark.parametrize("side_cap", [None, "top"])
def test_a_twin_is_priced_against_max_side_cost_s(tmp_path: Path, side_cap: str | None) -> None:
    """A crowd twin whose top rung is over max_trial_cost_s trains at the rung below it, unless max_side_cost_s
    affords the top: a linear net on the whole road takes ~250 s at 810k, over a ladder's 180 s cap, and at 270k
    that view scored 69–74 where at 810k it scored 75."""
    linear = {**space.encode(_spec(), HIDDEN), "n_layers": 0, "method": "adagrad", LR_X_INPUTS: 3.0}
    model = CostModel.prior()
    low, top = (model.predict(space.to_config(_spec(), linear, b)) for b in (400, 1200))
    study_keys: dict[str, Any] = {"max_trial_cost_s": (low + top) / 2}  # the top alone does not fit
    if side_cap:
        study_keys["max_side_cost_s"] = top * 1.01
    data = {**_data(linear_twins=RATES, **study_keys), "warm_start": {"crowd": True, "crowd_twins": True}}
    spec = parse_spec(data, source="x").with_overrides(storage=str(tmp_path / "j.log"))
    assert spec.study.side_cost_cap_s == (top * 1.01 if side_cap else (low + top) / 2)
    driver = Driver(spec, open_storage(spec.study.storage, spec.study.name))
    study = driver.open_study()
    driver.pool, driver._t0, driver.cost_model = FakePool(), time.perf_counter(), model  # noqa: SLF001
    _add(study, distributions(spec), linear, None, [(400, 40.0)], **{keys.WARM_START: "crowd:lin"})
    driver._enqueue_twins()  # noqa: SLF001
    assert driver._launch_next(0)  # noqa: SLF001
    assert driver.pool.tasks[-1].rungs == ((1200,) if side_cap else (400,))


def test_max_side_cost_s_is_checked() -> None:
    assert _spec().study.max_side_cost_s is None and "max_side_cost_s" not in _spec().to_dict()["study"]
    spec = _spec(linear_twins=RATES, max_trial_cost_s=100, max_side_cost_s=300)
    assert spec.study.side_cost_cap_s == 300 and spec.study.cost_cap_s == 100
    assert spec.to_dict()["study"]["max_side_cost_s"] == 300.0
    assert _spec(linear_twins=RATES, max_trial_cost_s=100).study.side_cost_cap_s == 100  # default: the gate's cap
    assert spec.study.cap_key(side=True) == "max_side_cost_s" and spec.study.cap_key() == "max_trial_cost_s"
    assert _spec(linear_twins=RATES, max_trial_cost_s=100).study.cap_key(side=True) == "max_trial_cost_s"
    with pytest.raises(SpecError, match=r"\[study\] max_side_cost_s: must be a positive number of seconds, got 0"):
        _spec(linear_twins=RATES, max_side_cost_s=0)
    with pytest.raises(SpecError, match=r"max_side_cost_s: caps the training of a linear twin or neighbour, but "
                                        r"neither is on.*remove max_side_cost_s"):  # fmt: skip
        _spec(max_side_cost_s=300)


# -- linear neighbours ------------------------------------------------------------------------


def test_neighbours_move_one_parameter_a_step_inside_the_space() -> None:
    """Each step of ``NEIGHBOUR_STEPS`` moves its one parameter (the temporal window to 0, 1 − γ × 2 and × 0.5,
    lanes ± 1, patches ahead × 3/4 and × 4/3, patches behind ± 2, the rate × 0.5 and × 2), clipped to the space, an
    integer moved by × or + rounded but by one at least; a step that changes nothing (at a bound, or a window
    already 0) or whose parameter is not searched is left out."""
    extra = (Dimension("one_minus_gamma", "float", 1e-4, 0.7, log=True), Dimension("patches_behind", "int", 0, 20),
             Dimension("temporal_window", "int", 0, 10))  # fmt: skip
    params = {"n_layers": 0, "method": "adagrad", LR_X_INPUTS: 3.0, "lanes_side": 2, "patches_ahead": 3,
              "patches_behind": 1, "one_minus_gamma": 0.1, "temporal_window": 7}  # fmt: skip
    made = twins.neighbours(params, (*_spec().space, *extra))
    moved = [next((k, t[k]) for k in t if t[k] != params[k]) for t in made]
    expected = [("temporal_window", 0), ("one_minus_gamma", 0.2), ("one_minus_gamma", 0.05), ("lanes_side", 1),
                ("patches_ahead", 2), ("patches_ahead", 4), ("patches_behind", 0), ("patches_behind", 3),
                (LR_X_INPUTS, 1.5), (LR_X_INPUTS, 6.0)]  # fmt: skip
    assert moved == expected  # lanes_side 3 is past the space's 2: left out
    assert all(sum(t[k] != params[k] for k in params) == 1 for t in made)
    assert isinstance(made[0]["temporal_window"], int) and isinstance(made[4]["patches_ahead"], int)
    base = {**params, "temporal_window": 0}
    unwindowed = twins.neighbours(base, (*_spec().space, *extra))  # no window to drop: the other steps alone
    assert [next((k, t[k]) for k in t if t[k] != base[k]) for t in unwindowed] == expected[1:]
    base = {**params, "patches_ahead": 1}
    narrow = twins.neighbours(base, _spec().space)  # no γ or behind searched here
    assert [next((k, t[k]) for k in t if t[k] != base[k]) for t in narrow] == [
        ("lanes_side", 1), ("patches_ahead", 2), (LR_X_INPUTS, 1.5), (LR_X_INPUTS, 6.0)]  # fmt: skip
    # 1 patch × 3/4 would be 0, below the space: left out; × 4/3 moves by one at least


def test_linear_neighbours_is_checked() -> None:
    assert _spec().study.linear_neighbours is False and "linear_neighbours" not in _spec().to_dict()["study"]
    spec = _spec(seed_soups=[2], linear_neighbours=True)
    assert spec.study.linear_neighbours and spec.to_dict()["study"]["linear_neighbours"] is True
    assert parse_spec(spec.to_dict(), source="twins.toml") == spec
    with pytest.raises(SpecError, match=r"\[study\] linear_neighbours: must be true or false, got 1"):
        _spec(seed_soups=[2], linear_neighbours=1)
    with pytest.raises(SpecError, match=r"linear_neighbours: retries the configuration of the best seed soup, but "
                                        r"seed_soups is empty; set seed_soups"):  # fmt: skip
        _spec(linear_neighbours=True)


def _neighbours_driver(tmp_path: Path) -> tuple[Driver, optuna.Study, dict[str, Any], dict[str, Any]]:
    """A driver with linear_neighbours on, and a linear adagrad configuration's parameters."""
    driver, study, dists = _driver(tmp_path, seed_soups=[2], linear_neighbours=True)
    linear = space.encode(driver.spec, HIDDEN.replace(layers="", method="adagrad"))
    return driver, study, dists, {**linear, "lanes_side": 1, "patches_ahead": 3, LR_X_INPUTS: 1.0}


def test_the_driver_enqueues_the_neighbours_of_the_linear_configuration_whose_soup_is_the_best_net(
    tmp_path: Path,
) -> None:
    driver, study, dists, linear = _neighbours_driver(tmp_path)
    hidden = space.encode(driver.spec, HIDDEN)
    owner = _add(study, dists, linear, 73.0, [(1200, 73.0)])
    _add(study, dists, hidden, 73.6, [(1200, 73.6)])
    seed = _add(study, dists, linear, 73.5, [(1200, 73.5)], **{keys.RACE_OF: owner, keys.RACE_SEED: 0})
    soup_attrs = {keys.SEED_SOUP_OF: owner, keys.SOUP_OF: [owner, seed],
                  keys.REFINE_OF: {"trial": seed, "budget": None, "score": 73.5}}  # fmt: skip
    _add(study, dists, linear, 73.2, [], **soup_attrs)
    driver._enqueue_neighbours()  # noqa: SLF001 - the best net has hidden layers: none
    assert len(study.trials) == 4
    _add(study, dists, linear, 74.0, [], **soup_attrs)
    driver._enqueue_neighbours()  # noqa: SLF001
    waiting = study.get_trials(states=(optuna.trial.TrialState.WAITING,))
    fixed = [t.system_attrs["fixed_params"] for t in waiting]
    assert fixed == twins.neighbours(linear, driver.spec.space) and len(fixed) == 6  # lanes, ahead, rate: each 2
    assert all(t.user_attrs == {keys.NEIGHBOUR_OF: owner, keys.LADDER_TOP: 1} for t in waiting)
    _add(study, dists, {**linear, LR_X_INPUTS: 1.5}, 74.2, [], **soup_attrs)  # a better soup of the same
    # configuration (its best net now a family member's at another rate): no new neighbours
    driver._enqueue_neighbours()  # noqa: SLF001
    assert len(study.get_trials(states=(optuna.trial.TrialState.WAITING,))) == 6
    # a neighbour trains like a twin: once, at its parent's budget, unpruned
    assert driver._launch_next(0)  # noqa: SLF001
    task = driver.pool.tasks[-1]
    assert task.config["layers"] == "" and task.rungs == (1200,) and driver._running[0].silent  # noqa: SLF001
    # none from a linear soup that is not the best net, a stack, or in the race's window
    other = _add(study, dists, {**linear, "patches_ahead": 4}, 73.0, [(1200, 73.0)])
    _add(study, dists, {**linear, "patches_ahead": 4}, 74.1, [], **{**soup_attrs, keys.SEED_SOUP_OF: other})
    driver._enqueue_neighbours()  # noqa: SLF001
    assert {t.user_attrs.get(keys.NEIGHBOUR_OF) for t in study.trials} == {None, owner}
    driver._t0 = time.perf_counter() - 3600 * 0.8  # noqa: SLF001 - in the last quarter: the seed race's time
    _add(study, dists, {**linear, "patches_ahead": 4}, 74.5, [], **{**soup_attrs, keys.SEED_SOUP_OF: other})
    driver._enqueue_neighbours()  # noqa: SLF001
    assert {t.user_attrs.get(keys.NEIGHBOUR_OF) for t in study.trials} == {None, owner}


def test_the_linear_configuration_with_the_best_seed_mean_gets_neighbours_so_a_better_neighbour_climbs_on(
    tmp_path: Path,
) -> None:
    driver, study, dists, linear = _neighbours_driver(tmp_path)
    hidden = space.encode(driver.spec, HIDDEN)

    def seeds(owner: int, params: dict[str, Any], *scores: float) -> None:
        for i, score in enumerate(scores):
            _add(study, dists, params, score, [(1200, score)], **{keys.RACE_OF: owner, keys.RACE_SEED: i})

    def waiting_of(owner: int) -> list[dict[str, Any]]:
        return [t.system_attrs["fixed_params"] for t in study.get_trials(states=(optuna.trial.TrialState.WAITING,))
                if t.user_attrs.get(keys.NEIGHBOUR_OF) == owner]  # fmt: skip

    _add(study, dists, {**hidden, "lanes_side": 2}, 74.8, [(1200, 74.8)])  # the best net: hidden layers
    parent = _add(study, dists, linear, 74.0, [(1200, 74.0)])
    seeds(parent, linear, 73.0, 73.4)
    driver._enqueue_neighbours()  # noqa: SLF001 - two seeds are no standing, and the best net is not linear: none
    assert len(study.trials) == 4
    seeds(parent, linear, 73.0, 73.4, 73.8)  # its third seed (the first two again: a retry's result replaces)
    better_hidden = _add(study, dists, hidden, 74.5, [(1200, 74.5)])
    seeds(better_hidden, hidden, 74.5, 74.6, 74.7)  # leads the standing, but has hidden layers: passed over
    driver._enqueue_neighbours()  # noqa: SLF001
    assert waiting_of(parent) == twins.neighbours(linear, driver.spec.space)
    assert waiting_of(better_hidden) == []
    lead = study.get_trials(states=(optuna.trial.TrialState.WAITING,))[0]
    assert lead.user_attrs == {keys.NEIGHBOUR_OF: parent, keys.LADDER_TOP: 1}  # at its seeds' budget
    driver._enqueue_neighbours()  # noqa: SLF001 - once per configuration
    assert len(waiting_of(parent)) == len(twins.neighbours(linear, driver.spec.space))
    # a neighbour (trained in place of its queued trial) whose seeds average above its parent's: its neighbours next
    moved = twins.neighbours(linear, driver.spec.space)[0]
    neighbour = _add(study, dists, moved, 74.2, [(1200, 74.2)], **{keys.NEIGHBOUR_OF: parent})
    seeds(neighbour, moved, 73.2, 73.3)
    driver._enqueue_neighbours()  # noqa: SLF001 - below its parent's mean: nothing new
    assert waiting_of(neighbour) == []
    seeds(neighbour, moved, 73.2, 73.3, 74.3)
    driver._enqueue_neighbours()  # noqa: SLF001
    assert waiting_of(neighbour) == [p for p in twins.neighbours(moved, driver.spec.space)
                                     if p not in [t.params for t in study.trials]]  # fmt: skip
    assert waiting_of(neighbour)


def test_the_linear_configuration_of_the_best_single_net_gets_neighbours_at_that_nets_budget(tmp_path: Path) -> None:
    """Not only a soup's: a crowd-prior hour's crowd twin was the best net from minute 6, its soups the best only from
    minute 18, and its neighbours, planned then, never trained before the race. But not a rung below the seed
    race's floor: a cold hour's first best nets are 10k rungs, and their neighbours (and theirs) took 27 of its
    first 50 trials."""
    driver, study, dists, linear = _neighbours_driver(tmp_path)
    hidden = space.encode(driver.spec, HIDDEN)

    def parents() -> list[tuple[int, Any]]:
        return [(owner, budget) for owner, _, budget in driver._neighbour_parents(study.trials)]  # noqa: SLF001

    assert parents() == []
    _add(study, dists, hidden, 73.0, [(1200, 73.0)])
    assert parents() == []  # the best net has hidden layers
    kept = {keys.ARTIFACT_RUNG_NETS: {"400": "a", "1200": "b"}, keys.OFFICIAL_PROTOCOL: "v2-official"}
    low = _add(study, dists, {**linear, LR_X_INPUTS: 7.0}, 72.0, [(400, 74.0), (1200, 72.0)], **kept)
    assert parents() == []  # its best net is a rung below the seed race's floor (min_top, here 1200): none
    ladder = _add(study, dists, linear, 74.2, [(400, 71.0), (1200, 74.2)], **kept)
    assert parents() == [(ladder, 1200)] and low != ladder  # a sampled ladder trial's rung at the floor or above
    twin = _add(study, dists, {**linear, LR_X_INPUTS: 3.0}, 74.5, [(1200, 74.5)], **{keys.TWIN_OF: 0})
    assert parents() == [(twin, 1200)]  # a twin's own net
    seed = _add(study, dists, linear, 75.0, [(1200, 75.0)], **{keys.RACE_OF: ladder, keys.RACE_SEED: 0})
    assert parents() == [(ladder, 1200)]  # a fresh seed run: its configuration's, at the run's budget
    _add(study, dists, linear, 75.5, [], **{keys.REFINE_OF: {"trial": seed, "budget": None, "score": 75.0}})
    assert parents() == []  # a refined net measures no configuration
    soup = {keys.SEED_SOUP_OF: ladder, keys.SOUP_OF: [ladder, seed],
            keys.REFINE_OF: {"trial": seed, "budget": None, "score": 75.0}}  # fmt: skip
    _add(study, dists, linear, 75.6, [], **soup)
    assert parents() == [(ladder, 1200)]  # a seed soup: its configuration's
    driver._enqueue_neighbours()  # noqa: SLF001
    waiting = _waiting(study)
    assert [t.system_attrs["fixed_params"] for t in waiting] == twins.neighbours(linear, driver.spec.space)
    assert all(t.user_attrs == {keys.NEIGHBOUR_OF: ladder, keys.LADDER_TOP: 1} for t in waiting)


# -- their share of the time ([study] side_share) ---------------------------------------------


def test_side_share_is_checked() -> None:
    assert _spec().study.side_share == 1.0 and "side_share" not in _spec().to_dict()["study"]  # as stored before
    spec = _spec(linear_twins=RATES, side_share=0.25)
    assert spec.study.side_share == 0.25 and spec.to_dict()["study"]["side_share"] == 0.25
    assert parse_spec(spec.to_dict(), source="twins.toml") == spec
    with pytest.raises(SpecError, match=r"\[study\] side_share: 0 would never start a linear twin or neighbour; "
                                        r"turn them off instead"):  # fmt: skip
        _spec(linear_twins=RATES, side_share=0)
    with pytest.raises(SpecError, match=r"\[study\] side_share: 1.5 is out of range; use \[0, 1\]"):
        _spec(linear_twins=RATES, side_share=1.5)
    with pytest.raises(SpecError, match=r"side_share: caps the time of linear twins and neighbours, but neither is "
                                        r"on; set linear_twins"):  # fmt: skip
        _spec(side_share=0.5)
    with pytest.raises(SpecError, match=r"\[study\] side_shar: unknown key.*side_share"):
        _spec(linear_twins=RATES, side_shar=0.5)


def _waiting(study: optuna.Study) -> list[Any]:
    return study.get_trials(states=(optuna.trial.TrialState.WAITING,))


def _train_next(driver: Driver, score: float, seconds: float) -> optuna.trial.Trial:
    """Start the waiting trial on slot 0 and store it as trained at the ladder's top: ``score`` in ``seconds``."""
    assert driver._launch_next(0)  # noqa: SLF001
    trial = driver._running.pop(0).trial  # noqa: SLF001
    task = driver.pool.tasks[-1]
    driver._finish(trial, TrialOutcome(trial.number, "complete", score, None, {  # noqa: SLF001
        keys.CONFIG: task.config, keys.RUNGS: [{keys.BUDGET: 1200, keys.SCORE: score}],
        keys.TRIAL_WALL_SECONDS: seconds}))  # fmt: skip
    return trial


def test_with_a_side_share_twins_wait_in_a_plan_and_start_one_at_a_time_while_their_share_allows(
    tmp_path: Path,
) -> None:
    driver, study, dists = _driver(tmp_path, side_share=0.25)
    hidden = space.encode(driver.spec, HIDDEN)
    first = _add(study, dists, hidden, 73.0, [(400, 70.0), (1200, 73.0)], **{keys.TRIAL_WALL_SECONDS: 100.0})
    driver._enqueue_twins()  # noqa: SLF001
    assert not _waiting(study)  # planned, not enqueued
    plan = study.user_attrs[keys.SIDE_PLAN]
    assert [(e["params"]["method"], e["params"][LR_X_INPUTS], e["released"]) for e in plan] == [
        ("adagrad", 3.0, False), ("adagrad", 10.0, False), ("sgd", 0.03, False)]  # fmt: skip
    assert all(e["user_attrs"] == {keys.TWIN_OF: first, keys.LADDER_TOP: 1} for e in plan)
    driver._enqueue_twins()  # noqa: SLF001 - planned counts as done: once per parent
    assert len(study.user_attrs[keys.SIDE_PLAN]) == 3

    driver._release_side()  # noqa: SLF001 - no side time yet: the first starts
    waiting = _waiting(study)
    assert [t.system_attrs["fixed_params"]["method"] for t in waiting] == ["adagrad"]
    assert waiting[0].user_attrs == {keys.TWIN_OF: first, keys.LADDER_TOP: 1}
    driver._release_side()  # noqa: SLF001 - one waits already: no other
    assert len(_waiting(study)) == 1
    _train_next(driver, 72.0, 60.0)
    driver._release_side()  # noqa: SLF001 - twins 60 s of 160: over a quarter, the search draws
    assert not _waiting(study)
    _add(study, dists, {**hidden, "lanes_side": 2}, 70.0, [(1200, 70.0)], **{keys.TRIAL_WALL_SECONDS: 60.0})
    driver._release_side()  # noqa: SLF001 - 60 of 220: still over
    assert not _waiting(study)
    _add(study, dists, {**hidden, "lanes_side": 0}, 70.0, [(1200, 70.0)], **{keys.TRIAL_WALL_SECONDS: 20.0})
    driver._release_side()  # noqa: SLF001 - 60 of 240: the next twin
    assert [t.system_attrs["fixed_params"][LR_X_INPUTS] for t in _waiting(study)] == [10.0]
    assert [e["released"] for e in study.user_attrs[keys.SIDE_PLAN]] == [True, True, False]

    # a resumed study goes on from its stored plan: the third twin, once, and no plan twice
    again = Driver(driver.spec, open_storage(driver.spec.study.storage, driver.spec.study.name))
    again_study = again.open_study()
    again.pool, again._t0 = FakePool(), time.perf_counter()  # noqa: SLF001
    assert again._launch_next(0)  # noqa: SLF001 - the waiting twin
    again._running.clear()  # noqa: SLF001
    again._enqueue_twins()  # noqa: SLF001
    again._release_side()  # noqa: SLF001 - its running time is not counted: 60 of 240
    assert [t.system_attrs["fixed_params"]["method"] for t in _waiting(again_study)] == ["sgd"]
    again._launch_next(0)  # noqa: SLF001
    again._running.clear()  # noqa: SLF001
    again._release_side()  # noqa: SLF001 - the plan is spent
    assert not _waiting(again_study) and all(e["released"] for e in again_study.user_attrs[keys.SIDE_PLAN])


def test_a_running_twin_counts_and_nothing_starts_from_the_plan_in_the_race_window(tmp_path: Path) -> None:
    driver, study, dists = _driver(tmp_path, side_share=0.5)
    hidden = space.encode(driver.spec, HIDDEN)
    _add(study, dists, hidden, 73.0, [(1200, 73.0)], **{keys.TRIAL_WALL_SECONDS: 10.0})
    driver._enqueue_twins()  # noqa: SLF001
    driver._release_side()  # noqa: SLF001
    assert driver._launch_next(0)  # noqa: SLF001
    driver._running[0].started -= 100.0  # noqa: SLF001 - the twin has run 100 s: 100 of 110
    driver._release_side()  # noqa: SLF001
    assert not _waiting(study)
    driver._running.clear()  # noqa: SLF001 - (gone: 0 of 10, the next would start)
    driver._t0 = time.perf_counter() - 3600 * 0.8  # noqa: SLF001 - but in the seed race's time, none does
    driver._release_side()  # noqa: SLF001
    assert not _waiting(study) and [e["released"] for e in study.user_attrs[keys.SIDE_PLAN]] == [True, False, False]
    driver._t0 = time.perf_counter()  # noqa: SLF001
    driver._release_side()  # noqa: SLF001
    assert len(_waiting(study)) == 1


def test_with_a_side_share_neighbours_are_planned_too_once_per_parent(tmp_path: Path) -> None:
    driver, study, dists = _driver(tmp_path, seed_soups=[2], linear_neighbours=True, side_share=0.5)
    linear = {**space.encode(driver.spec, HIDDEN.replace(layers="", method="adagrad")), "lanes_side": 1,
              "patches_ahead": 3, LR_X_INPUTS: 1.0}  # fmt: skip
    owner = _add(study, dists, linear, 73.0, [(1200, 73.0)])
    seed = _add(study, dists, linear, 73.5, [(1200, 73.5)], **{keys.RACE_OF: owner, keys.RACE_SEED: 0})
    _add(study, dists, linear, 74.0, [], **{keys.SEED_SOUP_OF: owner, keys.SOUP_OF: [owner, seed],
                                           keys.REFINE_OF: {"trial": seed, "budget": None, "score": 73.5}})  # fmt: skip
    driver._enqueue_neighbours()  # noqa: SLF001
    driver._enqueue_neighbours()  # noqa: SLF001
    plan = study.user_attrs[keys.SIDE_PLAN]
    assert [e["params"] for e in plan] == twins.neighbours(linear, driver.spec.space) and not _waiting(study)
    assert all(e["user_attrs"] == {keys.NEIGHBOUR_OF: owner, keys.LADDER_TOP: 1} for e in plan)
    driver._release_side()  # noqa: SLF001
    assert [t.system_attrs["fixed_params"] for t in _waiting(study)] == [plan[0]["params"]]


def test_the_side_plan_releases_the_newest_parents_entries_first_each_parents_in_order() -> None:
    def entry(key: str, parent: int, released: bool = False) -> dict[str, Any]:
        return {"params": {}, "user_attrs": {key: parent, keys.LADDER_TOP: 1}, "released": released}

    twin, neighbour = keys.TWIN_OF, keys.NEIGHBOUR_OF
    assert driver_next([]) is None
    plan = [entry(twin, 0), entry(twin, 0), entry(twin, 1), entry(neighbour, 1), entry(neighbour, 1)]
    assert driver_next(plan) == 3  # the newest parent is (neighbour_of, 1): a twin's parent is another
    plan[3]["released"] = True
    assert driver_next(plan) == 4
    plan[4]["released"] = True
    assert driver_next(plan) == 2  # then the twins of trial 1, then those of trial 0, oldest first
    plan[2]["released"] = True
    assert driver_next(plan) == 0
    plan.append(entry(twin, 5))  # a new parent goes first
    assert driver_next(plan) == 5
    assert driver_next([entry(twin, 0, released=True)]) is None


def test_with_a_side_share_a_new_bests_neighbours_start_before_older_twins(tmp_path: Path) -> None:
    """A crowd-prior hour (seed 2) trained its crowd twins and gsurma's from minute 12 to 25 while the neighbours of
    the best net waited; their second scored 75.85 at minute 33."""
    driver, study, dists = _driver(tmp_path, seed_soups=[2], linear_neighbours=True, side_share=0.5)
    hidden = space.encode(driver.spec, HIDDEN)
    first = _add(study, dists, hidden, 73.0, [(1200, 73.0)], **{keys.TRIAL_WALL_SECONDS: 10.0})
    driver._enqueue_twins()  # noqa: SLF001
    driver._release_side()  # noqa: SLF001 - the first twin
    twin = _train_next(driver, 74.0, 10.0)
    plan = study.user_attrs[keys.SIDE_PLAN]  # the best net is the twin's: its neighbours are planned after the twins
    assert [e["user_attrs"].get(keys.TWIN_OF, e["user_attrs"].get(keys.NEIGHBOUR_OF)) for e in plan] == [
        first, first, first, *[twin.number] * len(twins.neighbours(twin.params, driver.spec.space))]  # fmt: skip
    driver._release_side()  # noqa: SLF001 - 10 s of 20: the twin's first neighbour, not the second twin
    assert [t.user_attrs for t in _waiting(study)] == [{keys.NEIGHBOUR_OF: twin.number, keys.LADDER_TOP: 1}]
    assert [t.system_attrs["fixed_params"] for t in _waiting(study)] == [
        twins.neighbours(twin.params, driver.spec.space)[0]]  # fmt: skip


def test_a_worker_whose_trial_finished_starts_the_planned_twin_next(tmp_path: Path) -> None:
    """The driver starts a worker's next trial as soon as its last one is done, before storing that one; the plan is
    released there too (the idle-slot loop alone left a cold hour's 8 planned twins unstarted for 10 minutes)."""
    driver, study, dists = _driver(tmp_path, side_share=0.5)
    hidden = space.encode(driver.spec, HIDDEN)
    _add(study, dists, hidden, 73.0, [(1200, 73.0)], **{keys.TRIAL_WALL_SECONDS: 10.0})
    driver._enqueue_twins()  # noqa: SLF001 - planned; a sampled trial runs on slot 0
    study.enqueue_trial({**hidden, "lanes_side": 0})
    assert driver._launch_next(0) and not driver._running[0].silent  # noqa: SLF001
    task = driver.pool.tasks[-1]
    driver._handle(Event("done", 0, outcome=TrialOutcome(driver._running[0].trial.number, "pruned", None, "pruned", {  # noqa: SLF001
        keys.CONFIG: task.config, keys.RUNGS: [{keys.BUDGET: 400, keys.SCORE: 60.0}],
        keys.TRIAL_WALL_SECONDS: 5.0})))  # fmt: skip
    assert driver._running[0].silent and driver.pool.tasks[-1].config["layers"] == ""  # noqa: SLF001 - the twin
    assert driver._running[0].trial.user_attrs[keys.TWIN_OF] == 0  # noqa: SLF001
