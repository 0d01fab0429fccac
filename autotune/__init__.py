"""deeptraffic-autotune: the public API, re-exported lazily (``import autotune`` stays cheap).

Layers, bottom to top: ``sim`` (the engines) → ``autotune.convnet`` (convnetjs networks) →
``autotune.learner`` (deepqlearn: training, exact evaluation) → ``autotune.search`` (Optuna/Ray
studies) → ``dashboards`` (reports, the crowd) → ``autotune.commands`` (one module per subcommand)
→ ``autotune.cli``. Attributes resolve on first use so that code needing only the net format (e.g.
``dashboards``) never imports torch.

No exported name is also the name of a submodule: importing ``autotune.train`` (the
``python -m autotune.train`` shim) sets the package attribute ``train`` to that module, so the
training function lives at ``from autotune.learner import train``.
"""

from __future__ import annotations

import importlib
from typing import Any

# public name -> module that defines it
_EXPORTS: dict[str, str] = {
    # training configuration
    "ConfigError": "sim.config",
    # the DeepTraffic fields: one table (name, alias, type, range, defaults, doc)
    "FIELDS": "sim.fields",
    "Field": "sim.fields",
    "field_bounds": "sim.fields:bounds",
    "TrainConfig": "autotune.learner.config",
    "PRESETS": "autotune.learner.config",
    "preset": "autotune.learner.config",
    "load_toml": "autotune.learner.config",
    # learner (the training function is ``autotune.learner.train``: ``autotune.train`` is the
    # ``python -m autotune.train`` module, and no export may carry a submodule's name)
    "TrainResult": "autotune.learner.training",
    "CurvePoint": "autotune.learner.training",
    "StopTraining": "autotune.learner.training",
    "DivergedError": "autotune.learner.brain",
    "quick_evaluate": "autotune.learner.quick_eval",
    # exact evaluation of a net
    "evaluate_official": "autotune.learner.official",
    "screen_epsilons": "autotune.learner.official",
    "EpsilonScreens": "autotune.learner.official",
    "official_protocol": "autotune.learner.official",
    "OFFICIAL_PROTOCOL": "autotune.learner.official",
    "evaluate_net": "autotune.learner.brain_policy",
    "BrainPolicy": "autotune.learner.brain_policy",
    # convnetjs networks
    "ConvNet": "autotune.convnet.spec",
    "parse_hidden": "autotune.convnet.spec",
    "format_hidden": "autotune.convnet.spec",
    "layer_sizes": "autotune.convnet.spec",
    "Settings": "autotune.convnet.settings",
    "NetFormatError": "autotune.convnet.netjson",
    "load_net": "autotune.convnet.netjson",
    "loads_net": "autotune.convnet.netjson",
    "dumps_net": "autotune.convnet.netjson",
    "write_net": "autotune.convnet.netjson",
    "export_netjs": "autotune.convnet.netjson",
    "settings_from_config": "autotune.convnet.netjson",
    "settings_to_config": "autotune.convnet.netjson",
    "load_net_and_settings": "autotune.convnet.netjson:load",
    "forward": "autotune.convnet.forward",
    "greedy_actions": "autotune.convnet.forward",
    "build_torch": "autotune.convnet.torch_bridge",
    "to_torch": "autotune.convnet.torch_bridge",
    "from_torch": "autotune.convnet.torch_bridge",
    # process-wide settings
    "configure_process": "autotune.runtime",
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
