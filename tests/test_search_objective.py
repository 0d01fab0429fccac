"""The trial objective in-process (no Optuna, no Ray): every way a trial ends, and the record it carries.

Also the driver's pure pieces: every sampler and pruner a spec can name, and the per-trial seeds.
"""

from __future__ import annotations

import json

import optuna
import pytest

from autotune import TrainConfig, loads_net
from autotune.search.driver import make_pruner, make_sampler, trial_seed
from autotune.search.objective import COMPLETE, FAILED, PRUNED, TrialTask, process_alive, process_start, run_trial
from autotune.search.spec import PRUNERS, SAMPLERS, parse_spec

TINY = {
    "ruleset": "v2",
    "patches_ahead": 2,
    "other_agents": 1,
    "train_iterations": 600,
    "temporal_window": 0,
    "experience_size": 200,
    "start_learn_threshold": 50,
    "learning_steps_total": 300,
    "learning_steps_burnin": 50,
    "batch_size": 8,
    "layers": "fc:4:relu",
}

# the contract's "Trial records" user attrs an objective fills in (worker/retry/artifact ids are the driver's)
RECORD_KEYS = {
    "source", "config", "settings", "seed", "curve", "input_size", "num_states", "param_count",
    "frames_simulated", "train_seconds", "eval_seconds", "official_protocol", "official_mean", "official_std",
    "diverged", "worker",
}  # fmt: skip


def _task(**changes: object) -> TrialTask:
    config = TrainConfig.from_mapping({**TINY, **changes.pop("config", {})})  # type: ignore[dict-item]
    base = dict(number=7, config=config.to_mapping(), seed=3, report_points=3, quick_runs=2, quick_frames=200)
    return TrialTask(**{**base, **changes})  # type: ignore[arg-type]


def test_complete_trial_carries_the_record_and_is_reproducible() -> None:
    seen: list[tuple[int, int, float]] = []

    def report(k: int, frames: int, score: float) -> bool:
        seen.append((k, frames, score))
        return False

    out = run_trial(_task(), report)
    assert out.state == COMPLETE, out.cause
    assert out.cause is None and out.value is not None and 0 < out.value < 120
    assert RECORD_KEYS <= set(out.attrs), RECORD_KEYS - set(out.attrs)
    assert [k for k, _, _ in seen] == [0, 1, 2]
    assert [p["step"] for p in out.attrs["curve"]] == [0, 1, 2]
    assert [p["quick_score"] for p in out.attrs["curve"]] == [s for _, _, s in seen]
    config = TrainConfig.from_mapping(out.attrs["config"])
    assert out.attrs["input_size"] == config.net_inputs and out.attrs["seed"] == 3
    assert out.attrs["param_count"] == (config.net_inputs + 1) * 4 + (4 + 1) * 5
    assert out.attrs["official_protocol"] == "v2-official"
    # training frames + 3 quick scores of 2 × 200 frames + the official 500 × 2,000
    assert out.attrs["frames_simulated"] == config.total_frames + 3 * 2 * 200 + 500 * 2000
    json.dumps(out.attrs)  # user attrs must be JSON
    net = loads_net(out.net_json or "")
    assert net.params[0][0].shape == (4, config.net_inputs)
    assert "layer_defs" in (out.net_js or "") and "lanesSide" in (out.net_js or "")
    again = run_trial(_task(), lambda k, frames, score: False)
    assert again.value == out.value and again.attrs["curve"] == out.attrs["curve"]


def test_pruned_when_the_report_says_so() -> None:
    out = run_trial(_task(), lambda k, frames, score: k == 1)
    assert out.state == PRUNED and out.value is None and out.net_json is None
    assert out.cause == "pruned at step 1 by the pruner"
    assert [p["step"] for p in out.attrs["curve"]] == [0, 1]
    assert "eval_seconds" not in out.attrs  # never scored


def test_diverging_configuration_is_pruned_with_its_cause() -> None:
    task = _task(config={"learning_rate": 10.0, "momentum": 0.9, "l2_decay": 0.0, "layers": "fc:8:relu"})
    out = run_trial(task, lambda k, frames, score: False)
    assert out.state == PRUNED and out.attrs["diverged"] is True
    assert out.cause is not None and out.cause.startswith("diverged: ")


def test_wall_time_limit_ends_the_trial() -> None:
    out = run_trial(_task(timeout_s=0.01), lambda k, frames, score: False)
    assert out.state == PRUNED
    assert out.cause is not None and out.cause.startswith("timeout: trial wall time exceeded trial_timeout_s = 0.01 s")


def test_objective_error_is_a_failure_with_the_traceback() -> None:
    task = TrialTask(number=1, config={**TINY, "layers": "fc:4:bogus"}, seed=0)
    out = run_trial(task, lambda k, frames, score: False)
    assert out.state == FAILED and out.value is None
    assert out.cause is not None and "ConfigError" in out.cause and "Traceback" in out.cause


def _spec(sampler: str, pruner: str) -> object:
    return parse_spec(
        {
            "study": {"name": "t", "sampler": sampler, "pruner": pruner, "n_trials": 2},
            "evaluation": {"report_points": 4, "n_warmup_steps": 1, "n_startup_trials": 2},
            "space": {"learning_rate": {"low": 1e-4, "high": 1e-2, "log": True}},
            "resources": {"workers": 2},
        }
    )


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_every_sampler_is_seeded(sampler: str) -> None:
    def draws() -> list[float]:
        study = optuna.create_study(direction="maximize", sampler=make_sampler(_spec(sampler, "none"), 5))  # type: ignore[arg-type]
        out = []
        for i in range(3):
            trial = study.ask()
            out.append(trial.suggest_float("learning_rate", 1e-4, 1e-2, log=True))
            study.tell(trial, float(i))
        return out

    assert draws() == draws()


PRUNER_CLASSES = {
    "median": optuna.pruners.MedianPruner,
    "hyperband": optuna.pruners.HyperbandPruner,
    "sha": optuna.pruners.SuccessiveHalvingPruner,
    "wilcoxon": optuna.pruners.WilcoxonPruner,
    "none": optuna.pruners.NopPruner,
}


@pytest.mark.parametrize("pruner", PRUNERS)
def test_every_pruner_runs_on_the_report_schedule(pruner: str) -> None:
    """Four good trials, then a hopeless one: the median pruner stops it after the warm-up step; none never does."""
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    made = make_pruner(_spec("random", pruner))  # type: ignore[arg-type]
    assert type(made) is PRUNER_CLASSES[pruner]
    study = optuna.create_study(direction="maximize", pruner=made)
    stopped_at = []
    for i in range(5):
        trial = study.ask()
        for k in range(4):
            trial.report(0.0 if i == 4 else 60.0 + i + k, step=k)
            if trial.should_prune():
                stopped_at.append(k)
                study.tell(trial, state=optuna.trial.TrialState.PRUNED)
                break
        else:
            study.tell(trial, 0.0 if i == 4 else 60.0 + i)
    if pruner == "median":
        assert stopped_at == [1]  # n_warmup_steps = 1: step 0 is never pruned
    if pruner == "none":
        assert stopped_at == []


def test_trial_seeds_are_stable_and_distinct() -> None:
    seeds = [trial_seed(0, n) for n in range(100)]
    assert seeds == [trial_seed(0, n) for n in range(100)]
    assert len(set(seeds)) == 100 and trial_seed(1, 0) != seeds[0]
    assert all(0 <= s < 2**31 for s in seeds)


def test_process_identity() -> None:
    import os

    me = os.getpid()
    assert process_alive(me, process_start(me))
    assert not process_alive(me, (process_start(me) or 0) + 1)
    assert not process_alive(2**22 + 12345, None)
