"""Faithful, compiled, batched re-implementation of the DeepTraffic engines (v1 and v2).

Importing the package points numba's on-disk cache at a folder keyed by a hash of this
project's compiled sources (``sim`` and ``autotune``, every subpackage). numba keys each cached
function on its own file only, so a function that inlines code from another module would
otherwise keep stale machine code after an edit (or an upgrade) of that module. Set
``NUMBA_CACHE_DIR`` to choose the location yourself.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

COMPILED_PACKAGES = ("sim", "autotune")  # the packages whose compiled sources key numba's cache


def numba_cache_key(root: Path) -> str:
    """Hash of every compiled source (a ``.py`` file mentioning numba) under ``root/sim`` and ``root/autotune``,
    every subpackage at any depth; pure-Python files do not count, so their edits keep the cache."""
    digest = hashlib.sha1()
    for package in COMPILED_PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            source = path.read_bytes()
            if b"numba" in source:
                digest.update(path.relative_to(root).as_posix().encode())
                digest.update(source)
    return digest.hexdigest()[:16]


def _configure_numba_cache() -> None:
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    import numba

    key = numba_cache_key(Path(__file__).resolve().parent.parent)
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "deeptraffic-autotune" / "numba"
    numba.config.CACHE_DIR = str(base / key)


_configure_numba_cache()

from sim.config import ConfigError, EngineConfig  # noqa: E402
from sim.simulator import Observation, PolicyError, Simulator  # noqa: E402

__all__ = ["ConfigError", "EngineConfig", "Observation", "PolicyError", "Simulator"]
