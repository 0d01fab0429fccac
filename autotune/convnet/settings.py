"""The DeepTraffic settings a file sets: one record derived from ``sim.fields``, one reader, one writer.

``Settings`` has a field per row of the table, None where the file does not set it: it *is* the
settings of a net file (``*.config.json``, a net.js) and of a crowd submission, and
``autotune.learner.config.TrainConfig`` is this record with every field filled plus the learner's own.

* ``read(mapping)`` — the one reader of DeepTraffic's spellings: a key is a field's name or its alias
  (``lanesSide``, ``engine_version``, ``trainer_method``), a value is checked for the field's type,
  ``None`` means not set, and so does the crowd files' ``trainer_method = 'default(…)'`` (no
  ``tdtrainer_options`` in the file); every other key comes back as given, for the caller.
* ``write_flat(settings)`` / ``write_nested(settings)`` — the one writer: config.json's flat form
  (aliases), or net.js's nested form (the globals by their camelCase names, ``opt`` with the opt keys
  and ``tdtrainer_options``, each trainer key written as its ``sim.fields`` row says).
* ``settings.filled(nested=…)`` — the one function that fills what is not set, each default where the
  original applies it (engine_spec.md §10.1): a flat config takes the page's sample net; a nested
  (net.js) one takes deepqlearn's ``opt`` defaults, and for the trainer the Brain's own options when
  the file gives no ``tdtrainer_options``, else the convnetjs Trainer's defaults for the keys it lacks.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from autotune.convnet.spec import net_input_size
from sim import fields
from sim.config import ConfigError, FieldValueError, check, input_size, record

__all__ = ["Settings", "read", "write_flat", "write_nested", "written"]

NESTED_GLOBALS = ("engine", "protocol")
"""Groups net.js sets as plain globals (by their camelCase names); ``opt`` and ``trainer`` are nested."""


@dataclasses.dataclass(frozen=True)
@record(complete=False)
class Settings:
    """The DeepTraffic settings a file sets; None = not set (a default applies, see ``filled``)."""

    if TYPE_CHECKING:

        def __init__(self, **values: Any) -> None: ...

        def __getattr__(self, name: str) -> Any: ...

    @property
    def engine(self) -> str:
        """The engine the file was written for: its recorded ruleset, else v2 iff it sets otherAgents."""
        if self.ruleset is not None:
            return str(self.ruleset)
        return "v2" if self.other_agents is not None else "v1"

    @property
    def num_inputs(self) -> int:
        """``(2L+1)(P+B)``: one car's input vector (unset window fields: the page's defaults)."""
        full = self.filled()
        return input_size(full.lanes_side, full.patches_ahead, full.patches_behind)

    @property
    def net_inputs(self) -> int:
        """``num_inputs·tw + 5·tw + num_inputs``: the network's input size (unset tw: deepqlearn's 1)."""
        return net_input_size(self.num_inputs, self.filled().temporal_window)

    def values(self) -> dict[str, Any]:
        """Every field by name (None where not set), in table order."""
        return {f.name: getattr(self, f.name) for f in fields.FIELDS}

    def filled(self, *, nested: bool = True, trainer_given: bool | None = None) -> Settings:
        """This record with every unset field filled as the original fills it (module doc).

        ``nested``: the net.js form (deepqlearn's defaults) rather than a flat config (the page's).
        ``trainer_given``: whether the file gives a ``tdtrainer_options`` object; by default, whether
        it sets any trainer field.
        """
        values = self.values()
        if trainer_given is None:
            trainer_given = any(values[f.name] is not None for f in fields.group("trainer"))
        for f in fields.FIELDS:
            if values[f.name] is not None:
                continue
            if not nested or f.group in ("site", *NESTED_GLOBALS):
                values[f.name] = f.page_default
            elif f.group == "opt":
                values[f.name] = f.deepqlearn_default
            else:
                brain = not trainer_given and f.deepqlearn_default is not None
                values[f.name] = f.deepqlearn_default if brain else f.trainer_default
        if values["start_learn_threshold"] is None:  # deepqlearn: ⌊min(0.1·experience_size, 1000)⌋
            values["start_learn_threshold"] = int(math.floor(min(values["experience_size"] * 0.1, 1000)))
        return Settings(**values)


def read(
    values: Mapping[str, Any], *, where: str = "", groups: tuple[str, ...] = fields.GROUPS, aliases: bool = True
) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(fields, others)``: the table's fields that ``values`` sets, by name and typed, and every other key.

    Keys are field names, or aliases when ``aliases``; a field outside ``groups`` counts as another
    key. The same field given twice (name and alias) with two values is an error; a type error names
    the key as written, after ``where`` (e.g. ``config.lanesSide: must be an integer …``).
    """
    out: dict[str, Any] = {}
    others: dict[str, Any] = {}
    for key, value in values.items():
        name = fields.name_of(key) if aliases else (key if fields.name_of(key) == key else None)
        if name is None or fields.field(name).group not in groups:
            others[key] = value
            continue
        f = fields.field(name)
        if value is None or (f.name == "method" and isinstance(value, str) and value.startswith("default")):
            continue  # not set (JSON null, a blank cell; the crowd's 'default(…)': no tdtrainer_options)
        try:
            value = check(f, value, ranges=False)
        except FieldValueError as exc:
            raise FieldValueError(f"{where}{key}", exc.problem) from None
        if name in out and out[name] != value:
            raise ConfigError(f"{where}{key}: given twice with different values ({out[name]!r}, {value!r})")
        out[name] = value
    return out, others


def write_flat(settings: Settings) -> dict[str, Any]:
    """The fields set, under their flat file names (config.json, the crowd CSV): alias, else name."""
    return {f.alias or f.name: v for f in fields.FIELDS if (v := getattr(settings, f.name)) is not None}


def written(f: fields.Field, settings: Settings) -> bool:
    """Whether net.js's ``tdtrainer_options`` carries trainer field ``f`` (``sim.fields.Field.write``)."""
    value = getattr(settings, f.name)
    if value is None:
        return False
    if f.write == "if-not-default":
        return bool(value != f.trainer_default)
    if f.write == "with-method":
        return settings.method not in (None, "sgd")
    return True


def write_nested(settings: Settings) -> dict[str, Any]:
    """net.js's form of the fields set: the globals by camelCase name, then ``opt`` (with ``tdtrainer_options``
    when any trainer key is written). The site's ruleset is no net.js setting and is not written."""
    out: dict[str, Any] = {
        f.alias or f.name: v
        for f in fields.FIELDS
        if f.group in NESTED_GLOBALS and (v := getattr(settings, f.name)) is not None
    }
    opt = {f.name: v for f in fields.group("opt") if (v := getattr(settings, f.name)) is not None}
    trainer = {f.name: getattr(settings, f.name) for f in fields.group("trainer") if written(f, settings)}
    if trainer:
        opt["tdtrainer_options"] = trainer
    out["opt"] = opt
    return out
