"""The lazy public API (``autotune``, ``autotune.learner``): every exported name resolves to its definition,
whatever was imported before — no export carries the name of a submodule, which an import would replace."""

from __future__ import annotations

import importlib
import pkgutil
import subprocess
import sys

import pytest

import autotune
import autotune.learner
from tests.conftest import ROOT

PACKAGES = ("autotune", "autotune.learner")


@pytest.mark.parametrize("package", PACKAGES)
def test_no_export_is_named_like_a_submodule(package: str) -> None:
    module = importlib.import_module(package)
    submodules = {info.name for info in pkgutil.iter_modules(module.__path__)}
    assert "train" in submodules or package != "autotune"  # the shim the rule is about
    assert sorted(set(module._EXPORTS) & submodules) == []


CHECK = """
import importlib, sys
import autotune, autotune.learner
order = sys.argv[1]
if order == "shims-first":
    import autotune.train, autotune.evaluate
for package in (autotune, autotune.learner):
    for name, target in package._EXPORTS.items():
        getattr(package, name)  # resolved (and cached) before the shims are imported in the other order
if order == "shims-last":
    import autotune.train, autotune.evaluate
bad = []
for package in (autotune, autotune.learner):
    for name, target in package._EXPORTS.items():
        module, _, attr = target.partition(":")
        if getattr(package, name) is not getattr(importlib.import_module(module), attr or name):
            bad.append(f"{package.__name__}.{name}")
from autotune.learner import train
from autotune.learner.training import train as defined
assert train is defined and callable(train), train
print("bad:", bad)
"""


@pytest.mark.parametrize("order", ["shims-first", "shims-last"])
def test_importing_the_shims_breaks_no_exported_name(order: str) -> None:
    """A fresh interpreter: ``python -m autotune.train``'s module imported before or after every name resolves."""
    done = subprocess.run(
        [sys.executable, "-c", CHECK, order], cwd=ROOT, capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().splitlines()[-1] == "bad: []"


def test_the_training_function_is_the_learners() -> None:
    from autotune.learner import train
    from autotune.learner.training import train as defined

    assert train is defined and autotune.learner.__all__ == sorted(autotune.learner._EXPORTS)
    assert "train" not in autotune.__all__
