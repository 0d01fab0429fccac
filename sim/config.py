"""Settings records from ``sim.fields``: one check per value, the record decorator, and the engine configuration.

``check`` is the one validation of a setting's value (type, range or choices, message from the
table); ``record`` turns a class into a frozen dataclass whose fields are the table's (types,
defaults, validation, docs), so no record re-declares a setting. ``EngineConfig`` is the record of
what the simulator needs (engine_spec.md §7, v2 §8–§9). The names are DeepTraffic's own
(``lanesSide`` → ``lanes_side``, ``otherAgents`` → ``other_agents``); building a config from a
mapping accepts the original camelCase spellings too and rejects unknown keys with the nearest
valid name.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, TypeVar

from sim import fields

__all__ = [
    "RULESETS",
    "ConfigError",
    "FieldValueError",
    "EngineConfig",
    "check",
    "check_other_agents",
    "did_you_mean",
    "input_size",
    "nearest_key_error",
    "record",
]

RULESETS = fields.RULESETS
V1_NO_AGENTS = "the v1 engine has no other agents"

# DeepTraffic's global names → ours (the engine's; ``sim.fields`` is the one table).
CAMEL_ALIASES = {f.alias: f.name for f in (*fields.group("site"), *fields.group("engine")) if f.alias}


def input_size(lanes_side: int, patches_ahead: int, patches_behind: int) -> int:
    """Length of one car's input vector, (2·lanes_side + 1)·(patches_ahead + patches_behind) (v1 §7)."""
    return (2 * lanes_side + 1) * (patches_ahead + patches_behind)


class ConfigError(ValueError):
    """A configuration value or key is invalid; the message names the field and the fix."""


class FieldValueError(ConfigError):
    """A value outside its field's type, range or choices; ``problem`` is the message without the field's name,
    for callers that name the field their own way (a CSV column, a key path in a file)."""

    def __init__(self, name: str, problem: str) -> None:
        super().__init__(f"{name}: {problem}")
        self.name = name
        self.problem = problem


def did_you_mean(key: str, valid: tuple[str, ...] | list[str]) -> str:
    """``"; did you mean 'x'?"`` for the valid name closest to ``key``, or '' when none is close."""
    close = difflib.get_close_matches(key, list(valid), n=1, cutoff=0.4)
    return f"; did you mean '{close[0]}'?" if close else ""


def nearest_key_error(kind: str, key: str, valid: list[str] | tuple[str, ...]) -> ConfigError:
    """Error for an unknown key, naming the closest valid one."""
    return ConfigError(f"unknown {kind} key '{key}'{did_you_mean(key, valid)} (valid: {', '.join(sorted(valid))})")


def _allowed(f: fields.Field) -> str:
    if f.kind is str:
        return ", ".join(f.choices)
    assert f.low is not None and f.high is not None
    if f.kind is int:
        return f"{int(f.low)}–{int(f.high):,}"
    return f"{'(' if f.low_open else '['}{f.low:g}, {f.high:g}]"


def check(f: fields.Field, value: Any, *, ranges: bool = True) -> Any:
    """``value`` as field ``f`` holds it (integral floats → int, ints → float); ``FieldValueError`` otherwise.

    ``ranges=False`` checks the type only (what a file may say; the learner checks the range).
    """
    if f.kind is str:
        if not isinstance(value, str) or value not in f.choices:
            raise FieldValueError(f.name, f"{value!r} is not allowed{did_you_mean(str(value), f.choices)} "
                                          f"(use one of {_allowed(f)})")  # fmt: skip
        return value
    assert f.low is not None and f.high is not None
    if f.kind is int:
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            raise FieldValueError(f.name, f"must be an integer in {_allowed(f)}, got {value!r}")
        if ranges and not f.low <= value <= f.high:
            raise FieldValueError(f.name, f"{value} is out of range; allowed {_allowed(f)}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise FieldValueError(f.name, f"must be a number in {_allowed(f)}, got {value!r}")
    inside = (f.low < value if f.low_open else f.low <= value) and value <= f.high
    if ranges and not inside:
        raise FieldValueError(f.name, f"{value!r} is out of range; allowed {_allowed(f)}")
    return float(value)


def check_other_agents(ruleset: str, other_agents: int | None) -> None:
    """The one rule between the two engine settings: v1 has no other agents."""
    if ruleset == "v1" and other_agents:
        raise ConfigError(f"other_agents: {V1_NO_AGENTS}; use ruleset 'v2' or other_agents = 0")


T = TypeVar("T")


def record(*groups: str, complete: bool) -> Callable[[type[T]], type[T]]:
    """Class decorator (under ``@dataclasses.dataclass(frozen=True)``): the table's fields become the record's.

    The fields of ``groups`` (every group when none is named), in table order, come before the
    class's own annotated fields. ``complete=True``: each is ``kind`` with its page default and is
    checked against its range; ``complete=False``: each is ``kind | None`` with default None (not
    set) and a set value is checked for its type only. The class's own ``__post_init__`` runs after
    the checks; its docstring gains the field list. Type checkers see the fields as ``Any``
    attributes (declare ``__init__(**values)`` and ``__getattr__`` under ``TYPE_CHECKING``).
    """
    chosen = tuple(f for f in fields.FIELDS if not groups or f.group in groups)

    def apply(cls: type[T]) -> type[T]:
        own = dict(cls.__dict__.get("__annotations__", {}))
        clash = [f.name for f in chosen if f.name in own]
        if clash:
            raise TypeError(f"{cls.__name__}: {', '.join(clash)} declared again; sim.fields defines them")
        table: dict[str, Any] = {}
        for f in chosen:
            table[f.name] = f.kind.__name__ if complete else f"{f.kind.__name__} | None"
            setattr(cls, f.name, f.page_default if complete else None)
        cls.__annotations__ = {**table, **own}
        own_post = cls.__dict__.get("__post_init__")

        def __post_init__(self: Any) -> None:
            for f in chosen:
                value = getattr(self, f.name)
                if value is None and not complete:
                    continue
                checked = check(f, value, ranges=complete)
                if checked is not value:
                    object.__setattr__(self, f.name, checked)
            if own_post is not None:
                own_post(self)

        cls.__post_init__ = __post_init__  # type: ignore[attr-defined]
        cls.__doc__ = (cls.__doc__ or "").rstrip() + _fields_doc(chosen, complete)
        return cls

    return apply


def _fields_doc(chosen: tuple[fields.Field, ...], complete: bool) -> str:
    head = "Fields from ``sim.fields``" + ("" if complete else " (None: not set)") + ":"
    rows = [
        f"    {f.name}: {f.kind.__name__}{f' = {f.page_default!r}' if complete else ''} — {f.doc} ({_allowed(f)})"
        for f in chosen
    ]
    return "\n\n    " + head + "\n\n" + "\n".join(rows) + "\n"


@dataclasses.dataclass(frozen=True)
@record("site", "engine", complete=True)
class EngineConfig:
    """What the simulator needs to know: rules, agents and the learner's view of the grid.

    Cells beyond the road read 0, so lanes_side > 6 adds only dead inputs; agent 10 never decides
    (spec v2 §7)."""

    if TYPE_CHECKING:

        def __init__(self, **values: Any) -> None: ...

        def __getattr__(self, name: str) -> Any: ...

    def __post_init__(self) -> None:
        if self.patches_ahead + self.patches_behind < 1:
            raise ConfigError("patches_ahead + patches_behind: must be at least 1 (the input would be empty)")
        check_other_agents(self.ruleset, self.other_agents)

    @property
    def num_inputs(self) -> int:
        """Length of one car's input vector, (2·lanes_side + 1)·(patches_ahead + patches_behind)."""
        return input_size(self.lanes_side, self.patches_ahead, self.patches_behind)

    @property
    def controlled_cars(self) -> int:
        """Cars whose speed counts in the score: the ego plus the agents (v2 §11)."""
        return 1 + self.other_agents

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> EngineConfig:
        """Build from a dict (snake_case or DeepTraffic camelCase keys); unknown keys are errors."""
        names = [f.name for f in dataclasses.fields(cls)]
        kwargs: dict[str, Any] = {}
        for key, value in values.items():
            name = CAMEL_ALIASES.get(key, key)
            if name not in names:
                raise nearest_key_error("engine config", key, names)
            kwargs[name] = value
        return cls(**kwargs)
