"""The import graph reads as the architecture: each layer imports only the ones below it, and no
module imports another package's ``_private`` names (parsed with ``ast``, nothing imported)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from tests.conftest import ROOT

# bottom to top; a module may import project modules of its own rank or lower
LAYERS: tuple[tuple[str, int], ...] = (
    ("sim", 0),
    ("autotune.runtime", 1),
    ("autotune.cliutil", 1),  # the CLIs' shared error exit and storage options (stdlib only)
    ("autotune.convnet", 1),
    ("autotune.learner", 2),
    ("autotune.search", 3),
    ("dashboards", 3),
    ("autotune.commands", 4),
    ("autotune.cli", 4),
    ("autotune.train", 4),
    ("autotune.evaluate", 4),
    ("autotune", 4),  # any other top-level module
)
# third-party packages a layer must never import
FORBIDDEN: dict[str, tuple[str, ...]] = {
    "sim": ("torch", "optuna", "ray", "autotune", "dashboards"),
    "autotune.convnet": ("optuna", "ray"),
    "autotune.learner": ("optuna", "ray"),
    "dashboards": ("ray", "torch"),
}
# dashboards (the crowd, the reports) sits above the search: no autotune module but the console script imports it
ABOVE_AUTOTUNE = "dashboards"
ABOVE_AUTOTUNE_EXEMPT = ("autotune.cli",)


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _layer(module: str) -> tuple[str, int] | None:
    if module == "autotune":  # the lazy public API (``from autotune import X``): for the search and the reports
        return "autotune", 3
    for prefix, rank in LAYERS:
        if module == prefix or module.startswith(prefix + "."):
            return prefix, rank
    return None


def _imports(path: Path) -> list[tuple[int, str, tuple[str, ...]]]:
    """(line, imported module, imported names) for every import statement, nested ones included."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found: list[tuple[int, str, tuple[str, ...]]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name, ()) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module, tuple(alias.name for alias in node.names)))
    return sorted(found)


MODULES = sorted(p for pkg in ("sim", "autotune", "dashboards") for p in (ROOT / pkg).rglob("*.py"))


def _package(module: str, path: Path) -> str:
    return module if path.name == "__init__.py" else module.rpartition(".")[0]


def _violations(path: Path) -> list[str]:
    module = _module_name(path)
    layer = _layer(module)
    package = _package(module, path)
    problems = []
    for line, target, names in _imports(path):
        where = f"{path.relative_to(ROOT)}:{line}"
        target_layer = _layer(target)
        if layer is not None and target_layer is not None and target_layer[1] > layer[1]:
            problems.append(f"{where}: {module} ({layer[0]}) imports the higher layer {target}")
        for prefix, banned in FORBIDDEN.items():
            if layer is not None and layer[0] == prefix:
                for b in banned:
                    if target == b or target.startswith(b + "."):
                        problems.append(f"{where}: {module} must not import {target}")
        above = target == ABOVE_AUTOTUNE or target.startswith(ABOVE_AUTOTUNE + ".")
        if above and (module == "autotune" or module.startswith("autotune.")) and module not in ABOVE_AUTOTUNE_EXEMPT:
            problems.append(f"{where}: {module} must not import {target} (dashboards sits above autotune)")
        if target_layer is not None or target.split(".")[0] in ("sim", "autotune", "dashboards"):
            target_package = target.rpartition(".")[0] if "." in target else target
            if target_package != package and target != package:
                problems += [
                    f"{where}: imports {target}.{n}, private to another package" for n in names if n[:1] == "_"
                ]
    return problems


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(ROOT)))
def test_module_imports_follow_the_layers(path: Path) -> None:
    assert _violations(path) == []


def test_the_checker_catches_violations(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A lower layer importing a higher one, a private name across packages, a forbidden library, dashboards."""
    bad = tmp_path / "autotune" / "learner" / "bad.py"
    bad.parent.mkdir(parents=True)
    bad.write_text(
        "import ray\ndef f():\n    from autotune.search.driver import run\nfrom sim.protocols import _resolve\n"
    )
    fine = tmp_path / "sim" / "fine.py"
    fine.parent.mkdir()
    fine.write_text("from sim.protocols import _resolve\nimport numpy\n")  # same package: allowed
    monkeypatch.setattr(__import__(__name__, fromlist=["ROOT"]), "ROOT", tmp_path)
    problems = _violations(bad)
    assert len(problems) == 3, problems
    assert "must not import ray" in problems[0] and "higher layer autotune.search.driver" in problems[1]
    assert "sim.protocols._resolve, private to another package" in problems[2]
    assert _violations(fine) == []
    search = tmp_path / "autotune" / "search" / "uses_reports.py"
    search.parent.mkdir(parents=True)
    search.write_text("def f():\n    from dashboards import crowd\n")
    cli = tmp_path / "autotune" / "cli.py"
    cli.write_text("SUBCOMMANDS = ()\nimport dashboards.crowd_cli\n")
    assert [p.split(": ", 1)[1] for p in _violations(search)] == [
        "autotune.search.uses_reports must not import dashboards (dashboards sits above autotune)"
    ]
    assert _violations(cli) == []


PROTOCOL_NAMES = ("v2-official", "v1-original", "v1-distribution", "custom")
PROTOCOLS_HOME = "sim/protocols.py"


def _protocol_literals(path: Path) -> list[str]:
    """Places where code spells a protocol name as a bare string (docstrings and messages are longer strings)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    return [
        f"{path.relative_to(ROOT)}:{node.lineno}: {node.value!r}"
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and node.value in PROTOCOL_NAMES
    ]


def test_protocol_names_are_constants() -> None:
    """Protocol names are ``sim.protocols`` constants (V2_OFFICIAL, …, OFFICIAL per ruleset), spelled only there."""
    from autotune.learner.official import OFFICIAL_PROTOCOL
    from sim import protocols

    names = (protocols.V2_OFFICIAL, protocols.V1_ORIGINAL, protocols.V1_DISTRIBUTION, protocols.CUSTOM)
    assert names == PROTOCOL_NAMES and tuple(protocols.PROTOCOLS) == names
    assert {r: protocols.PROTOCOLS[p].ruleset for r, p in protocols.OFFICIAL.items()} == {"v1": "v1", "v2": "v2"}
    assert OFFICIAL_PROTOCOL is protocols.OFFICIAL
    assert _protocol_literals(ROOT / PROTOCOLS_HOME)  # the checker sees the home's own spelling
    assert [hit for p in MODULES if p != ROOT / PROTOCOLS_HOME for hit in _protocol_literals(p)] == []
