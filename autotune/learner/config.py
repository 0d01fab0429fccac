"""Training configuration: every DeepTraffic / deepqlearn hyperparameter, typed and validated.

``TrainConfig`` is the settings record of ``sim.fields`` (``autotune.convnet.settings.Settings``)
with every field filled, plus the learner's own fields (``layers``, ``dtype``): its fields, types,
page defaults, ranges and messages come from the table (``sim.config.record``), under
DeepTraffic's own names (``lanesSide`` → ``lanes_side``, ``trainIterations`` →
``train_iterations``; deepqlearn's ``opt`` and ``tdtrainer_options`` keys keep theirs). What a
config does not set is filled by one function, ``Settings.filled``, each default where the original
applies it. Two ways to build one:

* **flat** — ``TrainConfig(lanes_side=1, …)``, ``TrainConfig.from_mapping({...})``,
  ``load_toml(path)``: keys are the field names or their aliases (camelCase globals, the crowd's
  columns); an absent key takes the value of the **DeepTraffic page's default sample net**
  (engine_spec.md §10.8: L=0, P=1, B=0, 10,000 iterations, tw 3, fc(1, relu), lr 0.001,
  momentum 0, batch 64, l2 0.01, experience 3000, start 500, γ 0.7, total 10,000, burnin 1000,
  ε 0/0) — i.e. what a user gets by editing the template, which spells every one of these keys out.
* **nested** (``net.js`` / ``learner_scores.json`` form) — a mapping with ``opt`` and/or
  ``tdtrainer_options`` sub-mappings. Absent keys then follow convnetjs exactly (spec §10.1): a
  key missing from ``opt`` takes deepqlearn's library default (tw 1, experience 30000,
  start ⌊min(0.1·experience, 1000)⌋, γ 0.8, total 100000, burnin 3000, ε_min 0.05,
  ε_test 0.01); with no ``tdtrainer_options`` at all the Brain's own trainer options apply
  (lr 0.01, momentum 0, batch 64, l2 0.01), but a *given* ``tdtrainer_options`` object is handed
  to the Trainer, whose defaults fill its gaps: lr 0.01, l1 0, l2 0, batch 1, **momentum 0.9**,
  method sgd (the ``page_default``, ``deepqlearn_default`` and ``trainer_default`` columns of
  ``sim.fields``). ``to_deepqlearn`` writes this form back (``settings.write_nested``).

``layers`` is the hidden part of ``layer_defs`` (between the input layer, whose size deepqlearn
derives, and the final ``regression(5)``), as ``autotune.convnet.spec`` layer definitions; it accepts
the crowd's string form ``"fc:10:relu|fc:5:tanh"``, a list of netspec objects or a list of dicts
``{"type": "fc", "num_neurons": 10, "activation": "relu"}``.

Every violation raises ``ConfigError`` (the simulator's class) naming the field and the allowed
range; unknown keys name the nearest valid key.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from autotune.convnet import spec
from autotune.convnet.settings import Settings, read, write_nested
from sim import fields
from sim.config import ConfigError, EngineConfig, did_you_mean, input_size, nearest_key_error, record
from sim.engine_v2 import DECISION_PERIOD  # the same 30 frames in both engines

__all__ = [
    "ConfigError",
    "TrainConfig",
    "PRESETS",
    "TRAINER_METHODS",
    "preset",
    "load_toml",
    "run_schedule",
    "parse_layers",
]

NUM_ACTIONS = spec.NUM_ACTIONS
TRAINER_METHODS = fields.TRAINER_METHODS
DTYPES = ("float32", "float64")
# fc activations: convnetjs's four, plus two strings that explicitly mean "none" ('softmax' occurs in
# the crowd's nets; convnetjs adds no layer for it, so the fc stays linear). Anything else is a typo.
ACTIVATIONS = ("relu", "tanh", "sigmoid", "maxout", "softmax", "linear")

# The crowd CSV's name of ``layers`` (the settings' own aliases are in ``sim.fields``).
LAYERS_ALIASES = {"hidden_layers": "layers"}
# Keys of a nested (net.js-style) mapping that are documentation, not configuration.
IGNORED_KEYS = ("_comment", "comment", "description", "name")
OPT_KEYS = (
    *fields.OPT_NAMES,
    "layer_defs",
    "hidden_layer_sizes",
    "tdtrainer_options",
    "random_action_distribution",
)


def parse_layers(value: Any) -> tuple[spec.Layer, ...]:
    """Hidden layers from a crowd string, netspec objects or ``{"type": …}`` dicts (``ConfigError`` on error)."""
    try:
        if value is None:
            return ()
        if isinstance(value, str):
            parsed = spec.parse_hidden(value)
            _check_activations(parsed)
            return parsed
        if isinstance(value, Mapping):
            value = [value]
        if not isinstance(value, Sequence):
            raise ConfigError(f"layers: expected a string like 'fc:10:relu|fc:5:tanh' or a list, got {value!r}")
        out: list[spec.Layer] = []
        for i, item in enumerate(value):
            if isinstance(item, tuple(spec.LAYER_TYPES.values())):
                out.append(item)  # type: ignore[arg-type]
            elif isinstance(item, Mapping):
                out.append(_layer_from_dict(item, i))
            elif isinstance(item, str):
                out.extend(spec.parse_hidden(item))
            else:
                raise ConfigError(
                    f"layers[{i}]: {item!r} is not a layer (use a dict with 'type' or a string 'fc:10:relu')"
                )
        _check_activations(out)
        return tuple(out)
    except spec.NetSpecError as exc:
        raise ConfigError(f"layers: {exc}") from None


def _choice_error(field: str, value: Any, valid: tuple[str, ...]) -> ConfigError:
    return ConfigError(
        f"{field}: {value!r} is not allowed{did_you_mean(str(value), valid)} (use one of {', '.join(valid)})"
    )


def _check_activations(layers: Sequence[spec.Layer]) -> None:
    for i, layer in enumerate(layers):
        if isinstance(layer, spec.FC) and layer.activation is not None and layer.activation not in ACTIVATIONS:
            raise _choice_error(f"layers[{i}].activation", layer.activation, ACTIVATIONS)


def _layer_from_dict(item: Mapping[str, Any], i: int) -> spec.Layer:
    kind = item.get("type", item.get("layer_type"))
    if kind is None and "num_neurons" in item:
        kind = "fc"  # learner_scores.json's hidden_layers entries: {num_neurons, activation}
    if kind is None:
        raise ConfigError(f"layers[{i}]: missing 'type' (one of {', '.join(spec.LAYER_TYPES)})")
    kind = str(kind).lower()
    if kind not in spec.LAYER_TYPES or kind == "input":
        valid = [k for k in spec.LAYER_TYPES if k != "input"]
        raise nearest_key_error(f"layers[{i}] layer type", kind, valid)
    cls = spec.LAYER_TYPES[kind]
    names = [f.name for f in dataclasses.fields(cls)]
    kwargs = {}
    for key, val in item.items():
        if key in ("type", "layer_type"):
            continue
        if key == "num_classes" and kind == "regression":
            key = "num_neurons"
        if key not in names:
            raise nearest_key_error(f"layers[{i}] ({kind})", key, names)
        kwargs[key] = val
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise ConfigError(f"layers[{i}] ({kind}): {exc}") from None


def _layer_to_dict(layer: spec.Layer) -> dict[str, Any]:
    out: dict[str, Any] = {"type": spec.layer_type(layer)}
    for f in dataclasses.fields(layer):
        v = getattr(layer, f.name)
        if v is not None and v != f.default:
            out[f.name] = v
        elif f.default is dataclasses.MISSING:
            out[f.name] = v
    return out


def run_schedule(train_iterations: int) -> tuple[int, int]:
    """train.js / train_webworker.js run split: ``(runs executed, frames per run)`` (spec §9, v2 §12).

    ``totalFrames = 30·it``, ``numRuns = totalFrames/100000 + 1``; ``doEvalRun(numRuns,
    totalFrames/numRuns)`` runs ``⌈numRuns⌉`` runs of ``⌈totalFrames/numRuns⌉`` frames
    (10,000 → 4 × 75,000; 30,000 → 10 × 90,000; 60,000 → 19 × 94,737; 8,000 → 4 × 70,589).
    ``(0, 0)`` for 0 iterations (train.js then skips training).
    """
    if train_iterations <= 0:
        return 0, 0
    total = 30 * train_iterations
    num_runs = total / 100000 + 1
    frames = total / num_runs
    return math.ceil(num_runs), math.ceil(frames)


@dataclasses.dataclass(frozen=True)
@record(complete=True)
class TrainConfig:
    """One DeepTraffic training setup: every ``sim.fields`` setting, filled, plus the learner's own fields.

    Build it with keywords (absent ones take the page's defaults), ``from_mapping`` (flat or nested,
    see the module doc) or ``from_settings``; ``settings`` gives the record back, ``to_deepqlearn``
    the net.js form.
    """

    layers: tuple = (spec.FC(1, "relu"),)
    """Hidden layers (netspec defs; string 'fc:10:relu|fc:5:tanh' accepted); input and regression(5) implied."""
    dtype: str = "float32"
    """Training precision of the torch learner: 'float32' (fast) or 'float64' (as convnetjs)."""

    if TYPE_CHECKING:

        def __init__(self, **values: Any) -> None: ...

        def __getattr__(self, name: str) -> Any: ...

    def __post_init__(self) -> None:
        object.__setattr__(self, "layers", parse_layers(self.layers))
        if self.dtype not in DTYPES:
            raise ConfigError(f"dtype: '{self.dtype}' is not supported; use one of {', '.join(DTYPES)}")
        if self.start_learn_threshold >= self.experience_size:
            raise ConfigError(
                f"start_learn_threshold: {self.start_learn_threshold} ≥ experience_size {self.experience_size}; "
                "learning starts when the memory holds MORE than the threshold, so it would never start "
                f"(allowed 0–{self.experience_size - 1})"
            )
        self.engine_config  # noqa: B018 - validates the engine part (the input is not empty, v1 without agents)
        try:
            sizes = spec.layer_sizes(self.expanded_layers)
        except spec.NetSpecError as exc:
            raise ConfigError(f"layers: {exc}") from None
        if sizes[-1][1] != NUM_ACTIONS:  # pragma: no cover - regression(5) is appended by us
            raise ConfigError("layers: the network must end in 5 outputs")

    # -- derived ------------------------------------------------------------------------------
    @property
    def settings(self) -> Settings:
        """The DeepTraffic settings record of this config (what its net.js sets; v1: no otherAgents)."""
        values = {f.name: getattr(self, f.name) for f in fields.FIELDS}
        if self.ruleset == "v1":
            values["other_agents"] = None
        return Settings(**values)

    @property
    def engine_config(self) -> EngineConfig:
        """The simulator configuration (ruleset, input window, other agents)."""
        return EngineConfig(**{f.name: getattr(self, f.name) for f in dataclasses.fields(EngineConfig)})

    @property
    def num_states(self) -> int:
        """Length of one state vector, (2·lanes_side + 1)·(patches_ahead + patches_behind)."""
        return input_size(self.lanes_side, self.patches_ahead, self.patches_behind)

    @property
    def net_inputs(self) -> int:
        """Network input size: num_states·tw + 5·tw + num_states (spec §10.2)."""
        return spec.net_input_size(self.num_states, self.temporal_window)

    @property
    def layer_defs(self) -> tuple[spec.Layer, ...]:
        """Full ``layer_defs``: input(net_inputs), the hidden layers, regression(5)."""
        return spec.deepqlearn_defs(self.net_inputs, self.layers)

    @property
    def expanded_layers(self) -> tuple[spec.Layer, ...]:
        """The layers convnetjs builds from ``layer_defs`` (activations and inserted fcs explicit)."""
        try:
            return spec.expand(self.layer_defs)
        except spec.NetSpecError as exc:
            raise ConfigError(f"layers: {exc}") from None

    @property
    def param_count(self) -> int:
        """Weights + biases of the convnetjs net this config builds (fc layers; maxout, svm, lrn add none)."""
        return spec.param_count(self.expanded_layers)

    @property
    def hidden(self) -> str:
        """The crowd's string form of ``layers``."""
        return spec.format_hidden(self.layers)

    @property
    def schedule(self) -> tuple[int, int]:
        """(runs, frames per run) of the training protocol."""
        return run_schedule(self.train_iterations)

    @property
    def ego_decisions(self) -> int:
        """Ego decisions of the training protocol: one every ``DECISION_PERIOD`` frames of each run."""
        runs, frames = self.schedule
        return runs * -(-frames // DECISION_PERIOD)

    @property
    def replay_rows(self) -> int:
        """Rows of replay memory the training fills at most: ``experience_size``, or fewer when the schedule makes
        fewer ego decisions (one transition is stored per decision). The learner allocates this many, as
        deepqlearn's array grows: allocated whole, a 10k rung with ``experience_size`` 309,884 on 8,167 inputs
        asked for 20 GB, and Ray's memory monitor killed its worker."""
        return max(1, min(self.experience_size, self.ego_decisions))

    @property
    def replay_bytes(self) -> int:
        """Bytes of that replay memory (s₀ and s₁ rows of ``net_inputs``, the action's one-hot, the reward)."""
        return self.replay_rows * (2 * self.net_inputs + NUM_ACTIONS + 1) * np.dtype(self.dtype).itemsize

    @property
    def total_frames(self) -> int:
        """Frames actually simulated by the training protocol (⌈runs⌉·⌈frames⌉ ≥ 30·trainIterations)."""
        runs, frames = self.schedule
        return runs * frames

    def replace(self, **changes: Any) -> TrainConfig:
        """A copy with some fields changed (camelCase names accepted), validated again."""
        snake = {LAYERS_ALIASES.get(k) or fields.name_of(k) or k: v for k, v in changes.items()}
        return TrainConfig.from_mapping({**self.to_mapping(), **snake})

    # -- (de)serialisation ------------------------------------------------------------------
    def to_mapping(self) -> dict[str, Any]:
        """Flat snake_case mapping (layers as the crowd string); ``from_mapping`` inverts it."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            out[f.name] = getattr(self, f.name)
        out["layers"] = self.hidden
        return out

    def to_deepqlearn(self) -> dict[str, Any]:
        """net.js-style settings: the globals, ``opt`` and ``tdtrainer_options`` as DeepTraffic writes them."""
        nested = write_nested(self.settings)
        opt = nested.pop("opt")
        return {
            **nested,
            "num_inputs": self.num_states,
            "num_actions": NUM_ACTIONS,
            "temporal_window": self.temporal_window,
            "network_size": self.net_inputs,
            "layer_defs": [_layer_to_dict(layer) for layer in self.layer_defs],
            "opt": opt,
        }

    @classmethod
    def from_settings(
        cls, settings: Settings, *, nested: bool, trainer_given: bool | None = None, **learner: Any
    ) -> TrainConfig:
        """``settings`` with what it leaves unset filled (``Settings.filled``) plus the learner's (layers, dtype).

        A nested (net.js) record without layers gets deepqlearn's linear Q-function, a flat one the page's fc(1).
        """
        if nested:
            learner.setdefault("layers", ())
        return cls(**settings.filled(nested=nested, trainer_given=trainer_given).values(), **learner)

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> TrainConfig:
        """Build from a flat or nested (``opt`` / ``tdtrainer_options``) mapping; see the module doc."""
        if not isinstance(values, Mapping):
            raise ConfigError(f"config: expected a mapping of settings, got {type(values).__name__}")
        nested = "opt" in values or "tdtrainer_options" in values
        given: dict[str, Any] = {}
        learner: dict[str, Any] = {}

        def merge(part: Mapping[str, Any], where: str) -> None:
            for name, value in part.items():
                if name in given and given[name] != value:
                    raise ConfigError(f"{where}{name}: given twice with different values ({given[name]!r}, {value!r})")
                given[name] = value

        def layers(value: Any, where: str) -> None:
            if "layers" in learner and learner["layers"] != value:
                raise ConfigError(f"{where}layers: given twice with different values")
            learner["layers"] = value

        top, others = read(values)
        merge(top, "")
        own = [f.name for f in dataclasses.fields(cls) if fields.name_of(f.name) is None]
        valid = [f.name for f in fields.FIELDS] + list(fields.ALIASES) + own + list(LAYERS_ALIASES)
        valid += ["opt", "tdtrainer_options", "layer_defs"]
        for key, value in others.items():
            if key in IGNORED_KEYS or key in ("opt", "tdtrainer_options", "num_inputs", "num_actions", "network_size"):
                continue  # opt: below; num_*: derived quantities of net.js, checked below when nested
            if key == "layer_defs":
                layers(_hidden_from_layer_defs(value), "")
            elif key in LAYERS_ALIASES or key == "layers":
                layers(parse_layers(value), "")
            elif key in own:
                learner[key] = value
            else:
                raise nearest_key_error("training config", key, valid)
        trainer = None
        if nested:
            opt = values.get("opt", {}) or {}
            if not isinstance(opt, Mapping):
                raise ConfigError("opt: must be a mapping of deepqlearn options")
            part, rest = read(opt, where="opt.", groups=("opt",), aliases=False)
            merge(part, "opt.")
            for key, value in rest.items():
                if key in IGNORED_KEYS or key == "tdtrainer_options":
                    continue
                if key not in OPT_KEYS:
                    raise nearest_key_error("deepqlearn opt", key, list(OPT_KEYS))
                if key == "layer_defs":
                    layers(_hidden_from_layer_defs(value), "opt.")
                elif key == "hidden_layer_sizes":
                    layers(tuple(spec.FC(int(n), "relu") for n in value), "opt.")
                else:  # random_action_distribution
                    raise ConfigError("opt.random_action_distribution: not supported (no DeepTraffic template uses it)")
            trainer = values.get("tdtrainer_options", opt.get("tdtrainer_options"))
            if trainer is not None:
                if not isinstance(trainer, Mapping):
                    raise ConfigError("tdtrainer_options: must be a mapping of trainer options")
                part, rest = read(trainer, where="tdtrainer_options.", groups=("trainer",), aliases=False)
                for key in rest:
                    raise nearest_key_error("tdtrainer_options", key, list(fields.TRAINER_NAMES))
                merge(part, "tdtrainer_options.")
        config = cls.from_settings(Settings(**given), nested=nested, trainer_given=trainer is not None, **learner)
        declared = values.get("num_inputs")
        if nested and declared is not None and declared != config.num_states:
            raise ConfigError(
                f"num_inputs: {declared} ≠ (2·lanesSide+1)·(patchesAhead+patchesBehind) = {config.num_states}"
            )
        return config


def _hidden_from_layer_defs(defs: Any) -> tuple[spec.Layer, ...]:
    """Hidden part of a full ``layer_defs`` list (drops the input layer and the final regression)."""
    layers = list(parse_layers(_strip_input(defs)))
    if layers and isinstance(layers[-1], spec.Regression):
        if layers[-1].num_neurons != NUM_ACTIONS:
            raise ConfigError(
                f"layer_defs: the final regression has {layers[-1].num_neurons} outputs; DeepTraffic needs 5"
            )
        layers.pop()
    else:
        raise ConfigError("layer_defs: must end with {type: 'regression', num_neurons: 5}")
    return tuple(layers)


def _strip_input(defs: Any) -> Any:
    if isinstance(defs, Sequence) and not isinstance(defs, str) and defs:
        first = defs[0]
        if (isinstance(first, Mapping) and first.get("type", first.get("layer_type")) == "input") or isinstance(
            first, spec.Input
        ):
            return list(defs[1:])
    return defs


def load_toml(path: str | Path) -> TrainConfig:
    """Read a training config from TOML (flat keys, or nested ``[opt]`` / ``[tdtrainer_options]`` tables)."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"config: file {p} not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config: {p} is not valid TOML ({exc})") from None
    return TrainConfig.from_mapping(data)


# --------------------------------------------------------------------------------------------
# presets (the reference configurations of learner_scores.json / learner_scores_v2.json)
# --------------------------------------------------------------------------------------------

# the game page's sample net: what its template spells out (not otherAgents or the trainer's other options)
_DEFAULT_TEMPLATE: dict[str, Any] = {
    **{
        f.name: f.page_default
        for f in fields.FIELDS
        if f.group != "site" and f.name != "other_agents" and f.write == "always"
    },
    "layers": "fc:1:relu",
}
_NETWORK_BASIC: dict[str, Any] = {
    **_DEFAULT_TEMPLATE,
    "lanes_side": 1,
    "patches_ahead": 10,
    "train_iterations": 30000,
    "temporal_window": 0,
    "layers": "fc:10:relu",
    "gamma": 0.5,
    "other_agents": 0,
}
_STRONG: dict[str, Any] = {
    **_DEFAULT_TEMPLATE,
    "lanes_side": 3,
    "patches_ahead": 30,
    "patches_behind": 5,
    "train_iterations": 60000,
    "temporal_window": 0,
    "layers": "fc:32:relu|fc:32:relu",
    "learning_rate": 0.0001,
    "experience_size": 100000,
    "start_learn_threshold": 5000,
    "gamma": 0.9,
    "learning_steps_total": 50000,
    "learning_steps_burnin": 5000,
    "epsilon_min": 0.05,
}

PRESETS: dict[str, dict[str, Any]] = {
    # learner_scores.json "default_v1.json": the game page's default sample net, v1 engine.
    "default_v1": {**_DEFAULT_TEMPLATE, "ruleset": "v1"},
    # the same template in the v2 engine (the 2018 site's sample code).
    "default_v2": {**_DEFAULT_TEMPLATE, "ruleset": "v2"},
    # lexfridman/deeptraffic network_basic.js (learner_scores_v2.json: v2; learner_scores.json: v1).
    "network_basic": {**_NETWORK_BASIC, "ruleset": "v2"},
    "network_basic_v2": {**_NETWORK_BASIC, "ruleset": "v2"},
    "network_basic_v1": {**_NETWORK_BASIC, "ruleset": "v1"},
    # learner_scores.json "strong.json" (v1 engine): L3 P30 B5, fc32×2, lr 1e-4, γ 0.9, 60k iterations.
    "strong": {**_STRONG, "ruleset": "v1"},
    # learner_scores.json "strong_lr1e-3.json": the diverging variant (γ 0.95, lr 1e-3, 10k iterations).
    "strong_lr1e-3": {
        **_STRONG,
        "ruleset": "v1",
        "train_iterations": 10000,
        "learning_rate": 0.001,
        "gamma": 0.95,
        "learning_steps_total": 80000,
    },
}


def preset(name: str, **overrides: Any) -> TrainConfig:
    """A named reference configuration (``PRESETS``), optionally with some fields changed."""
    if name not in PRESETS:
        raise nearest_key_error("preset", name, list(PRESETS))
    return TrainConfig.from_mapping({**PRESETS[name], **overrides})
