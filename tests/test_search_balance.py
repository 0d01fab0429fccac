"""[study] balance: every value of a balanced categorical parameter keeps its share of the sampled trials."""

from __future__ import annotations

import collections
import dataclasses
import math
import re
from typing import Any

import optuna
import pytest

from autotune.search import space
from autotune.search.balance import BalancedSampler, conditional_startup, forced_value
from autotune.search.driver import make_sampler
from autotune.search.spec import SpecError, StudySpec, load_spec, parse_spec

optuna.logging.set_verbosity(optuna.logging.ERROR)

METHODS = ("sgd", "adagrad", "adadelta")


def _spec(**study: Any) -> StudySpec:
    return parse_spec({
        "study": {"name": "bal", "n_trials": 10, "timeout_s": 60, "sampler_startup_trials": 6, **study},
        "ladder": {"rungs": [400, 1200]},
        "fixed": {"otherAgents": 1, "temporal_window": 0, "experience_size": 500, "batch_size": 8},
        "space": {
            "lanes_side": {"low": 0, "high": 2}, "patches_ahead": {"low": 1, "high": 4},
            "learning_rate": {"low": 1e-6, "high": 1e-2, "log": True},
            "method": {"choices": list(METHODS)},
            "n_layers": {"low": 0, "high": 2}, "neurons": {"low": 2, "high": 8},
            "activation": {"choices": ["relu", "tanh"]},
        },
    })  # fmt: skip


def _greedy(params: dict[str, Any]) -> float:
    """adagrad looks best at once and everywhere; sgd is best, but only near lr 1e-3 (the benchmark's trap)."""
    lr = math.log10(params["learning_rate"])
    if params["method"] == "adagrad":
        return 72.0 - 0.1 * abs(lr + 3.0)
    if params["method"] == "sgd":
        return 75.0 - 5.0 * abs(lr + 3.0)
    return 60.0


def _run(spec: StudySpec, n: int, gated: bool = True) -> optuna.Study:
    sampler = make_sampler(spec, 0, (lambda _p: 1.0) if gated else None, lambda: 10.0)
    study = optuna.create_study(direction="maximize", sampler=sampler)
    for _ in range(n):
        trial = study.ask()
        study.tell(trial, _greedy(space.sample(trial, spec)))
    return study


def test_forced_value_goes_round_then_keeps_the_floor() -> None:
    assert forced_value(dict.fromkeys(METHODS, 0), 0.2) == "sgd"
    assert forced_value({"sgd": 1, "adagrad": 0, "adadelta": 0}, 0.2) == "adagrad"
    assert forced_value({"sgd": 1, "adagrad": 1, "adadelta": 0}, 0.2) == "adadelta"
    assert forced_value({"sgd": 1, "adagrad": 1, "adadelta": 1}, 0.2) is None  # 0.2 × 4 < 1
    assert forced_value({"sgd": 2, "adagrad": 15, "adadelta": 3}, 0.2) == "sgd"  # 2 < 4.2, the furthest below
    assert forced_value({"sgd": 6, "adagrad": 14, "adadelta": 6}, 0.2) is None  # 6 ≥ 0.2 × 27
    assert conditional_startup(16, 3) == 6 and conditional_startup(0, 3) == 1


@pytest.mark.parametrize("gated", [True, False])
def test_every_method_keeps_its_share_of_the_sampled_trials(gated: bool) -> None:
    """Without balance TPE piles onto the method that looked good first; with it each keeps ≥ 20 % at all times."""
    n = 60
    free = collections.Counter(t.params["method"] for t in _run(_spec(), n, gated).trials)
    assert min(free.values(), default=0) < 0.2 * n  # the trap works: some method is starved
    study = _run(_spec(balance=["method"], balance_min_share=0.2), n, gated)
    for k in range(1, n + 1):
        seen = collections.Counter(t.params["method"] for t in study.trials[:k])
        assert all(seen[m] >= math.floor(0.2 * k) for m in METHODS), (k, seen)
    assert [t.params["method"] for t in study.trials[:3]] == list(METHODS)  # the startup goes round the values
    assert max(t.value for t in study.trials if t.value is not None) > 74.0  # sgd's narrow optimum was found


def test_a_forced_draw_is_modelled_on_its_own_values_trials() -> None:
    """The conditional sampler sees only the forced value's trials (sgd's learning rate from sgd's history)."""
    spec = _spec(balance=["method"], balance_min_share=0.3)
    sampler = make_sampler(spec, 0, lambda _p: 1.0, lambda: 10.0)
    balanced = sampler.base  # type: ignore[attr-defined]
    assert isinstance(balanced, BalancedSampler)
    seen: list[set[str]] = []
    conditional = balanced._conditional  # noqa: SLF001
    original = conditional.sample_relative

    def spy(study: Any, trial: Any, search_space: Any) -> dict[str, Any]:
        seen.append({t.params["method"] for t in study._get_trials(deepcopy=False)})  # noqa: SLF001
        assert "method" not in search_space
        return original(study, trial, search_space)

    conditional.sample_relative = spy  # type: ignore[method-assign]
    study = optuna.create_study(direction="maximize", sampler=sampler)
    for _ in range(30):
        trial = study.ask()
        params = space.sample(trial, spec)
        forced = balanced.forced(trial.number)
        if forced is not None:
            assert forced == ("method", params["method"])
        study.tell(trial, _greedy(params))
    assert seen and all(len(s) <= 1 for s in seen)


def test_enqueued_trials_are_not_draws() -> None:
    """Crowd settings, retries and race runs are enqueued: they neither count towards a share nor get forced."""
    spec = _spec(balance=["method"], balance_min_share=0.3)
    study = optuna.create_study(direction="maximize", sampler=make_sampler(spec, 0, lambda _p: 1.0, lambda: 10.0))
    fixed = {"lanes_side": 1, "patches_ahead": 2, "learning_rate": 1e-3, "method": "adagrad", "n_layers": 0,
             "neurons_0": 2, "activation_0": "relu", "neurons_1": 2, "activation_1": "relu"}  # fmt: skip
    for _ in range(5):
        study.enqueue_trial(fixed)
        trial = study.ask()
        assert space.sample(trial, spec)["method"] == "adagrad"
        study.tell(trial, 70.0)
    trial = study.ask()
    assert space.sample(trial, spec)["method"] == "sgd"  # five adagrad trials enqueued, yet sgd comes first


def test_balance_is_checked_against_the_space() -> None:
    spec = _spec(balance=["method"])
    assert spec.study.balance == ("method",) and spec.study.balance_min_share == 0.2
    assert parse_spec(spec.to_dict()) == spec
    assert _spec().study.balance == ()
    bad = {
        "methd": "'methd' is not in [space]; did you mean 'method'",
        "lanes_side": "is not a categorical",
        "activation": "is not a categorical [space] parameter of its own",
    }
    for name, message in bad.items():
        with pytest.raises(SpecError, match=r"\[study\] balance: .*" + re.escape(message)):
            _spec(balance=[name])
    with pytest.raises(SpecError, match=r"\[study\] balance: must be a list"):
        _spec(balance="method")
    with pytest.raises(SpecError, match=r"\[study\] balance: names a parameter twice"):
        _spec(balance=["method", "method"])
    with pytest.raises(SpecError, match=r"\[study\] balance_min_share: 0.4 × the 3 values of method is over 1"):
        _spec(balance=["method"], balance_min_share=0.4)
    with pytest.raises(SpecError, match=r"\[study\] balance_min_share: must be above 0"):
        _spec(balance=["method"], balance_min_share=0)
    with pytest.raises(SpecError, match=r"\[study\] balance: needs a sampler whose model is its trial history"):
        _spec(balance=["method"], sampler="cmaes")


def test_paper_balances_the_trainer_method() -> None:
    spec = load_spec("study_configs/paper.toml")
    assert spec.study.balance == ("method",) and spec.study.balance_min_share == 0.2
    sampler = make_sampler(spec, 0)
    assert isinstance(sampler, BalancedSampler) and isinstance(sampler.base, optuna.samplers.TPESampler)
    plain = make_sampler(dataclasses.replace(spec, study=dataclasses.replace(spec.study, balance=())), 0)
    assert isinstance(plain, optuna.samplers.TPESampler)
