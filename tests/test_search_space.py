"""Search space: sample() with a real Optuna trial, to_config/encode round trips, param_count vs the crowd."""

from __future__ import annotations

import csv
import math
from typing import Any

import optuna
import pytest

from autotune import ConfigError, TrainConfig
from autotune.search import space
from autotune.search.spec import SpecError, StudySpec, load_spec, parse_spec, shift_epsilon, unshift_epsilon
from sim import fields
from tests.conftest import CROWD, ROOT

CONFIGS = ROOT / "study_configs"
optuna.logging.set_verbosity(optuna.logging.WARNING)


def _number(text: str) -> int | float:
    value = float(text)
    return int(value) if value.is_integer() else value


def _crowd_rows() -> list[dict[str, str]]:
    path = CROWD / "submissions.csv"
    if not path.exists():
        pytest.fail(f"crowd data not found at {path} (CI keeps ../shared beside the checkout)")
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def _crowd_config(row: dict[str, str]) -> TrainConfig:
    """A CSV row's settings as a flat config (from_mapping reads the columns' names: sim.fields' aliases)."""
    values: dict[str, Any] = {"hidden_layers": row["hidden_layers"]}  # an empty hidden_layers is a linear net
    for key, text in row.items():
        f = fields.field(key) if fields.name_of(key) else None
        if f is not None and text != "":
            values[key] = text if f.kind is str else _number(text)
    return TrainConfig.from_mapping(values)


def _random_params(spec: StudySpec, n: int, seed: int) -> list[dict[str, Any]]:
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=seed))
    out = []
    for _ in range(n):
        trial = study.ask()
        out.append(space.sample(trial, spec))
        study.tell(trial, 0.0)
    return out


@pytest.mark.parametrize("name", ["smoke.toml", "quick.toml", "paper.toml"])
def test_every_sampled_config_is_valid(name: str) -> None:
    spec = load_spec(CONFIGS / name)
    n = 200 if name == "paper.toml" else 50
    for params in _random_params(spec, n, seed=1):
        config = space.to_config(spec, params)
        assert config.ruleset == spec.ruleset
        for field, value in spec.fixed:
            assert config.to_mapping()[field] == value
        assert not space.outside(spec, params)


def test_sample_coordinates_and_fixed_shape_layout() -> None:
    spec = load_spec(CONFIGS / "paper.toml")
    values: dict[str, Any] = {name: (d.choices[0] if d.kind == "categorical" else d.low)
                              for name, d in space.dimensions(spec).items()}  # fmt: skip
    values.update({"one_minus_gamma": 0.1, "n_layers": 2, "neurons_0": 384, "activation_0": "tanh", "neurons_1": 8,
                   "activation_1": "maxout", "neurons_2": 99, "method": "adagrad",
                   "learning_steps_burnin_fraction": 0.02, "learning_steps_total_fraction": 0.5})  # fmt: skip
    params = space.sample(optuna.trial.FixedTrial(values), spec)
    # fixed shape: every slot is a parameter of every trial, the first n_layers are used
    assert params["neurons_2"] == 99 and params["n_layers"] == 2 and "neurons_7" in params
    config = space.to_config(spec, params, budget=90_000)
    assert config.hidden == "fc:384:tanh|fc:8:maxout" and config.method == "adagrad"
    assert config.gamma == 0.9 and config.train_iterations == 90_000
    assert (config.learning_steps_burnin, config.learning_steps_total) == (1_800, 45_000)
    assert config.start_learn_threshold == 100 and config.experience_size == 1000
    assert space.to_config(spec, params).train_iterations == spec.ladder[-1]  # default: the top of the ladder


def _enumerate(spec: StudySpec) -> set[str]:
    """Every configuration a small space can reach (all params enumerated), as canonical JSON."""
    import itertools
    import json

    dims = space.dimensions(spec)
    grids = [list(d.choices) if d.kind == "categorical" else list(range(int(d.low), int(d.high) + 1))  # type: ignore
             for d in dims.values()]  # fmt: skip
    out = set()
    for combo in itertools.product(*grids):
        config = space.to_config(spec, dict(zip(dims, combo, strict=True)))
        out.add(json.dumps(config.to_mapping(), sort_keys=True, default=str))
    return out


def test_fixed_shape_reaches_the_define_by_run_set() -> None:
    """The fixed-shape layout reaches exactly the configurations the define-by-run one did."""
    import json

    spec = parse_spec({"study": {"name": "d", "n_trials": 1}, "space": {
        "lanes_side": {"low": 0, "high": 1}, "n_layers": {"low": 0, "high": 2},
        "neurons": {"low": 2, "high": 4}, "activation": {"choices": ["relu", "tanh"]}}})  # fmt: skip
    reached = _enumerate(spec)
    define_by_run = set()  # n_layers, then neurons_i / activation_i for i < n_layers only
    for lanes in (0, 1):
        for n in (0, 1, 2):
            import itertools

            for layers in itertools.product(itertools.product((2, 3, 4), ("relu", "tanh")), repeat=n):
                hidden = "|".join(f"fc:{k}:{a}" for k, a in layers)
                config = space.build_config("v2", {"lanes_side": lanes, "layers": hidden}, cap_start=True)
                define_by_run.add(json.dumps(config.to_mapping(), sort_keys=True, default=str))
    assert reached == define_by_run and len(reached) == 2 * (1 + 6 + 36)


def test_start_threshold_capped_below_experience() -> None:
    spec = load_spec(CONFIGS / "paper.toml")
    params = space.encode(spec, TrainConfig(experience_size=3000, start_learn_threshold=500))
    params["start_learn_threshold"] = 50_000
    config = space.to_config(spec, params)
    assert config.start_learn_threshold == 2999 and config.experience_size == 3000


def test_round_trip() -> None:
    for name in ("paper.toml", "smoke.toml"):
        spec = load_spec(CONFIGS / name)
        for params in _random_params(spec, 100, seed=2):
            config = space.to_config(spec, params)
            back = space.encode(spec, config)
            assert space.to_config(spec, back) == config
            assert back.keys() == params.keys()
            n = params.get("n_layers", 0)
            for key, value in params.items():
                if key == "one_minus_gamma":
                    assert math.isclose(back[key], value, rel_tol=0.0, abs_tol=1e-15), key  # gamma has 15 digits
                elif key == "learning_rate_x_inputs":  # the rate has 15 digits: the product comes back to 1e-14
                    assert math.isclose(back[key], value, rel_tol=1e-14), key
                elif key == "start_learn_threshold":
                    assert back[key] == config.start_learn_threshold  # capped below the memory and the budget
                elif key.endswith("_fraction"):
                    assert math.isclose(back[key], value, rel_tol=1e-4, abs_tol=2 / config.train_iterations), key
                elif key.startswith(("neurons_", "activation_")) and int(key.rsplit("_", 1)[1]) >= n:
                    continue  # an unused slot of the fixed shape: encode writes the range's first value
                else:
                    assert back[key] == value, key


def test_encode_crowd_names() -> None:
    spec = load_spec(CONFIGS / "paper.toml")
    gsurma = TrainConfig.from_mapping(
        {"lanesSide": 2, "patchesAhead": 15, "patchesBehind": 7, "otherAgents": 10, "layers": "fc:384:tanh",
         "trainIterations": 50000, "gamma": 0.9, "batch_size": 32, "l2_decay": 0.001, "experience_size": 10000}
    )  # fmt: skip
    params = space.encode(spec, gsurma)
    assert params["one_minus_gamma"] == 0.1
    assert (params["n_layers"], params["neurons_0"], params["activation_0"]) == (1, 384, "tanh")
    assert params["other_agents"] == 10 and params["learning_steps_total_fraction"] == 10000 / 50000
    assert params["neurons_1"] == 2 and params["activation_1"] == "relu"  # unused slots: the ranges' first values
    assert space.outside(spec, params) == []
    at = space.to_config(spec, params, budget=50_000)  # the ladder at the crowd's own length: the crowd's settings
    assert at == gsurma.replace(start_learn_threshold=min(gsurma.start_learn_threshold, 12_500))
    svm = space.encode(spec, gsurma.replace(layers="fc:10:relu|svm:10|lrn|fc:3:softmax"))
    assert (svm["n_layers"], svm["neurons_1"], svm["activation_1"], svm["activation_2"]) == (3, 10, "svm", "linear")
    choices = "['relu', 'tanh', 'sigmoid', 'maxout']"
    assert space.outside(spec, svm) == [
        f"activation_1: 'svm' not in {choices}",
        f"activation_2: 'linear' not in {choices}",
    ]
    v1 = space.encode(spec, gsurma.replace(ruleset="v1", otherAgents=0))
    assert "other_agents" not in v1  # v1 has no other agents: no parameter
    assert space.active(svm)["n_layers"] == 3 and "neurons_3" in svm and "neurons_3" not in space.active(svm)
    assert space.unencodable(gsurma) == []
    assert space.unencodable(gsurma.replace(layers="fc:10:relu|svm:10|lrn")) == [
        "hidden layer 1 'svm:10' is not fc:N[:activation]; the layout space only has plain fc layers",
        "hidden layer 2 'lrn' is not fc:N[:activation]; the layout space only has plain fc layers",
    ]  # what encode changes or leaves out: the crowd prior skips such settings
    wide = space.encode(spec, gsurma.replace(lanesSide=50, layers="fc:10"))
    assert wide["activation_0"] == "linear"
    assert space.outside(spec, wide) == ["lanes_side: 50 outside [0, 10]", "activation_0: 'linear' not in "
                                         "['relu', 'tanh', 'sigmoid', 'maxout']"]  # fmt: skip


def test_to_config_rejects_wrong_params() -> None:
    spec = load_spec(CONFIGS / "smoke.toml")
    params = _random_params(spec, 1, seed=3)[0]
    with pytest.raises(SpecError, match="'lanes_sid' is not a parameter"):
        space.to_config(spec, {**params, "lanes_sid": 1})
    with pytest.raises(SpecError, match="'learning_rate' is missing"):
        space.to_config(spec, {k: v for k, v in params.items() if k != "learning_rate"})
    with pytest.raises(ConfigError, match="lanes_side"):
        space.to_config(spec, {**params, "lanes_side": 99})


def test_sample_uses_only_the_duck_typed_trial() -> None:
    spec = parse_spec(
        {
            "study": {"name": "d", "n_trials": 1},
            "space": {
                "batch_size": {"choices": [16, 32]},
                "learning_rate": {"low": 0.001, "high": 0.01, "log": True},
                "momentum": {"low": 0.0, "high": 0.9, "step": 0.1},
                "lanes_side": {"low": 0, "high": 6, "step": 2},
            },
        }
    )
    calls: list[tuple[str, tuple[Any, ...], dict[str, Any]]] = []

    class Recorder:
        def suggest_int(self, name: str, low: int, high: int, *, step: int = 1, log: bool = False) -> int:
            calls.append(("int", (name, low, high), {"step": step, "log": log}))
            return low

        def suggest_float(
            self, name: str, low: float, high: float, *, step: float | None = None, log: bool = False
        ) -> float:
            calls.append(("float", (name, low, high), {"step": step, "log": log}))
            return high

        def suggest_categorical(self, name: str, choices: Any) -> Any:
            calls.append(("categorical", (name, tuple(choices)), {}))
            return choices[-1]

    params = space.sample(Recorder(), spec)
    assert params == {"batch_size": 32, "learning_rate": 0.01, "momentum": 0.9, "lanes_side": 0}
    assert calls == [
        ("categorical", ("batch_size", (16, 32)), {}),
        ("float", ("learning_rate", 0.001, 0.01), {"step": None, "log": True}),
        ("float", ("momentum", 0.0, 0.9), {"step": 0.1, "log": False}),
        ("int", ("lanes_side", 0, 6), {"step": 2, "log": False}),
    ]


def test_param_count_matches_the_crowd() -> None:
    """The CSV's n_params for every row whose config the site accepts (3 rows have 4 actions: skipped)."""
    rows = [r for r in _crowd_rows() if r["num_inputs_formula_ok"] == "true"]
    checked = 0
    mismatched = []
    for row in rows:
        try:
            config = _crowd_config(row)
        except ConfigError:
            continue  # experience_size 0, momentum 5: outside what TrainConfig accepts
        checked += 1
        if config.param_count != int(row["n_params"]):
            mismatched.append(f"{row['id']} {row['hidden_layers']}: {config.param_count} vs {row['n_params']}")
    assert checked >= 0.95 * len(rows), f"only {checked}/{len(rows)} crowd rows build a TrainConfig"
    # m-quadra's svm:25 row: the CSV omits the final regression's fc (5·5 + 5 = 30); convnetjs builds it
    assert len(mismatched) <= 1, f"{len(mismatched)}/{checked} crowd rows disagree on n_params: {mismatched}"


def test_param_count_small() -> None:
    # 19 inputs (default template: L0 P1 B0 tw3) → fc(1) → regression(5): 19·1+1 + 1·5+5
    assert TrainConfig().param_count == 30
    # maxout halves the width the next layer sees: 10 → 5 → fc 5·4+4 → 4·5+5
    cfg = TrainConfig(lanes_side=0, patches_ahead=2, temporal_window=0, layers="fc:10:maxout|fc:4:relu")
    assert cfg.param_count == (2 * 10 + 10) + (5 * 4 + 4) + (4 * 5 + 5)


def test_default_space_spans_the_crowd() -> None:
    """Most crowd configs lie inside DEFAULT_SPACE (the rest are documented outliers)."""
    spec = parse_spec({"study": {"name": "d", "n_trials": 1}, "space": space.DEFAULT_SPACE})
    inside = total = 0
    for row in _crowd_rows():
        try:
            config = _crowd_config(row)
            params = space.encode(spec, config)
        except (ConfigError, SpecError):
            continue
        total += 1
        inside += not space.outside(spec, params)
    assert inside >= 0.85 * total, f"only {inside}/{total} crowd configs inside DEFAULT_SPACE"


# -- the learning rate per input (spec.LR_X_INPUTS) ----------------------------------------------


def _lr_spec(**extra: Any) -> StudySpec:
    table: dict[str, Any] = {
        "study": {"name": "lr", "n_trials": 1},
        "space": {"patches_ahead": {"low": 1, "high": 60}, "learning_rate_x_inputs": {"low": 1e-3, "high": 1.0,
                                                                                       "log": True}},
    }  # fmt: skip
    for name, value in extra.items():
        table.setdefault(name.split("__")[0], {})[name.split("__")[1]] = value
    return parse_spec(table)


def test_learning_rate_is_the_product_over_the_input_width() -> None:
    spec = _lr_spec()
    narrow = space.to_config(spec, {"patches_ahead": 1, "learning_rate_x_inputs": 0.5})
    wide = space.to_config(spec, {"patches_ahead": 60, "learning_rate_x_inputs": 0.5})
    assert narrow.net_inputs < wide.net_inputs
    for config in (narrow, wide):  # the same product: a rate that shrinks as the view widens
        assert math.isclose(config.learning_rate * config.net_inputs, 0.5, rel_tol=1e-14)
    assert math.isclose(narrow.learning_rate / wide.learning_rate, wide.net_inputs / narrow.net_inputs)
    assert space.encode(spec, wide)["learning_rate_x_inputs"] == pytest.approx(0.5, rel=1e-14)


def test_paper_searches_the_learning_rate_per_input_over_the_crowds_products() -> None:
    spec = load_spec(CONFIGS / "paper.toml")
    d = spec.dimensions["learning_rate_x_inputs"]
    assert "learning_rate" not in spec.dimensions and d.log
    products = []
    for row in _crowd_rows():
        try:
            config = _crowd_config(row)
        except ConfigError:
            continue
        products.append(config.learning_rate * config.net_inputs)
    assert d.low <= min(products) and max(products) <= d.high  # every crowd setting's rate is reachable


def test_learning_rate_searched_twice_or_fixed_is_refused() -> None:
    with pytest.raises(SpecError, match=r"learning_rate_x_inputs.*learning_rate.*keep one"):
        _lr_spec(space__learning_rate={"low": 1e-4, "high": 1e-2})
    with pytest.raises(SpecError, match=r"\[fixed\] also sets learning_rate"):
        _lr_spec(fixed__learning_rate=1e-3)
    with pytest.raises(SpecError, match=r"learning_rate_x_inputs.*above 0|log scale needs low > 0"):
        _lr_spec(space__learning_rate_x_inputs={"low": 0.0, "high": 1.0, "log": True})


def test_a_product_too_large_for_the_narrowest_view_is_refused() -> None:
    spec = _lr_spec(space__learning_rate_x_inputs={"low": 1e-3, "high": 1e3, "log": True})
    with pytest.raises(SpecError, match=r"learning_rate_x_inputs's high with the narrowest view.*narrow the range"):
        space.check(spec)
    space.check(_lr_spec())  # the narrowest view (1 patch ahead, the page's other defaults) at 1.0: a valid rate


# -- ε_test on a shifted log scale (spec.EPSILON_TEST_SHIFTED) ---------------------------------------


def _shifted_paper() -> StudySpec:
    """paper.toml with ε_test searched as epsilon_test_time_shifted over the same 0–0.9."""
    data = load_spec(CONFIGS / "paper.toml").to_dict()
    data["space"] = {k: v for k, v in data["space"].items() if k != "epsilon_test_time"}
    data["ladder"] = {k: v for k, v in data["ladder"].items() if not k.startswith("epsilon_test")}  # ε_test searched
    data["space"]["epsilon_test_time_shifted"] = {"low": 0.005, "high": 0.905, "log": True}
    return parse_spec(data)


def test_epsilon_test_shifted_spans_the_same_range_on_a_log_scale() -> None:
    """ε_test + 0.005 on a log scale: the corners are ε_test 0 and 0.9, every crowd value is reachable and maps back
    exactly, round trips hold, and about 58 % of random draws fall below 0.1 (11 % uniformly)."""
    spec = _shifted_paper()
    d = spec.dimensions["epsilon_test_time_shifted"]
    assert d.low is not None and d.high is not None
    assert (unshift_epsilon(d.low), unshift_epsilon(d.high)) == (0.0, 0.9)
    crowd = {float(row["epsilon_test_time"]) for row in _crowd_rows() if row["epsilon_test_time"] != ""}
    assert 0.0 in crowd and len(crowd) > 3
    for eps in crowd:
        assert d.low <= shift_epsilon(eps) <= d.high and unshift_epsilon(shift_epsilon(eps)) == eps
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=5))
    draws = []
    for _ in range(2000):
        params = space.sample(study.ask(), spec)
        config = space.to_config(spec, params)
        back = space.encode(spec, config)
        assert math.isclose(back["epsilon_test_time_shifted"], params["epsilon_test_time_shifted"], abs_tol=1e-12)
        assert space.to_config(spec, back) == config
        draws.append(config.epsilon_test_time)
    assert 0.0 <= min(draws) and max(draws) <= 0.9
    assert 0.54 < sum(e < 0.1 for e in draws) / len(draws) < 0.62


def test_epsilon_test_searched_twice_or_fixed_is_refused() -> None:
    base = {"study": {"name": "e", "n_trials": 1}, "space": {"epsilon_test_time_shifted": {"low": 0.005, "high": 0.5,
                                                                                         "log": True}}}  # fmt: skip
    with pytest.raises(SpecError, match=r"\[fixed\] also sets epsilon_test_time"):
        parse_spec({**base, "fixed": {"epsilon_test_time": 0.0}})
    with pytest.raises(SpecError, match=r"epsilon_test_time_shifted.*high 1\.5"):
        parse_spec({**base, "space": {"epsilon_test_time_shifted": {"low": 0.005, "high": 1.5, "log": True}}})
