"""TrainConfig: defaults, validation messages, DeepTraffic names, nested convnetjs defaults, presets, TOML, CLI."""

from __future__ import annotations

import json

import pytest

from autotune.convnet import spec
from autotune.learner.config import PRESETS, ConfigError, TrainConfig, load_toml, preset, run_schedule
from tests.conftest import REFERENCE, ROOT


def test_defaults_are_the_deeptraffic_template():
    c = TrainConfig()
    assert (c.lanes_side, c.patches_ahead, c.patches_behind, c.other_agents) == (0, 1, 0, 0)
    assert (c.train_iterations, c.temporal_window, c.hidden) == (10000, 3, "fc:1:relu")
    assert (c.learning_rate, c.momentum, c.batch_size, c.l2_decay, c.l1_decay) == (0.001, 0.0, 64, 0.01, 0.0)
    assert (c.experience_size, c.start_learn_threshold, c.gamma) == (3000, 500, 0.7)
    assert (c.learning_steps_total, c.learning_steps_burnin, c.epsilon_min, c.epsilon_test_time) == (
        10000,
        1000,
        0.0,
        0.0,
    )
    assert c.ruleset == "v2" and c.method == "sgd"
    assert c.num_states == 1 and c.net_inputs == 19  # 1·3 + 5·3 + 1


@pytest.mark.parametrize(
    "iterations, expected",
    [
        (10000, (4, 75000)),
        (30000, (10, 90000)),
        (60000, (19, 94737)),
        (100000, (31, 96775)),
        (8000, (4, 70589)),
        (0, (0, 0)),
    ],
)
def test_run_schedule(iterations, expected):
    assert run_schedule(iterations) == expected


def test_total_frames_of_the_references():
    assert preset("default_v1").total_frames == 300_000
    assert preset("network_basic").total_frames == 900_000
    assert preset("strong").total_frames == 1_800_003


@pytest.mark.parametrize(
    "field, value, allowed",
    [
        ("gamma", 1.5, "[0, 1]"),
        ("learning_rate", -0.1, "[0, 10]"),
        ("momentum", 5, "[0, 1]"),
        ("epsilon_min", 2.0, "[0, 1]"),
        ("batch_size", 0, "1–4,096"),
        ("experience_size", 0, "1–2,000,000"),
        ("temporal_window", -1, "0–100"),
        ("lanes_side", 51, "0–50"),
        ("other_agents", 11, "0–10"),
        ("train_iterations", -5, "0–100,000,000"),
    ],
)
def test_out_of_range_names_field_and_range(field, value, allowed):
    with pytest.raises(ConfigError) as err:
        TrainConfig.from_mapping({field: value})
    msg = str(err.value)
    assert msg.startswith(f"{field}:") and allowed in msg


def test_type_errors():
    with pytest.raises(ConfigError, match=r"^gamma: must be a number"):
        TrainConfig(gamma="high")
    with pytest.raises(ConfigError, match=r"^batch_size: must be an integer"):
        TrainConfig(batch_size=6.5)
    assert TrainConfig(batch_size=32.0).batch_size == 32  # integral floats (TOML/JSON) are fine


def test_unknown_key_names_nearest():
    with pytest.raises(ConfigError, match="did you mean 'lanesSide'"):
        TrainConfig.from_mapping({"lanesSid": 2})
    with pytest.raises(ConfigError, match="did you mean 'experience_size'"):
        TrainConfig.from_mapping({"experiance_size": 2})
    with pytest.raises(ConfigError, match="did you mean 'gamma'"):
        TrainConfig.from_mapping({"opt": {"gama": 0.9}})
    with pytest.raises(ConfigError, match="did you mean 'momentum'"):
        TrainConfig.from_mapping({"tdtrainer_options": {"momentun": 0.9}})


def test_cross_field_rules():
    with pytest.raises(ConfigError, match="^other_agents: the v1 engine"):
        TrainConfig(ruleset="v1", other_agents=2)
    with pytest.raises(ConfigError, match="^start_learn_threshold: .* never start"):
        TrainConfig(experience_size=100, start_learn_threshold=100)
    with pytest.raises(ConfigError, match="^method: 'adam' is not allowed; did you mean 'adagrad'"):
        TrainConfig(method="adam")
    with pytest.raises(ConfigError, match="^ruleset"):
        TrainConfig(ruleset="v3")


def test_camel_case_names():
    c = TrainConfig.from_mapping(
        {
            "lanesSide": 2,
            "patchesAhead": 5,
            "patchesBehind": 1,
            "otherAgents": 3,
            "trainIterations": 500,
            "hidden_layers": "fc:4:tanh",
        }
    )
    assert (c.lanes_side, c.patches_ahead, c.patches_behind, c.other_agents, c.train_iterations) == (2, 5, 1, 3, 500)
    assert c.layers == (spec.FC(4, "tanh"),)
    with pytest.raises(ConfigError, match="given twice"):
        TrainConfig.from_mapping({"lanesSide": 2, "lanes_side": 3})


def test_layer_forms():
    s = TrainConfig(layers="fc:10:relu|fc:5:tanh")
    d = TrainConfig(
        layers=[
            {"type": "fc", "num_neurons": 10, "activation": "relu"},
            {"type": "fc", "num_neurons": 5, "activation": "tanh"},
        ]
    )
    o = TrainConfig(layers=[spec.FC(10, "relu"), spec.FC(5, "tanh")])
    assert s == d == o and s.hidden == "fc:10:relu|fc:5:tanh"
    crowd = TrainConfig(layers="svm:14|fc:10:maxout|lrn|fc:3:softmax|dropout:0.5")
    types = [spec.layer_type(layer) for layer in crowd.expanded_layers]
    assert types == ["input", "fc", "svm", "fc", "maxout", "lrn", "fc", "dropout", "fc", "regression"]
    assert TrainConfig(layers="").layers == ()  # linear Q-function
    with pytest.raises(ConfigError, match=r"^layers\[0\]\.activation: 'rel' is not allowed; did you mean 'relu'"):
        TrainConfig(layers="fc:10:rel")
    with pytest.raises(ConfigError, match=r"did you mean 'fc'"):
        TrainConfig(layers=[{"type": "fcc", "num_neurons": 3}])
    with pytest.raises(ConfigError, match=r"did you mean 'activation'"):
        TrainConfig(layers=[{"type": "fc", "num_neurons": 3, "activaton": "relu"}])
    with pytest.raises(ConfigError, match=r"^layers:"):
        TrainConfig(layers="fc:0:relu")


def test_nested_form_follows_convnetjs_defaults():
    c = TrainConfig.from_mapping({"lanesSide": 1, "patchesAhead": 4, "opt": {"gamma": 0.9, "experience_size": 5000}})
    # deepqlearn's own defaults for absent opt keys; start = ⌊min(0.1·experience, 1000)⌋
    assert (c.temporal_window, c.learning_steps_total, c.learning_steps_burnin) == (1, 100000, 3000)
    assert (c.epsilon_min, c.epsilon_test_time, c.start_learn_threshold) == (0.05, 0.01, 500)
    # no tdtrainer_options: the Brain's own trainer options
    assert (c.learning_rate, c.momentum, c.batch_size, c.l2_decay) == (0.01, 0.0, 64, 0.01)
    assert c.layers == ()  # no layer_defs: deepqlearn's linear default net
    # a given (partial) tdtrainer_options object: the Trainer's defaults fill the gaps
    t = TrainConfig.from_mapping({"opt": {"tdtrainer_options": {"learning_rate": 0.001}}})
    assert (t.learning_rate, t.momentum, t.batch_size, t.l2_decay, t.l1_decay, t.method) == (
        0.001,
        0.9,
        1,
        0.0,
        0.0,
        "sgd",
    )
    assert TrainConfig.from_mapping({"opt": {"experience_size": 30000}}).start_learn_threshold == 1000


def test_nested_layer_defs_and_net_js_settings_round_trip():
    c = preset("network_basic")
    settings = c.to_deepqlearn()
    assert settings["network_size"] == 30 and settings["opt"]["tdtrainer_options"]["momentum"] == 0.0
    assert TrainConfig.from_mapping({**settings, "ruleset": "v2"}) == c
    with pytest.raises(ConfigError, match="num_inputs"):
        TrainConfig.from_mapping({**settings, "num_inputs": 31})


def test_mapping_round_trip_and_replace():
    c = preset("strong")
    assert TrainConfig.from_mapping(c.to_mapping()) == c
    r = c.replace(gamma=0.8, trainIterations=100)
    assert (r.gamma, r.train_iterations, r.lanes_side) == (0.8, 100, 3)
    with pytest.raises(ConfigError, match="^gamma"):
        c.replace(gamma=-1)


@pytest.mark.skipif(not REFERENCE.is_dir(), reason="reference data not available")
def test_presets_match_reference_json():
    from tests.conftest import load_json

    v1 = load_json(REFERENCE / "learner_scores.json")
    names = {
        "default_v1.json": "default_v1",
        "network_basic.json": "network_basic_v1",
        "strong.json": "strong",
        "strong_lr1e-3.json": "strong_lr1e-3",
    }
    for run in v1["runs"]:
        ref = TrainConfig.from_mapping({**run["config"], "ruleset": "v1"})
        assert ref == preset(names[run["config_file"]]), run["config_file"]
    v2 = load_json(REFERENCE / "learner_scores_v2.json")
    for run in v2["runs"]:
        assert TrainConfig.from_mapping({**run["config"], "ruleset": "v2"}) == preset("network_basic")


def test_presets():
    assert set(PRESETS) >= {"default_v1", "network_basic", "strong"}
    assert preset("default_v1").ruleset == "v1" and preset("network_basic").ruleset == "v2"
    assert preset("network_basic", ruleset="v1") == preset("network_basic_v1")
    with pytest.raises(ConfigError, match="did you mean 'strong'"):
        preset("strang")


def test_toml(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text('ruleset = "v1"\nlanesSide = 1\npatchesAhead = 10\ntrainIterations = 30000\ntemporal_window = 0\n'
                 'layers = "fc:10:relu"\ngamma = 0.5\n')  # fmt: skip
    assert load_toml(p) == preset("network_basic_v1")
    p.write_text("gamma = [\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_toml(p)
    with pytest.raises(ConfigError, match="not found"):
        load_toml(tmp_path / "missing.toml")
    p.write_text("[opt]\ngamma = 0.9\n[tdtrainer_options]\nlearning_rate = 0.002\nmomentum = 0.0\nbatch_size = 32\n")
    c = load_toml(p)
    assert (c.gamma, c.learning_rate, c.batch_size, c.l2_decay) == (0.9, 0.002, 32, 0.0)


def test_study_configs_load():
    assert load_toml(ROOT / "study_configs" / "train_network_basic_v2.toml") == preset("network_basic")
    assert load_toml(ROOT / "study_configs" / "train_network_basic_v1.toml") == preset("network_basic_v1")
    assert load_toml(ROOT / "study_configs" / "train_strong_v1_nested.toml") == preset("strong")


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--preset", "network_basic", "--set", "gama=0.9"], "did you mean 'gamma'"),
        (["--preset", "network_basic", "--set", "gamma=2"], "gamma: 2"),
        (["--preset", "nope"], "unknown preset key 'nope'"),
        (["--config", "/nonexistent/c.toml"], "not found"),
        ([], "give exactly one of --config"),
        (["--preset", "network_basic", "--stream", "js"], "--stream: invalid choice"),
    ],
)
def test_cli_bad_input_exits_2(argv, needle, tmp_path, capsys):
    from autotune.cli import main

    assert main(["train", *argv, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and needle in err[0]


def test_cli_bad_flag_exits_2(tmp_path, capsys):
    from autotune.train import main  # the python -m autotune.train shim

    assert main(["--preset", "network_basic", "--seed", "x", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "--seed" in err[0]


def test_json_config_values_in_set(tmp_path):
    from autotune.commands.train import _parse_value

    assert _parse_value("0.5") == 0.5 and _parse_value("fc:3:relu") == "fc:3:relu" and _parse_value("true") is True
    assert json.loads(json.dumps(preset("network_basic").to_mapping()))["layers"] == "fc:10:relu"
