"""deepqlearn: the DQN and the DeepTraffic training protocol, quick and exact official evaluation of a net,
and the float64 replica of the original learner kept as the executable reference (``js_learner``).

Imports ``sim`` and ``autotune.convnet`` only; never the search, optuna or ray. Import the
submodules directly (``autotune`` re-exports the public names lazily); the training entry point is
``from autotune.learner import train`` (resolved on first use, so that importing the package, e.g.
for ``autotune.learner.official``, does not import torch).
"""

from __future__ import annotations

import importlib
from typing import Any

# public name -> module that defines it (none of them is a submodule's name)
_EXPORTS: dict[str, str] = {
    "train": "autotune.learner.training",
    "TrainResult": "autotune.learner.training",
    "CurvePoint": "autotune.learner.training",
    "StopTraining": "autotune.learner.training",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module_name = _EXPORTS.get(name)
    if module_name is None:
        raise AttributeError(f"module 'autotune.learner' has no attribute {name!r}")
    value = getattr(importlib.import_module(module_name), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
