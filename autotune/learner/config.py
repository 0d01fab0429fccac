"""Training configuration: every DeepTraffic / deepqlearn hyperparameter, typed and validated.

``TrainConfig`` holds the hyperparameters of the paper's Table 1 under DeepTraffic's own names
(``lanesSide`` → ``lanes_side``, ``trainIterations`` → ``train_iterations``; deepqlearn's ``opt``
and ``tdtrainer_options`` keys keep their names). Two ways to build one:

* **flat** — ``TrainConfig(lanes_side=1, …)``, ``TrainConfig.from_mapping({...})``,
  ``load_toml(path)``: keys are the field names or the DeepTraffic camelCase globals; an absent key
  takes the value of the **DeepTraffic page's default sample net** (engine_spec.md §10.8:
  L=0, P=1, B=0, 10,000 iterations, tw 3, fc(1, relu), lr 0.001, momentum 0, batch 64, l2 0.01,
  experience 3000, start 500, γ 0.7, total 10,000, burnin 1000, ε 0/0) — i.e. what a user gets
  by editing the template, which spells every one of these keys out.
* **nested** (``net.js`` / ``learner_scores.json`` form) — a mapping with ``opt`` and/or
  ``tdtrainer_options`` sub-mappings. Absent keys then follow convnetjs exactly (spec §10.1): a
  key missing from ``opt`` takes deepqlearn's library default (tw 1, experience 30000,
  start ⌊min(0.1·experience, 1000)⌋, γ 0.8, total 100000, burnin 3000, ε_min 0.05,
  ε_test 0.01); with no ``tdtrainer_options`` at all the Brain's own trainer options apply
  (lr 0.01, momentum 0, batch 64, l2 0.01), but a *given* ``tdtrainer_options`` object is handed
  to the Trainer, whose defaults fill its gaps: lr 0.01, l1 0, l2 0, batch 1, **momentum 0.9**,
  method sgd.

``layers`` is the hidden part of ``layer_defs`` (between the input layer, whose size deepqlearn
derives, and the final ``regression(5)``), as ``autotune.convnet.spec`` layer definitions; it accepts
the crowd's string form ``"fc:10:relu|fc:5:tanh"``, a list of netspec objects or a list of dicts
``{"type": "fc", "num_neurons": 10, "activation": "relu"}``.

Every violation raises ``ConfigError`` (the simulator's class) naming the field and the allowed
range; unknown keys name the nearest valid key.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from autotune.convnet import spec
from sim import fields
from sim.config import RULESETS, ConfigError, EngineConfig, input_size, nearest_key_error

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
TRAINER_METHODS = ("sgd", "adagrad", "windowgrad", "adadelta", "nesterov")
DTYPES = ("float32", "float64")
# fc activations: convnetjs's four, plus two strings that explicitly mean "none" ('softmax' occurs in
# the crowd's nets; convnetjs adds no layer for it, so the fc stays linear). Anything else is a typo.
ACTIVATIONS = ("relu", "tanh", "sigmoid", "maxout", "softmax", "linear")

# DeepTraffic's global names (and the crowd CSV's column names) → field names.
CAMEL_ALIASES = {**fields.ALIASES, "hidden_layers": "layers", "trainer_method": "method"}
# Keys of a nested (net.js-style) mapping that are documentation, not configuration.
IGNORED_KEYS = ("_comment", "comment", "description", "name")

# deepqlearn library defaults for keys absent from ``opt`` (spec §10.1).
# (start_learn_threshold: ⌊min(0.1·experience_size, 1000)⌋, computed from the experience size)
DEEPQLEARN_OPT_DEFAULTS: dict[str, Any] = {
    f.name: f.deepqlearn_default for f in fields.group("opt") if f.deepqlearn_default is not None
}
# deepqlearn's own tdtrainer_options when the user passes none.
BRAIN_TRAINER_DEFAULTS: dict[str, Any] = {
    f.name: f.deepqlearn_default for f in fields.group("trainer") if f.deepqlearn_default is not None
}
# convnetjs Trainer defaults for keys missing from a given tdtrainer_options object.
TRAINER_DEFAULTS: dict[str, Any] = {
    "learning_rate": 0.01,
    "l1_decay": 0.0,
    "l2_decay": 0.0,
    "batch_size": 1,
    "method": "sgd",
    "momentum": 0.9,
    "ro": 0.95,
    "eps": 1e-6,
}
OPT_KEYS = (
    *fields.OPT_NAMES,
    "layer_defs",
    "hidden_layer_sizes",
    "tdtrainer_options",
    "random_action_distribution",
)
TRAINER_KEYS = (*fields.TRAINER_NAMES, "method", "ro", "eps")


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


def _choice_error(field: str, value: Any, valid: Sequence[str]) -> ConfigError:
    close = difflib.get_close_matches(str(value), list(valid), n=1, cutoff=0.4)
    hint = f"; did you mean '{close[0]}'?" if close else ""
    return ConfigError(f"{field}: {value!r} is not allowed{hint} (use one of {', '.join(valid)})")


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
class TrainConfig:
    """One DeepTraffic training setup (engine + deepqlearn brain + trainer). Units in brackets."""

    # -- engine / input window (net.js globals) ---------------------------------------------
    ruleset: str = "v2"
    """Engine rules: 'v2' (2018 multi-agent site, default) or 'v1' (2017 single-car engine)."""
    lanes_side: int = 0
    """lanesSide [lanes]: lanes seen on each side of the car's target lane (0–50)."""
    patches_ahead: int = 1
    """patchesAhead [grid rows of 10 px]: rows seen ahead of the car's front row (0–70)."""
    patches_behind: int = 0
    """patchesBehind [grid rows]: rows seen from the car's front row backwards (0–70)."""
    other_agents: int = 0
    """otherAgents [cars]: v2 extra red cars (0–10); random drivers during training, the net in evaluation."""
    train_iterations: int = 10000
    """trainIterations [decisions]: training length; 30 frames each, split into runs as train.js does."""
    # -- deepqlearn opt ----------------------------------------------------------------------
    temporal_window: int = 3
    """temporal_window [decisions]: past (state, action) pairs appended to the input (0–100)."""
    experience_size: int = 3000
    """experience_size [transitions]: replay memory size; random replacement once full (1–2,000,000)."""
    start_learn_threshold: int = 500
    """start_learn_threshold [transitions]: learning starts once the memory holds more than this."""
    gamma: float = 0.7
    """gamma [1]: discount of the TD target r + γ·max_a Q(s′, a) (0–1)."""
    learning_steps_total: int = 10000
    """learning_steps_total [decisions]: age at which ε reaches epsilon_min."""
    learning_steps_burnin: int = 1000
    """learning_steps_burnin [decisions]: age until which ε = 1 (fully random)."""
    epsilon_min: float = 0.0
    """epsilon_min [probability]: exploration floor during training (0–1)."""
    epsilon_test_time: float = 0.0
    """epsilon_test_time [probability]: exploration when not learning (evaluation) (0–1)."""
    # -- network ------------------------------------------------------------------------------
    layers: tuple = (spec.FC(1, "relu"),)
    """Hidden layers (netspec defs; string 'fc:10:relu|fc:5:tanh' accepted); input and regression(5) implied."""
    # -- tdtrainer_options -------------------------------------------------------------------
    learning_rate: float = 0.001
    """learning_rate [1]: step size (unused by adadelta) (0–10)."""
    momentum: float = 0.0
    """momentum [1]: sgd momentum μ (v = μv − lr·g; w += v) and nesterov's μ (0–1)."""
    batch_size: int = 64
    """batch_size [samples]: replay samples per update; exactly one update per decision (1–4096)."""
    l2_decay: float = 0.01
    """l2_decay [1]: L2 weight decay added to the weight gradients, not the biases (0–10)."""
    l1_decay: float = 0.0
    """l1_decay [1]: L1 decay; convnetjs fc layers have l1_decay_mul 0, so it only acts via a layer's mul (0–10)."""
    method: str = "sgd"
    """Trainer method: sgd, adagrad, windowgrad, adadelta, nesterov (spec §10.9)."""
    ro: float = 0.95
    """ro [1]: decay of the squared-gradient averages of windowgrad/adadelta (0–1)."""
    eps: float = 1e-6
    """eps [1]: denominator guard of adagrad/windowgrad/adadelta (> 0)."""
    # -- implementation -----------------------------------------------------------------------
    dtype: str = "float32"
    """Training precision of the torch learner: 'float32' (fast) or 'float64' (as convnetjs)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "layers", parse_layers(self.layers))
        if self.ruleset not in RULESETS:
            raise ConfigError(f"ruleset: '{self.ruleset}' is not a ruleset; use one of {', '.join(RULESETS)}")
        ints = [(f.name, int(f.low), int(f.high)) for f in fields.FIELDS if f.kind is int]
        for name, lo, hi in ints:
            value = getattr(self, name)
            if isinstance(value, float) and value.is_integer():
                value = int(value)
                object.__setattr__(self, name, value)
            if isinstance(value, bool) or not isinstance(value, int):
                raise ConfigError(f"{name}: must be an integer in {lo}–{hi:,}, got {value!r}")
            if not lo <= value <= hi:
                raise ConfigError(f"{name}: {value} is out of range; allowed {lo}–{hi:,}")
        floats = [(f.name, f.low, f.high) for f in fields.FIELDS if f.kind is float] + [("ro", 0.0, 1.0)]
        for name, flo, fhi in floats:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"{name}: must be a number in [{flo:g}, {fhi:g}], got {value!r}")
            if not flo <= value <= fhi:
                raise ConfigError(f"{name}: {value!r} is out of range; allowed [{flo:g}, {fhi:g}]")
            object.__setattr__(self, name, float(value))
        if isinstance(self.eps, bool) or not isinstance(self.eps, (int, float)) or not (0.0 < self.eps <= 1.0):
            raise ConfigError(f"eps: {self.eps!r} is out of range; allowed (0, 1]")
        object.__setattr__(self, "eps", float(self.eps))
        if self.method not in TRAINER_METHODS:
            raise _choice_error("method", self.method, TRAINER_METHODS)
        if self.dtype not in DTYPES:
            raise ConfigError(f"dtype: '{self.dtype}' is not supported; use one of {', '.join(DTYPES)}")
        if self.start_learn_threshold >= self.experience_size:
            raise ConfigError(
                f"start_learn_threshold: {self.start_learn_threshold} ≥ experience_size {self.experience_size}; "
                "learning starts when the memory holds MORE than the threshold, so it would never start "
                f"(allowed 0–{self.experience_size - 1})"
            )
        self.engine_config  # noqa: B018 - validates the engine part (ranges, v1 without agents)
        try:
            sizes = spec.layer_sizes(self.expanded_layers)
        except spec.NetSpecError as exc:
            raise ConfigError(f"layers: {exc}") from None
        if sizes[-1][1] != NUM_ACTIONS:  # pragma: no cover - regression(5) is appended by us
            raise ConfigError("layers: the network must end in 5 outputs")

    # -- derived ------------------------------------------------------------------------------
    @property
    def engine_config(self) -> EngineConfig:
        """The simulator configuration (ruleset, input window, agents)."""
        return EngineConfig(
            ruleset=self.ruleset,
            lanes_side=self.lanes_side,
            patches_ahead=self.patches_ahead,
            patches_behind=self.patches_behind,
            other_agents=self.other_agents,
        )

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
    def hidden(self) -> str:
        """The crowd's string form of ``layers``."""
        return spec.format_hidden(self.layers)

    @property
    def schedule(self) -> tuple[int, int]:
        """(runs, frames per run) of the training protocol."""
        return run_schedule(self.train_iterations)

    @property
    def total_frames(self) -> int:
        """Frames actually simulated by the training protocol (⌈runs⌉·⌈frames⌉ ≥ 30·trainIterations)."""
        runs, frames = self.schedule
        return runs * frames

    def replace(self, **changes: Any) -> TrainConfig:
        """A copy with some fields changed (camelCase names accepted), validated again."""
        snake = {CAMEL_ALIASES.get(k, k): v for k, v in changes.items()}
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
        trainer: dict[str, Any] = {
            "learning_rate": self.learning_rate,
            "momentum": self.momentum,
            "batch_size": self.batch_size,
            "l2_decay": self.l2_decay,
        }
        if self.l1_decay:
            trainer["l1_decay"] = self.l1_decay
        if self.method != "sgd":
            trainer["method"] = self.method
            trainer["ro"] = self.ro
            trainer["eps"] = self.eps
        out: dict[str, Any] = {
            "lanesSide": self.lanes_side,
            "patchesAhead": self.patches_ahead,
            "patchesBehind": self.patches_behind,
            "trainIterations": self.train_iterations,
        }
        if self.ruleset == "v2":
            out["otherAgents"] = self.other_agents
        out.update(
            {
                "num_inputs": self.num_states,
                "num_actions": NUM_ACTIONS,
                "temporal_window": self.temporal_window,
                "network_size": self.net_inputs,
                "layer_defs": [_layer_to_dict(layer) for layer in self.layer_defs],
                "opt": {
                    "temporal_window": self.temporal_window,
                    "experience_size": self.experience_size,
                    "start_learn_threshold": self.start_learn_threshold,
                    "gamma": self.gamma,
                    "learning_steps_total": self.learning_steps_total,
                    "learning_steps_burnin": self.learning_steps_burnin,
                    "epsilon_min": self.epsilon_min,
                    "epsilon_test_time": self.epsilon_test_time,
                    "tdtrainer_options": trainer,
                },
            }
        )
        return out

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> TrainConfig:
        """Build from a flat or nested (``opt`` / ``tdtrainer_options``) mapping; see the module doc."""
        if not isinstance(values, Mapping):
            raise ConfigError(f"config: expected a mapping of settings, got {type(values).__name__}")
        names = [f.name for f in dataclasses.fields(cls)]
        valid = names + list(CAMEL_ALIASES) + ["opt", "tdtrainer_options", "layer_defs"]
        nested = "opt" in values or "tdtrainer_options" in values
        kwargs: dict[str, Any] = {}

        def put(key: str, value: Any, where: str) -> None:
            name = CAMEL_ALIASES.get(key, key)
            if name in kwargs and kwargs[name] != value:
                raise ConfigError(f"{where}{key}: given twice with different values ({kwargs[name]!r}, {value!r})")
            kwargs[name] = value

        for key, value in values.items():
            if key in IGNORED_KEYS or key in ("opt", "tdtrainer_options"):
                continue
            if key == "layer_defs":
                put("layers", _hidden_from_layer_defs(value), "")
                continue
            if key in ("num_inputs", "num_actions", "network_size"):
                continue  # derived quantities of net.js; checked below when nested
            if CAMEL_ALIASES.get(key, key) not in names:
                raise nearest_key_error("training config", key, valid)
            put(key, value, "")
        if nested:
            opt = values.get("opt", {}) or {}
            if not isinstance(opt, Mapping):
                raise ConfigError("opt: must be a mapping of deepqlearn options")
            for key, value in opt.items():
                if key in IGNORED_KEYS:
                    continue
                if key not in OPT_KEYS:
                    raise nearest_key_error("deepqlearn opt", key, list(OPT_KEYS))
                if key == "tdtrainer_options":
                    continue
                if key == "layer_defs":
                    put("layers", _hidden_from_layer_defs(value), "opt.")
                elif key == "hidden_layer_sizes":
                    put("layers", [spec.FC(int(n), "relu") for n in value], "opt.")
                elif key == "random_action_distribution":
                    raise ConfigError("opt.random_action_distribution: not supported (no DeepTraffic template uses it)")
                else:
                    put(key, value, "opt.")
            trainer = values.get("tdtrainer_options", opt.get("tdtrainer_options"))
            for key, default in DEEPQLEARN_OPT_DEFAULTS.items():
                kwargs.setdefault(key, default)
            if "start_learn_threshold" not in kwargs:
                exp = kwargs["experience_size"]
                kwargs["start_learn_threshold"] = int(math.floor(min(exp * 0.1, 1000)))
            if trainer is None:
                tdefaults = {**TRAINER_DEFAULTS, **BRAIN_TRAINER_DEFAULTS}
                trainer = {}
            else:
                if not isinstance(trainer, Mapping):
                    raise ConfigError("tdtrainer_options: must be a mapping of trainer options")
                tdefaults = TRAINER_DEFAULTS
            for key, value in trainer.items():
                if key not in TRAINER_KEYS:
                    raise nearest_key_error("tdtrainer_options", key, list(TRAINER_KEYS))
                put(key, value, "tdtrainer_options.")
            for key, default in tdefaults.items():
                kwargs.setdefault(key, default)
            kwargs.setdefault("layers", ())  # deepqlearn without layer_defs: a linear Q-function
        try:
            config = cls(**kwargs)
        except TypeError as exc:  # pragma: no cover - keys are checked above
            raise ConfigError(f"config: {exc}") from None
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

# the game page's sample net (other_agents and l1_decay: the page sets neither, 0 applies)
_DEFAULT_TEMPLATE: dict[str, Any] = {
    **{f.name: f.page_default for f in fields.FIELDS if f.name not in ("other_agents", "l1_decay")},
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
