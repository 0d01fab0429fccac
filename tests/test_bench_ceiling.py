"""bench/ceiling.py: where a configuration comes from, and the figures it prints (the trainings are run_trial's)."""

from __future__ import annotations

import importlib.util
import itertools
import statistics
import sys
from pathlib import Path
from typing import Any

import pytest

from autotune.search.storage import open_storage
from tests.conftest import ROOT

_SPEC = importlib.util.spec_from_file_location("bench_ceiling", ROOT / "bench" / "ceiling.py")
assert _SPEC is not None and _SPEC.loader is not None
ce: Any = sys.modules.setdefault("bench_ceiling", importlib.util.module_from_spec(_SPEC))
_SPEC.loader.exec_module(ce)


def test_expected_best_of_k_is_the_exact_order_statistic_of_draws_with_replacement() -> None:
    scores = [70.0, 72.5, 74.0]
    for k in (1, 2, 3):
        brute = statistics.fmean(max(draw) for draw in itertools.product(scores, repeat=k))
        assert ce.expected_best_of(scores, k) == pytest.approx(brute)
    assert ce.expected_best_of(scores, 1) == pytest.approx(statistics.fmean(scores))
    assert ce.expected_best_of(scores, 1000) == pytest.approx(74.0)


def test_summary_counts_the_tail() -> None:
    row = ce.summary([73.0, 74.0, 75.0, 75.6])
    assert row["n"] == 4 and row["max"] == 75.6 and row["median"] == 74.5
    assert row["share_at_or_above"] == {"74": 0.75, "75": 0.5, "75.5": 0.25}
    assert row["expected_best_of"]["10"] <= 75.6
    assert ce.summary([]) == {"n": 0}


def test_a_config_from_a_crowd_id_a_trial_or_a_toml_and_a_clear_error_otherwise(tmp_path: Path) -> None:
    gsurma = ce.load_config(ce.DEFAULT_CONFIG)
    assert gsurma["layers"] == "fc:384:tanh" and gsurma["method"] == "sgd"

    from tests.test_search_inspect import make_study

    journal = tmp_path / "s.log"
    study = make_study(open_storage(str(journal), "s", artifacts=tmp_path / "store"), "s")
    assert ce.load_config(f"{journal}:1") == study.trials[1].user_attrs["config"]
    with pytest.raises(ce.BenchError, match=r"has no trial 9 with a stored config \(it has 4 trials\)"):
        ce.load_config(f"{journal}:9")

    toml = tmp_path / "c.toml"
    toml.write_text('ruleset = "v2"\nlayers = "fc:8:relu"\nbatch_size = 16\n')
    assert ce.load_config(str(toml))["batch_size"] == 16
    with pytest.raises(ce.BenchError, match=r"--config nobody: neither a crowd submission id.*e\.g\. --config dt-"):
        ce.load_config("nobody")


def test_scoring_follows_the_spec_grid_or_the_configs_own_epsilon(tmp_path: Path) -> None:
    from autotune.search.spec import load_spec

    paper = load_spec(ROOT / "study_configs" / "paper.toml")
    assert paper.ladder_epsilon_grid  # the default study chooses ε_test per net, so the bench does too
    assert ce.scoring("paper") == (paper.ladder_epsilon_grid, paper.ladder_epsilon_screen_runs)
    assert ce.scoring("none") == ((), ())
    with pytest.raises(ce.BenchError, match=r"--space nothing: no such spec .*or none \(the configuration's own"):
        ce.scoring("nothing")
    bad = tmp_path / "bad.toml"
    bad.write_text("[study]\nn_trials = 1\n[ladder]\nrungs = [10000, 30000]\nepsilon_test_grid = 3\n")
    with pytest.raises(ce.BenchError, match=r"--space: .*bad\.toml: \[ladder\] epsilon_test_grid: must be a list"):
        ce.scoring(str(bad))


def test_a_job_with_a_grid_is_a_one_rung_ladder_that_chooses_epsilon_and_without_one_keeps_the_config(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from autotune.search import objective

    seen: list[Any] = []

    class Out:
        state, value, cause = "complete", 73.5, ""
        attrs = {"rungs": [{"budget": 10000, "chosen_epsilon_test": 0.05}]}

    def fake_run_trial(task: Any, report: Any) -> Any:
        seen.append(task)
        return Out()

    monkeypatch.setattr(objective, "run_trial", fake_run_trial)
    config = ce.load_config(ce.DEFAULT_CONFIG)
    out = ce.job((config, 10_000, 5, ((0.0, 0.05, 0.2), (50, 100))))
    task = seen[-1]
    assert task.rungs == (10_000,) and task.seed == 5
    assert task.epsilon_test_grid == (0.0, 0.05, 0.2) and task.epsilon_test_screen_runs == (50, 100)
    assert task.config["train_iterations"] == 10_000 and not task.prune_static and task.min_weight_change == 0.0
    assert out["score"] == 73.5 and out["epsilon_test"] == 0.05

    Out.attrs = {}
    out = ce.job((config, 10_000, 5, ((), ())))
    task = seen[-1]
    assert task.rungs == () and task.epsilon_test_grid == ()
    assert task.config["epsilon_test_time"] == config["epsilon_test_time"] and out["epsilon_test"] is None
