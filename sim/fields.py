"""The DeepTraffic settings, defined once: name, alias, type, range or choices, defaults, one-line doc.

Every record that carries settings is derived from this table — the engine config
(``sim.config.EngineConfig``), the settings of a net file or a crowd submission
(``autotune.convnet.settings.Settings``, None = not set) and the training config
(``autotune.learner.config.TrainConfig``) get their fields, types, defaults and validation from it
(``sim.config.record``); the camelCase reader and writer, the search-space vocabulary and bounds, the
crowd study's bounds and every range message read it too. A new setting is one row here.

The defaults, each applied where the original applies it (engine_spec.md §10.1):

* ``page_default`` — the DeepTraffic game page's sample net (the ``default_v1`` preset): what a
  user gets by editing the template, so what a flat config lacking the key means;
* ``deepqlearn_default`` — what ``deepqlearn.js`` uses when ``opt`` lacks the key; for trainer
  keys, the ``tdtrainer_options`` the Brain passes when the user gives none (None: none, or
  computed — ``start_learn_threshold`` = ⌊min(0.1·experience_size, 1000)⌋);
* ``trainer_default`` — what convnetjs's ``Trainer`` uses for a key missing from a *given*
  ``tdtrainer_options`` object.
"""

from __future__ import annotations

import dataclasses

__all__ = [
    "Field",
    "FIELDS",
    "ALIASES",
    "GROUPS",
    "OPT_NAMES",
    "TRAINER_NAMES",
    "TRAINER_METHODS",
    "RULESETS",
    "field",
    "bounds",
    "group",
    "name_of",
]

GROUPS = ("site", "engine", "protocol", "opt", "trainer")
"""Where the original sets a field: the site version, the net.js globals, train.js, ``opt``, ``tdtrainer_options``."""
WRITES = ("always", "if-not-default", "with-method")
RULESETS = ("v1", "v2")
TRAINER_METHODS = ("sgd", "adagrad", "windowgrad", "adadelta", "nesterov")


@dataclasses.dataclass(frozen=True)
class Field:
    """One DeepTraffic setting."""

    name: str
    """snake_case name (ours, and deepqlearn's for ``opt`` / trainer keys)."""
    alias: str | None
    """Its flat name in DeepTraffic files when that differs: the camelCase global (``lanesSide``), or the
    config.json / crowd CSV column (``engine_version``, ``trainer_method``); None: the name itself."""
    kind: type
    """``int``, ``float`` or ``str`` (one of ``choices``)."""
    low: float | None
    """Smallest allowed value (inclusive unless ``low_open``); None for a str field."""
    high: float | None
    """Largest allowed value (inclusive); None for a str field."""
    page_default: int | float | str
    """Value in the DeepTraffic page's sample net (what a flat config lacking the key means)."""
    deepqlearn_default: int | float | str | None
    """deepqlearn.js's default for a key absent from ``opt`` / the Brain's own trainer options (None: none)."""
    group: str
    """Where the original sets it: one of ``GROUPS``."""
    doc: str
    """One line: meaning and unit."""
    trainer_default: int | float | str | None = None
    """convnetjs Trainer's default for a key missing from a given ``tdtrainer_options`` (trainer fields)."""
    choices: tuple[str, ...] = ()
    """The allowed values of a str field."""
    low_open: bool = False
    """``low`` itself is not allowed (a strictly positive quantity)."""
    required: bool = False
    """A net file must set it (it sizes the network's input)."""
    write: str = "always"
    """When the net.js ``tdtrainer_options`` writer includes it: 'always', 'if-not-default' (only when it
    differs from ``trainer_default``) or 'with-method' (only with a method other than sgd: its options)."""


FIELDS: tuple[Field, ...] = (
    Field("ruleset", "engine_version", str, None, None, "v2", None, "site",
          "engine rules: 'v2' (2018 multi-agent site) or 'v1' (2017 single-car engine)", choices=RULESETS),
    Field("lanes_side", "lanesSide", int, 0, 50, 0, None, "engine",
          "lanes seen on each side of the car's target lane [lanes]", required=True),
    Field("patches_ahead", "patchesAhead", int, 0, 70, 1, None, "engine",
          "grid rows (10 px) seen ahead of the car's front row [rows]", required=True),
    Field("patches_behind", "patchesBehind", int, 0, 70, 0, None, "engine",
          "grid rows seen from the car's front row backwards [rows]", required=True),
    Field("train_iterations", "trainIterations", int, 0, 100_000_000, 10000, None, "protocol",
          "training length, 30 frames each, split into runs as train.js does [decisions]"),
    Field("other_agents", "otherAgents", int, 0, 10, 0, None, "engine",
          "v2: extra red cars — random drivers in training, driven by the net in evaluation [cars]"),
    Field("temporal_window", None, int, 0, 100, 3, 1, "opt",
          "past (state, action) pairs appended to the input [decisions]"),
    Field("experience_size", None, int, 1, 2_000_000, 3000, 30000, "opt",
          "replay memory size; random replacement once full [transitions]"),
    Field("start_learn_threshold", None, int, 0, 2_000_000, 500, None, "opt",
          "learning starts once the memory holds more than this [transitions]"),
    Field("gamma", None, float, 0.0, 1.0, 0.7, 0.8, "opt",
          "discount of the TD target r + γ·max_a Q(s′, a) [1]"),
    Field("learning_steps_total", None, int, 0, 1_000_000_000, 10000, 100000, "opt",
          "age at which ε reaches epsilon_min [decisions]"),
    Field("learning_steps_burnin", None, int, 0, 1_000_000_000, 1000, 3000, "opt",
          "age until which ε = 1, fully random [decisions]"),
    Field("epsilon_min", None, float, 0.0, 1.0, 0.0, 0.05, "opt",
          "exploration floor during training [probability]"),
    Field("epsilon_test_time", None, float, 0.0, 1.0, 0.0, 0.01, "opt",
          "exploration when not learning (evaluation) [probability]"),
    Field("learning_rate", None, float, 0.0, 10.0, 0.001, 0.01, "trainer",
          "step size (unused by adadelta) [1]", trainer_default=0.01),
    Field("momentum", None, float, 0.0, 1.0, 0.0, 0.0, "trainer",
          "sgd momentum μ (v = μv − lr·g; w += v), and nesterov's [1]", trainer_default=0.9),
    Field("batch_size", None, int, 1, 4096, 64, 64, "trainer",
          "replay samples per update; one update per decision [samples]", trainer_default=1),
    Field("l2_decay", None, float, 0.0, 10.0, 0.01, 0.01, "trainer",
          "L2 weight decay on the weight gradients, not the biases [1]", trainer_default=0.0),
    Field("l1_decay", None, float, 0.0, 10.0, 0.0, None, "trainer",
          "L1 decay; fc layers have l1_decay_mul 0, so it acts only via a layer's mul [1]", trainer_default=0.0,
          write="if-not-default"),
    Field("method", "trainer_method", str, None, None, "sgd", None, "trainer",
          "trainer update rule (spec §10.9)", trainer_default="sgd", choices=TRAINER_METHODS,
          write="if-not-default"),
    Field("ro", None, float, 0.0, 1.0, 0.95, None, "trainer",
          "decay of the squared-gradient averages of windowgrad / adadelta [1]", trainer_default=0.95,
          write="with-method"),
    Field("eps", None, float, 0.0, 1.0, 1e-6, None, "trainer",
          "denominator guard of adagrad / windowgrad / adadelta [1]", trainer_default=1e-6, low_open=True,
          write="with-method"),
)  # fmt: skip

_BY_NAME = {f.name: f for f in FIELDS}
ALIASES: dict[str, str] = {f.alias: f.name for f in FIELDS if f.alias}
"""DeepTraffic's flat file names (camelCase globals, config.json / CSV columns) → our names."""
OPT_NAMES: tuple[str, ...] = tuple(f.name for f in FIELDS if f.group == "opt")
"""The ``opt`` keys of deepqlearn's ``Brain``, in the order net.js / the crowd files write them."""
TRAINER_NAMES: tuple[str, ...] = tuple(f.name for f in FIELDS if f.group == "trainer")
"""The ``tdtrainer_options`` keys, in the order net.js writes them."""


def name_of(key: str) -> str | None:
    """The field a key names (its snake_case name or its alias), None when it names none."""
    name = ALIASES.get(key, key)
    return name if name in _BY_NAME else None


def field(name: str) -> Field:
    """The field called ``name`` (snake_case or its alias); KeyError naming it otherwise."""
    try:
        return _BY_NAME[ALIASES.get(name, name)]
    except KeyError:
        raise KeyError(f"'{name}' is not a DeepTraffic field") from None


def bounds(name: str) -> tuple[float, float]:
    """``(low, high)`` of a numeric field, inclusive (for validation and search-space bounds)."""
    f = field(name)
    if f.low is None or f.high is None:
        raise KeyError(f"'{name}' is a choice ({', '.join(f.choices)}), not a range")
    return f.low, f.high


def group(name: str) -> tuple[Field, ...]:
    """The fields of one group (``GROUPS``), in table order."""
    return tuple(f for f in FIELDS if f.group == name)


def _check_table() -> None:
    for f in FIELDS:
        assert f.group in GROUPS and f.write in WRITES, f.name
        assert (f.kind is str) == bool(f.choices) == (f.low is None), f.name
        assert f.trainer_default is not None or f.group != "trainer", f.name


_check_table()
