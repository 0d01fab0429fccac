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


def _configure_numba_cache() -> None:
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    import numba

    root = Path(__file__).resolve().parent.parent
    digest = hashlib.sha1()
    for package in ("sim", "autotune"):
        for path in sorted((root / package).rglob("*.py")):  # every subpackage (autotune/convnet, …/learner, …)
            source = path.read_bytes()
            if b"numba" in source:  # only compiled code can go stale; pure-Python edits keep the cache
                digest.update(path.relative_to(root).as_posix().encode())
                digest.update(source)
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "deeptraffic-autotune" / "numba"
    numba.config.CACHE_DIR = str(base / digest.hexdigest()[:16])


_configure_numba_cache()

from sim.config import ConfigError, EngineConfig  # noqa: E402
from sim.simulator import Observation, PolicyError, Simulator  # noqa: E402

__all__ = ["ConfigError", "EngineConfig", "Observation", "PolicyError", "Simulator"]
