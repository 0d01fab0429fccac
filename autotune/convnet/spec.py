"""convnetjs network descriptions: layer definitions, ``layer_defs`` expansion, ``ConvNet``.

Everything here follows engine_spec.md §10.5 and §10.9 (the convnetjs build shipped with both
DeepTraffic engines). A network exists at two levels:

* **layer definitions** ("defs") — what a user writes in ``layer_defs`` (``FC(36, "tanh")``,
  ``SVM(14)``, ``Regression(5)``); the crowd's compact string form ``fc:36:tanh|svm:14|lrn`` parses to
  the hidden part of that list (``parse_hidden``).
* **expanded layers** — what ``Net.makeLayers`` actually builds (``expand``): loss layers are
  preceded by an inserted ``FC(n)``, an fc's ``activation`` becomes its own layer, a ``drop_prob``
  adds a ``Dropout``, every ``FC`` gets its ``bias_pref`` (0.1 after relu, else 0.0). Expanded
  ``FC`` layers never carry an activation.

``ConvNet`` = the expanded layer tuple + float64 parameters, one ``(weights (out, in), biases (out,))``
pair per ``FC`` in order. The exact prediction-mode forward pass is ``autotune.convnet.forward``; JSON
import/export is ``autotune.convnet.netjson``; the torch module is ``autotune.convnet.torch_bridge``; the
simulator policy is ``autotune.learner.brain_policy``.

API for the training side (torch)::

    from autotune.convnet.spec import Input, FC, Regression, expand
    from autotune.convnet.torch_bridge import build_torch, to_torch, from_torch
    from autotune.convnet.netjson import write_net, dumps_net, export_netjs
    from autotune.convnet.settings import Settings
    from autotune.learner.brain_policy import evaluate_net

    layers = expand([Input(net_inputs), FC(36, "tanh"), FC(24, "tanh"), Regression(5)])
    # (or expand(deepqlearn_defs(net_inputs, "fc:36:tanh|fc:24:tanh")))
    module = build_torch(layers, dtype=torch.float32)   # nn.Sequential subclass; Linear k ↔ k-th FC
    ...train module...
    net = from_torch(module, layers)                    # ConvNet (float64) with the trained weights
    settings = Settings(lanes_side=3, patches_ahead=50, patches_behind=10, temporal_window=0,
                        other_agents=0, epsilon_test_time=0.0)  # None / absent: not set (a default applies)
    write_net("out/net.json", net, settings)            # convnetjs JSON + net.config.json beside it
    export_netjs(net, settings)                         # net.js text for the DeepTraffic page
    result = evaluate_net(net, settings, "v2-official") # exact evaluation (sim.protocols.EvalResult)

    to_torch(net, dtype=torch.float64)                  # ConvNet → module carrying its weights
    init_convnet(layers, seed)                          # convnetjs-style fresh weights (N(0, 1/fan_in), bias_pref)
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from sim.config import ConfigError

NUM_ACTIONS = 5
ACTIVATIONS = ("relu", "tanh", "sigmoid", "maxout")
LRN_DEFAULTS = {"k": 1.0, "n": 3, "alpha": 0.1, "beta": 0.75}  # used when a hidden-layer string says just "lrn"


class NetSpecError(ConfigError):
    """An invalid layer definition or network; the message names the field (bad input: exit 2 in the CLI)."""


# --------------------------------------------------------------------------------------------
# layer definitions (frozen); after ``expand`` the same classes describe the built layers
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Input:
    """Input volume ``out_sx × out_sy × out_depth`` (deepqlearn always feeds a flat 1×1×N vector)."""

    out_depth: int
    out_sx: int = 1
    out_sy: int = 1


@dataclasses.dataclass(frozen=True)
class FC:
    """Fully connected ``num_neurons`` outputs; ``activation``/``drop_prob`` add layers on expansion."""

    num_neurons: int
    activation: str | None = None
    bias_pref: float | None = None
    drop_prob: float | None = None
    group_size: int | None = None  # maxout group size when activation == "maxout"
    l1_decay_mul: float = 0.0
    l2_decay_mul: float = 1.0


@dataclasses.dataclass(frozen=True)
class Relu:
    """``max(0, x)`` (convnetjs: values < 0 set to 0; NaN passes)."""


@dataclasses.dataclass(frozen=True)
class Tanh:
    """``(e^{2x} − 1)/(e^{2x} + 1)`` with ``Math.exp`` (not a library tanh)."""


@dataclasses.dataclass(frozen=True)
class Sigmoid:
    """``1/(1 + e^{−x})``."""


@dataclasses.dataclass(frozen=True)
class Maxout:
    """Max over consecutive groups of ``group_size`` inputs (ties keep the lowest index); ⌊n/g⌋ outputs."""

    group_size: int = 2


@dataclasses.dataclass(frozen=True)
class Dropout:
    """Training: zero each value with probability ``drop_prob``; prediction: multiply by ``drop_prob`` (bug)."""

    drop_prob: float = 0.5


@dataclasses.dataclass(frozen=True)
class SVM:
    """SVM loss layer (identity forward); the def inserts ``FC(num_classes)`` before it."""

    num_classes: int


@dataclasses.dataclass(frozen=True)
class Softmax:
    """Softmax loss layer ``e^{x−max}/Σ``; the def inserts ``FC(num_classes)`` before it."""

    num_classes: int


@dataclasses.dataclass(frozen=True)
class Regression:
    """Regression loss layer (identity forward); the def inserts ``FC(num_neurons)`` before it."""

    num_neurons: int


@dataclasses.dataclass(frozen=True)
class LRN:
    """Local response normalisation ``x_i/(k + (α/n)·Σ_{|j−i|≤⌊n/2⌋} x_j²)^β`` (1-D case)."""

    k: float
    n: int
    alpha: float
    beta: float


Layer = Input | FC | Relu | Tanh | Sigmoid | Maxout | Dropout | SVM | Softmax | Regression | LRN
LAYER_TYPES = {
    "input": Input,
    "fc": FC,
    "relu": Relu,
    "tanh": Tanh,
    "sigmoid": Sigmoid,
    "maxout": Maxout,
    "dropout": Dropout,
    "svm": SVM,
    "softmax": Softmax,
    "regression": Regression,
    "lrn": LRN,
}
TYPE_NAMES = {cls: name for name, cls in LAYER_TYPES.items()}


def layer_type(layer: Layer) -> str:
    """convnetjs ``layer_type`` string of a layer object."""
    return TYPE_NAMES[type(layer)]


# --------------------------------------------------------------------------------------------
# expansion (convnetjs desugar) and sizes
# --------------------------------------------------------------------------------------------


def expand(defs: Sequence[Layer]) -> tuple[Layer, ...]:
    """convnetjs ``Net.makeLayers`` desugaring of a ``layer_defs`` list (spec §10.9), in list order."""
    out: list[Layer] = []
    for i, d in enumerate(defs):
        if not isinstance(d, tuple(LAYER_TYPES.values())):
            raise NetSpecError(f"layer_defs[{i}]: {d!r} is not a layer definition")
        if isinstance(d, (SVM, Softmax)):
            out.append(FC(d.num_classes, bias_pref=0.0))
        elif isinstance(d, Regression):
            out.append(FC(d.num_neurons, bias_pref=0.0))
        if isinstance(d, FC):
            bias = d.bias_pref
            if bias is None:
                bias = 0.1 if d.activation == "relu" else 0.0
            out.append(FC(d.num_neurons, bias_pref=bias, l1_decay_mul=d.l1_decay_mul, l2_decay_mul=d.l2_decay_mul))
            if d.activation == "relu":
                out.append(Relu())
            elif d.activation == "tanh":
                out.append(Tanh())
            elif d.activation == "sigmoid":
                out.append(Sigmoid())
            elif d.activation == "maxout":
                out.append(Maxout(d.group_size if d.group_size is not None else 2))
            # any other activation string adds nothing (convnetjs logs a message)
            if d.drop_prob is not None:
                out.append(Dropout(d.drop_prob))
        else:
            out.append(d)
    return tuple(out)


def collapse(layers: Sequence[Layer]) -> tuple[Layer, ...]:
    """Inverse of ``expand`` for a built layer list: fc+activation → ``FC(n, act)``, fc(n)+svm(n) → ``SVM(n)``…

    ``expand(collapse(layers))`` has the same layers and fc shapes (bias_pref may differ; it only
    matters for fresh initialisation).
    """
    out: list[Layer] = []
    i = 0
    n = len(layers)
    while i < n:
        layer = layers[i]
        nxt = layers[i + 1] if i + 1 < n else None
        if isinstance(layer, FC):
            width = layer.num_neurons
            if isinstance(nxt, SVM) and nxt.num_classes == width:
                out.append(SVM(width))
                i += 2
                continue
            if isinstance(nxt, Softmax) and nxt.num_classes == width:
                out.append(Softmax(width))
                i += 2
                continue
            if isinstance(nxt, Regression) and nxt.num_neurons == width:
                out.append(Regression(width))
                i += 2
                continue
            act = None
            group = None
            step = 1
            if isinstance(nxt, (Relu, Tanh, Sigmoid, Maxout)):
                act = layer_type(nxt)
                group = nxt.group_size if isinstance(nxt, Maxout) and nxt.group_size != 2 else None
                step = 2
            drop = None
            after = layers[i + step] if i + step < n else None
            if isinstance(after, Dropout):
                drop = after.drop_prob
                step += 1
            bias = layer.bias_pref
            default_bias = 0.1 if act == "relu" else 0.0
            out.append(
                FC(
                    width,
                    act,
                    bias_pref=None if bias is None or bias == default_bias else bias,
                    drop_prob=drop,
                    group_size=group,
                    l1_decay_mul=layer.l1_decay_mul,
                    l2_decay_mul=layer.l2_decay_mul,
                )
            )
            i += step
            continue
        out.append(layer)
        i += 1
    return tuple(out)


def layer_sizes(layers: Sequence[Layer]) -> list[tuple[int, int]]:
    """(input size, output size) of every expanded layer; the first layer must be ``Input``."""
    if not layers or not isinstance(layers[0], Input):
        raise NetSpecError("layers[0]: the first layer must be an input layer")
    sizes: list[tuple[int, int]] = []
    prev = 0
    for i, layer in enumerate(layers):
        if isinstance(layer, Input):
            if i != 0:
                raise NetSpecError(f"layers[{i}]: an input layer is only allowed first")
            for name in ("out_depth", "out_sx", "out_sy"):
                v = getattr(layer, name)
                if not _is_int(v) or v < 1:
                    raise NetSpecError(f"layers[{i}].{name}: must be a positive integer, got {v!r}")
            out = layer.out_sx * layer.out_sy * layer.out_depth
            sizes.append((out, out))
        elif isinstance(layer, FC):
            if layer.activation is not None or layer.drop_prob is not None:
                raise NetSpecError(f"layers[{i}]: fc with activation/drop_prob is a definition; expand() it first")
            if not _is_int(layer.num_neurons) or layer.num_neurons < 1:
                raise NetSpecError(f"layers[{i}].num_neurons: must be a positive integer, got {layer.num_neurons!r}")
            out = layer.num_neurons
            sizes.append((prev, out))
        elif isinstance(layer, Maxout):
            if not _is_int(layer.group_size) or layer.group_size < 1:
                raise NetSpecError(f"layers[{i}].group_size: must be a positive integer, got {layer.group_size!r}")
            out = prev // layer.group_size
            if out < 1:
                raise NetSpecError(f"layers[{i}]: maxout group_size {layer.group_size} exceeds its {prev} inputs")
            sizes.append((prev, out))
        elif isinstance(layer, (SVM, Softmax)):
            if layer.num_classes != prev:
                raise NetSpecError(f"layers[{i}].num_classes: {layer.num_classes} ≠ its {prev} inputs")
            sizes.append((prev, prev))
        elif isinstance(layer, Regression):
            if layer.num_neurons != prev:
                raise NetSpecError(f"layers[{i}].num_neurons: {layer.num_neurons} ≠ its {prev} inputs")
            sizes.append((prev, prev))
        elif isinstance(layer, Dropout):
            if not (isinstance(layer.drop_prob, (int, float)) and math.isfinite(layer.drop_prob)):
                raise NetSpecError(f"layers[{i}].drop_prob: must be a finite number, got {layer.drop_prob!r}")
            sizes.append((prev, prev))
        elif isinstance(layer, LRN):
            if not _is_int(layer.n) or layer.n < 1:
                raise NetSpecError(f"layers[{i}].n: must be a positive integer, got {layer.n!r}")
            for name in ("k", "alpha", "beta"):
                v = getattr(layer, name)
                if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)):
                    raise NetSpecError(f"layers[{i}].{name}: must be a finite number, got {v!r}")
            sizes.append((prev, prev))
        elif isinstance(layer, (Relu, Tanh, Sigmoid)):
            sizes.append((prev, prev))
        else:
            raise NetSpecError(f"layers[{i}]: {layer!r} is not a layer")
        prev = sizes[-1][1]
    return sizes


def param_count(layers: Sequence[Layer]) -> int:
    """Weights + biases of the expanded ``layers`` (the fc layers': in·out + out; the rest hold none)."""
    return sum(n_in * n_out + n_out for layer, (n_in, n_out) in zip(layers, layer_sizes(layers), strict=True)
               if isinstance(layer, FC))  # fmt: skip


def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


# --------------------------------------------------------------------------------------------
# ConvNet
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class ConvNet:
    """Expanded layers + float64 parameters: ``params[k] = (weights (out, in), biases (out,))`` of the k-th FC."""

    layers: tuple[Layer, ...]
    params: tuple[tuple[np.ndarray, np.ndarray], ...]

    def __post_init__(self) -> None:
        sizes = layer_sizes(self.layers)
        fcs = [(i, s) for i, (layer, s) in enumerate(zip(self.layers, sizes, strict=True)) if isinstance(layer, FC)]
        if len(fcs) != len(self.params):
            raise NetSpecError(f"params: {len(self.params)} (weights, biases) pairs for {len(fcs)} fc layers")
        fixed = []
        for (i, (n_in, n_out)), (w, b) in zip(fcs, self.params, strict=True):
            w = np.ascontiguousarray(w, dtype=np.float64)
            b = np.ascontiguousarray(b, dtype=np.float64)
            if w.shape != (n_out, n_in):
                raise NetSpecError(f"layers[{i}]: weights shape {w.shape}, expected ({n_out}, {n_in})")
            if b.shape != (n_out,):
                raise NetSpecError(f"layers[{i}]: biases shape {b.shape}, expected ({n_out},)")
            fixed.append((w, b))
        object.__setattr__(self, "params", tuple(fixed))

    @property
    def input_size(self) -> int:
        first = self.layers[0]
        assert isinstance(first, Input)
        return first.out_sx * first.out_sy * first.out_depth

    @property
    def output_size(self) -> int:
        return layer_sizes(self.layers)[-1][1]

    @property
    def fc_shapes(self) -> list[tuple[int, int]]:
        """(out, in) of every fc layer, in order."""
        return [w.shape for w, _b in self.params]  # type: ignore[misc]

    @property
    def n_params(self) -> int:
        return int(sum(w.size + b.size for w, b in self.params))

    @property
    def hidden(self) -> str:
        """The crowd's ``hidden_layers`` string of this net (layers between input and the final regression)."""
        defs = collapse(self.layers)
        if defs and isinstance(defs[-1], Regression):
            defs = defs[:-1]
        return format_hidden(defs[1:])

    def same_as(self, other: ConvNet) -> bool:
        """Same layers (an fc's ``bias_pref`` — initialisation only — ignored) and bit-identical parameters."""
        if not same_structure(self.layers, other.layers) or len(self.params) != len(other.params):
            return False
        for (w1, b1), (w2, b2) in zip(self.params, other.params, strict=True):
            if w1.shape != w2.shape or b1.shape != b2.shape:
                return False
            if not (
                np.array_equal(w1.view(np.int64), w2.view(np.int64))
                and np.array_equal(b1.view(np.int64), b2.view(np.int64))
            ):
                return False
        return True


def _structure(layers: Sequence[Layer]) -> tuple[Layer, ...]:
    return tuple(dataclasses.replace(x, bias_pref=None) if isinstance(x, FC) else x for x in layers)


def same_structure(a: Sequence[Layer], b: Sequence[Layer]) -> bool:
    """Whether two expanded layer lists build the same net: an fc's ``bias_pref`` (initialisation only, never in a
    net's JSON) is ignored."""
    return _structure(a) == _structure(b)


def describe_layers(layers: Sequence[Layer]) -> str:
    """``layers`` (expanded, from the input) in a line: the input size and the crowd's hidden-layer string."""
    sizes = layer_sizes(layers)
    defs = collapse(layers)
    if defs and isinstance(defs[-1], Regression):
        defs = defs[:-1]
    hidden = format_hidden(defs[1:])
    return f"{sizes[0][1]} inputs, hidden '{hidden}'" if hidden else f"{sizes[0][1]} inputs, no hidden layer"


def fc_bias_prefs(layers: Sequence[Layer]) -> list[float]:
    """Initial bias value of every fc (its ``bias_pref``; 0.0 when unset)."""
    return [float(layer.bias_pref or 0.0) for layer in layers if isinstance(layer, FC)]


def init_convnet(layers: Sequence[Layer], seed: int = 0) -> ConvNet:
    """Fresh convnetjs-style parameters: weights N(0, std √(1/fan_in)), biases = ``bias_pref``.

    Uses numpy's generator (not the JS stream); for a JS-exact initialisation see
    ``autotune.convnet.random.build_draws`` (the draw count) — the values themselves are never needed
    for evaluation because trained weights replace them.
    """
    layers = tuple(layers)
    sizes = layer_sizes(layers)
    rng = np.random.default_rng(seed)
    params = []
    for layer, (n_in, n_out) in zip(layers, sizes, strict=True):
        if isinstance(layer, FC):
            w = rng.standard_normal((n_out, n_in)) * math.sqrt(1.0 / n_in)
            b = np.full(n_out, float(layer.bias_pref or 0.0))
            params.append((w, b))
    return ConvNet(layers, tuple(params))


# --------------------------------------------------------------------------------------------
# hidden-layer strings (crowd CSV / config.json form)
# --------------------------------------------------------------------------------------------


def _num(text: str, where: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise NetSpecError(f"{where}: '{text}' is not a number") from None


def _int(text: str, where: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise NetSpecError(f"{where}: '{text}' is not an integer") from None
    if v < 1:
        raise NetSpecError(f"{where}: must be ≥ 1, got {v}")
    return v


def parse_hidden(text: str | None) -> tuple[Layer, ...]:
    """Parse ``fc:36:tanh|svm:14|fc:10:maxout|lrn`` into layer definitions (no input, no final regression).

    Tokens: ``fc:N[:act][:key=value…]`` (keys ``drop_prob``, ``bias_pref``, ``group_size``),
    ``svm:N``, ``softmax:N``, ``regression:N``, ``relu``, ``tanh``, ``sigmoid``, ``maxout[:g]``,
    ``dropout:p``, ``lrn[:k:n:alpha:beta]`` (bare ``lrn``: k=1, n=3, α=0.1, β=0.75). Empty / "(none: linear)" → ().
    """
    if text is None:
        return ()
    text = text.strip()
    if text in ("", "(none: linear)", "none", "linear"):
        return ()
    out: list[Layer] = []
    for j, token in enumerate(text.split("|")):
        where = f"hidden_layers[{j}] '{token}'"
        parts = [p.strip() for p in token.strip().split(":")]
        kind = parts[0].lower()
        args = parts[1:]
        if kind == "fc":
            if not args:
                raise NetSpecError(f"{where}: fc needs a size, e.g. fc:36:tanh")
            n = _int(args[0], where)
            act = None
            extra: dict[str, Any] = {}
            for a in args[1:]:
                if "=" in a:
                    key, val = a.split("=", 1)
                    if key == "drop_prob":
                        extra[key] = _num(val, where)
                    elif key == "bias_pref":
                        extra[key] = _num(val, where)
                    elif key == "group_size":
                        extra[key] = _int(val, where)
                    else:
                        raise NetSpecError(f"{where}: unknown option '{key}' (use drop_prob, bias_pref, group_size)")
                elif act is None:
                    act = a or None
                else:
                    raise NetSpecError(f"{where}: too many fields")
            out.append(FC(n, act, **extra))
        elif kind in ("svm", "softmax", "regression"):
            if len(args) != 1:
                raise NetSpecError(f"{where}: {kind} needs exactly one size, e.g. {kind}:14")
            n = _int(args[0], where)
            out.append(SVM(n) if kind == "svm" else Softmax(n) if kind == "softmax" else Regression(n))
        elif kind in ("relu", "tanh", "sigmoid"):
            if args:
                raise NetSpecError(f"{where}: {kind} takes no arguments")
            out.append(Relu() if kind == "relu" else Tanh() if kind == "tanh" else Sigmoid())
        elif kind == "maxout":
            out.append(Maxout(_int(args[0], where) if args else 2))
        elif kind == "dropout":
            if len(args) != 1:
                raise NetSpecError(f"{where}: dropout needs its drop_prob, e.g. dropout:0.25")
            out.append(Dropout(_num(args[0], where)))
        elif kind == "lrn":
            if not args:
                out.append(LRN(**LRN_DEFAULTS))  # type: ignore[arg-type]
            elif len(args) == 4:
                out.append(LRN(_num(args[0], where), _int(args[1], where), _num(args[2], where), _num(args[3], where)))
            else:
                raise NetSpecError(f"{where}: lrn takes no or four arguments (lrn:k:n:alpha:beta)")
        else:
            raise NetSpecError(
                f"{where}: unknown layer type '{kind}' "
                "(use fc, svm, softmax, regression, relu, tanh, sigmoid, maxout, dropout, lrn)"
            )
    return tuple(out)


def _fmt_num(x: float) -> str:
    return repr(int(x)) if float(x) == int(x) else repr(float(x))


def format_hidden(defs: Iterable[Layer]) -> str:
    """Inverse of ``parse_hidden`` (the crowd's format for the common cases)."""
    parts = []
    for d in defs:
        if isinstance(d, FC):
            s = f"fc:{d.num_neurons}"
            if d.activation:
                s += f":{d.activation}"
            for key in ("drop_prob", "bias_pref", "group_size"):
                v = getattr(d, key)
                if v is not None:
                    s += f":{key}={_fmt_num(v)}"
            parts.append(s)
        elif isinstance(d, SVM):
            parts.append(f"svm:{d.num_classes}")
        elif isinstance(d, Softmax):
            parts.append(f"softmax:{d.num_classes}")
        elif isinstance(d, Regression):
            parts.append(f"regression:{d.num_neurons}")
        elif isinstance(d, (Relu, Tanh, Sigmoid)):
            parts.append(layer_type(d))
        elif isinstance(d, Maxout):
            parts.append("maxout" if d.group_size == 2 else f"maxout:{d.group_size}")
        elif isinstance(d, Dropout):
            parts.append(f"dropout:{_fmt_num(d.drop_prob)}")
        elif isinstance(d, LRN):
            if dataclasses.asdict(d) == LRN_DEFAULTS:
                parts.append("lrn")
            else:
                parts.append(f"lrn:{_fmt_num(d.k)}:{d.n}:{_fmt_num(d.alpha)}:{_fmt_num(d.beta)}")
        else:
            raise NetSpecError(f"format_hidden: {d!r} cannot appear between input and output")
    return "|".join(parts)


def net_input_size(num_states: int, temporal_window: int, num_actions: int = NUM_ACTIONS) -> int:
    """deepqlearn's network input size, ``num_states·tw + num_actions·tw + num_states`` (v1 §10.2)."""
    return num_states * temporal_window + num_actions * temporal_window + num_states


def deepqlearn_defs(
    net_inputs: int, hidden: str | Sequence[Layer], num_actions: int = NUM_ACTIONS
) -> tuple[Layer, ...]:
    """The full ``layer_defs`` of a DeepTraffic net: input(net_inputs), hidden, regression(num_actions)."""
    hid = parse_hidden(hidden) if isinstance(hidden, str) else tuple(hidden)
    return (Input(net_inputs), *hid, Regression(num_actions))
