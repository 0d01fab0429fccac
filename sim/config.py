"""Engine configuration: the ruleset and the learner-input window (engine_spec.md §7, v2 §8–§9).

The names are DeepTraffic's own (``lanesSide`` → ``lanes_side``, ``otherAgents`` →
``other_agents``). Building a config from a mapping rejects unknown keys with the nearest valid
name, and accepts the original camelCase spellings too, so net.js-style settings load as is.
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Mapping
from typing import Any

from sim import fields

RULESETS = ("v1", "v2")

# DeepTraffic's global names → ours (the engine's four; ``sim.fields`` is the one table).
CAMEL_ALIASES = {f.alias: f.name for f in fields.group("engine") if f.alias}


def input_size(lanes_side: int, patches_ahead: int, patches_behind: int) -> int:
    """Length of one car's input vector, (2·lanes_side + 1)·(patches_ahead + patches_behind) (v1 §7)."""
    return (2 * lanes_side + 1) * (patches_ahead + patches_behind)


class ConfigError(ValueError):
    """A configuration value or key is invalid; the message names the field and the fix."""


def nearest_key_error(kind: str, key: str, valid: list[str] | tuple[str, ...]) -> ConfigError:
    """Error for an unknown key, naming the closest valid one."""
    close = difflib.get_close_matches(key, list(valid), n=1, cutoff=0.4)
    hint = f"; did you mean '{close[0]}'?" if close else ""
    return ConfigError(f"unknown {kind} key '{key}'{hint} (valid: {', '.join(sorted(valid))})")


@dataclasses.dataclass(frozen=True)
class EngineConfig:
    """What the simulator needs to know: rules, agents and the learner's view of the grid."""

    ruleset: str = "v2"
    """'v2' (2018 multi-agent site engine, default) or 'v1' (2017 single-car engine)."""
    lanes_side: int = 0
    """Lanes seen on each side of the deciding car's target lane (0–6 useful; cells off-road read 0)."""
    patches_ahead: int = 1
    """Grid rows (10 px each) seen ahead of the car's front row (1–70)."""
    patches_behind: int = 0
    """Grid rows seen from the car's front row backwards (0–70)."""
    other_agents: int = 0
    """v2 only: extra red cars driven by the same policy (0–10; agent 10 never decides, spec v2 §7)."""

    def __post_init__(self) -> None:
        if self.ruleset not in RULESETS:
            raise ConfigError(f"ruleset: '{self.ruleset}' is not a ruleset; use one of {', '.join(RULESETS)}")
        for f in fields.group("engine"):
            name, lo, hi = f.name, int(f.low), int(f.high)
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int):
                raise ConfigError(f"{name}: must be an integer, got {value!r}")
            if not lo <= value <= hi:
                raise ConfigError(f"{name}: {value} is out of range; allowed {lo}–{hi}")
        if self.patches_ahead + self.patches_behind < 1:
            raise ConfigError("patches_ahead + patches_behind: must be at least 1 (the input would be empty)")
        if self.ruleset == "v1" and self.other_agents != 0:
            raise ConfigError("other_agents: the v1 engine has no other agents; use ruleset 'v2' or other_agents = 0")

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
