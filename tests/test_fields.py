"""``sim.fields``: the one table of DeepTraffic settings, the records derived from it, and one setting added to it."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import pytest

from autotune.convnet.netjson import settings_from_config
from autotune.convnet.settings import Settings, read, write_flat, write_nested
from autotune.learner.config import ConfigError, TrainConfig
from sim import fields
from sim.config import EngineConfig
from tests.conftest import ROOT

NUMERIC = tuple(f for f in fields.FIELDS if f.kind is not str)
CHOICES = tuple(f for f in fields.FIELDS if f.kind is str)


def test_lookup_by_name_or_alias_and_bounds() -> None:
    assert fields.field("lanesSide") is fields.field("lanes_side")
    assert fields.field("trainer_method") is fields.field("method")
    assert fields.bounds("patchesAhead") == (0, 70) and fields.bounds("gamma") == (0.0, 1.0)
    assert [f.name for f in fields.group("engine")] == ["lanes_side", "patches_ahead", "patches_behind", "other_agents"]
    assert fields.field("method").choices == ("sgd", "adagrad", "windowgrad", "adadelta", "nesterov")
    assert fields.name_of("otherAgents") == "other_agents" and fields.name_of("hidden_layers") is None
    with pytest.raises(KeyError, match="'lane_side' is not a DeepTraffic field"):
        fields.field("lane_side")


def test_records_are_the_table() -> None:
    """Settings, TrainConfig and EngineConfig carry the table's fields, in its order, with its defaults."""
    names = [f.name for f in fields.FIELDS]
    assert [f.name for f in dataclasses.fields(Settings)] == names
    assert [f.name for f in dataclasses.fields(TrainConfig)] == [*names, "layers", "dtype"]
    engine = [f.name for f in fields.FIELDS if f.group in ("site", "engine")]
    assert [f.name for f in dataclasses.fields(EngineConfig)] == engine
    assert all(v is None for v in Settings().values().values())
    assert "lanes_side: int = 0 — lanes seen on each side" in (TrainConfig.__doc__ or "")


def test_train_config_defaults_are_the_page_defaults() -> None:
    config = TrainConfig()
    assert {f.name: getattr(config, f.name) for f in fields.FIELDS} == {f.name: f.page_default for f in fields.FIELDS}


@pytest.mark.parametrize("f", NUMERIC, ids=lambda f: f.name)
def test_configs_enforce_the_table_ranges(f: fields.Field) -> None:
    assert f.low is not None and f.high is not None
    step = 1 if f.kind is int else 1e-9
    base = {"experience_size": 2_000_000, "start_learn_threshold": 0}  # room for either's extremes
    base = {k: v for k, v in base.items() if k != f.name}
    top = f.high - 1 if f.name == "start_learn_threshold" else f.high  # must stay below experience_size
    TrainConfig.from_mapping({**base, f.name: f.kind(top)})
    for bad in (f.low - (0 if f.low_open else step), f.high + step):
        with pytest.raises(ConfigError, match=f"^{f.name}: .* out of range"):
            TrainConfig.from_mapping({**base, f.name: f.kind(bad)})
        if f.group == "engine":
            with pytest.raises(ConfigError, match=f"^{f.name}: .* out of range"):
                EngineConfig.from_mapping({"patches_ahead": 1, f.name: bad, "ruleset": "v2"})


@pytest.mark.parametrize("f", CHOICES, ids=lambda f: f.name)
def test_choices_come_from_the_table(f: fields.Field) -> None:
    for choice in f.choices:
        if choice != "v1":  # (v1 with the default other agents: allowed too, see below)
            assert getattr(TrainConfig.from_mapping({f.alias or f.name: choice}), f.name) == choice
    with pytest.raises(
        ConfigError, match=rf"^{f.name}: '{f.choices[0]}x' is not allowed; did you mean '{f.choices[0]}'"
    ):
        TrainConfig.from_mapping({f.name: f.choices[0] + "x"})
    assert TrainConfig(ruleset="v1").ruleset == "v1"


def test_net_settings_read_every_field_by_its_alias() -> None:
    cfg = {
        f.alias or f.name: f.choices[0] if f.choices else f.kind(f.high if f.low_open else f.low) for f in fields.FIELDS
    }
    cfg |= {"patchesAhead": 1}
    settings = settings_from_config(cfg)
    assert settings.lanes_side == 0 and settings.train_iterations == 0 and settings.experience_size == 1
    assert write_flat(settings) == cfg  # every field read under its flat name, and written back under it


def test_one_reader_one_writer() -> None:
    values, others = read({"lanesSide": 2, "gamma": 0.9, "trainer_method": "default(no options)", "x": 1})
    assert values == {"lanes_side": 2, "gamma": 0.9} and others == {"x": 1}  # 'default(…)': not set
    with pytest.raises(ConfigError, match="given twice"):
        read({"lanesSide": 2, "lanes_side": 3})
    with pytest.raises(ConfigError, match=r"^opt\.gamma: must be a number in \[0, 1\], got 'high'"):
        read({"gamma": "high"}, where="opt.")
    nested = write_nested(Settings(lanes_side=1, gamma=0.5, learning_rate=0.01, l1_decay=0.0, ro=0.9))
    assert nested == {"lanesSide": 1, "opt": {"gamma": 0.5, "tdtrainer_options": {"learning_rate": 0.01}}}
    adagrad = write_nested(Settings(method="adagrad", ro=0.9))["opt"]["tdtrainer_options"]
    assert adagrad == {"method": "adagrad", "ro": 0.9}  # a non-sgd method's options are written with it


def test_filled_applies_each_default_where_the_original_does() -> None:
    empty = Settings()
    assert empty.filled(nested=False) == Settings(**{f.name: f.page_default for f in fields.FIELDS})
    brain = empty.filled()  # net.js without tdtrainer_options: deepqlearn's opt and the Brain's trainer options
    assert (brain.temporal_window, brain.gamma, brain.start_learn_threshold) == (1, 0.8, 1000)
    assert (brain.learning_rate, brain.momentum, brain.batch_size, brain.l2_decay) == (0.01, 0.0, 64, 0.01)
    given = Settings(learning_rate=0.002).filled()  # a given tdtrainer_options: the Trainer's defaults
    assert (given.learning_rate, given.momentum, given.batch_size, given.l2_decay) == (0.002, 0.9, 1, 0.0)
    assert Settings().filled(trainer_given=True).momentum == 0.9
    assert Settings(experience_size=5000).filled().start_learn_threshold == 500


# -- one row more ------------------------------------------------------------------------------------------

SYNTHETIC_ROW = (
    '    Field("synthetic_rate", "syntheticRate", float, 0.0, 2.0, 0.25, 0.5, "opt",\n'
    '          "a synthetic deepqlearn option, added by tests/test_fields.py [1]"),\n'
)

SYNTHETIC_SCRIPT = r"""
import json, sys, types
from pathlib import Path

root = Path(sys.argv[1])
source = (root / "sim" / "fields.py").read_text()
anchor = ")  # fmt: skip"
assert source.count(anchor) == 1
module = types.ModuleType("sim.fields")
module.__file__ = str(root / "sim" / "fields.py")
sys.modules["sim.fields"] = module  # before the package imports it: the table with one row more
exec(compile(source.replace(anchor, sys.argv[2] + anchor), module.__file__, "exec"), module.__dict__)

from autotune.convnet.netjson import export_netjs, settings_from_config
from autotune.convnet.spec import Input, FC, Regression, expand, init_convnet
from autotune.learner.config import ConfigError, TrainConfig, load_toml
from autotune.search import space
from autotune.search.spec import SpecError, parse_spec
from dashboards import crowd_data

out = {}
toml = Path(sys.argv[3])
toml.write_text("syntheticRate = 0.75\n")
out["toml"] = load_toml(toml).synthetic_rate
out["default"] = TrainConfig().synthetic_rate
out["nested_default"] = TrainConfig.from_mapping({"opt": {}}).synthetic_rate
out["nested"] = TrainConfig.from_mapping({"opt": {"synthetic_rate": 1.5}}).synthetic_rate
for bad in ({"synthetic_rate": 3.0}, {"syntheticRate": "x"}):
    try:
        TrainConfig.from_mapping(bad)
    except ConfigError as exc:
        out.setdefault("errors", []).append(str(exc))
try:
    TrainConfig.from_mapping({"synthetic_rat": 1.0})
except ConfigError as exc:
    out["hint"] = str(exc)
text = (crowd_data.data_dir() / "submissions.csv").read_text()
head, first, *rest = text.split("\n")
csv = "\n".join([head + ",syntheticRate", first + ",1.25", *(r + "," if r else r for r in rest)])
subs = crowd_data.parse_submissions(csv)
out["csv"] = [subs[0].settings.synthetic_rate, subs[1].settings.synthetic_rate]
out["csv_config"] = [crowd_data.train_config(subs[0]).synthetic_rate, crowd_data.train_config(subs[1]).synthetic_rate]
settings = settings_from_config({"lanesSide": 0, "patchesAhead": 1, "patchesBehind": 0, "syntheticRate": 0.125})
out["netjs_read"] = settings.synthetic_rate
net = init_convnet(expand([Input(settings.net_inputs), FC(2, "relu"), Regression(5)]), 0)
out["netjs"] = [line for line in export_netjs(net, settings, with_weights=False).splitlines() if "synthetic" in line]
config = TrainConfig(synthetic_rate=1.0)
out["deepqlearn"] = config.to_deepqlearn()["opt"]["synthetic_rate"]
out["netjs_config"] = [l for l in export_netjs(init_convnet(expand(config.layer_defs), 0), config.settings,
                                                with_weights=False).splitlines() if "synthetic" in l]
spec = parse_spec({"study": {"name": "s", "n_trials": 1}, "space": {"synthetic_rate": {"low": 0.1, "high": 1.0}}})
params = {"synthetic_rate": 0.5}
out["searched"] = space.to_config(spec, params).synthetic_rate
out["encoded"] = space.encode(spec, TrainConfig(synthetic_rate=0.3))
try:
    parse_spec({"study": {"name": "s", "n_trials": 1}, "space": {"synthetic_rate": {"low": 0.1, "high": 5.0}}})
except SpecError as exc:
    out["space_error"] = str(exc)
print(json.dumps(out))
"""


def test_one_row_more_in_the_table_is_parsed_validated_searched_and_exported(tmp_path) -> None:  # noqa: ANN001
    """Add a deepqlearn option to ``sim.fields`` — one row, nothing else — in a fresh interpreter."""
    done = subprocess.run(
        [sys.executable, "-c", SYNTHETIC_SCRIPT, str(ROOT), SYNTHETIC_ROW, str(tmp_path / "c.toml")],
        cwd=ROOT, capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert (out["toml"], out["default"], out["nested_default"], out["nested"]) == (0.75, 0.25, 0.5, 1.5)
    assert out["errors"] == [
        "synthetic_rate: 3.0 is out of range; allowed [0, 2]",
        "syntheticRate: must be a number in [0, 2], got 'x'",
    ]
    assert "did you mean 'synthetic_rate'" in out["hint"]
    assert out["csv"] == [1.25, None] and out["csv_config"] == [1.25, 0.5]  # blank: deepqlearn's default
    assert out["netjs_read"] == 0.125 and out["netjs"] == ["  synthetic_rate: 0.125,"]
    assert out["deepqlearn"] == 1.0 and out["netjs_config"] == ["  synthetic_rate: 1,"]
    assert out["searched"] == 0.5 and out["encoded"] == {"synthetic_rate": 0.3}
    assert "[space] synthetic_rate: high 5.0 is above what deepqlearn accepts (0–2)" in out["space_error"]


def test_search_and_crowd_bounds_come_from_the_table() -> None:
    from autotune.search.records import Distribution
    from autotune.search.space import DEFAULT_SPACE
    from autotune.search.spec import param_bounds
    from dashboards import crowd

    assert DEFAULT_SPACE["other_agents"] == {"low": 0, "high": 10} and DEFAULT_SPACE["momentum"]["high"] == 1.0
    assert param_bounds("one_minus_gamma") == ("float", 0.0, 1.0) and param_bounds("method") == ("str", 0, None)
    dists = crowd.distributions(
        [
            {"lanes_side": 2, "learning_rate": 1e-3, "l2_decay": 0.0, "n_layers": 3},
            {"lanes_side": 60, "learning_rate": 1e-5, "l2_decay": 0.1, "n_layers": 1},
        ]
    )
    assert dists["lanes_side"] == Distribution("int", 0, 60, False, 1)  # the table's 0–50, widened to hold every value
    # log as the paper samples it, from where the paper starts (the table's 0 cannot start a log scale)
    assert dists["learning_rate"] == Distribution("float", 1e-8, 10.0, True)
    assert dists["l2_decay"] == Distribution("float", 0.0, 10.0, False)  # a 0 allows no log scale
    assert dists["n_layers"] == Distribution("int", 0, 8, False, 1)  # the open-ended layout: the paper's largest
