"""bench/refine.py: a refinement climb outside a study, its held-out scores, and its arguments."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from typing import Any

import pytest

from autotune.learner.config import TrainConfig
from tests.conftest import ROOT

_SPEC = importlib.util.spec_from_file_location("bench_refine", ROOT / "bench" / "refine.py")
assert _SPEC is not None and _SPEC.loader is not None
br: Any = sys.modules.setdefault("bench_refine", importlib.util.module_from_spec(_SPEC))
_SPEC.loader.exec_module(br)


def test_the_climb_keeps_the_best_net_and_scores_it_on_held_out_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(br, "HELDOUT_RUNS", 50)  # the held-out sets' size does not change the climb: CI time
    config = tmp_path / "tiny.toml"
    config.write_text('ruleset = "v2"\nlanes_side = 0\npatches_ahead = 2\nother_agents = 1\ntrain_iterations = 600\n'
                      'temporal_window = 0\nexperience_size = 500\nstart_learn_threshold = 100\nlayers = "fc:4:relu"\n'
                      "batch_size = 8\n")  # fmt: skip
    args = br.parse_args(["--config", str(config), "--seed", "3", "--steps", "2", "--runs", "2", "--iterations",
                          "1000", "--workers", "1", "--heldout", "1", "--soups", "2"])  # fmt: skip
    result = br.run(args)
    first, second = result["steps"]
    assert len(first["runs"]) == 2 and first["best_run"] == max(first["runs"]) and len(first["best_heldout"]) == 1
    assert list(first["soups"]) == ["2"] and first["best"] == max(*first["runs"], first["soups"]["2"])
    assert second["parent"] == max(first["parent"], first["best"])  # the better run became the parent
    assert result["final"] == max(second["parent"], second["best"])
    assert result["heldout_seeds"] == [br.HELDOUT_SEED]
    base = TrainConfig.from_mapping({"layers": "fc:4:relu", "learning_rate": 0.01, "learning_steps_burnin": 3000})
    own = br.child_config(base, br.parse_args(["--own-schedule", "--iterations", "5000"]))
    assert own.learning_steps_burnin == 3000 and own.train_iterations == 5000
    assert own.learning_rate == pytest.approx(1e-3)
    short = br.child_config(base, br.parse_args([]))
    assert short.learning_steps_total == 1000 and short.learning_steps_burnin == 100


def test_bad_arguments_name_the_option(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        br.parse_args(["--runs", "0"])
    assert "--runs: must be ≥ 1, got 0" in capsys.readouterr().err
    for bad in ("2,x", "1"):
        with pytest.raises(SystemExit):
            br.parse_args(["--soups", bad])
        assert "--soups: " in capsys.readouterr().err
    assert br.main(["--config", "no-such-setting", "--steps", "1"]) == 2
    assert "--config no-such-setting: neither a crowd submission id" in capsys.readouterr().err
