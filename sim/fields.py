"""The DeepTraffic settings, defined once: name, camelCase alias, type, range, defaults, one-line doc.

Engine config (``sim.config.EngineConfig``), training config (``autotune.learner.config.TrainConfig``),
net settings (``autotune.convnet.netjson``) and search-space bounds all read this table; none
keeps its own copy of a name, an alias or a range. ``page_default`` is the DeepTraffic game page's
sample net (the ``default_v1`` preset); ``deepqlearn_default`` is what ``deepqlearn.js`` uses
when ``opt`` / ``tdtrainer_options`` lacks the key (spec §10.1; ``None``: not a deepqlearn key,
or computed — ``start_learn_threshold`` = ⌊min(0.1·experience_size, 1000)⌋).
"""

from __future__ import annotations

import dataclasses

__all__ = ["Field", "FIELDS", "ALIASES", "OPT_NAMES", "TRAINER_NAMES", "field", "bounds", "group"]


@dataclasses.dataclass(frozen=True)
class Field:
    """One DeepTraffic setting."""

    name: str
    """snake_case name (ours, and deepqlearn's for ``opt`` / trainer keys)."""
    alias: str | None
    """DeepTraffic's camelCase global (``lanesSide``), None when the name is already the original's."""
    kind: type
    """``int`` or ``float``."""
    low: float
    """Smallest allowed value (inclusive)."""
    high: float
    """Largest allowed value (inclusive)."""
    page_default: int | float
    """Value in the DeepTraffic page's sample net."""
    deepqlearn_default: int | float | None
    """deepqlearn.js's default for an absent key (None: none, or computed from other keys)."""
    group: str
    """Where the original sets it: 'engine' (net.js globals), 'protocol' (trainIterations), 'opt', 'trainer'."""
    doc: str
    """One line: meaning and unit."""


FIELDS: tuple[Field, ...] = (
    Field("lanes_side", "lanesSide", int, 0, 50, 0, None, "engine",
          "lanes seen on each side of the car's target lane [lanes]"),
    Field("patches_ahead", "patchesAhead", int, 0, 70, 1, None, "engine",
          "grid rows (10 px) seen ahead of the car's front row [rows]"),
    Field("patches_behind", "patchesBehind", int, 0, 70, 0, None, "engine",
          "grid rows seen from the car's front row backwards [rows]"),
    Field("other_agents", "otherAgents", int, 0, 10, 0, None, "engine",
          "v2: extra red cars driven by the same net [cars]"),
    Field("train_iterations", "trainIterations", int, 0, 100_000_000, 10000, None, "protocol",
          "training length, 30 frames each, split into runs as train.js does [decisions]"),
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
          "step size (unused by adadelta) [1]"),
    Field("momentum", None, float, 0.0, 1.0, 0.0, 0.0, "trainer",
          "sgd / nesterov momentum μ [1]"),
    Field("batch_size", None, int, 1, 4096, 64, 64, "trainer",
          "replay samples per update; one update per decision [samples]"),
    Field("l2_decay", None, float, 0.0, 10.0, 0.01, 0.01, "trainer",
          "L2 weight decay on the weight gradients, not the biases [1]"),
    Field("l1_decay", None, float, 0.0, 10.0, 0.0, None, "trainer",
          "L1 decay; acts only through a layer's l1_decay_mul [1]"),
)  # fmt: skip

_BY_NAME = {f.name: f for f in FIELDS}
ALIASES: dict[str, str] = {f.alias: f.name for f in FIELDS if f.alias}
"""DeepTraffic's camelCase globals → our names."""
OPT_NAMES: tuple[str, ...] = tuple(f.name for f in FIELDS if f.group == "opt")
"""The scalar ``opt`` keys of deepqlearn's ``Brain``, in the order net.js / the crowd files write them."""
TRAINER_NAMES: tuple[str, ...] = tuple(f.name for f in FIELDS if f.group == "trainer")
"""The numeric ``tdtrainer_options`` keys, in the order net.js / the crowd files write them."""


def field(name: str) -> Field:
    """The field called ``name`` (snake_case or its camelCase alias); KeyError naming it otherwise."""
    try:
        return _BY_NAME[ALIASES.get(name, name)]
    except KeyError:
        raise KeyError(f"'{name}' is not a DeepTraffic field") from None


def bounds(name: str) -> tuple[float, float]:
    """``(low, high)`` of a field, inclusive (for validation and search-space bounds)."""
    f = field(name)
    return f.low, f.high


def group(name: str) -> tuple[Field, ...]:
    """The fields of one group ('engine', 'protocol', 'opt', 'trainer'), in table order."""
    return tuple(f for f in FIELDS if f.group == name)
