"""bench/search_quality.py's machinery in seconds: the statistics and plot data as values, the spec copy,
the plain loop's space, one plain-loop worker and a calibration set on tiny trainings, the worker pool."""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import sys
import time
import tomllib
import types
from pathlib import Path
from typing import Any

import optuna
import pytest
from optuna.storages import JournalStorage
from optuna.storages.journal import JournalFileBackend

from autotune import TrainConfig
from autotune.search.spec import load_spec, parse_spec
from tests.conftest import ROOT

# bench/ is scripts, not a package: load the file as a module (registered first, as dataclasses need)
_SPEC = importlib.util.spec_from_file_location("bench_search_quality", ROOT / "bench" / "search_quality.py")
assert _SPEC is not None and _SPEC.loader is not None
sq: Any = sys.modules.setdefault("bench_search_quality", importlib.util.module_from_spec(_SPEC))
_SPEC.loader.exec_module(sq)

PAPER = ROOT / "study_configs" / "paper.toml"
SMOKE = ROOT / "study_configs" / "smoke.toml"
TINY = {  # a net that trains in a second
    "ruleset": "v2", "patches_ahead": 2, "other_agents": 1, "temporal_window": 0, "experience_size": 200,
    "start_learn_threshold": 50, "learning_steps_total": 300, "learning_steps_burnin": 50, "batch_size": 8,
    "layers": "fc:4:relu",
}  # fmt: skip


def row(number: int, value: float | None, end_s: float | None, **attrs: Any) -> Any:
    state = attrs.pop("state", "COMPLETE" if value is not None else "PRUNED")
    return sq.TrialRow(number=number, state=state, value=value, end_s=end_s, **attrs)


# -- the spec copy ------------------------------------------------------------------------------


@pytest.mark.parametrize("path", [PAPER, SMOKE])
def test_study_copy_round_trips_and_is_a_valid_spec(path: Path) -> None:
    data = tomllib.loads(path.read_text())
    copy = sq.study_copy(data, "sq-cold-s2", 2, 600.0)
    assert tomllib.loads(sq.toml_dumps(copy)) == copy
    spec = parse_spec(tomllib.loads(sq.toml_dumps(copy)))
    assert (spec.study.name, spec.study.seed, spec.study.timeout_s, spec.study.n_trials) == ("sq-cold-s2", 2, 600, None)
    assert spec.space == load_spec(path).space and spec.fixed == load_spec(path).fixed
    assert data["study"]["name"] != "sq-cold-s2"  # the original is not touched


def test_toml_values() -> None:
    data = {"t": {"a": 1e-8, "b": -math.inf, "c": True, "d": 'x"y', "e": ["p", 1], "f": {"low": 1, "log": False}}}
    assert tomllib.loads(sq.toml_dumps(data)) == data
    with pytest.raises(TypeError):
        sq.toml_dumps({"t": {"a": object()}})


# -- the plain loop's space -----------------------------------------------------------------------


def test_plain_space_is_define_by_run_over_the_papers_space() -> None:
    spec = load_spec(PAPER)
    dims, notes = sq.plain_space(spec)
    # the service's learning rate per input is the user's learning rate over the crowd's range
    # and ε_test, which the service chooses per net ([ladder] epsilon_test_grid), is the user's to draw
    assert {d.name for d in dims} == {d.name for d in spec.space} - {"learning_rate_x_inputs"} | {
        "train_iterations",
        "learning_rate",
        "epsilon_test_time",
    }
    (length,) = [d for d in dims if d.name == "train_iterations"]
    assert (length.low, length.high, length.log) == (10_000, 90_000, True)  # the ladder's range up to min_top
    (rate,) = [d for d in dims if d.name == "learning_rate"]
    assert (rate.low, rate.high, rate.log) == (1e-8, 1e-2, True)
    assert len(notes) == 3 and "learning_rate over the crowd's range" in notes[0] and "ladder" in notes[2]
    assert "epsilon_test_grid) sampled as epsilon_test_time" in notes[1]
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=3))
    layer_counts = set()
    for _ in range(40):
        params = sq.sample_plain(study.ask(), dims)
        n = params["n_layers"]
        layer_counts.add(n)
        assert {k for k in params if k.startswith(("neurons_", "activation_"))} == {
            f"{p}_{i}" for p in ("neurons", "activation") for i in range(n)
        }
        config = sq.decode_plain(spec, params)
        assert len(config.layers) == n and config.method == params["method"]
        assert config.start_learn_threshold < config.experience_size
        assert config.gamma == pytest.approx(1 - params["one_minus_gamma"])
        fraction = params["learning_steps_burnin_fraction"]
        assert config.learning_steps_burnin == round(fraction * params["train_iterations"])
    assert len(layer_counts) > 3


def test_plain_space_samples_a_shifted_epsilon_test_as_a_user_would() -> None:
    """A spec searching ε_test + 0.005 on a log scale: the plain loop draws ε_test itself, uniform on the same range."""
    data = load_spec(PAPER).to_dict()
    data["space"] = {k: v for k, v in data["space"].items() if k != "epsilon_test_time"}
    data["ladder"] = {k: v for k, v in data["ladder"].items() if not k.startswith("epsilon_test")}
    data["space"]["epsilon_test_time_shifted"] = {"low": 0.005, "high": 0.905, "log": True}
    dims, notes = sq.plain_space(parse_spec(data))
    (eps,) = [d for d in dims if d.name.startswith("epsilon_test")]
    assert (eps.name, eps.low, eps.high, eps.log) == ("epsilon_test_time", 0.0, 0.9, False)
    assert any("epsilon_test_time_shifted sampled as epsilon_test_time, uniform on 0–0.9" in n for n in notes)


def test_plain_space_draws_epsilon_test_where_the_service_chooses_it_per_net() -> None:
    """paper.toml chooses ε_test per trained net ([ladder] epsilon_test_grid): the plain loop, a user's own, draws it
    as a setting, uniformly over the paper's 0–0.9, and says so."""
    spec = load_spec(PAPER)
    assert spec.ladder_epsilon_grid and "epsilon_test_time" not in spec.dimensions
    dims, notes = sq.plain_space(spec)
    (eps,) = [d for d in dims if d.name.startswith("epsilon_test")]
    assert (eps.name, eps.low, eps.high, eps.log) == ("epsilon_test_time", 0.0, 0.9, False)
    assert any("epsilon_test_grid) sampled as epsilon_test_time, uniform on 0–0.9" in n for n in notes)


def test_plain_space_leaves_out_service_only_names_and_keeps_a_train_length() -> None:
    spec = load_spec(SMOKE)
    extra = types.SimpleNamespace(name="budget_rung", kind="int", low=0, high=3, log=False, step=None, choices=())
    unknown = types.SimpleNamespace(space=(*spec.space, extra), fixed_values={}, ruleset="v2")
    dims, notes = sq.plain_space(unknown)
    names = [d.name for d in dims]
    assert "budget_rung" not in names and names[0] == "train_iterations"
    assert dims[0].low == sq.FALLBACK_ITERATIONS["low"] and dims[0].high == sq.FALLBACK_ITERATIONS["high"]
    assert any("budget_rung" in n for n in notes) and any("train_iterations" in n for n in notes)


# -- trial records → figures ------------------------------------------------------------------------


def test_rows_from_trials_reads_the_contract_attrs() -> None:
    study = optuna.create_study(direction="maximize")
    t0 = time.time()
    attrs = {"config": {"a": 1}, "seed": 5, "trial_wall_seconds": 2.0, "predicted_cost_s": 3.0, "warm_start": "crowd:x"}
    study.add_trial(optuna.trial.create_trial(value=70.0, user_attrs=attrs))
    study.add_trial(optuna.trial.create_trial(state=optuna.trial.TrialState.PRUNED, user_attrs={"cause": "timeout"}))
    rows = sq.rows_from_trials(study.get_trials(), t0)
    assert [r.state for r in rows] == ["COMPLETE", "PRUNED"]
    assert (rows[0].value, rows[0].seed, rows[0].wall_s, rows[0].predicted_cost_s) == (70.0, 5, 2.0, 3.0)
    assert rows[0].warm_start == "crowd:x" and rows[0].config == {"a": 1} and rows[1].cause == "timeout"
    assert rows[1].value is None and all(0 <= r.end_s < 60 for r in rows)
    assert not rows[0].side and not rows[1].side
    for key in ("twin_of", "neighbour_of"):
        twin = optuna.trial.create_trial(value=71.0, user_attrs={key: 0, "trial_wall_seconds": 1.0})
        assert sq.rows_from_trials([twin], t0)[0].side


def test_best_single_and_the_best_not_enqueued() -> None:
    rows = [
        row(0, 75.0, 30, warm_start="crowd:a"),
        row(1, 72.0, 100),
        row(2, 74.0, 700),
        row(3, None, 50),
        row(4, 80.0, None, state="RUNNING"),
    ]
    assert sq.best_single(rows, 20) is None
    assert sq.best_single(rows, 600).number == 0
    assert sq.best_single(rows, 600, enqueued=False).number == 1
    assert sq.best_single(rows, 3600, enqueued=False).number == 2
    picks = sq.checkpoint_picks(rows, [1, 10, 15])
    assert [p["best"] for p in picks] == [75.0, 75.0, 75.0]
    assert [p["best_not_enqueued"] for p in picks] == [None, 72.0, 74.0]
    assert [p["finished"] for p in picks] == [2, 3, 4]


def test_the_best_single_net_counts_kept_rungs() -> None:
    """A kept rung of a finished trial (pruned too) that outscores every value is the checkpoint's best net, as
    ``autotune best`` ranks it; a rung whose net was not kept does not count; ties go to a trial's value."""
    study = optuna.create_study(direction="maximize")
    t0 = time.time()
    rungs = [{"budget": 10_000, "score": 76.0}, {"budget": 30_000, "score": 74.5}, {"budget": 90_000, "score": 80.0}]
    study.add_trial(optuna.trial.create_trial(
        state=optuna.trial.TrialState.PRUNED,
        user_attrs={"rungs": rungs, "artifact_rung_nets": {"10000": "a", "30000": "b"},  # 90k's net not kept
                    "official_protocol": "v2-official"},
    ))  # fmt: skip
    study.add_trial(optuna.trial.create_trial(  # scored with another protocol: its rungs are no official nets
        state=optuna.trial.TrialState.PRUNED,
        user_attrs={"rungs": rungs, "artifact_rung_nets": {"10000": "a"}, "official_protocol": "custom"},
    ))  # fmt: skip
    read = sq.rows_from_trials(study.get_trials(), t0)
    assert read[0].rung_scores == ((10_000, 76.0), (30_000, 74.5)) and read[1].rung_scores == ()
    rows = [
        dataclasses.replace(row(0, None, 100, state="PRUNED"), rung_scores=read[0].rung_scores),
        row(1, 75.0, 50),
        dataclasses.replace(row(2, 76.0, 200), rung_scores=((30_000, 76.0),)),
        row(3, 90.0, 60, state="RUNNING"),
    ]
    assert sq.best_net(rows, 60) == sq.Net(75.0, 1, None)
    assert sq.best_net(rows, 150) == sq.Net(76.0, 0, 10_000)
    assert sq.best_net(rows, 300) == sq.Net(76.0, 2, None)  # a trial's value wins the tie with a rung
    picks = sq.checkpoint_picks(rows, [2.5])
    assert (picks[0]["best"], picks[0]["best_trial"], picks[0]["best_rung"]) == (76.0, 0, 10_000)
    assert sq.running_best(rows) == [(50 / 60, 75.0), (100 / 60, 76.0)]


def test_chosen_trial_prefers_the_raced_configuration() -> None:
    rows = [row(0, 76.0, 10, config={"c": 0}), row(1, 74.0, 20, config={"c": 1})]
    assert sq.chosen_trial(rows, 60).number == 0  # no race yet: the best single net's configuration
    rows += [
        row(2, 71.0, 30, race_of=0, race_seed=0),
        row(3, 73.0, 31, race_of=1, race_seed=0),
        row(4, 72.0, 40, race_of=0, race_seed=1),
        row(5, 73.5, 41, race_of=1, race_seed=1),
        row(6, 79.0, 50, race_of=0, race_seed=2),
        row(7, 80.0, 55, race_of=0, race_seed=3),
    ]
    race = ([0, 1], 1)  # the study's stored field (best first) and seeds per round
    assert sq.chosen_trial(rows, 35, race).number == 1  # one race run each: 73 beats 71
    assert sq.chosen_trial(rows, 45, ([0, 1], 2)).number == 1  # two each: 73.25 beats 71.5
    assert sq.chosen_trial(rows, 60, ([0, 1], 2)).number == 1  # paired: trial 1's seeds 2, 3 not run: on 0, 1
    assert sq.chosen_trial(rows, 60, ([0, 1], 2)).config == {"c": 1}
    assert sq.chosen_trial(rows, 60, ([0, 1], 4)).number == 1  # one round still running: the same
    # trial 1 won round 0 (73 against 71); its tail's 73.5 leaves its mean, 73.25, under trial 0's 75.5 over its 4
    # seeds: the tail overturns the halving (racing.tail_leader)
    assert sq.chosen_trial(rows, 60, race).number == 0
    early = [dataclasses.replace(rows[2], end_s=21, seed_run=True),
             dataclasses.replace(rows[3], end_s=22, incumbent=True)]  # fmt: skip
    assert sq.chosen_trial(rows[:2] + early, 25, race).number == 0  # runs before the race: no field yet
    assert sq.chosen_trial(rows[:2] + early + rows[4:6], 45, race).number == 1  # then they count as its seeds
    rung = [row(8, 81.0, 70, race_of=1, race_seed=2, config={"c": 1, "train_iterations": 10_000})]  # at a rung
    chosen = sq.chosen_trial(rows + rung, 80, race)
    assert chosen.number == 1 and chosen.config == {"c": 1, "train_iterations": 10_000}  # what the race measured


def test_chosen_trial_before_the_race_ranks_configurations_by_their_seed_runs() -> None:
    """Before the race a lucky seed is not the pick: a configuration with 3 fresh seed runs is ranked by their
    mean (``racing.provisional_standings``), as ``autotune best`` shows it."""
    rows = [row(0, 76.0, 10, config={"c": 0}), row(1, 74.0, 20, config={"c": 1})]
    seeds = [row(2 + i, v, 30 + i, race_of=0, race_seed=i, seed_run=True) for i, v in enumerate((71.0, 72.0, 73.0))]
    stacks = [row(5 + i, v, 40 + i, race_of=1, race_seed=i, seed_run=True) for i, v in enumerate((73.0, 74.0, 75.0))]
    assert sq.chosen_trial(rows + seeds, 60).number == 0  # the only one with 3 seeds: 72.0
    assert sq.chosen_trial(rows + seeds + stacks[:2], 60).number == 0  # trial 1 has 2: not ranked yet
    assert sq.chosen_trial(rows + seeds + stacks, 60).number == 1  # 74.0 beats 72.0
    assert sq.chosen_trial(rows + seeds + stacks, 41).number == 0  # by 41 s trial 1's third had not finished
    assert sq.chosen_trial(rows + stacks[:2], 60).number == 0  # none has 3: the best single trial
    assert sq.chosen_trial(rows + seeds + stacks, 60, ([0, 1], 1)).number == 1  # a stored field, no race run yet


def test_chosen_trial_leaves_out_the_seeds_the_deadline_stopped() -> None:
    """The 30-minute cold study's race: entrant 1 led round 0, its round-1 runs ended at the deadline (PRUNED,
    cause ``deadline…``); the winner is paired on round 0, not entrant 0 for having finished more runs. A race
    run its own limit stopped, or that failed, ranks its configuration last."""
    entrants = [row(n, v, 10, config={"c": n}) for n, v in enumerate((73.0, 73.5, 72.0, 71.0))]
    runs = [
        row(4, 66.7, 20, race_of=0, race_seed=0), row(5, 70.4, 21, race_of=0, race_seed=1),
        row(6, 72.3, 22, race_of=1, race_seed=0), row(7, 72.5, 23, race_of=1, race_seed=1),
        row(8, 65.0, 24, race_of=2, race_seed=0), row(9, 66.0, 25, race_of=2, race_seed=1),
        row(10, 60.0, 26, race_of=3, race_seed=0), row(11, None, 27, race_of=3, race_seed=1, state="FAIL"),
        row(12, 71.0, 40, race_of=0, race_seed=2), row(13, 72.0, 41, race_of=0, race_seed=3),
    ]  # fmt: skip
    deadline = "deadline: the study's time budget ended (training at 80 %)"
    stopped = [row(14, None, 50, race_of=1, race_seed=2, cause=deadline),
               row(15, None, 50, race_of=1, race_seed=3, cause=deadline)]  # fmt: skip
    rows = entrants + runs + stopped
    race = ([1, 0, 2, 3], 2)  # the stored field, best first
    assert sq.chosen_trial(rows, 45, race).number == 1  # round 1 running
    assert sq.chosen_trial(rows, 60, race).number == 1  # and stopped: 72.4 against 68.55 on 0, 1
    limit = [dataclasses.replace(stopped[0], cause="timeout: trial wall time exceeded trial_timeout_s = 60 s")]
    assert sq.chosen_trial(entrants + runs + limit, 60, race).number == 0  # over its limit: last


def test_running_best_and_the_run_figures() -> None:
    rows = [
        row(0, 70.0, 60, wall_s=50.0, predicted_cost_s=40.0),
        row(1, 69.0, 90, wall_s=30.0, predicted_cost_s=60.0),
        row(2, None, 120, wall_s=20.0, cause="timeout: trial wall time exceeded", refused_draws=3),
        row(3, 72.0, 180, wall_s=10.0, refused_draws=1),
        row(4, 71.0, 30, wall_s=100.0, warm_start="crowd:a", predicted_cost_s=1.0),
    ]
    assert sq.running_best(rows) == [(0.5, 71.0), (3.0, 72.0)]
    err, n = sq.cost_model_error(rows)
    assert n == 3 and err == pytest.approx(sorted([0.2, 1.0, 0.99])[1])
    assert sq.limit_share(rows, 2 * 100.0) == pytest.approx(0.1)
    assert sq.refused_share(rows) == pytest.approx(4 / (4 + 4))
    assert sq.refused_share(rows[:2]) is None
    assert sq.worst_overrun(rows, 50.0) == pytest.approx(2.0)
    figures = sq.run_figures(rows, 100.0, 2, 50.0)
    assert figures["states"] == {"COMPLETE": 4, "PRUNED": 1, "FAIL": 0, "RUNNING": 0}
    assert figures["pruned_by"] == {"trial limit": 1}
    assert (figures["incumbent_runs"], figures["incumbent_share"], figures["incumbent_best"]) == (0, 0.0, None)
    early = [dataclasses.replace(rows[1], race_of=0, race_seed=0, incumbent=True),
             dataclasses.replace(rows[2], race_of=0, race_seed=1, incumbent=True)]  # fmt: skip
    assert sq.incumbent_figures(early + rows[3:], 200.0) == {
        "incumbent_runs": 2, "incumbent_share": pytest.approx(0.25), "incumbent_best": 69.0,
    }  # fmt: skip
    causes = ["does not learn at rung 0 (…)", "static policy at rung 1 (…)", "does not learn at rung 0 (…)",
              "pruned after rung 0 (…) by the pruner", "diverged at rung 2, …", "deadline: …", "lost"]  # fmt: skip
    pruned = [row(k, None, 10.0 * k, cause=c) for k, c in enumerate(causes)]
    assert sq.pruned_by(pruned + rows[:2]) == {
        "not learning": 2, "by the pruner": 1, "deadline": 1, "diverged": 1, "other": 1, "static": 1,
    }  # fmt: skip


def test_time_shares_split_the_workers_time_by_kind_up_to_a_checkpoint() -> None:
    rows = [
        row(0, 70.0, 60, wall_s=60.0),  # a draw: 0–60 s
        row(1, 71.0, 50, wall_s=40.0, warm_start="crowd:a"),  # 10–50 s
        row(2, 72.0, 120, wall_s=60.0, side=True),  # 60–120 s: half of it after the 90-s checkpoint
        row(3, 73.0, 100, wall_s=30.0, race_of=2, seed_run=True),
        row(4, 74.0, 110, wall_s=10.0, race_of=2),
        row(5, 75.0, 115, wall_s=5.0, refine_of=2, soup=True),
        row(6, 74.5, 80, wall_s=20.0, refine_of=2),
        row(7, None, 30, wall_s=30.0, state="PRUNED"),  # a pruned draw counts too
        row(8, None, None, wall_s=None, state="RUNNING"),  # unfinished: not counted
    ]
    assert [sq.trial_kind(r) for r in rows[:7]] == [
        "search", "warm start", "twins and neighbours", "seed runs", "race", "soups", "refinement",
    ]  # fmt: skip
    assert sq.trial_kind(row(9, 70.0, 10, race_of=2, incumbent=True)) == "incumbent runs"
    early = sq.time_shares(rows, 90.0, 2)
    assert early == {
        "search": pytest.approx(90 / 180), "warm start": pytest.approx(40 / 180),
        "twins and neighbours": pytest.approx(30 / 180), "seed runs": pytest.approx(20 / 180),
        "refinement": pytest.approx(20 / 180),
    }  # fmt: skip
    assert list(early) == ["search", "warm start", "twins and neighbours", "seed runs", "refinement"]
    late = sq.time_shares(rows, 120.0, 2)
    assert late["race"] == pytest.approx(10 / 240) and late["soups"] == pytest.approx(5 / 240)
    assert sum(late.values()) == pytest.approx((60 + 40 + 60 + 30 + 10 + 5 + 20 + 30) / 240)
    assert sq.time_shares([], 60.0, 2) == {} and sq.time_shares(rows, 0.0, 2) == {}


def test_arm_checkpoints_are_medians_over_runs() -> None:
    def run(best: float | None, mean: float | None) -> dict[str, Any]:
        return {"checkpoints": [{"best": best, "best_not_enqueued": best, "reseed_mean": mean}]}

    cps = sq.arm_checkpoints([run(70.0, 60.0), run(74.0, None), run(None, 62.0), run(72.0, 64.0)], [10])
    assert cps[0]["best_median"] == 72.0 and cps[0]["reseed_mean_median"] == 62.0 and cps[0]["runs"] == 4
    assert sq.median([None, None]) is None
    assert sq.mean_sd([1.0, 3.0]) == (2.0, pytest.approx(math.sqrt(2))) and sq.mean_sd([]) == (None, None)


def test_reseed_scores_keep_the_unscored_runs_and_why() -> None:
    cache = {
        "k|1": {"state": "complete", "value": 70.0, "seconds": 5.0},
        "k|2": {"state": "pruned", "value": None, "cause": "diverged: loss", "seconds": 2.0},
        "k|3": {"state": "complete", "value": 74.0, "seconds": 5.0},
    }
    out = sq.reseed_scores("k", [1, 2, 3], cache)
    assert (out["reseed_mean"], out["reseed_n"], out["reseed_unscored"]) == (72.0, 2, ["diverged: loss"])
    assert out["reseed_train_s"] == 12.0


def test_rung_correlations() -> None:
    def rungs(*scores: float | None) -> list[dict[str, Any]]:
        return [{"budget": b, "score": s} for b, s in zip((10, 30, 90), scores, strict=False)]

    sets = [rungs(50, 60, 70), rungs(55, 65, 72), rungs(52, 58, 71), rungs(40, 50), rungs(60, None), rungs(45)]
    out = {c["budget"]: c for c in sq.rung_correlations(sets)}
    assert out[10]["n"] == 4 and out[30]["n"] == 3  # rungs(60, None) and rungs(45) have no pair
    assert out[10]["spearman"] == pytest.approx(1.0)  # 50, 55, 52, 40 against tops 70, 72, 71, 50: same order
    assert out[30]["spearman"] == pytest.approx(0.5)  # 60, 65, 58 against 70, 72, 71: rank differences 1, 0, 1
    assert sq.rung_correlations([rungs(1, 2, 3), rungs(2, 3, 4)])[0]["spearman"] is None  # n < 3


def test_plot_data_and_figure() -> None:
    result: dict[str, Any] = {
        "minutes": [10, 30],
        "arms": {
            "cold": {"runs": [{"study_seed": 0, "wall_s": 1800.0, "running_best": [[2.0, 70.0], [12.0, 73.0]]}]},
            "warm": {"skipped": "no --warm-start"},
            "plain": {"runs": [{"study_seed": 1, "wall_s": 1800.0, "running_best": []}]},
        },
        "reference": {"id": "dt-x", "reseed_mean": 71.5, "reseed_sd": 1.0, "reseed_n": 3},
        "fresh_seeds": [1, 2, 3],
    }
    data = sq.plot_data(result)
    assert data["traces"] == [
        {"arm": "cold", "name": "cold (study seed 0)", "x": [2.0, 12.0, 30.0], "y": [70.0, 73.0, 73.0]}
    ]
    fig = sq.draw(data)
    assert len(fig.data) == 1 and list(fig.data[0].y) == [70.0, 73.0, 73.0]
    assert len(fig.layout.shapes) == 3  # the two checkpoints and the reference's mean
    table = sq.format_table({**result, "arms": {"warm": result["arms"]["warm"]}})
    assert "warm    skipped: no --warm-start" in table
    assert "reference dt-x: mean 71.50 ± 1.00 over seeds [1, 2, 3] (n=3)" in table


# -- the workers ------------------------------------------------------------------------------------


def test_pool_round_trip_and_deadline() -> None:
    with sq.Pool(2) as pool:
        out = pool.run([{"kind": "echo", "payload": i} for i in range(3)])
        assert [o["echo"] for o in out] == [0, 1, 2] and len({o["pid"] for o in out}) == 2
        assert "error" in pool.run([{"kind": "nope"}])[0]
    with sq.Pool(1) as pool:
        t = time.time()
        out = pool.run([{"kind": "echo", "sleep_s": 60}], deadline=time.time() + 1.0)
        assert "killed" in out[0]["error"] and time.time() - t < 20


def _smoke_copy(tmp_path: Path, trial_timeout_s: float) -> Path:
    data = sq.study_copy(tomllib.loads(SMOKE.read_text()), "smoke-copy", 0, 60.0)
    data["study"]["trial_timeout_s"] = trial_timeout_s
    path = tmp_path / f"smoke-{trial_timeout_s:g}.toml"
    path.write_text(sq.toml_dumps(data))
    return path


def test_plain_loop_worker_records_the_contract_and_stops_at_the_trial_limit(tmp_path: Path) -> None:
    storage = JournalStorage(JournalFileBackend(str(tmp_path / "j.log")))
    for name in ("ok", "limit"):
        optuna.create_study(study_name=name, storage=storage, direction="maximize")
    job = {"kind": "loop", "storage": str(tmp_path / "j.log"), "study_seed": 0, "worker": 0, "prune": True}
    t0 = time.time()
    roomy = _smoke_copy(tmp_path, trial_timeout_s=600)  # a cold numba cache compiles for a minute or more
    out = sq.loop_job({**job, "space": str(roomy), "study": "ok", "deadline": t0 + 900, "n_trials": 2})
    assert out["trials"] == 2
    tiny = _smoke_copy(tmp_path, trial_timeout_s=0.001)  # stopped at its first progress call
    sq.loop_job({**job, "space": str(tiny), "study": "limit", "deadline": time.time() + 120, "n_trials": 1})
    rows = sq.read_rows(tmp_path / "j.log", "ok", t0)
    assert [r.state for r in rows] == ["COMPLETE", "COMPLETE"]
    for r in rows:
        assert 30 < r.value < 90 and r.wall_s > 0 and isinstance(r.seed, int)
        assert TrainConfig.from_mapping(r.config).train_iterations == 2000
    assert rows[0].seed != rows[1].seed
    (limited,) = sq.read_rows(tmp_path / "j.log", "limit", t0)
    assert limited.state == "PRUNED" and limited.cause.startswith("timeout: trial wall time exceeded")
    assert sq.limit_share([limited], 1.0) > 0


def test_read_race_gives_the_stored_field_and_seeds_per_round(tmp_path: Path) -> None:
    """The pick ranks a race as ``autotune best`` does: with the field and race_seeds the study stored."""
    storage = JournalStorage(JournalFileBackend(str(tmp_path / "j.log")))
    study = optuna.create_study(study_name="raced", storage=storage, direction="maximize")
    study.set_user_attr("race_field", [3, 1])
    study.set_user_attr("spec", {"study": {"race_seeds": 2}})
    optuna.create_study(study_name="plain", storage=storage, direction="maximize")
    assert sq.read_race(tmp_path / "j.log", "raced") == ([3, 1], 2)
    assert sq.read_race(tmp_path / "j.log", "plain") == ([], 1)  # no race (a plain loop's study)
    assert sq.read_race(tmp_path / "none.log", "raced") == ([], 1)  # never created


def test_calibration_draws_are_priced_by_the_prior_and_reproducible() -> None:
    from autotune.search.cost import CostModel

    spec = load_spec(PAPER)
    jobs, refused, drawn = sq.calibration_draws(spec, 4, 14, 300.0)
    assert len(jobs) == 4 and drawn == 4 + len(refused)
    for job in jobs:
        assert len(job["rungs"]) >= 2 and job["rungs"] == list(spec.ladder[: len(job["rungs"])])
        assert sum(job["predicted_s"]) <= 300.0
        top = TrainConfig.from_mapping(job["config"])
        assert top.train_iterations == job["rungs"][-1]
        # the study's model: each rung screens its net at paper.toml's ε_test grid, all 5 values on 50 of the 500
        # runs and the better 2 on to 100: 350 runs over 5 values, the chosen one's 100 carried on
        model = CostModel.prior().screening(spec.ladder_epsilon_grid, 350 / 5 / 500, 100 / 500)
        assert model.predict(top) == pytest.approx(job["predicted_s"][-1])
        assert job["predicted_s"][-1] > CostModel.prior().predict(top)
        assert job["epsilon_test_grid"] == list(spec.ladder_epsilon_grid)
        assert job["epsilon_test_screen_runs"] == [50, 100]
    assert len({job["seed"] for job in jobs}) == 4
    again, _, _ = sq.calibration_draws(spec, 4, 14, 300.0)
    assert again == jobs
    none, refused, drawn = sq.calibration_draws(spec, 2, 14, 0.5)  # no rung 0 costs under half a second
    assert none == [] and drawn == 200 and len(refused) == 200 and "rung 0 over the cap" in refused[0]


def test_train_job_climbs_every_rung_unpruned() -> None:
    config = TrainConfig.from_mapping({**TINY, "train_iterations": 800})
    out = sq.train_job({"config": config.to_mapping(), "seed": 7, "rungs": [400, 800]})
    assert out["state"] == "complete" and [r["budget"] for r in out["rungs"]] == [400, 800]
    assert all(r["score"] > 0 and r["seconds"] > 0 for r in out["rungs"])
    assert out["value"] == out["rungs"][-1]["score"]
    args = types.SimpleNamespace(calibration_cap=None, calibration_seed=0, workers=1)
    skipped = sq.run_calibration(3, args, {"spec": load_spec(SMOKE), "space": SMOKE})
    assert "no [ladder]" in skipped["skipped"]


def test_reference_and_bad_options(capsys: pytest.CaptureFixture[str]) -> None:
    ref = sq.reference_config(sq.REFERENCE_ID)
    assert TrainConfig.from_mapping(ref).ruleset == "v2" and ref["layers"] == "fc:384:tanh"
    with pytest.raises(sq.BenchError):
        sq.reference_config("dt-nobody")
    for argv in (["--arms", "plain,fancy"], ["--minutes", "0"], ["--space", "nope"], ["--study-seeds", "a"]):
        assert sq.main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and err.startswith(f"{argv[0]} ")


def test_refinement_runs_count_as_nets_not_as_picks() -> None:
    """A refinement run's net is a best single net; its configuration is never the pick (it trains on from its
    parent's net), and one descending from a crowd setting is not the search's own find ("not enqueued")."""
    study = optuna.create_study(direction="maximize")
    study.add_trial(optuna.trial.create_trial(value=75.2, user_attrs={"refine_of": {"trial": 0, "budget": None,
                                                                                    "score": 74.9}}))  # fmt: skip
    study.add_trial(optuna.trial.create_trial(value=75.3, user_attrs={"refine_of": {"trial": 0, "budget": None,
                                                                                    "score": 74.9},
                                                                      "soup_of": [1, 2]}))  # fmt: skip
    found = sq.rows_from_trials(study.get_trials(), time.time())
    assert found[0].refine_of == 0 and not found[0].soup and found[1].soup
    rows = [
        row(0, 74.9, 30, warm_start="crowd:a"),
        row(1, 74.0, 60),
        dataclasses.replace(row(2, 75.2, 90, wall_s=20.0), refine_of=0),
        dataclasses.replace(row(3, 75.4, 120, wall_s=20.0), refine_of=2, soup=True),
        dataclasses.replace(row(4, 74.5, 150, wall_s=20.0), refine_of=1),
        dataclasses.replace(row(5, None, 160, state="PRUNED", wall_s=20.0), refine_of=3),
    ]
    assert sq.best_net(rows, 200) == sq.Net(75.4, 3, None)
    assert sq.best_net(rows, 200, enqueued=False) == sq.Net(74.5, 4, None)  # 2 and 3 descend from crowd:a
    assert sq.lineage_root(rows[3], {r.number: r for r in rows}).number == 0
    assert sq.best_single(rows, 200).number == 0 and sq.chosen_trial(rows, 200).number == 0
    figures = sq.refine_figures(rows, 400.0)
    assert figures == {"refine_runs": 4, "refine_soups": 1, "refine_share": pytest.approx(0.2), "refine_best": 75.4,
                       "refine_root": 0}  # fmt: skip


# -- held-out scores of the best nets -----------------------------------------------------------


def test_held_out_scores_rescore_the_stored_net_on_unplayed_runs(tmp_path: Path) -> None:
    """``held_out_scores``: a trial's stored net (its value's, or a kept rung's with that rung's ε_test) scored on the
    ``v2-heldout`` protocol's runs from each seed (the official harness on other runs), exactly as
    ``evaluate_official`` scores it there; a trial without a stored net gives its one-line cause; ``add_held_out``
    and the table carry them per checkpoint."""
    from autotune.convnet.netjson import dumps_net, loads_net
    from autotune.learner.official import evaluate_official
    from autotune.learner.training import train
    from autotune.search import keys
    from autotune.search.ladder import trained_rung_config
    from autotune.search.storage import open_storage

    config = TrainConfig.from_mapping({**TINY, "train_iterations": 300})
    text = dumps_net(train(config, seed=3, quick_eval=False).convnet())
    journal, name = tmp_path / "journal.log", "sq-warm-s0"
    storages = open_storage(str(journal), name, heartbeat=False)
    study = optuna.create_study(study_name=name, storage=storages.storage, direction="maximize")
    (tmp_path / "net.json").write_text(text)
    artifact = optuna.artifacts.upload_artifact(artifact_store=storages.artifacts, file_path=str(tmp_path / "net.json"),
                                                study_or_trial=study)  # fmt: skip
    rungs = [{keys.BUDGET: 100, keys.SEED: 4, "score": 61.0, keys.EPSILON_TEST: 0.45}]
    study.add_trial(optuna.trial.create_trial(value=60.0, user_attrs={
        keys.CONFIG: config.to_mapping(), keys.ARTIFACT_NET_JSON: artifact, keys.RUNGS: rungs,
        keys.ARTIFACT_RUNG_NETS: {"100": artifact}}))  # fmt: skip
    study.add_trial(optuna.trial.create_trial(value=59.0, user_attrs={keys.CONFIG: config.to_mapping()}))

    got = sq.held_out_scores(journal, name, [(0, None), (0, 100), (1, None), (0, None)], [1_000_000, 7], 4)
    net = loads_net(text)
    assert sq.held_out_protocol("v2") == "v2-heldout" and sq.held_out_protocol("v1") == "custom"
    want = [evaluate_official(net, config, seed=s, protocol="v2-heldout", runs=4).median_site
            for s in (1_000_000, 7)]  # fmt: skip
    assert got[(0, None)] == want
    rung = trained_rung_config(config, 100, rungs)  # as the rung scored it: its ε_test 0.45, not the config's 0
    assert rung.epsilon_test_time == 0.45
    assert got[(0, 100)] == [evaluate_official(net, rung, seed=s, protocol="v2-heldout", runs=4).median_site
                             for s in (1_000_000, 7)]  # fmt: skip
    assert got[(0, 100)] != want
    assert "no trained network stored" in got[(1, None)]
    assert list(got) == [(0, None), (0, 100), (1, None)]  # in order, once each

    checkpoints: list[dict[str, Any]] = [
        {"best_trial": 0, "best_rung": None, "best": 60.0},
        {"best_trial": None, "best_rung": None, "best": None},
    ]
    sq.add_held_out({"storage": str(journal), "study": name, "checkpoints": checkpoints}, [1_000_000, 7], 4)
    assert checkpoints[0]["best_held_out"] == want and "best_held_out" not in checkpoints[1]
    assert sq._held_out_text(want) == f" (held out {want[0]:.2f} / {want[1]:.2f})"
    assert sq._held_out_text("trial 1: no net") == " (held out: trial 1: no net)" and sq._held_out_text(None) == ""

    # a study that cannot be read leaves every net its cause, not an exception that would lose the arm's figures
    gone = sq.held_out_scores(tmp_path / "nowhere.log", name, [(0, None), (0, 100)], [7], 4)
    assert list(gone) == [(0, None), (0, 100)] and all(isinstance(v, str) and v for v in gone.values())


def test_held_out_options() -> None:
    assert sq.parse_args([]).held_out_seeds == list(sq.HELD_OUT_SEEDS)
    assert sq.parse_args(["--held-out", "none"]).held_out_seeds == []
    for bad in (["--held-out", "1e6"], ["--held-out", "-1"], ["--held-out-runs", "0"]):
        with pytest.raises(sq.BenchError):
            sq.parse_args(bad)
