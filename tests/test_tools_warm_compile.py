"""``tools/warm_compile.py``: CI's compile step before the tests (``.ci/run``) runs and refuses bad arguments."""

from __future__ import annotations

import importlib.util
import sys
from typing import Any

import pytest

from tests.conftest import ROOT

_SPEC = importlib.util.spec_from_file_location("warm_compile", ROOT / "tools" / "warm_compile.py")
assert _SPEC is not None and _SPEC.loader is not None
wc: Any = sys.modules.setdefault("warm_compile", importlib.util.module_from_spec(_SPEC))
_SPEC.loader.exec_module(wc)


def test_it_runs_each_engines_compiled_paths(capsys: pytest.CaptureFixture[str]) -> None:
    assert wc.main(["--ruleset", "v1"]) == 0  # loaded from the cache CI's run of it filled
    assert capsys.readouterr().out.startswith("v1: compiled or loaded in ")


def test_a_bad_ruleset_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        wc.main(["--ruleset", "v3"])
    assert exc.value.code == 2 and "invalid choice: 'v3'" in capsys.readouterr().err


def test_ci_runs_it_beside_the_linters() -> None:
    text = (ROOT / ".ci" / "run").read_text()
    assert text.index("tools/warm_compile.py") < text.index("mypy") < text.index('wait "$warm"') < text.index("pytest")
