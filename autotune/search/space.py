"""The search space as a pure function of the trial: sample, decode to a TrainConfig, encode back.

``sample(trial, spec)`` uses only ``trial.suggest_int / suggest_float / suggest_categorical``
(duck typing: this module does not import optuna), so the same code serves an Optuna trial, a
fixed-params trial or a test double. Params are in sampling coordinates — ``one_minus_gamma``
on a log scale instead of gamma, the learning rate per input (``learning_rate_x_inputs``), optionally ε_test + 0.005
on a log scale (``epsilon_test_time_shifted``), ε's schedule
as fractions of the budget in a ladder study — and
``to_config`` turns them into the real TrainConfig; ``encode`` is the inverse, so crowd submissions
enter a study under the same names. ``check`` is a loaded spec's last validation: its space's corners
must map to configurations deepqlearn accepts. This module reads ``autotune.search.spec`` (the parsed
tables); the spec never reads it.

The layout is fixed-shape: ``n_layers``, then ``neurons_i`` / ``activation_i`` for EVERY i below the
space's largest n_layers, of which the first n_layers are used. Every trial then has the same
parameters, so multivariate TPE models them jointly and GP / CMA-ES do not fall back to independent
sampling; the reachable configurations are those of the define-by-run layout (tests).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any, Protocol

from autotune import TrainConfig, format_hidden
from autotune.convnet import spec as netspec
from autotune.search.ladder import cap_start, relative_schedule
from autotune.search.spec import (
    _FIELD_OF,
    EPSILON_TEST_SHIFTED,
    FRACTIONS,
    LAYOUT,
    LR_X_INPUTS,
    Dimension,
    SpecError,
    StudySpec,
    build_config,
    one_minus,
    shift_epsilon,
    unshift_epsilon,
)  # fmt: skip
from sim import fields
from sim.config import ConfigError

__all__ = [
    "DEFAULT_SPACE", "PAPER_SPACE", "Trial", "sample", "dimensions", "to_config", "check", "encode", "active",
    "unencodable",
    "outside",
]  # fmt: skip


class Trial(Protocol):
    """What ``sample`` needs of a trial (Optuna's ``Trial`` has it)."""

    def suggest_int(self, name: str, low: int, high: int, *, step: int = 1, log: bool = False) -> int: ...

    def suggest_float(
        self, name: str, low: float, high: float, *, step: float | None = None, log: bool = False
    ) -> float: ...

    def suggest_categorical(self, name: str, choices: Any) -> Any: ...


def _table_range(name: str) -> dict[str, Any]:
    """A [space] entry spanning the field's whole range in ``sim.fields``."""
    low, high = fields.bounds(name)
    return {"low": low, "high": high}


# The paper's full space (Table 1 + the layout), as [space] entries (paper.toml spells out the same).
# Bounds cover what the crowd explored (shared/crowd/submissions.csv, 164 rows, min–max of each column
# in brackets) within what the site accepts (sim.fields: a range that is the table's is read from it);
# log scales where the crowd spans decades.
DEFAULT_SPACE: dict[str, dict[str, Any]] = {
    # crowd 0–50, but 162/164 rows ≤ 10 and two at 50: the road has 7 lanes, so beyond 6 a net only
    # sees off-road zeros (lanes_side 50 is lanes_side 6 plus dead inputs); 10 covers all but those two.
    "lanes_side": {"low": 0, "high": 10},
    "patches_ahead": {"low": 1, "high": 60},  # crowd 1–55; ≥ 1 so the input is never empty
    "patches_behind": {"low": 0, "high": 20},  # crowd 0–20
    "other_agents": _table_range("other_agents"),  # crowd 0–10 (v2 files)
    "temporal_window": {"low": 0, "high": 10},  # crowd 0–10
    "train_iterations": {"low": 5_000, "high": 1_000_000, "log": True},  # crowd 5,000–1,000,000
    "experience_size": {"low": 1_000, "high": 500_000, "log": True},  # crowd 1,000–500,000 (one 0: rejected)
    # crowd 100–100,000; capped at experience_size − 1 per trial (see autotune.search.spec)
    "start_learn_threshold": {"low": 100, "high": 100_000, "log": True},
    "batch_size": {"low": 1, "high": 512, "log": True},  # crowd 1–265
    "learning_rate": {"low": 1e-8, "high": 1e-2, "log": True},  # crowd 1e-8–0.01 (mode 0.001)
    "l2_decay": {"low": 1e-8, "high": 1.0, "log": True},  # crowd 1e-8–0.79 (mode 0.01)
    # crowd 0–1 (one 5: rejected by the site's range); mode 0
    "momentum": _table_range("momentum"),
    "one_minus_gamma": {"low": 1e-4, "high": 0.7, "log": True},  # crowd gamma 0.3–0.99985
    "learning_steps_total": {"low": 10_000, "high": 500_000, "log": True},  # crowd 10,000–500,000
    "learning_steps_burnin": {"low": 100, "high": 100_000, "log": True},  # crowd 300–75,000
    "epsilon_min": {"low": 0.0, "high": 0.7},  # crowd 0–0.65 (mode 0)
    "epsilon_test_time": {"low": 0.0, "high": 0.9},  # crowd 0–0.9 (mode 0)
    "n_layers": {"low": 0, "high": 8},  # crowd 0–8 hidden layers
    # crowd 1–3000 per layer; low 2 because a 1-neuron maxout layer has no output (the 1-neuron layers
    # are the page's unscored fc:1:relu template)
    "neurons": {"low": 2, "high": 4096, "log": True},
    # crowd: relu, tanh, maxout (+ 2 'softmax' fc activations, which convnetjs ignores: linear);
    # sigmoid is convnetjs's fourth activation
    "activation": {"choices": ["relu", "tanh", "sigmoid", "maxout"]},
}

# learning_rate × net_inputs (spec.LR_X_INPUTS): crowd 6.8e-6–9.3, its sgd nets of 74+ mph 0.1–0.8
_LR_X_INPUTS_RANGE = {"low": 1e-6, "high": 10.0, "log": True}

# paper.toml's space: the same Table-1 settings on a budget ladder — the training length is the ladder's,
# the learning rate is searched per input of the net (its good range moves far less with the view: spec.LR_X_INPUTS),
# ε's schedule is searched as fractions of each rung's budget (crowd: burn-in 0.06 %–37.5 % of
# trainIterations, decay end 1 %–2,500 %, 10–90 % quantiles 0.5 %–20 % and 10 %–150 %), and the trainer
# method joins (the best v2 human net, jnorthrup-v05, trained with adagrad; convnetjs's three methods); ε_test
# leaves the space: paper.toml's [ladder] epsilon_test_grid chooses it per trained net (crowd 0–0.9).
PAPER_SPACE: dict[str, dict[str, Any]] = {
    **{(LR_X_INPUTS if k == "learning_rate" else k): (_LR_X_INPUTS_RANGE if k == "learning_rate" else v)
       for k, v in DEFAULT_SPACE.items()
       if k not in ("train_iterations", "learning_steps_total", "learning_steps_burnin", "n_layers", "neurons",
                    "activation", "epsilon_test_time")},
    "learning_steps_burnin_fraction": {"low": 5e-4, "high": 0.5, "log": True},
    "learning_steps_total_fraction": {"low": 0.01, "high": 5.0, "log": True},
    "method": {"choices": ["sgd", "adagrad", "adadelta"]},
    "n_layers": DEFAULT_SPACE["n_layers"],
    "neurons": DEFAULT_SPACE["neurons"],
    "activation": DEFAULT_SPACE["activation"],
}  # fmt: skip
"""``study_configs/paper.toml``'s [space] (a test keeps the two equal)."""


_FC_RE = re.compile(r"^fc:(\d+)(?::([A-Za-z]+))?$")


def sample(trial: Trial, spec: StudySpec) -> dict[str, Any]:
    """Suggest every [space] parameter of ``spec`` on ``trial``; returns the params (sampling coordinates)."""
    return {name: _suggest(trial, d, name) for name, d in dimensions(spec).items()}


def dimensions(spec: StudySpec) -> dict[str, Dimension]:
    """Every parameter of the space by its name, in sampling order (the layout expanded to fixed shape)."""
    out: dict[str, Dimension] = {}
    dims = spec.dimensions
    for d in spec.space:
        if d.name in LAYOUT:
            if d.name == "n_layers":
                out["n_layers"] = d
                for i in range(spec.max_layers):
                    out[f"neurons_{i}"] = dims["neurons"]
                    out[f"activation_{i}"] = dims["activation"]
            continue
        out[d.name] = d
    return out


def _suggest(trial: Trial, d: Dimension, name: str) -> Any:
    if d.kind == "categorical":
        return trial.suggest_categorical(name, list(d.choices))
    assert d.low is not None and d.high is not None
    if d.kind == "int":
        return trial.suggest_int(name, int(d.low), int(d.high), step=int(d.step or 1), log=d.log)
    return trial.suggest_float(name, float(d.low), float(d.high), step=d.step, log=d.log)


def to_config(spec: StudySpec, params: Mapping[str, Any], budget: int | None = None) -> TrainConfig:
    """The TrainConfig a trial trains: [fixed] ∪ the decoded params (ConfigError if deepqlearn rejects it).

    ``start_learn_threshold`` (unless fixed) is capped at ``experience_size − 1``; gamma is
    ``1 − one_minus_gamma`` printed to 15 significant digits (so 0.3 stays 0.3 after the round trip).
    A searched ``learning_rate_x_inputs`` is divided by the configuration's ``net_inputs`` (15 significant digits).
    In a ladder study ``budget`` is the training length (default: the ladder's last rung), the
    ε fractions become iterations at it and the threshold is capped at a quarter of it.
    """
    expected = _param_names(spec, params)
    unknown = [k for k in params if k not in expected]
    if unknown:
        raise SpecError(f"params: {unknown[0]!r} is not a parameter of this space; expected {', '.join(expected)}")
    missing = [k for k in expected if k not in params]
    if missing:
        raise SpecError(f"params: {missing[0]!r} is missing; sample() gives every parameter of the space")
    values = spec.fixed_values
    fractions: dict[str, float] = {}
    lr_x_inputs: float | None = None
    for d in spec.space:
        if d.name in LAYOUT:
            continue
        if d.name == "one_minus_gamma":
            values["gamma"] = one_minus(params["one_minus_gamma"])
        elif d.name == EPSILON_TEST_SHIFTED:
            values["epsilon_test_time"] = unshift_epsilon(params[EPSILON_TEST_SHIFTED])
        elif d.name == LR_X_INPUTS:
            lr_x_inputs = float(params[LR_X_INPUTS])
        elif d.name in FRACTIONS:
            fractions[d.name] = float(params[d.name])
        else:
            values[d.name] = params[d.name]
    if spec.searches_layout:
        n = params["n_layers"]
        values["layers"] = "|".join(f"fc:{params[f'neurons_{i}']}:{params[f'activation_{i}']}" for i in range(n))
    cap = "start_learn_threshold" not in spec.fixed_values
    if spec.ladder:
        b = int(budget if budget is not None else spec.ladder[-1])
        values["train_iterations"] = b
        burnin_f = fractions.get(FRACTIONS[0])
        total_f = fractions.get(FRACTIONS[1])
        if burnin_f is not None or total_f is not None:
            d = TrainConfig()
            if burnin_f is None:
                burnin_f = values.get("learning_steps_burnin", d.learning_steps_burnin) / b
            if total_f is None:
                total_f = values.get("learning_steps_total", d.learning_steps_total) / b
            values["learning_steps_burnin"], values["learning_steps_total"] = relative_schedule(b, burnin_f, total_f)
        if cap:
            exp = values.get("experience_size", TrainConfig().experience_size)
            start = values.get("start_learn_threshold", TrainConfig().start_learn_threshold)
            values["start_learn_threshold"] = cap_start(int(start), int(exp), b)
    if lr_x_inputs is not None:  # the input width follows from the view, fixed or searched
        width = build_config(spec.ruleset, values, cap_start=cap).net_inputs
        values["learning_rate"] = float(f"{lr_x_inputs / width:.15g}")  # 15 digits: encode's product maps back
    return build_config(spec.ruleset, values, cap_start=cap)


def check(spec: StudySpec) -> StudySpec:
    """``spec`` if its space maps to valid configurations, else ``SpecError`` naming the corner and the fix.

    Probed: every parameter at its low corner, every one at its high corner (with [fixed]), the largest
    learning rate per input on the narrowest view, and the narrowest layer with each activation — where
    deepqlearn's own rules (an empty input, a 1-neuron maxout layer, a rate above 10, …) reject a combination
    the per-key ranges allow.
    """
    for label, params in _probe_points(spec):
        try:
            to_config(spec, params)
        except ConfigError as exc:
            raise SpecError(f"{spec.source}: [space] {label} of the space (with [fixed]) is rejected: "
                            f"{' '.join(str(exc).split())}; narrow the range") from None  # fmt: skip
    return spec


def _probe_points(spec: StudySpec) -> list[tuple[str, dict[str, Any]]]:
    """Params at the low and the high corner, and the narrowest layer with every activation."""
    points: list[tuple[str, dict[str, Any]]] = []
    for label, pick in (("the low corner", 0), ("the high corner", -1)):
        params: dict[str, Any] = {}
        for d in spec.space:
            if d.name in LAYOUT:
                continue
            params[d.name] = _corner(d, pick)
        if spec.searches_layout:
            dims = spec.dimensions
            params["n_layers"] = _corner(dims["n_layers"], pick)
            for i in range(spec.max_layers):
                params[f"neurons_{i}"] = _corner(dims["neurons"], pick)
                params[f"activation_{i}"] = dims["activation"].choices[pick]
        points.append((label, params))
    dims = spec.dimensions
    if LR_X_INPUTS in dims:  # the largest learning rate: the largest product on the narrowest view
        points.append((f"{LR_X_INPUTS}'s high with the narrowest view",
                       {**points[0][1], LR_X_INPUTS: _corner(dims[LR_X_INPUTS], -1)}))  # fmt: skip
    if spec.searches_layout:
        if max(_corner(dims["n_layers"], 0), _corner(dims["n_layers"], -1)) >= 1:
            narrow = _corner(dims["neurons"], 0)
            for act in dims["activation"].choices:
                params = {**points[0][1], "n_layers": 1, "neurons_0": narrow, "activation_0": act}
                for i in range(1, spec.max_layers):
                    params[f"neurons_{i}"], params[f"activation_{i}"] = narrow, act
                points.append((f"neurons {narrow} with activation {act!r}", params))
    return points


def _corner(d: Dimension, pick: int) -> Any:
    if d.kind == "categorical":
        numeric = all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in d.choices)
        return sorted(d.choices)[pick] if numeric else d.choices[pick]
    return d.low if pick == 0 else d.high


def _param_names(spec: StudySpec, params: Mapping[str, Any]) -> list[str]:
    return list(dimensions(spec))


def encode(spec: StudySpec, config: TrainConfig) -> dict[str, Any]:
    """The params of a real config in this space's coordinates: the one encoder (crowd import, tests); inverse of
    ``to_config`` on what the space can draw.

    Values outside the space's ranges or choices are returned as they are (``outside`` lists them).
    v1 has no other agents, so a v1 config has no ``other_agents`` param. Layout: every hidden layer
    with neurons is one (``fc:n:act`` → neurons n and its activation, 'linear' when it has none
    of convnetjs's; ``svm:n`` → neurons n, activation 'svm', which no space offers); a layer
    without neurons (lrn, dropout) is no parameter and is left out; the unused slots of the fixed
    shape take their range's first value (``active`` leaves them out).
    """
    params: dict[str, Any] = {}
    for d in spec.space:
        if d.name in LAYOUT or (d.name == "other_agents" and config.ruleset == "v1"):
            continue
        if d.name in FRACTIONS:
            steps = config.learning_steps_burnin if d.name == FRACTIONS[0] else config.learning_steps_total
            params[d.name] = steps / max(1, config.train_iterations)
            continue
        if d.name == LR_X_INPUTS:
            params[d.name] = config.learning_rate * config.net_inputs
            continue
        if d.name == EPSILON_TEST_SHIFTED:
            params[d.name] = shift_epsilon(config.epsilon_test_time)
            continue
        value = getattr(config, _FIELD_OF.get(d.name, d.name))
        params[d.name] = one_minus(value) if d.name == "one_minus_gamma" else value
    if spec.searches_layout:
        layers = [layer for layer in config.layers if isinstance(layer, (netspec.FC, netspec.SVM))]
        params["n_layers"] = len(layers)
        for i, layer in enumerate(layers):
            if isinstance(layer, netspec.FC):
                params[f"neurons_{i}"] = layer.num_neurons
                params[f"activation_{i}"] = layer.activation if layer.activation in netspec.ACTIVATIONS else "linear"
            else:
                params[f"neurons_{i}"] = layer.num_classes
                params[f"activation_{i}"] = "svm"
        dims = spec.dimensions
        for i in range(len(layers), spec.max_layers):  # unused slots of the fixed shape: the first value of each
            params[f"neurons_{i}"] = _first(dims["neurons"])
            params[f"activation_{i}"] = _first(dims["activation"])
    return params


def unencodable(config: TrainConfig) -> list[str]:
    """One line per hidden layer the layout cannot express (not a plain ``fc:N[:activation]``): what ``encode``
    changes (svm → activation 'svm') or leaves out (lrn, dropout); empty when the params are the config."""
    problems = []
    for i, layer in enumerate(config.layers):
        text = format_hidden([layer])
        if _FC_RE.match(text) is None:
            problems.append(
                f"hidden layer {i} '{text}' is not fc:N[:activation]; the layout space only has plain fc layers"
            )
    return problems


def active(params: Mapping[str, Any]) -> dict[str, Any]:
    """The params that shape the configuration: without the unused slots of the fixed-shape layout
    (``neurons_i`` / ``activation_i`` for i ≥ n_layers) — what a record of a configuration shows."""
    n = params.get("n_layers")
    if not isinstance(n, int):
        return dict(params)
    return {
        k: v for k, v in params.items()
        if not (k.startswith(("neurons_", "activation_")) and int(k.rsplit("_", 1)[1]) >= n)
    }  # fmt: skip


def _first(d: Dimension) -> Any:
    if d.kind == "categorical":
        return d.choices[0]
    return int(d.low) if d.kind == "int" else d.low  # type: ignore[arg-type]


def outside(spec: StudySpec, params: Mapping[str, Any]) -> list[str]:
    """One line per param outside the space's ranges or choices (empty: Optuna can store them as is)."""
    dims = spec.dimensions
    problems = []
    for name, value in params.items():
        base = re.sub(r"_\d+$", "", name) if name.startswith(("neurons_", "activation_")) else name
        d = dims.get(base)
        if d is None:
            problems.append(f"{name}: not searched")
        elif d.kind == "categorical":
            if value not in d.choices:
                problems.append(f"{name}: {value!r} not in {list(d.choices)}")
        elif d.low is not None and d.high is not None and not d.low <= value <= d.high:
            problems.append(f"{name}: {value!r} outside [{d.low}, {d.high}]")
    return problems
