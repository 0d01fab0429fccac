"""convnetjs Net JSON import/export and a net's DeepTraffic settings (``*.json`` + ``*.config.json``).

* ``load(net_path, config_path)`` → ``(ConvNet, Settings)``, validated against each other (the
  settings record and its one reader/writer are ``autotune.convnet.settings``; unset = None):
  the input layer must have ``net_inputs = num_inputs·tw + 5·tw + num_inputs`` values with
  ``num_inputs = (2L+1)(P+B)``, the output 5; every layer must fit the previous one.
* ``parse_net(obj)`` reads the object passed to ``brain.value_net.fromJSON`` (``Net.toJSON()``
  format: ``layers[]`` with ``layer_type``; fc ``filters[i].w`` and ``biases.w`` as index→value
  objects). As in convnetjs (spec §10.7) a ``null`` weight loads as 0; a literal ``NaN``/``Infinity``
  (not valid convnetjs output) is an error.
* ``dumps_net(net)`` writes the JSON exactly as ``JSON.stringify(net.toJSON())`` would (compact, same
  key order, JS number formatting — shortest round-trip digits), so import → export reproduces a
  convnetjs file byte for byte and import → export → import is bit-exact. Non-finite parameters
  are written as ``null`` (what ``toJSON`` does with NaN; they load back as 0).
* ``export_netjs(net, settings)`` writes a net.js for the DeepTraffic page: the settings as plain
  JS assignments, ``layer_defs``, the ``opt`` object literal (``settings.write_nested``, the form
  ``TrainConfig.to_deepqlearn`` writes too), the brain, ``learn`` and (optionally) the appended
  ``brain.value_net.fromJSON(…)``. Numbers are written as JavaScript does (``sim.jsnumber``).

Every problem raises ``NetFormatError`` with a one-line message that starts with the field,
e.g. ``layers[3].filters[2].w[17]: NaN weight; …``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from autotune.convnet.settings import Settings, read, write_flat, write_nested
from autotune.convnet.spec import (
    FC,
    LRN,
    NUM_ACTIONS,
    SVM,
    ConvNet,
    Dropout,
    Input,
    Layer,
    Maxout,
    NetSpecError,
    Regression,
    Relu,
    Sigmoid,
    Softmax,
    Tanh,
    collapse,
    layer_sizes,
    layer_type,
    net_input_size,
)
from sim import fields
from sim.config import ConfigError, FieldValueError, check, input_size
from sim.jsnumber import js_number_to_string

SUPPORTED_TYPES = ("input", "fc", "relu", "tanh", "sigmoid", "maxout", "dropout", "svm", "softmax", "regression", "lrn")


class NetFormatError(ConfigError):
    """A net or settings file is unusable; the one-line message names the field (bad input: exit 2 in the CLI)."""


# --------------------------------------------------------------------------------------------
# JS number formatting (ECMAScript Number::toString, as JSON.stringify writes numbers)
# --------------------------------------------------------------------------------------------


def js_num(x: float) -> str:
    """A number as ``JSON.stringify`` writes it: ``String(x)`` (``sim.jsnumber``), non-finite values as ``null``."""
    return js_number_to_string(x) if math.isfinite(x) else "null"


# --------------------------------------------------------------------------------------------
# settings
# --------------------------------------------------------------------------------------------

# the settings a net is evaluated with: they must lie in the table's ranges (the rest only needs its type)
EVALUATION_FIELDS = ("lanes_side", "patches_ahead", "patches_behind", "temporal_window", "epsilon_test_time")


def settings_from_config(cfg: dict[str, Any], where: str = "config") -> Settings:
    """The ``Settings`` of a ``*.config.json`` / crowd CSV row (camelCase or snake_case keys, ``settings.read``).

    Other keys (provenance metadata) are ignored; ``null`` or ``""`` means not set (a library default
    applies). The input window must be set, and what evaluation uses must lie in its range.
    """
    if not isinstance(cfg, dict):
        raise NetFormatError(f"{where}: must be a JSON object, got {type(cfg).__name__}")
    try:
        values, _others = read({k: v for k, v in cfg.items() if v != ""}, where=f"{where}.")
        result = Settings(**values)
        for name in EVALUATION_FIELDS:
            if values.get(name) is not None:
                check(fields.field(name), values[name])
    except FieldValueError as exc:
        key = exc.name if exc.name.startswith(f"{where}.") else f"{where}.{fields.field(exc.name).alias or exc.name}"
        raise NetFormatError(f"{key}: {exc.problem}") from None
    except ConfigError as exc:
        raise NetFormatError(str(exc)) from None
    for f in fields.FIELDS:
        if f.required and values.get(f.name) is None:
            raise NetFormatError(f"{where}.{f.alias or f.name}: missing (required to size the input)")
    if values["patches_ahead"] + values["patches_behind"] < 1:
        raise NetFormatError(f"{where}.patchesAhead: patchesAhead + patchesBehind must be ≥ 1")
    return result


def settings_to_config(settings: Settings) -> dict[str, Any]:
    """``Settings`` → config.json-style dict (``settings.write_flat``: flat file names, unset keys omitted)."""
    return write_flat(settings)


# --------------------------------------------------------------------------------------------
# JSON → ConvNet
# --------------------------------------------------------------------------------------------


def _reject_constant(name: str) -> float:
    return {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}[name]


def _int_field(layer: dict[str, Any], where: str, key: str, default: int | None = None) -> int:
    if key not in layer:
        if default is not None:
            return default
        raise NetFormatError(f"{where}.{key}: missing")
    v = layer[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v != int(v) or v < 0:
        raise NetFormatError(f"{where}.{key}: must be a non-negative integer, got {v!r}")
    return int(v)


def _float_field(layer: dict[str, Any], where: str, key: str, default: float | None = None) -> float:
    if key not in layer or layer[key] is None:
        if default is not None:
            return default
        raise NetFormatError(f"{where}.{key}: missing")
    v = layer[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise NetFormatError(f"{where}.{key}: must be a finite number, got {v!r}")
    return float(v)


def _vol_values(vol: Any, where: str, n: int, what: str) -> np.ndarray:
    """Values of a serialized Vol (``w`` as index→value object or list); null → 0, NaN/Inf → error."""
    if not isinstance(vol, dict):
        raise NetFormatError(f"{where}: must be a Vol object with sx, sy, depth, w; got {type(vol).__name__}")
    if "w" not in vol:
        raise NetFormatError(f"{where}.w: missing")
    sx = _int_field(vol, where, "sx", 1)
    sy = _int_field(vol, where, "sy", 1)
    depth = _int_field(vol, where, "depth", n)
    if sx * sy * depth != n:
        raise NetFormatError(f"{where}: Vol size {sx}×{sy}×{depth} = {sx * sy * depth}, expected {n} {what}")
    w = vol["w"]
    if isinstance(w, dict):
        if len(w) != n:
            raise NetFormatError(f"{where}.w: {len(w)} entries, expected {n} {what}")
        try:
            raw = [w[str(i)] for i in range(n)]
        except KeyError as exc:
            raise NetFormatError(f"{where}.w: missing index {exc.args[0]} (keys must be 0…{n - 1})") from None
    elif isinstance(w, list):
        if len(w) != n:
            raise NetFormatError(f"{where}.w: {len(w)} entries, expected {n} {what}")
        raw = w
    else:
        raise NetFormatError(f"{where}.w: must be an index→value object or a list, got {type(w).__name__}")
    out = np.empty(n)
    for i, v in enumerate(raw):
        if v is None:
            out[i] = 0.0  # Float64Array assignment of null (convnetjs fromJSON): 0
        elif isinstance(v, bool) or not isinstance(v, (int, float)):
            raise NetFormatError(f"{where}.w[{i}]: must be a number, got {v!r}")
        else:
            out[i] = v
    bad = ~np.isfinite(out)
    if bad.any():
        i = int(np.argmax(bad))
        kind = "NaN" if math.isnan(out[i]) else "infinite"
        raise NetFormatError(
            f"{where}.w[{i}]: {kind} weight; convnetjs JSON never holds NaN/Infinity (toJSON writes null, "
            "which loads as 0) - fix the file or re-export the net"
        )
    return out


def parse_net(obj: Any) -> ConvNet:
    """The ``ConvNet`` of a convnetjs ``Net.toJSON()`` object (the argument of ``value_net.fromJSON``)."""
    if not isinstance(obj, dict):
        raise NetFormatError(f"net: must be a JSON object with a 'layers' list, got {type(obj).__name__}")
    if "layers" not in obj:
        raise NetFormatError("layers: missing (a convnetjs Net JSON has a top-level 'layers' list)")
    items = obj["layers"]
    if not isinstance(items, list) or not items:
        raise NetFormatError("layers: must be a non-empty list")
    layers: list[Layer] = []
    params: list[tuple[np.ndarray, np.ndarray]] = []
    prev = 0
    flat = True  # still the input's shape (sx, sy) before the first fc
    for i, layer in enumerate(items):
        where = f"layers[{i}]"
        if not isinstance(layer, dict):
            raise NetFormatError(f"{where}: must be an object, got {type(layer).__name__}")
        t = layer.get("layer_type")
        if t is None:
            raise NetFormatError(f"{where}.layer_type: missing")
        if t not in SUPPORTED_TYPES:
            raise NetFormatError(
                f"{where}.layer_type: unknown layer type {t!r} (supported: {', '.join(SUPPORTED_TYPES)})"
            )
        if (t == "input") != (i == 0):
            raise NetFormatError(f"{where}.layer_type: the first layer must be 'input' and only the first, got {t!r}")
        if t == "input":
            sx = _int_field(layer, where, "out_sx", 1)
            sy = _int_field(layer, where, "out_sy", 1)
            depth = _int_field(layer, where, "out_depth")
            if sx * sy * depth < 1:
                raise NetFormatError(f"{where}: input size {sx}×{sy}×{depth} is empty")
            layers.append(Input(depth, sx, sy))
            prev = sx * sy * depth
            flat = sx * sy == 1
            continue
        out_depth = _int_field(layer, where, "out_depth")
        if t == "fc":
            n_in = _int_field(layer, where, "num_inputs")
            if n_in != prev:
                raise NetFormatError(f"{where}.num_inputs: {n_in}, but the previous layer has {prev} outputs")
            filters = layer.get("filters")
            if not isinstance(filters, list):
                raise NetFormatError(f"{where}.filters: missing or not a list")
            if len(filters) != out_depth or out_depth < 1:
                raise NetFormatError(f"{where}.filters: {len(filters)} filters, but out_depth is {out_depth}")
            w = np.empty((out_depth, n_in))
            for j, f in enumerate(filters):
                w[j] = _vol_values(f, f"{where}.filters[{j}]", n_in, "weights (num_inputs)")
            if "biases" not in layer:
                raise NetFormatError(f"{where}.biases: missing")
            b = _vol_values(layer["biases"], f"{where}.biases", out_depth, "biases (out_depth)")
            l1 = _float_field(layer, where, "l1_decay_mul", 1.0)  # fromJSON defaults both to 1.0
            l2 = _float_field(layer, where, "l2_decay_mul", 1.0)
            layers.append(FC(out_depth, bias_pref=None, l1_decay_mul=l1, l2_decay_mul=l2))
            params.append((w, b))
            prev = out_depth
            flat = True
            continue
        expected = prev
        if t == "maxout":
            g = _int_field(layer, where, "group_size", 2)
            if g < 1:
                raise NetFormatError(f"{where}.group_size: must be ≥ 1, got {g}")
            if not flat:
                raise NetFormatError(
                    f"{where}: maxout on a {items[0].get('out_sx')}×{items[0].get('out_sy')} input volume "
                    "is not supported"
                )
            expected = prev // g
            new: Layer = Maxout(g)
        elif t == "relu":
            new = Relu()
        elif t == "tanh":
            new = Tanh()
        elif t == "sigmoid":
            new = Sigmoid()
        elif t == "dropout":
            new = Dropout(_float_field(layer, where, "drop_prob", 0.5))
        elif t == "lrn":
            if not flat:
                raise NetFormatError(
                    f"{where}: lrn on a {items[0].get('out_sx')}×{items[0].get('out_sy')} input volume is not supported"
                )
            n = _int_field(layer, where, "n")
            if n < 1:
                raise NetFormatError(f"{where}.n: must be ≥ 1, got {n}")
            new = LRN(
                _float_field(layer, where, "k"),
                n,
                _float_field(layer, where, "alpha"),
                _float_field(layer, where, "beta"),
            )
        else:  # svm, softmax, regression: out_depth = num_inputs = previous size
            n_in = _int_field(layer, where, "num_inputs", prev)
            if n_in != prev:
                raise NetFormatError(f"{where}.num_inputs: {n_in}, but the previous layer has {prev} outputs")
            new = SVM(prev) if t == "svm" else Softmax(prev) if t == "softmax" else Regression(prev)
        if t in ("relu", "tanh", "sigmoid", "dropout", "lrn") and not flat:
            # elementwise layers straight after a non-flat input keep its volume shape
            sx = _int_field(items[0], "layers[0]", "out_sx", 1)
            sy = _int_field(items[0], "layers[0]", "out_sy", 1)
            if out_depth * sx * sy != prev:
                raise NetFormatError(
                    f"{where}.out_depth: {out_depth}, expected {prev // (sx * sy)} for a {sx}×{sy} volume"
                )
        elif out_depth != expected:
            raise NetFormatError(
                f"{where}.out_depth: {out_depth}, expected {expected} (from the previous layer's {prev} outputs)"
            )
        layers.append(new)
        prev = expected
        if t in ("svm", "softmax", "regression"):
            flat = True
    try:
        return ConvNet(tuple(layers), tuple(params))
    except NetSpecError as exc:  # pragma: no cover - parse checks come first
        raise NetFormatError(str(exc)) from None


def loads_net(text: str, where: str = "net") -> ConvNet:
    """Parse convnetjs Net JSON text."""
    try:
        obj = json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as exc:
        raise NetFormatError(f"{where}: invalid JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from None
    return parse_net(obj)


def _read_text(path: str | Path, what: str) -> str:
    p = Path(path)
    try:
        return p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise NetFormatError(f"{what}: file not found: {p}") from None
    except IsADirectoryError:
        raise NetFormatError(f"{what}: {p} is a directory, expected a JSON file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise NetFormatError(f"{what}: cannot read {p} ({exc})") from None


def load_net(path: str | Path) -> ConvNet:
    """Read a convnetjs Net JSON file."""
    return loads_net(_read_text(path, "--net"), where=str(path))


def load_config(path: str | Path) -> Settings:
    """Read a ``*.config.json`` (DeepTraffic settings)."""
    text = _read_text(path, "--config")
    try:
        cfg = json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as exc:
        raise NetFormatError(f"{path}: invalid JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from None
    return settings_from_config(cfg, where="config")


def default_config_path(net_path: str | Path) -> Path:
    """``x.json`` → ``x.config.json`` (the crowd layout)."""
    p = Path(net_path)
    name = p.name[:-5] if p.name.endswith(".json") else p.name
    return p.with_name(name + ".config.json")


def validate(net: ConvNet, settings: Settings) -> None:
    """Raise ``NetFormatError`` unless the net's input/output sizes fit the settings (unset tw: deepqlearn's 1)."""
    full = settings.filled()
    check_sizes(net, full.lanes_side, full.patches_ahead, full.patches_behind, full.temporal_window)


def check_sizes(net: ConvNet, lanes_side: int, patches_ahead: int, patches_behind: int, temporal_window: int) -> None:
    """Raise ``NetFormatError`` unless ``net`` takes the input this window and temporal window give, and 5 outputs."""
    num_inputs = input_size(lanes_side, patches_ahead, patches_behind)
    net_inputs = net_input_size(num_inputs, temporal_window)
    if net.input_size != net_inputs:
        raise NetFormatError(
            f"layers[0].out_depth: the net takes {net.input_size} inputs but the settings give net_inputs = "
            f"num_inputs·tw + 5·tw + num_inputs = {net_inputs} (num_inputs = (2·{lanes_side}+1)·"
            f"({patches_ahead}+{patches_behind}) = {num_inputs}, temporal_window = {temporal_window})"
        )
    n_out = net.output_size
    if n_out != NUM_ACTIONS:
        raise NetFormatError(
            f"layers[{len(net.layers) - 1}]: the net has {n_out} outputs; "
            f"DeepTraffic needs {NUM_ACTIONS} (one Q-value per action)"
        )


def load(net_path: str | Path, config_path: str | Path | None = None) -> tuple[ConvNet, Settings]:
    """Read and cross-validate a net JSON and its config (default: ``<net>.config.json`` beside it)."""
    cfg_path = default_config_path(net_path) if config_path is None else config_path
    net = load_net(net_path)
    settings = load_config(cfg_path)
    validate(net, settings)
    return net, settings


# --------------------------------------------------------------------------------------------
# ConvNet → JSON
# --------------------------------------------------------------------------------------------


def _vol_text(values: np.ndarray, sx: int, sy: int, depth: int) -> str:
    body = ",".join(f'"{i}":{js_num(v)}' for i, v in enumerate(values.tolist()))
    return f'{{"sx":{sx},"sy":{sy},"depth":{depth},"w":{{{body}}}}}'


def dumps_net(net: ConvNet) -> str:
    """convnetjs Net JSON text of ``net``, byte-identical to ``JSON.stringify(value_net.toJSON())``."""
    sizes = layer_sizes(net.layers)
    parts = []
    fc = 0
    first = net.layers[0]
    assert isinstance(first, Input)
    sx, sy = first.out_sx, first.out_sy
    for layer, (n_in, n_out) in zip(net.layers, sizes, strict=True):
        t = layer_type(layer)
        if isinstance(layer, (FC, SVM, Softmax, Regression)):
            sx = sy = 1  # these layers flatten their input (out_depth = num_inputs)
        depth = n_out // (sx * sy)
        head = f'"out_depth":{depth},"out_sx":{sx},"out_sy":{sy},"layer_type":"{t}"'
        if isinstance(layer, Input):
            parts.append("{" + head + "}")
        elif isinstance(layer, FC):
            w, b = net.params[fc]
            fc += 1
            filters = ",".join(_vol_text(w[j], 1, 1, n_in) for j in range(n_out))
            parts.append(
                "{" + head + f',"num_inputs":{n_in},"l1_decay_mul":{js_num(layer.l1_decay_mul)},'
                f'"l2_decay_mul":{js_num(layer.l2_decay_mul)},"filters":[{filters}],'
                f'"biases":{_vol_text(b, 1, 1, n_out)}' + "}"
            )
        elif isinstance(layer, Maxout):
            parts.append("{" + head + f',"group_size":{layer.group_size}' + "}")
        elif isinstance(layer, Dropout):
            parts.append("{" + head + f',"drop_prob":{js_num(layer.drop_prob)}' + "}")
        elif isinstance(layer, (SVM, Softmax, Regression)):
            parts.append("{" + head + f',"num_inputs":{n_in}' + "}")
        elif isinstance(layer, LRN):
            parts.append(
                f'{{"k":{js_num(layer.k)},"n":{layer.n},"alpha":{js_num(layer.alpha)},"beta":{js_num(layer.beta)},'
                f'"out_sx":{sx},"out_sy":{sy},"out_depth":{depth},"layer_type":"lrn"}}'
            )
        else:  # relu, tanh, sigmoid
            parts.append("{" + head + "}")
    return '{"layers":[' + ",".join(parts) + "]}"


def net_to_json(net: ConvNet) -> dict[str, Any]:
    """The convnetjs Net JSON of ``net`` as a Python object (``json.loads(dumps_net(net))``)."""
    return json.loads(dumps_net(net))


def write_net(path: str | Path, net: ConvNet, settings: Settings | None = None) -> None:
    """Write ``net`` as convnetjs JSON, and ``settings`` beside it as ``<name>.config.json`` when given."""
    p = Path(path)
    p.write_text(dumps_net(net), encoding="utf-8")
    if settings is not None:
        validate(net, settings)
        cfg = settings_to_config(settings)
        cfg["hidden_layers"] = net.hidden
        default_config_path(p).write_text(json.dumps(cfg, indent=1) + "\n", encoding="utf-8")


# --------------------------------------------------------------------------------------------
# net.js
# --------------------------------------------------------------------------------------------


def _js_value(v: Any) -> str:
    if isinstance(v, str):
        return "'" + v.replace("\\", "\\\\").replace("'", "\\'") + "'"
    if isinstance(v, bool):
        return "true" if v else "false"
    return js_num(v)


def layer_defs_js(net: ConvNet) -> list[str]:
    """``layer_defs.push({...});`` lines that rebuild ``net``'s layers (input sized by ``network_size``)."""
    lines = []
    defs = collapse(net.layers)
    for i, d in enumerate(defs):
        if isinstance(d, Input):
            fields = f"type: 'input', out_sx: {d.out_sx}, out_sy: {d.out_sy}, out_depth: network_size"
        elif isinstance(d, FC):
            fields = f"type: 'fc', num_neurons: {d.num_neurons}"
            if d.activation:
                fields += f", activation: {_js_value(d.activation)}"
            if d.group_size is not None:
                fields += f", group_size: {d.group_size}"
            if d.bias_pref is not None:
                fields += f", bias_pref: {js_num(d.bias_pref)}"
            if d.drop_prob is not None:
                fields += f", drop_prob: {js_num(d.drop_prob)}"
        elif isinstance(d, Regression):
            n = "num_actions" if i == len(defs) - 1 and d.num_neurons == NUM_ACTIONS else str(d.num_neurons)
            fields = f"type: 'regression', num_neurons: {n}"
        elif isinstance(d, (SVM, Softmax)):
            fields = f"type: '{layer_type(d)}', num_classes: {d.num_classes}"
        elif isinstance(d, Maxout):
            fields = f"type: 'maxout', group_size: {d.group_size}"
        elif isinstance(d, Dropout):
            fields = f"type: 'dropout', drop_prob: {js_num(d.drop_prob)}"
        elif isinstance(d, LRN):
            fields = f"type: 'lrn', k: {js_num(d.k)}, n: {d.n}, alpha: {js_num(d.alpha)}, beta: {js_num(d.beta)}"
        else:
            fields = f"type: '{layer_type(d)}'"
        lines.append(f"layer_defs.push({{{fields}}});")
    return lines


def settings_js(settings: Settings) -> str:
    """The settings' net.js globals (plain assignments, as the game expects; ``settings.write_nested``)."""
    nested = write_nested(settings)
    return "\n".join(f"{key} = {_js_value(value)};" for key, value in nested.items() if key != "opt")


def opt_js(settings: Settings) -> str:
    """The ``opt`` object literal (``settings.write_nested``: the keys set, ``tdtrainer_options`` when written)."""
    opt = write_nested(settings)["opt"]
    entries = ["  temporal_window: temporal_window"]  # the global below, as the page writes it
    entries += [
        f"  {key}: {_js_value(v)}" for key, v in opt.items() if key not in ("temporal_window", "tdtrainer_options")
    ]
    entries.append("  layer_defs: layer_defs")
    if "tdtrainer_options" in opt:
        trainer = ", ".join(f"{key}: {_js_value(v)}" for key, v in opt["tdtrainer_options"].items())
        entries.append("  tdtrainer_options: {" + trainer + "}")
    return "var opt = {\n" + ",\n".join(entries) + "\n};"


def export_netjs(net: ConvNet, settings: Settings, with_weights: bool = True) -> str:
    """A net.js for the DeepTraffic page: settings, layer_defs, opt, brain, learn (+ trained weights)."""
    validate(net, settings)
    parts = [
        "//<![CDATA[",
        "// generated by deeptraffic-autotune",
        settings_js(settings),
        "",
        "var num_inputs = (lanesSide * 2 + 1) * (patchesAhead + patchesBehind);",
        "var num_actions = 5;",
        f"var temporal_window = {settings.filled().temporal_window};",
        "var network_size = num_inputs * temporal_window + num_actions * temporal_window + num_inputs;",
        "",
        "var layer_defs = [];",
        *layer_defs_js(net),
        "",
        opt_js(settings),
        "",
        "brain = new deepqlearn.Brain(num_inputs, num_actions, opt);",
        "",
        "learn = function (state, lastReward) {",
        "    brain.backward(lastReward);",
        "    var action = brain.forward(state);",
        "    draw_net();",
        "    draw_stats();",
        "    return action;",
        "}",
    ]
    if with_weights:
        parts += ["", "brain.value_net.fromJSON(" + dumps_net(net) + ");"]
    parts.append("//]]>")
    return "\n".join(parts) + "\n"
