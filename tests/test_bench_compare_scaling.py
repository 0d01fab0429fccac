"""bench/compare_scaling.py's synthetic study: N finished trials of paper.toml's space that the report reads as
N points (so the timed command works on what a real study stores)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from typing import Any

from autotune.search import keys
from autotune.search.records import read_study
from autotune.search.storage import open_storage
from dashboards.extract import study_data
from tests.conftest import ROOT

_SPEC = importlib.util.spec_from_file_location("bench_compare_scaling", ROOT / "bench" / "compare_scaling.py")
assert _SPEC is not None and _SPEC.loader is not None
cs: Any = sys.modules.setdefault("bench_compare_scaling", importlib.util.module_from_spec(_SPEC))
_SPEC.loader.exec_module(cs)


def test_synthetic_study_is_what_the_report_reads(tmp_path: Path) -> None:
    journal = tmp_path / "s.log"
    cs.write_study(journal, "syn", 40, seed=1)
    study = read_study(open_storage(str(journal), "syn", read_only=True), "syn")
    assert len(study.trials) == 40 and {t.state for t in study.trials} <= {"COMPLETE", "PRUNED"}
    assert all(keys.CONFIG in t.user_attrs and keys.PARAM_COUNT in t.user_attrs for t in study.trials)
    data = study_data(study)
    assert len(data.trials) == 40 and not data.skipped
    assert len(data.scored) == sum(t.state == "COMPLETE" for t in study.trials) > 20


def test_a_study_like_a_launched_one_copies_every_attr(tmp_path: Path) -> None:
    """``--like``: a launched study's finished trials, round robin, each copy its own configuration."""
    from tests.test_search_inspect import make_study

    source = tmp_path / "real.log"
    make_study(open_storage(str(source), "real", artifacts=tmp_path / "store"), "real")
    real = read_study(open_storage(str(source), "real", read_only=True), "real")
    finished = [t for t in real.trials if t.state in ("COMPLETE", "PRUNED", "FAIL")]
    journal = tmp_path / "like.log"
    cs.clone_study(journal, "like", 3 * len(finished), source)
    copy = read_study(open_storage(str(journal), "like", read_only=True), "like")
    assert len(copy.trials) == 3 * len(finished)
    for i, t in enumerate(copy.trials):
        original = finished[i % len(finished)]
        assert t.state == original.state and set(t.user_attrs) == set(original.user_attrs)
    configs = [t.user_attrs[keys.CONFIG] for t in copy.trials if keys.CONFIG in t.user_attrs]
    assert len({str(sorted(c.items())) for c in configs}) == len(configs)  # every copy its own configuration
