"""convnetjs Net JSON import/export: byte-exact round trips of the crowd nets, validation errors, CLI."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from autotune import cli
from autotune.convnet.netjson import (
    NetFormatError,
    dumps_net,
    export_netjs,
    js_num,
    load,
    load_net,
    loads_net,
    parse_net,
    settings_from_config,
    validate,
    write_net,
)
from autotune.convnet.settings import Settings
from autotune.convnet.spec import FC, SVM, Input, Regression, expand, init_convnet, parse_hidden

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
NETS = SHARED / "crowd" / "nets"
CROWD = sorted(p for p in NETS.glob("*.json") if not p.name.endswith(".config.json")) if NETS.exists() else []

SMALL = {
    "layers": [
        {"out_depth": 3, "out_sx": 1, "out_sy": 1, "layer_type": "input"},
        {
            "out_depth": 2,
            "out_sx": 1,
            "out_sy": 1,
            "layer_type": "fc",
            "num_inputs": 3,
            "l1_decay_mul": 0,
            "l2_decay_mul": 1,
            "filters": [
                {"sx": 1, "sy": 1, "depth": 3, "w": {"0": 0.5, "1": -1.25, "2": 1e-7}},
                {"sx": 1, "sy": 1, "depth": 3, "w": {"0": None, "1": 2, "2": -3.5e-5}},
            ],
            "biases": {"sx": 1, "sy": 1, "depth": 2, "w": {"0": 0.1, "1": 0}},
        },
        {"out_depth": 2, "out_sx": 1, "out_sy": 1, "layer_type": "tanh"},
        {
            "out_depth": 5,
            "out_sx": 1,
            "out_sy": 1,
            "layer_type": "fc",
            "num_inputs": 2,
            "l1_decay_mul": 0,
            "l2_decay_mul": 1,
            "filters": [{"sx": 1, "sy": 1, "depth": 2, "w": {"0": i, "1": -i}} for i in range(5)],
            "biases": {"sx": 1, "sy": 1, "depth": 5, "w": {str(i): 0 for i in range(5)}},
        },
        {"out_depth": 5, "out_sx": 1, "out_sy": 1, "layer_type": "regression", "num_inputs": 5},
    ]
}


def _small() -> dict:
    return json.loads(json.dumps(SMALL))


# -- round trips -------------------------------------------------------------------------------------


def test_crowd_nets_present() -> None:
    if len(CROWD) != 25:
        pytest.fail(f"expected the 25 crowd nets in {NETS} (CI keeps ../shared beside the checkout)")


@pytest.mark.parametrize("path", CROWD, ids=lambda p: p.stem)
def test_crowd_net_roundtrip_is_byte_exact(path: Path) -> None:
    text = path.read_text()
    net, settings = load(path)
    out = dumps_net(net)
    assert out == text  # what JSON.stringify(net.toJSON()) wrote
    again = loads_net(out)
    assert again.same_as(net)
    config = json.loads(path.with_name(path.stem + ".config.json").read_text())
    assert net.hidden == config["hidden_layers"]
    assert net.input_size == settings.net_inputs == config["net_inputs_std"]
    assert net.n_params == config["n_params"]


def test_null_weight_loads_as_zero_and_roundtrip(tmp_path: Path) -> None:
    net = parse_net(_small())
    assert net.params[0][0][1, 0] == 0.0  # null → 0 (Float64Array assignment)
    assert net.params[0][0][0, 2] == 1e-7
    text = dumps_net(net)
    assert '"0":0,"1":2,"2":-0.000035' in text and '"2":1e-7' in text
    assert loads_net(text).same_as(net)
    settings = Settings(lanes_side=1, patches_ahead=1, patches_behind=0, temporal_window=0, other_agents=2)
    write_net(tmp_path / "n.json", net, settings)
    net2, settings2 = load(tmp_path / "n.json")
    assert net2.same_as(net) and settings2 == settings  # unset stays unset
    assert settings2.filled().epsilon_test_time == 0.01 and settings2.engine == "v2"


def test_nan_parameters_export_as_null() -> None:
    net = init_convnet(expand([Input(3), FC(2, "relu"), Regression(5)]))
    w, b = net.params[0]
    w[0, 1] = math.nan
    text = dumps_net(net)
    assert '"1":null' in text
    assert loads_net(text).params[0][0][0, 1] == 0.0  # what convnetjs's fromJSON makes of it


@pytest.mark.parametrize(
    ("x", "js"),
    [
        (0.0, "0"),
        (-0.0, "0"),
        (1.0, "1"),
        (-2.5, "-2.5"),
        (1e-7, "1e-7"),
        (1.5e-7, "1.5e-7"),
        (3.5e-5, "0.000035"),
        (1e-6, "0.000001"),
        (123456789012345680000.0, "123456789012345680000"),
        (1e21, "1e+21"),
        (1.7976931348623157e308, "1.7976931348623157e+308"),
        (5e-324, "5e-324"),
        (0.1, "0.1"),
        (math.nan, "null"),
        (math.inf, "null"),
    ],
)
def test_js_number_format(x: float, js: str) -> None:
    assert js_num(x) == js
    if math.isfinite(x):
        assert float(js) == x


def test_export_netjs_block() -> None:
    net = parse_net(_small())
    settings = settings_from_config(
        {
            "lanesSide": 1,
            "patchesAhead": 1,
            "patchesBehind": 0,
            "temporal_window": 0,
            "otherAgents": 3,
            "gamma": 0.9,
            "learning_rate": 0.001,
            "epsilon_test_time": 0,
            "trainIterations": 10000,
        }
    )
    js = export_netjs(net, settings)
    for line in (
        "lanesSide = 1;",
        "patchesAhead = 1;",
        "patchesBehind = 0;",
        "otherAgents = 3;",
        "trainIterations = 10000;",
        "var temporal_window = 0;",
        "layer_defs.push({type: 'input', out_sx: 1, out_sy: 1, out_depth: network_size});",
        "layer_defs.push({type: 'fc', num_neurons: 2, activation: 'tanh'});",
        "layer_defs.push({type: 'regression', num_neurons: num_actions});",
        "  gamma: 0.9,",
        "  tdtrainer_options: {learning_rate: 0.001}",
        "brain = new deepqlearn.Brain(num_inputs, num_actions, opt);",
        "    brain.backward(lastReward);",
    ):
        assert line in js, line
    weights = js.split("brain.value_net.fromJSON(")[1].rsplit(");", 1)[0]
    assert loads_net(weights).same_as(net)
    assert "fromJSON" not in export_netjs(net, settings, with_weights=False)


def test_svm_and_maxout_defs_in_netjs() -> None:
    layers = expand([Input(4), SVM(3), FC(6, "maxout"), Regression(5)])
    net = init_convnet(layers)
    settings = Settings(lanes_side=0, patches_ahead=4, patches_behind=0, temporal_window=0)
    js = export_netjs(net, settings, with_weights=False)
    assert "layer_defs.push({type: 'svm', num_classes: 3});" in js
    assert "layer_defs.push({type: 'fc', num_neurons: 6, activation: 'maxout'});" in js
    assert net.hidden == "svm:3|fc:6:maxout"
    assert expand((Input(4), *parse_hidden(net.hidden), Regression(5))) == tuple(
        layer if not isinstance(layer, FC) else FC(layer.num_neurons, bias_pref=layer.bias_pref) for layer in layers
    )


# -- errors -------------------------------------------------------------------------------------------


def _err(obj: dict) -> str:
    with pytest.raises(NetFormatError) as info:
        parse_net(obj)
    msg = str(info.value)
    assert "\n" not in msg
    return msg


def test_nan_and_infinite_weights_are_errors() -> None:
    text = json.dumps(SMALL).replace("-1.25", "NaN")
    with pytest.raises(NetFormatError, match=r"^layers\[1\]\.filters\[0\]\.w\[1\]: NaN weight"):
        loads_net(text)
    text = json.dumps(SMALL).replace('"1": 2,', '"1": -Infinity,')
    with pytest.raises(NetFormatError, match=r"^layers\[1\]\.filters\[1\]\.w\[1\]: infinite weight"):
        loads_net(text)


def test_structural_errors_name_the_field() -> None:
    obj = _small()
    obj["layers"][2]["layer_type"] = "conv"
    assert _err(obj).startswith("layers[2].layer_type: unknown layer type 'conv'")
    obj = _small()
    del obj["layers"][1]["filters"][1]["w"]["2"]
    assert _err(obj).startswith("layers[1].filters[1].w: 2 entries, expected 3")
    obj = _small()
    obj["layers"][1]["filters"][0]["w"]["1"] = "x"
    assert _err(obj).startswith("layers[1].filters[0].w[1]: must be a number")
    obj = _small()
    obj["layers"][3]["num_inputs"] = 3
    assert _err(obj).startswith("layers[3].num_inputs: 3, but the previous layer has 2 outputs")
    obj = _small()
    obj["layers"][1]["filters"].pop()
    assert _err(obj).startswith("layers[1].filters: 1 filters, but out_depth is 2")
    obj = _small()
    obj["layers"][2]["out_depth"] = 7
    assert _err(obj).startswith("layers[2].out_depth: 7, expected 2")
    assert _err({"net": []}).startswith("layers: missing")
    obj = _small()
    del obj["layers"][2]["layer_type"]
    assert _err(obj) == "layers[2].layer_type: missing"
    with pytest.raises(NetFormatError, match="invalid JSON"):
        loads_net('{"layers": [')


def test_sizes_must_fit_the_settings() -> None:
    net = parse_net(_small())
    with pytest.raises(NetFormatError, match=r"^layers\[0\]\.out_depth: the net takes 3 inputs .* = 7 "):
        validate(net, Settings(lanes_side=0, patches_ahead=1, patches_behind=0, temporal_window=1))
    with pytest.raises(NetFormatError, match=r"^config.lanesSide: must be an integer in 0–50, got 1.5"):
        settings_from_config({"lanesSide": 1.5, "patchesAhead": 1, "patchesBehind": 0})
    with pytest.raises(NetFormatError, match=r"^config.temporal_window: 101 is out of range; allowed 0–100"):
        settings_from_config({"lanesSide": 1, "patchesAhead": 1, "patchesBehind": 0, "temporal_window": 101})
    with pytest.raises(NetFormatError, match=r"^config.engine_version: 'v3' is not allowed"):
        settings_from_config({"lanesSide": 1, "patchesAhead": 1, "patchesBehind": 0, "engine_version": "v3"})
    with pytest.raises(NetFormatError, match="config.patchesAhead: missing"):
        settings_from_config({"lanesSide": 1, "patchesBehind": 0})
    loaded = settings_from_config({"lanesSide": 1, "patchesAhead": 1, "patchesBehind": 0, "momentum": 5})
    assert loaded.temporal_window is None and loaded.filled().temporal_window == 1  # deepqlearn's default
    assert loaded.momentum == 5.0  # out of the learner's range, but a net file may say it: evaluation ignores it


def test_missing_files(tmp_path: Path) -> None:
    with pytest.raises(NetFormatError, match="--net: file not found"):
        load_net(tmp_path / "nope.json")
    (tmp_path / "a.json").write_text(json.dumps(SMALL))
    with pytest.raises(NetFormatError, match="--config: file not found"):
        load(tmp_path / "a.json")


# -- CLI (in-process) --------------------------------------------------------------------------------


def _cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        code = cli.main(["evaluate", *args])
    except SystemExit as exc:  # argparse
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_bad_input_exits_2_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(SMALL).replace("-1.25", "NaN"))
    (tmp_path / "bad.config.json").write_text(json.dumps({"lanesSide": 1, "patchesAhead": 1, "patchesBehind": 0}))
    for args, needle in (
        (["--net", str(tmp_path / "missing.json")], "--net: file not found"),
        (["--net", str(bad)], "NaN weight"),
        (["--net", str(bad), "--config", str(tmp_path / "bad.config.json"), "--protocol", "nope"], "NaN weight"),
    ):
        code, out, err = _cli(args, capsys)
        assert code == 2 and out == ""
        assert err.count("\n") == 1 and err.startswith("error: ") and needle in err
    good = tmp_path / "good.json"
    good.write_text(json.dumps(SMALL))
    (tmp_path / "good.config.json").write_text(json.dumps({"lanesSide": 1, "patchesAhead": 1, "patchesBehind": 0}))
    code, _out, err = _cli(["--net", str(good)], capsys)
    assert code == 2 and "the net takes 3 inputs" in err  # temporal_window defaults to 1 → 11 inputs
    (tmp_path / "good.config.json").write_text(
        json.dumps({"lanesSide": 1, "patchesAhead": 1, "patchesBehind": 0, "temporal_window": 0, "otherAgents": 1})
    )
    code, _out, err = _cli(["--net", str(good), "--protocol", "nope"], capsys)
    assert code == 2 and err.startswith("error: protocol: 'nope'")
    code, _out, err = _cli(["--net", str(good), "--ruleset", "v1", "--protocol", "v2-official"], capsys)
    assert code == 2 and "v2 protocol but the ruleset is v1" in err


def test_cli_json_last_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = tmp_path / "good.json"
    good.write_text(json.dumps(SMALL))
    (tmp_path / "good.config.json").write_text(
        json.dumps({"lanesSide": 1, "patchesAhead": 1, "patchesBehind": 0, "temporal_window": 0, "otherAgents": 1})
    )
    code, out, _err = _cli(["--net", str(good), "--runs", "3", "--frames", "300", "--json"], capsys)
    assert code == 0
    res = json.loads(out.strip().splitlines()[-1])
    assert res["protocol"] == "v2-official" and res["other_agents"] == 1 and res["runs"] == 3
    assert len(res["scores"]) == 3 and {"median_site", "median", "mean", "ci95"} <= set(res)
    assert res["median_site"] in res["scores"]
    assert np.isfinite(res["mean"])
