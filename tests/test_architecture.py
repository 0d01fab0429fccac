"""The import graph reads as the architecture: each layer imports only the ones below it, no module reads
another package's ``_private`` names (by import or by attribute), Optuna stays inside ``autotune/search``,
no two modules import each other, and shared names (protocols, trial-record keys) are spelled in one place
(parsed with ``ast``, nothing imported)."""

from __future__ import annotations

import ast
import functools
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
# dashboards (the crowd, the reports) sits above the search: no autotune module but the commands import it
ABOVE_AUTOTUNE = "dashboards"
ABOVE_AUTOTUNE_EXEMPT = ("autotune.cli", "autotune.commands")
# Optuna (and optuna-dashboard) is imported only here; everything above reads studies through its records
OPTUNA_HOME = "autotune.search"
OPTUNA = ("optuna", "optuna_dashboard")
# the public API of namedtuples: underscored so as not to clash with field names, but not private
PUBLIC_UNDERSCORED = frozenset({"_asdict", "_replace", "_fields", "_make", "_field_defaults"})
# third-party private names read where no public API does the job: (file, expression) -> why
PRIVATE_ALLOWED: dict[tuple[str, str], str] = {
    ("autotune/learner/kernel.py", "torch._foreach_zero_"): "torch's fused multi-tensor zero; no public equivalent",
}


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
        exempt = any(module == e or module.startswith(e + ".") for e in ABOVE_AUTOTUNE_EXEMPT)
        if above and (module == "autotune" or module.startswith("autotune.")) and not exempt:
            problems.append(f"{where}: {module} must not import {target} (dashboards sits above autotune)")
        if target.split(".")[0] in OPTUNA and not (module == OPTUNA_HOME or module.startswith(OPTUNA_HOME + ".")):
            problems.append(f"{where}: {module} imports {target}; Optuna is imported only under autotune/search/")
        if target_layer is not None or target.split(".")[0] in ("sim", "autotune", "dashboards"):
            target_package = target.rpartition(".")[0] if "." in target else target
            if target_package != package and target != package:
                problems += [
                    f"{where}: imports {target}.{n}, private to another package" for n in names if n[:1] == "_"
                ]
    return problems + _private_attributes(path)


def _dunder(name: str) -> bool:
    return name.startswith("__") and name.endswith("__")


@functools.cache
def _defined_private(package_dir: Path) -> frozenset[str]:
    """The ``_names`` a package defines: functions, classes, variables, attributes it assigns, fields."""
    names: set[str] = set()
    for path in package_dir.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names.add(node.name)
            elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                names.add(node.id)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                names.add(node.attr)
            elif isinstance(node, ast.arg):
                names.add(node.arg)
    return frozenset(n for n in names if n.startswith("_") and not _dunder(n))


def _private_attributes(path: Path) -> list[str]:
    """``x._name`` reads where ``_name`` is not defined in the module's own package (``self``/``cls`` aside)."""
    own = _defined_private(path.parent)
    problems = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if not isinstance(node, ast.Attribute) or not node.attr.startswith("_") or _dunder(node.attr):
            continue
        if node.attr in own or node.attr in PUBLIC_UNDERSCORED:
            continue
        if isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
            continue
        if (str(path.relative_to(ROOT)), ast.unparse(node)) in PRIVATE_ALLOWED:
            continue
        problems.append(
            f"{path.relative_to(ROOT)}:{node.lineno}: reads {ast.unparse(node)}, private to another package"
        )
    return problems


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(ROOT)))
def test_module_imports_follow_the_layers(path: Path) -> None:
    assert _violations(path) == []


def _cycles(paths: list[Path]) -> list[str]:
    """``a <-> b`` for every module ``a`` importing ``b`` (at any depth) while ``b`` leads back to ``a``."""
    known = {_module_name(p) for p in paths}

    def targets(path: Path) -> set[str]:  # ``from pkg import mod`` is an import of pkg.mod, not of pkg
        found = set()
        for _line, target, names in _imports(path):
            modules = {f"{target}.{n}" for n in names} & known
            found |= modules if modules else {target} & known
        return found

    graph = {_module_name(p): targets(p) for p in paths}

    def reaches(start: str, goal: str) -> bool:
        seen, todo = set(), [start]
        while todo:
            module = todo.pop()
            if module == goal:
                return True
            if module not in seen:
                seen.add(module)
                todo += graph.get(module, ())
        return False

    return sorted(f"{a} <-> {b}" for a, targets in graph.items() for b in targets if a < b and reaches(b, a))


def test_no_two_modules_import_each_other() -> None:
    """A cycle is one job split wrongly (spec parses, space maps; never the other way round)."""
    assert _cycles(MODULES) == []


def test_the_checker_catches_cycles(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(__import__(__name__, fromlist=["ROOT"]), "ROOT", tmp_path)
    search = tmp_path / "autotune" / "search"
    search.mkdir(parents=True)
    (search / "spec.py").write_text("def f():\n    from autotune.search import space\n")
    (search / "space.py").write_text("from autotune.search.spec import build_config\n")
    (search / "driver.py").write_text("from autotune.search import space\n")
    assert _cycles(sorted(search.glob("*.py"))) == ["autotune.search.space <-> autotune.search.spec"]


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
    cli.write_text("SUBCOMMANDS = ()\nimport dashboards.crowd\n")
    assert [p.split(": ", 1)[1] for p in _violations(search)] == [
        "autotune.search.uses_reports must not import dashboards (dashboards sits above autotune)"
    ]
    assert _violations(cli) == []


def test_the_checker_catches_private_attributes_and_optuna(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``engine._finish_run``, ``obs._mrand``, ``t._trial_id`` read from another package fail; own names pass."""
    monkeypatch.setattr(__import__(__name__, fromlist=["ROOT"]), "ROOT", tmp_path)
    _defined_private.cache_clear()
    learner = tmp_path / "autotune" / "learner"
    learner.mkdir(parents=True)
    bad = learner / "bad.py"
    bad.write_text(
        "from sim import engine\n"
        "def f(obs, t, p):\n"
        "    engine._finish_run()\n"
        "    return obs._mrand, t._trial_id, p._asdict(), _Own()._slot\n"
        "class _Own:\n"
        "    def __init__(self):\n"
        "        self._slot = 1\n"
    )
    reports = tmp_path / "dashboards" / "reads_optuna.py"
    reports.parent.mkdir()
    reports.write_text("def f():\n    import optuna_dashboard\n    from optuna.trial import TrialState\n")
    search = tmp_path / "autotune" / "search" / "fine.py"
    search.parent.mkdir(parents=True)
    search.write_text("import optuna\n")
    try:
        problems = [p.split(": ", 1)[1] for p in _violations(bad)]
        assert problems == [
            "reads engine._finish_run, private to another package",
            "reads obs._mrand, private to another package",
            "reads t._trial_id, private to another package",
        ]
        assert [p.split(": ", 1)[1] for p in _violations(reports)] == [
            f"dashboards.reads_optuna imports {m}; Optuna is imported only under autotune/search/"
            for m in ("optuna_dashboard", "optuna.trial")
        ]
        assert _violations(search) == []
    finally:
        _defined_private.cache_clear()


PROTOCOL_NAMES = ("v2-official", "v2-heldout", "v1-original", "v1-distribution", "custom")
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

    names = (
        protocols.V2_OFFICIAL,
        protocols.V2_HELDOUT,
        protocols.V1_ORIGINAL,
        protocols.V1_DISTRIBUTION,
        protocols.CUSTOM,
    )
    assert names == PROTOCOL_NAMES and tuple(protocols.PROTOCOLS) == names
    assert {r: protocols.PROTOCOLS[p].ruleset for r, p in protocols.OFFICIAL.items()} == {"v1": "v1", "v2": "v2"}
    assert OFFICIAL_PROTOCOL is protocols.OFFICIAL
    assert _protocol_literals(ROOT / PROTOCOLS_HOME)  # the checker sees the home's own spelling
    assert [hit for p in MODULES if p != ROOT / PROTOCOLS_HOME for hit in _protocol_literals(p)] == []


# trial-record keys: named in autotune/search/keys.py; code spells them through it, never as literals
KEYS_HOME = "autotune/search/keys.py"
RECORD_ATTRS = ("user_attrs", "system_attrs")
RECORD_SETTERS = ("set_user_attr", "set_system_attr", "set_trial_user_attr", "set_trial_system_attr")


def _record_keys() -> dict[str, str]:
    """{value: NAME} of every key constant in ``keys.py`` (read from its source)."""
    tree = ast.parse((ROOT / KEYS_HOME).read_text())
    out = {}
    for node in tree.body:
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and isinstance(node.value, ast.Constant)
            and isinstance(node.value.value, str)
        ):
            out[node.value.value] = node.target.id
    return out


def _distinctive(value: str) -> bool:
    """A key no other vocabulary uses (``frames_simulated``, ``retry_of``, ``autotune:driver``, …)."""
    generic = {
        "source", "seed", "config", "settings", "curve", "cause", "worker", "step", "frames", "spec", "skipped",
        "diverged", "quick_score", "input_size", "num_states", "param_count", "train_seconds", "official_protocol",
        "engine_version", "reported_score_mph", "autotune", "crowd", "crowd-replay", "ladder", "rungs", "warm_start",
        "score", "seconds", "budget", "loss", "mean_reward", "weight_change",
    }  # fmt: skip
    return value not in generic


def _key_literals(path: Path) -> list[str]:
    """Record keys spelled as literals: in a record access (``t.user_attrs["seed"]``, ``set_user_attr("cause",
    …)``, ``"retry_of" in t.user_attrs``) whatever the key, and the distinctive keys anywhere."""
    keys = _record_keys()
    tree = ast.parse(path.read_text(), filename=str(path))
    exported = {  # names in __all__ are function names, not keys
        id(c)
        for node in ast.walk(tree)
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets)
        for c in ast.walk(node.value)
    }
    hits = []

    def record(node: ast.AST) -> bool:
        return isinstance(node, ast.Attribute) and node.attr in RECORD_ATTRS

    for node in ast.walk(tree):
        spelled: list[ast.AST] = []
        if isinstance(node, ast.Subscript) and record(node.value):
            spelled.append(node.slice)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            if node.func.attr == "get" and record(node.func.value):
                spelled += node.args[:1]
            elif node.func.attr in RECORD_SETTERS:
                spelled += node.args[:2]
        elif isinstance(node, ast.Compare) and any(record(c) for c in node.comparators):
            spelled.append(node.left)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in keys:
            if _distinctive(node.value) and id(node) not in exported:
                spelled.append(node)
        for lit in spelled:
            if isinstance(lit, ast.Constant) and isinstance(lit.value, str) and lit.value in keys:
                hits.append(f"{path.relative_to(ROOT)}:{lit.lineno}: {lit.value!r} (keys.{keys[lit.value]})")
    return sorted(set(hits))


def test_trial_record_keys_are_constants() -> None:
    """Every module reads and writes trial records through ``autotune.search.keys``."""
    assert _key_literals(ROOT / KEYS_HOME)  # the checker sees the home's own spelling
    assert {"frames_simulated", "retry_of", "artifact_net_json", "autotune:driver"} <= set(_record_keys())
    assert [hit for p in MODULES if p != ROOT / KEYS_HOME for hit in _key_literals(p)] == []


def test_the_checker_catches_key_literals(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    keys_home = tmp_path / KEYS_HOME
    keys_home.parent.mkdir(parents=True)
    keys_home.write_text((ROOT / KEYS_HOME).read_text())
    monkeypatch.setattr(__import__(__name__, fromlist=["ROOT"]), "ROOT", tmp_path)
    bad = tmp_path / "dashboards" / "bad.py"
    bad.parent.mkdir()
    bad.write_text(
        "def f(t, trial, keys):\n"
        "    a = t.user_attrs['seed'], t.user_attrs.get('curve'), 'cause' in t.user_attrs\n"
        "    trial.set_user_attr('worker', 1)\n"
        "    b = {'retry_of': 3, 'frames': 2, 'seed': 1}\n"
        "    return t.user_attrs[keys.SEED], t.user_attrs.get(keys.CURVE), a, b\n"
    )
    assert [hit.split(": ", 1)[1] for hit in _key_literals(bad)] == [
        "'cause' (keys.CAUSE)", "'curve' (keys.CURVE)", "'seed' (keys.SEED)", "'worker' (keys.WORKER)",
        "'retry_of' (keys.RETRY_OF)",
    ]  # fmt: skip
