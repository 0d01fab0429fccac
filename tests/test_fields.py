"""``sim.fields``: the one table of DeepTraffic settings, and the configs that read it."""

from __future__ import annotations

import pytest

from autotune.convnet.netjson import settings_from_config
from autotune.learner.config import ConfigError, TrainConfig
from sim import fields
from sim.config import EngineConfig


def test_lookup_by_name_or_alias_and_bounds() -> None:
    assert fields.field("lanesSide") is fields.field("lanes_side")
    assert fields.bounds("patchesAhead") == (0, 70) and fields.bounds("gamma") == (0.0, 1.0)
    assert [f.name for f in fields.group("engine")] == ["lanes_side", "patches_ahead", "patches_behind", "other_agents"]
    with pytest.raises(KeyError, match="'lane_side' is not a DeepTraffic field"):
        fields.field("lane_side")


def test_train_config_defaults_are_the_page_defaults() -> None:
    config = TrainConfig()
    assert {f.name: getattr(config, f.name) for f in fields.FIELDS} == {f.name: f.page_default for f in fields.FIELDS}


@pytest.mark.parametrize("f", fields.FIELDS, ids=lambda f: f.name)
def test_configs_enforce_the_table_ranges(f: fields.Field) -> None:
    step = 1 if f.kind is int else 1e-9
    base = {"experience_size": 2_000_000, "start_learn_threshold": 0}  # room for either's extremes
    base = {k: v for k, v in base.items() if k != f.name}
    top = f.high - 1 if f.name == "start_learn_threshold" else f.high  # must stay below experience_size
    TrainConfig.from_mapping({**base, f.name: f.kind(top)})
    for bad in (f.low - step, f.high + step):
        with pytest.raises(ConfigError, match=f"^{f.name}: .* out of range"):
            TrainConfig.from_mapping({**base, f.name: f.kind(bad)})
        if f.group == "engine":
            with pytest.raises(ConfigError, match=f"^{f.name}: .* out of range"):
                EngineConfig.from_mapping({"patches_ahead": 1, f.name: bad, "ruleset": "v2"})


def test_net_settings_read_every_field_by_its_alias() -> None:
    cfg = {f.alias or f.name: f.kind(f.low) for f in fields.FIELDS} | {"patchesAhead": 1}
    settings = settings_from_config(cfg)
    assert settings.lanes_side == 0 and settings.train_iterations == 0 and settings.experience_size == 1
