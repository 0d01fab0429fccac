"""A ladder smoke study launched for real (Ray, journal): rungs reported at B_r/B_0, the balanced trainer
method, the seed race, ``best``.

One ~1-minute launch: trials climb a 2-rung ladder under successive halving, the trial budget runs
out, then the race retrains the best configurations with the same fresh seeds; ``autotune best``
reports the best single net and the best configuration by its fresh-seed mean.
"""

from __future__ import annotations

import json
import subprocess
import sys
from datetime import datetime
from pathlib import Path

import optuna
import pytest

from autotune.search.driver import StudyCounts, race_entry
from autotune.search.racing import race_seed
from autotune.search.spec import load_spec
from tests.test_search_launch import finish, launch, load, tagged_processes

SPEC = """
[study]
name = "race"
ruleset = "v2"
sampler = "tpe"
pruner = "sha"
n_trials = 5
timeout_s = 240
seed = 0
trial_timeout_s = 60
max_trial_cost_s = 60
sampler_startup_trials = 2
race_fraction = 0.5
race_configs = 3
race_seeds = 1
balance = ["method"]
balance_min_share = 0.5

[ladder]
rungs = [500, 1500]

[fixed]
otherAgents = 2
temporal_window = 0
experience_size = 1000
batch_size = 16

[space]
lanes_side = { low = 0, high = 2 }
patches_ahead = { low = 2, high = 8 }
learning_rate = { low = 1e-4, high = 1e-2, log = true }
learning_steps_burnin_fraction = { low = 0.01, high = 0.3, log = true }
method = { choices = ["sgd", "adagrad"] }
n_layers = { low = 0, high = 2 }
neurons = { low = 2, high = 16, log = true }
activation = { choices = ["relu", "tanh"] }

[evaluation]
final_protocol = "v2-official"

[resources]
workers = 2
"""


@pytest.mark.slow
def test_ladder_study_races_the_best_configurations(tmp_path: Path) -> None:
    spec = tmp_path / "race.toml"
    spec.write_text(SPEC)
    code, out, err = finish(launch(tmp_path, str(spec), tag="race-" + tmp_path.name), timeout=400)
    assert code == 0, err
    study = load(tmp_path, "race")
    trials = study.get_trials(deepcopy=False)
    original = [t for t in trials if "race_of" not in t.user_attrs and "retry_of" not in t.user_attrs]
    assert len(original) == 5
    methods = [t.params["method"] for t in original]  # balanced: the draws alternate, the first two forced
    assert methods.count("sgd") >= 2 and methods.count("adagrad") >= 2, methods
    assert [t.user_attrs.get("balanced") for t in original[:2]] == ["method=sgd", "method=adagrad"]
    for t in original:
        assert set(t.intermediate_values) <= {1, 3}  # rung r reported at step B_r / B_0
        assert t.user_attrs["predicted_cost_s"] > 0 and t.user_attrs["refused_draws"] >= 0
        if t.state == optuna.trial.TrialState.COMPLETE:
            assert [r["budget"] for r in t.user_attrs["rungs"]] == [500, 1500]
            assert t.value == t.user_attrs["rungs"][-1]["score"]
            assert set(t.user_attrs["artifact_rung_nets"]) == {"500", "1500"}
    field = study.user_attrs["race_field"]
    assert 1 <= len(field) <= 3
    race = [t for t in trials if "race_of" in t.user_attrs]
    min_budget = load_spec(spec).race_min_budget
    assert min_budget == 1500 and race and {t.user_attrs["race_of"] for t in race} <= set(field)
    by_seed: dict[int, set[int]] = {}
    for t in race:  # the same fresh seed for every configuration of a round, never a selecting trial's seed
        by_seed.setdefault(t.user_attrs["race_seed"], set()).add(t.user_attrs["seed"])
        assert t.user_attrs["seed"] not in {o.user_attrs["seed"] for o in original}
        entry = race_entry(trials[t.user_attrs["race_of"]], min_budget)  # no 500-iteration net enters
        assert entry is not None and t.user_attrs["config"] == entry[2]
        assert t.state == optuna.trial.TrialState.COMPLETE, t.user_attrs.get("cause")
    assert all(len(seeds) == 1 for seeds in by_seed.values())
    expected, n = 0, len(field)  # successive halving: every survivor of a round runs, until one is left
    while True:
        expected += n
        if n <= 1:
            break
        n = -(-n // 2)
        if n == 1:
            break
    assert sorted(by_seed)[0] == 0 and len(race) == expected
    retries = sum(1 for t in trials if "retry_of" in t.user_attrs and "race_of" not in t.user_attrs)
    assert f"({retries} retries, {len(race)} race runs)" in out  # race runs are not called retries
    assert tagged_processes("race-" + tmp_path.name) == []

    best = subprocess.run(
        [sys.executable, "-m", "autotune.cli", "best", "race", "--storage", str(tmp_path / "runs/race/journal.log"),
         "--json"], cwd=tmp_path, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert best.returncode == 0, best.stderr
    record = json.loads(best.stdout)
    winner = record["race"]["winner"]
    assert winner["trial"] in field and winner["n"] >= 1
    mine = [float(t.value or 0.0) for t in race if t.user_attrs["race_of"] == winner["trial"]]
    assert winner["mean"] == pytest.approx(sum(mine) / len(mine))
    assert record["value"] == max(t.value for t in trials if t.value is not None and t.state.name == "COMPLETE")


@pytest.mark.slow
def test_the_search_retrains_its_incumbent_then_races_in_the_last_part_of_the_time(tmp_path: Path) -> None:
    """With trials to spare, the race starts when the clock reaches the last race_fraction of timeout_s; with
    ``intensify_share``, race runs start before that window: the incumbent's, on the race's seeds (from index 0,
    at its entry's configuration), one at a time on half of the 2 workers; the race then takes them as its own.

    (Finished trials normally hand their worker the next draw at once; in the race's rounds they must not.)
    """
    spec = tmp_path / "race.toml"
    text = SPEC.replace("n_trials = 5", "n_trials = 1000").replace("timeout_s = 240", "timeout_s = 60")
    spec.write_text(text.replace("race_seeds = 1\n", "race_seeds = 1\nintensify_share = 0.5\n"))
    launched = datetime.now()  # the driver starts after this, and its race window 30 s after it starts
    code, out, err = finish(launch(tmp_path, str(spec), tag="raci-" + tmp_path.name), timeout=400)
    assert code == 0, err
    study = load(tmp_path, "race")
    trials = study.get_trials(deepcopy=False)
    early = [t for t in trials if t.user_attrs.get("incumbent_run")]
    assert early, "no incumbent run before the race"
    min_budget = load_spec(spec).race_min_budget
    for t in early:
        assert "race_of" in t.user_attrs and "race_seed" in t.user_attrs, t.number
        assert t.user_attrs["seed"] == race_seed(0, t.user_attrs["race_seed"])
        entry = race_entry(trials[t.user_attrs["race_of"]], min_budget)
        assert entry is not None and t.user_attrs["config"] == entry[2]
    first = early[0].user_attrs["race_of"]
    seeds = sorted(t.user_attrs["race_seed"] for t in early if t.user_attrs["race_of"] == first)
    assert seeds[0] == 0 and seeds == sorted(set(seeds))  # from the first race seed, each once
    spans = sorted((t.datetime_start, t.datetime_complete) for t in early if t.datetime_start and t.datetime_complete)
    # one at a time: the next starts as the last ends (its worker's next task, a moment before the result is told)
    assert all((a[1] - b[0]).total_seconds() < 2.0 for a, b in zip(spans, spans[1:], strict=False)), spans
    assert study.user_attrs.get("race_field"), "no race after the incumbent's runs"
    # the race's own runs start in its window (the last half of the time, from the driver's start)
    race = [t for t in trials if "race_of" in t.user_attrs and not t.user_attrs.get("incumbent_run")]
    assert race, "no race in the last half of the study's time"
    first_race = min(t.datetime_start for t in race if t.datetime_start is not None)
    assert (first_race - launched).total_seconds() >= 0.5 * 60 - 1, (first_race, launched)  # trial clocks: local
    later = [t for t in trials if "race_of" not in t.user_attrs and t.datetime_start is not None
             and t.datetime_start > first_race]  # fmt: skip
    # once racing, no new draw starts until the race has started its last run: the halving's, or the winner's
    # further seeds while its runs reach the study's best (then a worker may take a draw the time left affords)
    last = max(t.datetime_start for t in race if t.datetime_start is not None)
    assert all(t.datetime_start is not None and t.datetime_start >= last for t in later), [t.number for t in later]
    assert tagged_processes("raci-" + tmp_path.name) == []


def test_race_runs_use_no_budget_and_are_not_called_retries() -> None:
    raced = StudyCounts(budget=5, complete=9, pruned=2, retries=1, race_runs=6)
    assert raced.finished == 4
    assert raced.reruns == "1 retries, 6 race runs"
    assert StudyCounts(budget=5, complete=3).reruns == "0 retries"


@pytest.mark.slow
def test_refinement_runs_train_on_from_the_best_net_and_retrain_exactly(tmp_path: Path) -> None:
    """With ``refine_share``, half of the 2 workers train on from the study's best single net through Ray: each
    run's parent is a stored net with the score it names, its seeds are the study's refinement seeds in order, it
    uses no budget, and ``autotune evaluate --retrain`` (``retrain_trial``) gives its score again from its parent's
    stored net, exactly; with ``refine_soups`` a soup of a parent's best 2 runs is scored and retrains exactly too."""
    from autotune.search.records import retrain_trial, scored_nets
    from autotune.search.refine import refine_seed
    from autotune.search.storage import open_storage

    spec = tmp_path / "race.toml"
    text = SPEC.replace("n_trials = 5", "n_trials = 1000").replace("timeout_s = 240", "timeout_s = 45")
    text = text.replace("race_fraction = 0.5", "race_fraction = 0.2")  # refinement waits out the race's rounds
    spec.write_text(
        text.replace(
            "race_seeds = 1\n",
            "race_seeds = 1\nrefine_share = 0.5\nrefine_iterations = 1000\nrefine_soups = [2]\n"
            "refine_soup_span = 100\n",  # the smoke nets' runs scatter by mph: any finished pair is soup
        )
    )
    code, out, err = finish(launch(tmp_path, str(spec), tag="refi-" + tmp_path.name), timeout=400)
    assert code == 0, err
    study = load(tmp_path, "race")
    trials = study.get_trials(deepcopy=False)
    refined = [t for t in trials if "refine_of" in t.user_attrs]
    assert refined, "no refinement run"
    runs = [t for t in refined if "soup_of" not in t.user_attrs]  # the weight soups train nothing: no seed of theirs
    assert [t.user_attrs["seed"] for t in runs] == [refine_seed(0, k) for k in range(len(runs))]
    for t in refined:
        parent = t.user_attrs["refine_of"]
        source = trials[parent["trial"]]
        nets = dict((b, s) for s, b in scored_nets(source.user_attrs, source.value, source.state.name == "COMPLETE"))
        assert nets[parent["budget"]] == parent["score"], t.number
        assert t.user_attrs["config"]["train_iterations"] == 1000 and not t.intermediate_values
    done = [t for t in refined if t.state == optuna.trial.TrialState.COMPLETE]
    assert done, "no refinement run finished"
    storages = open_storage(str(tmp_path / "runs" / "race" / "journal.log"), "race", heartbeat=False,
                            artifacts=tmp_path / "runs" / "race" / "artifacts")  # fmt: skip
    rep = retrain_trial(storages, "race", done[-1].number)
    assert rep.identical and rep.stored == done[-1].value
    soups = [t for t in done if "soup_of" in t.user_attrs]
    assert soups, "no weight soup"
    rep = retrain_trial(storages, "race", soups[-1].number)  # its ingredients' stored nets averaged again
    assert rep.identical and rep.stored == soups[-1].value
    assert tagged_processes("refi-" + tmp_path.name) == []
