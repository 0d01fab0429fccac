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
from autotune.search.balance import ApartPruner, BalancedSampler, conditional_startup, forced_value
from autotune.search.driver import make_pruner, make_sampler
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
    """A forced draw takes the rate from the forced value's trials alone (sgd's learning rate from sgd's
    history) and every other parameter from the base sampler's model of all trials."""
    spec = _spec(balance=["method"], balance_min_share=0.3)
    sampler = make_sampler(spec, 0, lambda _p: 1.0, lambda: 10.0)
    balanced = sampler.base  # type: ignore[attr-defined]
    assert isinstance(balanced, BalancedSampler)
    own: list[tuple[set[str], set[str], set[str]]] = []
    shared: list[tuple[set[str], set[str]]] = []
    conditional, base = balanced._conditional, balanced.base  # noqa: SLF001
    sample_own, sample_base = conditional.sample_relative, base.sample_relative

    def spy_own(study: Any, trial: Any, search_space: Any) -> dict[str, Any]:
        out = sample_own(study, trial, search_space)
        own.append(({t.params["method"] for t in study._get_trials(deepcopy=False)}, set(search_space), set(out)))  # noqa: SLF001
        return out

    def spy_base(study: Any, trial: Any, search_space: Any) -> dict[str, Any]:
        out = sample_base(study, trial, search_space)
        if balanced.forced(trial.number) is not None:
            shared.append(({t.params.get("method") for t in study._get_trials(deepcopy=False)}, set(search_space)))  # noqa: SLF001
        return out

    conditional.sample_relative = spy_own  # type: ignore[method-assign]
    base.sample_relative = spy_base  # type: ignore[method-assign]
    study = optuna.create_study(direction="maximize", sampler=sampler)
    for _ in range(30):
        trial = study.ask()
        params = space.sample(trial, spec)
        forced = balanced.forced(trial.number)
        if forced is not None:
            assert forced == ("method", params["method"])
        study.tell(trial, _greedy(params))
    assert own and all(len(methods) <= 1 and asked == {"learning_rate"} and got <= asked for methods, asked, got in own)
    assert any(got for _m, _a, got in own)  # past its startup the conditional sampler drew the rate
    everything = set(space.dimensions(spec)) - {"method", "learning_rate"}
    assert shared and all(asked == everything for _m, asked in shared)
    assert any(len(methods) > 1 for methods, _a in shared)  # the base's history holds every method's trials


def _spy_conditional(balanced: BalancedSampler, name: str) -> list[tuple[set[Any], set[str]]]:
    """Record, for each draw of ``balanced``'s conditional sampler, the values of ``name`` among the trials it was
    shown and the parameters it was asked for."""
    own: list[tuple[set[Any], set[str]]] = []
    conditional = balanced._conditional  # noqa: SLF001
    sample_own = conditional.sample_relative

    def spy_own(study: Any, trial: Any, search_space: Any) -> dict[str, Any]:
        own.append(({t.params[name] for t in study._get_trials(deepcopy=False)}, set(search_space)))  # noqa: SLF001
        return sample_own(study, trial, search_space)

    conditional.sample_relative = spy_own  # type: ignore[method-assign]
    return own


def test_a_forced_layer_count_draw_models_its_trainer_method_on_its_own_trials() -> None:
    """A draw forced to linear nets (``n_layers = 0``) takes its trainer method, as its rate and layout, from the
    linear trials alone: which method suits a net depends on its depth."""
    spec = _spec(balance=["n_layers"], balance_values={"n_layers": [0]}, balance_min_share=0.3)
    sampler = make_sampler(spec, 0, lambda _p: 1.0, lambda: 10.0)
    balanced = sampler.base  # type: ignore[attr-defined]
    assert isinstance(balanced, BalancedSampler)
    own = _spy_conditional(balanced, "n_layers")
    study = optuna.create_study(direction="maximize", sampler=sampler)
    for _ in range(30):
        trial = study.ask()
        study.tell(trial, _greedy(space.sample(trial, spec)))
    assert own and all(layers <= {0} for layers, _asked in own)
    assert any("method" in asked and "learning_rate" in asked for _l, asked in own)


def test_a_forced_view_draw_models_its_own_view_gamma_epsilon_and_rate_on_its_own_trials() -> None:
    """``balance_values = {lanes_side = [2]}`` (an integer other than the layer count): a draw forced to that view
    width takes the patches and the rate (``OWN_PARAMETERS["lanes_side"]``) from the trials with that width alone,
    and the trainer method and layers from every trial's model; the width keeps its share."""
    spec = _spec(balance=["lanes_side"], balance_values={"lanes_side": [2]}, balance_min_share=0.3)
    assert spec.study.balance_values == (("lanes_side", (2,)),) and parse_spec(spec.to_dict()) == spec
    sampler = make_sampler(spec, 0, lambda _p: 1.0, lambda: 10.0)
    balanced = sampler.base  # type: ignore[attr-defined]
    assert isinstance(balanced, BalancedSampler)
    own = _spy_conditional(balanced, "lanes_side")
    shared: list[set[str]] = []
    base = balanced._base  # noqa: SLF001
    sample_base = base.sample_relative

    def spy_base(study: Any, trial: Any, search_space: Any) -> dict[str, Any]:
        if balanced.forced(trial.number) is not None:
            shared.append(set(search_space))
        return sample_base(study, trial, search_space)

    base.sample_relative = spy_base  # type: ignore[method-assign]
    study = optuna.create_study(direction="maximize", sampler=sampler)
    for _ in range(30):
        trial = study.ask()
        study.tell(trial, _greedy(space.sample(trial, spec)))
    assert own and all(widths <= {2} for widths, _asked in own)
    assert any({"patches_ahead", "learning_rate"} <= asked for _w, asked in own)
    assert not any(asked & {"method", "n_layers", "lanes_side"} for _w, asked in own)
    assert shared and any("method" in asked for asked in shared)
    assert not any(asked & {"patches_ahead", "learning_rate"} for asked in shared)
    widths = collections.Counter(t.params["lanes_side"] for t in study.trials)
    assert widths[2] >= 0.3 * 30 - 1


def _shared_optimum(params: dict[str, Any]) -> float:
    """``_greedy`` plus a view that is best for every method (lanes_side 2, patches_ahead 4)."""
    return _greedy(params) - 2.0 * (2 - params["lanes_side"]) - 2.0 * (4 - params["patches_ahead"])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_forced_draw_keeps_what_the_other_values_trials_taught(seed: int) -> None:
    """The view is learnt mostly from adagrad's trials (the free draws pile there); forced sgd draws pick it up
    from the base sampler, where modelling every parameter on sgd's few trials alone (``own={}``: the old
    behaviour) finds it less often."""
    spec = _spec(balance=["method"], balance_min_share=0.2, sampler_startup_trials=6)

    def hits(own: dict[str, Any] | None) -> int:
        sampler = make_sampler(spec, seed, lambda _p: 1.0, lambda: 10.0)
        balanced = sampler.base  # type: ignore[attr-defined]
        if own is not None:
            balanced._own = own  # noqa: SLF001
        study = optuna.create_study(direction="maximize", sampler=sampler)
        found = 0
        for _ in range(80):
            trial = study.ask()
            params = space.sample(trial, spec)
            if trial.number >= 20 and balanced.forced(trial.number) is not None:
                found += params["lanes_side"] == 2 and params["patches_ahead"] == 4
            study.tell(trial, _shared_optimum(params))
        return found

    assert hits(None) > hits({})


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
        "learning_rate": "is not a categorical or integer [space] parameter of its own",
        "activation": "is not a categorical or integer [space] parameter of its own",
        "neurons": "is not a categorical or integer [space] parameter of its own",
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
    assert spec.study.balance == ("method", "n_layers") and spec.study.balance_min_share == 0.2
    assert spec.study.balance_values == (("n_layers", (0,)),)  # every method, and linear nets
    assert not spec.study.balance_every_draw  # measured on the real space and left off (README)
    spec = dataclasses.replace(spec, study=dataclasses.replace(spec.study, denoise=False))  # denoise: its own test
    sampler = make_sampler(spec, 0)
    assert isinstance(sampler, BalancedSampler) and isinstance(sampler.base, optuna.samplers.TPESampler)
    plain = make_sampler(dataclasses.replace(spec, study=dataclasses.replace(spec.study, balance=())), 0)
    assert isinstance(plain, optuna.samplers.TPESampler)


def _layer_trap(params: dict[str, Any]) -> float:
    """``_greedy`` where linear nets look good at once (+3) and only one tanh layer of 8 units does better (+5)."""
    if params["n_layers"] == 1 and params["activation_0"] == "tanh":
        return _greedy(params) + 5.0 - 3.0 * abs(params["neurons_0"] - 8)
    return _greedy(params) + (-8.0 if params["n_layers"] else 3.0)


def test_one_hidden_layer_keeps_its_share() -> None:
    """``balance_values = {n_layers = [1]}``: the layer count (an integer) is balanced on one value. Free TPE draws
    pile onto linear nets here and never beat them (78); with a fifth of the draws kept on one hidden layer, whose
    width and activation are modelled on the one-layer trials, the study finds the tanh layer of 8 (above 78)."""
    free = _run_with(_spec(balance=["method"], balance_min_share=0.2), _layer_trap, 60)
    assert collections.Counter(t.params["n_layers"] for t in free.trials)[1] < 0.2 * 60
    assert max(t.value for t in free.trials if t.value is not None) < 78.0
    spec = _spec(balance=["method", "n_layers"], balance_values={"n_layers": [1]}, balance_min_share=0.2)
    assert spec.study.balance_values == (("n_layers", (1,)),) and parse_spec(spec.to_dict()) == spec
    forced: list[tuple[str, Any]] = []
    study = _run_with(spec, _layer_trap, 60, forced)
    assert ("n_layers", 1) in forced  # the floor bound at least once
    for k in range(1, 61):
        layers = collections.Counter(t.params["n_layers"] for t in study.trials[:k])
        methods = collections.Counter(t.params["method"] for t in study.trials[:k])
        assert layers[1] >= math.floor(0.2 * k) and all(methods[m] >= math.floor(0.2 * k) for m in METHODS), k
    best = max(study.trials, key=lambda t: t.value or 0.0)
    assert best.value is not None and best.value > 78.0 and best.params["activation_0"] == "tanh"


def _run_with(spec: StudySpec, score: Any, n: int, forced: list[tuple[str, Any]] | None = None) -> optuna.Study:
    sampler = make_sampler(spec, 0, lambda _p: 1.0, lambda: 10.0)
    study = optuna.create_study(direction="maximize", sampler=sampler)
    for _ in range(n):
        trial = study.ask()
        params = space.sample(trial, spec)
        why = sampler.base.forced(trial.number)  # type: ignore[attr-defined]
        if why is not None and forced is not None:
            assert params[why[0]] == why[1]
            forced.append(why)
        study.tell(trial, score(params))
    return study


def test_balance_values_are_checked() -> None:
    with pytest.raises(SpecError, match=r"\[study\] balance: n_layers is an integer: name the values"):
        _spec(balance=["n_layers"])
    with pytest.raises(SpecError, match=r"\[study\] balance_values: n_layers value 3 is not in \[space\] n_layers"):
        _spec(balance=["n_layers"], balance_values={"n_layers": [3]})
    with pytest.raises(SpecError, match=r"\[study\] balance_values: 'n_layer' is not in balance"):
        _spec(balance=["method"], balance_values={"n_layer": [1]})
    with pytest.raises(SpecError, match=r"\[study\] balance_values: must be a table of non-empty lists"):
        _spec(balance=["n_layers"], balance_values={"n_layers": []})
    with pytest.raises(SpecError, match=r"\[study\] balance_values: method value 'sdg' is not in \[space\] method"):
        _spec(balance=["method"], balance_values={"method": ["sdg"]})
    one = _spec(balance=["method"], balance_values={"method": ["sgd"]}, balance_min_share=0.9)
    assert one.study.balance_min_share == 0.9  # one value with a floor: its share may go up to 1


def _linear_trap(params: dict[str, Any]) -> float:
    """Hidden-layer nets do best with sgd near lr 1e-4 (74); linear nets do better with adagrad near 5e-3 (77),
    which a rate modelled on the sgd trials, or a method modelled on every trial, never reaches."""
    lr = math.log10(params["learning_rate"])
    if params["method"] == "adadelta":
        return 60.0
    if params["n_layers"] == 0:
        return 77.0 - 4.0 * abs(lr + 2.3) if params["method"] == "adagrad" else 73.0 - 3.0 * abs(lr + 4.0)
    return 74.0 - 3.0 * abs(lr + 4.0) if params["method"] == "sgd" else 71.0 - abs(lr + 4.0)


def _trap_study(seed: int, every_draw: bool, n: int = 80) -> tuple[optuna.Study, BalancedSampler]:
    spec = _spec(balance=["method", "n_layers"], balance_values={"n_layers": [0]}, balance_min_share=0.2,
                 balance_every_draw=every_draw)  # fmt: skip
    sampler = make_sampler(spec, seed, lambda _p: 1.0, lambda: 10.0)
    balanced = sampler.base  # type: ignore[attr-defined]
    assert isinstance(balanced, BalancedSampler)
    study = optuna.create_study(direction="maximize", sampler=sampler)
    for _ in range(n):
        trial = study.ask()
        study.tell(trial, _linear_trap(space.sample(trial, spec)))
    return study, balanced


@pytest.mark.parametrize("seed", [2, 4])
def test_every_draw_models_a_linear_draws_method_and_rate_on_its_own_trials(seed: int) -> None:
    """``balance_every_draw``: a free linear draw's method comes from the linear trials, each method keeps its share
    of the linear draws, and a method's rate comes from the trials with that method and depth. On these study
    seeds only forced draws are conditioned otherwise, and the linear adagrad optimum is never found (1 and 0 of
    80 trials are linear adagrad); with every draw conditioned it is."""
    plain, _ = _trap_study(seed, every_draw=False)
    assert max(t.value for t in plain.trials if t.value is not None) < 76.0
    study, balanced = _trap_study(seed, every_draw=True)
    assert max(t.value for t in study.trials if t.value is not None) > 76.0
    linear = [t for t in study.trials if t.params["n_layers"] == 0]
    for k in range(1, len(linear) + 1):
        methods = collections.Counter(t.params["method"] for t in linear[:k])
        assert all(methods[m] >= math.floor(0.2 * k) for m in METHODS), (k, methods)
    inside = [balanced.forced_within(t.number) for t in study.trials]
    assert any(inside) and all(name == "method" for pairs in inside for name, _v in pairs)


def test_every_draw_takes_a_rate_from_its_method_and_depth() -> None:
    """A draw's rate (the conditional sampler's last draw of it: a linear draw's method and rate are first drawn
    together from the linear trials) comes from trials of its method, and for a linear draw from the linear trials
    of that method alone."""
    spec = _spec(balance=["method", "n_layers"], balance_values={"n_layers": [0]}, balance_min_share=0.2,
                 balance_every_draw=True)  # fmt: skip
    sampler = make_sampler(spec, 0, lambda _p: 1.0, lambda: 10.0)
    balanced = sampler.base  # type: ignore[attr-defined]
    conditional = balanced._conditional  # noqa: SLF001
    sample_own = conditional.sample_relative
    seen: list[tuple[set[Any], set[Any], bool]] = []

    def spy(study: Any, trial: Any, search_space: Any) -> dict[str, Any]:
        shown = study._get_trials(deepcopy=False)  # noqa: SLF001
        out = sample_own(study, trial, search_space)
        if "learning_rate" in out:
            seen.append(({t.params["method"] for t in shown}, {t.params["n_layers"] for t in shown}, trial.number))
        return out

    sample_one = conditional.sample_independent

    def spy_one(study: Any, trial: Any, name: str, distribution: Any) -> Any:
        if name == "learning_rate":
            shown = study._get_trials(deepcopy=False)  # noqa: SLF001
            seen.append(({t.params["method"] for t in shown}, {t.params["n_layers"] for t in shown}, trial.number))
        return sample_one(study, trial, name, distribution)

    conditional.sample_relative = spy  # type: ignore[method-assign]
    conditional.sample_independent = spy_one  # type: ignore[method-assign]
    study = optuna.create_study(direction="maximize", sampler=sampler)
    rates: dict[int, float] = {}
    for _ in range(60):
        trial = study.ask()
        params = space.sample(trial, spec)
        rates[trial.number] = params["n_layers"]
        study.tell(trial, _linear_trap(params))
    last = {number: (methods, layers, number) for methods, layers, number in seen}
    assert len(last) > 20 and sum(len(m) == 1 for m, _l, _n in last.values()) > 20
    assert any(rates[n] == 0 for n in last) and any(rates[n] != 0 for n in last)
    for methods, layers, number in last.values():
        assert len(methods) <= 1  # (none: the first draw of its method and depth, at random)
        if rates[number] == 0 and number >= 6:  # (in the base's startup a draw's depth is drawn after its rate)
            assert layers <= {0}


def test_balance_every_draw_is_checked() -> None:
    spec = _spec(balance=["method"], balance_every_draw=True)
    assert spec.study.balance_every_draw and parse_spec(spec.to_dict()) == spec
    with pytest.raises(SpecError, match=r"\[study\] balance_every_draw: must be true or false"):
        _spec(balance=["method"], balance_every_draw="yes")
    with pytest.raises(SpecError, match=r"\[study\] balance_every_draw: conditions the draws .* balance is empty"):
        _spec(balance_every_draw=True)


def _apart_halving(pruner: optuna.pruners.BasePruner) -> list[bool]:
    """Whether each whole-road trial (``lanes_side = 2`` here; 70–73, then 60 and 69 at the first rung) and then a
    narrow one (75.4) is pruned, after nine narrow trials (74–76) reached that rung."""
    study = optuna.create_study(direction="maximize", sampler=optuna.samplers.RandomSampler(seed=0), pruner=pruner)
    width: dict[str, optuna.distributions.BaseDistribution] = {"lanes_side": optuna.distributions.IntDistribution(0, 2)}
    out = []
    for lanes, score in (
        [(0, 74.0 + i / 4) for i in range(9)] + [(2, s) for s in (70, 71, 72, 73, 60, 69)] + [(1, 75.4)]
    ):
        study.enqueue_trial({"lanes_side": lanes})
        trial = study.ask(width)
        trial.report(score, 1)
        out.append(trial.should_prune())
        study.tell(trial, state=optuna.trial.TrialState.PRUNED)
    return out[9:]


def test_a_balanced_views_draws_are_halved_among_their_own_kind() -> None:
    """``balance_prune_apart``: the draws of a floored value are ranked by the pruner among the trials with that
    value, every other trial among the trials without it: a narrow 75.4, in the top third of all 16, is not in that of
    the ten narrow ones."""
    sha = optuna.pruners.SuccessiveHalvingPruner(min_resource=1, reduction_factor=3, min_early_stopping_rate=0)
    assert _apart_halving(sha) == [True] * 6 + [False]  # among the narrow ones: never in the top third
    assert _apart_halving(ApartPruner(sha, {"lanes_side": (2,)})) == [False] * 4 + [True, True, True]
    with pytest.raises(ValueError, match="name at least one"):
        ApartPruner(sha, {})
    spec = _spec(balance=["method", "lanes_side"], balance_values={"lanes_side": [2]}, pruner="sha",
                 balance_prune_apart=["lanes_side"])  # fmt: skip
    assert spec.study.balance_prune_apart == ("lanes_side",) and parse_spec(spec.to_dict()) == spec
    made = make_pruner(spec)
    assert isinstance(made, ApartPruner) and isinstance(made.base, optuna.pruners.SuccessiveHalvingPruner)
    plain = _spec(balance=["method"], pruner="sha")
    assert not isinstance(make_pruner(plain), ApartPruner) and "balance_prune_apart" not in plain.to_dict()["study"]
    with pytest.raises(SpecError, match=r"\[study\] balance_prune_apart: 'lanes_side' is not in balance"):
        _spec(balance=["method"], balance_prune_apart=["lanes_side"])
    for bad in ("lanes_side", ["method", "method"], [1]):
        with pytest.raises(SpecError, match=r"\[study\] balance_prune_apart: must be a list of balanced parameters"):
            _spec(balance=["method"], balance_prune_apart=bad)
    with pytest.raises(SpecError, match=r"balance_prune_aprt.*balance_prune_apart"):  # a misspelt key
        _spec(balance=["method"], balance_prune_aprt=["method"])
