"""numba's cache folder is keyed by every compiled source of ``sim`` and ``autotune``, at any depth.

numba keys a cached function on its own file only; a function inlining code from another module
(``autotune.convnet.deepqlearn`` into ``learner.brain_policy``, ``sim.rng`` into everything) would
keep stale machine code unless the folder changes whenever any compiled file changes.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from sim import COMPILED_PACKAGES, numba_cache_key
from tests.conftest import ROOT


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the packages' Python sources."""
    root = tmp_path_factory.mktemp("tree")
    for package in COMPILED_PACKAGES:
        shutil.copytree(ROOT / package, root / package, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    return root


def _compiled(root: Path) -> list[Path]:
    return sorted(p for pkg in COMPILED_PACKAGES for p in (root / pkg).rglob("*.py") if b"numba" in p.read_bytes())


def test_the_copy_has_the_key_of_the_tree(tree: Path) -> None:
    assert numba_cache_key(tree) == numba_cache_key(ROOT)
    if not os.environ.get("NUMBA_CACHE_DIR"):  # this process's cache folder is the tree's key
        import numba

        assert Path(numba.config.CACHE_DIR).name == numba_cache_key(ROOT)


def test_editing_any_compiled_file_changes_the_key(tree: Path) -> None:
    files = _compiled(tree)
    depths = {len(p.relative_to(tree).parts) for p in files}
    assert {"sim", "autotune"} <= {p.relative_to(tree).parts[0] for p in files} and max(depths) >= 3  # nested too
    before = numba_cache_key(tree)
    for path in files:
        source = path.read_bytes()
        path.write_bytes(source.replace(b"\n", b"\n\n", 1))  # a one-line change anywhere
        try:
            assert numba_cache_key(tree) != before, path.relative_to(tree)
        finally:
            path.write_bytes(source)
    assert numba_cache_key(tree) == before


def test_new_nested_compiled_module_changes_the_key_and_pure_python_does_not(tree: Path) -> None:
    before = numba_cache_key(tree)
    sources = sorted(p for pkg in COMPILED_PACKAGES for p in (tree / pkg).rglob("*.py"))
    plain = next(p for p in sources if p not in _compiled(tree))
    source = plain.read_bytes()
    plain.write_bytes(source + b"\n# a pure-Python edit keeps the compiled cache\n")
    try:
        assert numba_cache_key(tree) == before, plain.relative_to(tree)
    finally:
        plain.write_bytes(source)
    deep = tree / "autotune" / "search" / "deeper" / "still" / "kernel.py"
    deep.parent.mkdir(parents=True)
    deep.write_text("from numba import njit\n")
    try:
        assert numba_cache_key(tree) != before
    finally:
        shutil.rmtree(tree / "autotune" / "search" / "deeper")
