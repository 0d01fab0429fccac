"""deeptraffic-autotune: the public API, re-exported lazily (``import autotune`` stays cheap).

Layers, bottom to top: ``sim`` (the engines) → ``autotune.convnet`` (convnetjs networks) →
``autotune.learner`` (deepqlearn: training, exact evaluation) → ``autotune.search`` (Optuna/Ray
studies) → ``autotune.cli``. Attributes resolve on first use so that code needing only the net
format (e.g. ``dashboards``) never imports torch.
"""

from __future__ import annotations

import importlib
from typing import Any

# public name -> module that defines it
_EXPORTS: dict[str, str] = {
    # training configuration
    "ConfigError": "sim.config",
    "TrainConfig": "autotune.config",
    "PRESETS": "autotune.config",
    "preset": "autotune.config",
    "load_toml": "autotune.config",
    # learner
    "train": "autotune.learner",
    "TrainResult": "autotune.learner",
    "CurvePoint": "autotune.learner",
    "StopTraining": "autotune.learner",
    "DivergedError": "autotune.learner",
    "quick_evaluate": "autotune.learner",
    # exact evaluation of a net
    "evaluate_official": "autotune.train",
    "net_settings": "autotune.train",
    "official_protocol": "autotune.train",
    "evaluate_net": "autotune.brain_policy",
    "BrainPolicy": "autotune.brain_policy",
    # convnetjs networks
    "ConvNet": "autotune.netspec",
    "parse_hidden": "autotune.netspec",
    "format_hidden": "autotune.netspec",
    "layer_sizes": "autotune.netspec",
    "NetSettings": "autotune.netjson",
    "NetFormatError": "autotune.netjson",
    "load_net": "autotune.netjson",
    "loads_net": "autotune.netjson",
    "dumps_net": "autotune.netjson",
    "write_net": "autotune.netjson",
    "export_netjs": "autotune.netjson",
    "settings_from_config": "autotune.netjson",
    "settings_to_config": "autotune.netjson",
    "load_net_and_settings": "autotune.netjson:load",
    "forward": "autotune.forward",
    "greedy_actions": "autotune.forward",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    target = _EXPORTS.get(name)
    if target is None:
        raise AttributeError(f"module 'autotune' has no attribute {name!r}")
    module_name, _, attr = target.partition(":")
    value = getattr(importlib.import_module(module_name), attr or name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
