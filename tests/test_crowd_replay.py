"""``autotune crowd replay``: crowd settings retrained by the search driver and scored by the exact engine.

End to end through the real CLI (a subprocess: real Ray, real journal file) on two small crowd
settings — one v2, one v1 — trained for their full ``trainIterations`` (an honest replay; the
filter picks short ones instead). Then the driver's enqueued-full-config path without Ray: the
task it hands a worker, and a retry that keeps what the trial was enqueued with.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import uuid
from pathlib import Path

import optuna
import pytest

from autotune.learner.config import TrainConfig
from autotune.search import keys
from autotune.search.driver import Driver
from autotune.search.enqueue import replay_spec
from autotune.search.storage import load_study, open_storage
from dashboards import crowd, crowd_data
from dashboards.crowd_replay import enqueue_replay, replay_seed
from tests.conftest import FakePool
from tests.test_search_launch import check_finished_trials, tagged_processes, wait_until

# short crowd settings (≤ 2,300 weights): 5,000 iterations (one v2 row), or v1 ones above 70.5 mph (10,000 iterations)
SMALL = "n_params <= 2300 and (trainIterations == 5000 or reported_score_mph > 70.5 and trainIterations <= 10000)"
PICKED = ("dt-lupuleasa-core-deeptraffic-v11", "dt-rahulpawar1489-deeptraffic-v07")  # the first 2 of 4, CSV order


def replay(cwd: Path, *args: str, tag: str) -> tuple[int, str, str]:
    """``autotune crowd replay ARGS`` in ``cwd``; ``tag`` marks every process it starts."""
    env = {**os.environ, "AUTOTUNE_TEST_TAG": tag, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.run(
        [sys.executable, "-m", "autotune.cli", "crowd", "replay", *args],
        cwd=cwd, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    return proc.returncode, proc.stdout, proc.stderr


def test_replay_trains_crowd_settings_and_a_rerun_runs_nothing(tmp_path: Path) -> None:
    tag = uuid.uuid4().hex
    storage = str(tmp_path / "replay.log")
    args = ("--storage", storage, "--filter", SMALL, "--limit", "2", "--workers", "1")
    t0 = time.perf_counter()
    rc, out, err = replay(tmp_path, *args, tag=tag)
    first_s = time.perf_counter() - t0
    assert rc == 0, err
    assert "2 crowd setting(s) selected; 2 trial(s) enqueued" in out and "ran 2 trial(s)" in out, out
    study = load_study(open_storage(storage, "crowd-replay", heartbeat=False), "crowd-replay")
    check_finished_trials(study)
    subs = {s.id: s for s in crowd_data.load_submissions() if s.id in PICKED}
    assert [t.user_attrs["crowd_id"] for t in study.trials] == list(PICKED)
    for t in study.trials:
        sub = subs[t.user_attrs["crowd_id"]]
        config = crowd_data.train_config(sub)
        assert t.state == optuna.trial.TrialState.COMPLETE and t.value is not None and 30 < t.value < 90
        assert t.user_attrs["seed"] == replay_seed(sub.id, 0) and t.user_attrs["seed_index"] == 0
        assert t.user_attrs["config"] == config.to_mapping()  # the submission's own settings, all of them
        assert t.user_attrs["official_protocol"] == {"v2": "v2-official", "v1": "v1-original"}[sub.engine_version]
        # full training: training frames (30 per iteration) + 5 quick scores of 10 × 2,000 + the official runs
        assert t.user_attrs["frames_simulated"] >= 30 * config.train_iterations + 1_000_000
        assert len(t.intermediate_values) == 5
        expected = crowd.crowd_params(config)
        assert {k: t.params[k] for k in expected} == pytest.approx(expected)
    table = out[out.index("crowd id") :].splitlines()
    assert table[0].split() == ["crowd", "id", "engine", "self-reported", "replayed", "mean", "sd", "seeds"]
    for line, t in zip(table[1:], study.trials, strict=True):
        sub = subs[t.user_attrs["crowd_id"]]
        assert line.split() == [sub.id, sub.engine_version, f"{sub.reported_score_mph:.2f}", f"{t.value:.2f}", "—", "1"]
    print(f"\nreplay of 2 settings on 1 worker: {first_s:.1f} s\n{chr(10).join(table)}")

    t0 = time.perf_counter()
    rc, out, err = replay(tmp_path, *args, tag=tag)
    assert rc == 0, err
    assert "0 trial(s) enqueued, 2 already there" in out and "nothing to run" in out, out
    assert time.perf_counter() - t0 < 20  # no Ray, no training
    again = load_study(open_storage(storage, "crowd-replay", heartbeat=False), "crowd-replay")
    assert [(t.state, t.value, t.datetime_complete) for t in again.trials] == [
        (t.state, t.value, t.datetime_complete) for t in study.trials
    ]
    rc, out, err = replay(tmp_path, *args, "--seeds", "2", "--enqueue-only", tag=tag)
    assert rc == 0 and "2 trial(s) enqueued, 2 already there" in out and "ran " not in out, (out, err)
    waiting = load_study(open_storage(storage, "crowd-replay"), "crowd-replay").trials[2:]
    assert [(t.state, t.user_attrs["seed_index"]) for t in waiting] == [(optuna.trial.TrialState.WAITING, 1)] * 2
    wait_until(lambda: not tagged_processes(tag), 30, "the replay's Ray processes to end")


def test_driver_trains_an_enqueued_full_config_and_its_retry_keeps_it(tmp_path: Path) -> None:
    by_id = {s.id: s for s in crowd_data.load_submissions()}
    v1 = by_id["dt-rahulpawar1489-deeptraffic-v05"]  # sgd, l1 0, its own start_learn_threshold: not all params
    odd = by_id["dt-blackvitriol-rl-v00"]  # fc:1:softmax → neurons_0 = 1, activation_0 'linear': beyond paper.toml
    configs = {sub.id: crowd_data.train_config(sub) for sub in (v1, odd)}
    storages = open_storage(str(tmp_path / "j.log"), "r")
    spec = replay_spec(
        "r", storage="", workers=1, n_trials=2, params=[crowd.crowd_params(c) for c in configs.values()],
        activations=crowd.ACTIVATION_CHOICES,
    )  # fmt: skip
    assert spec.study.pruner == "none" and spec.evaluation.final_protocol == "v2-official"  # the space's ruleset
    assert spec.dimensions["neurons"].low == 1 and "linear" in spec.dimensions["activation"].choices
    driver = Driver(spec, storages)
    study = driver.open_study()
    assert enqueue_replay(storages, "r", [v1, odd], seeds=1)[:2] == (2, 0)
    driver.pool = FakePool()
    assert driver._launch_next(0) and driver._launch_next(1)
    for task, sub in zip(driver.pool.tasks, (v1, odd), strict=True):
        assert TrainConfig.from_mapping(task.config) == configs[sub.id] and task.config == configs[sub.id].to_mapping()
        assert task.final_protocol == "" and task.seed == replay_seed(sub.id, 0)  # '': the config's own ruleset's
        assert task.timeout_s == spec.study.trial_timeout_s >= 3600
    params = driver._running[1].trial.params
    assert (params["n_layers"], params["neurons_0"], params["activation_0"]) == (1, 1, "linear")
    run = driver._running.pop(0)
    driver._fail(run.trial, "lost: worker died", retryable=True)
    driver._enqueue_retries()
    retry = study.get_trials(states=(optuna.trial.TrialState.WAITING,))
    assert len(retry) == 1 and retry[0].user_attrs[keys.CONFIG] == configs[v1.id].to_mapping()
    assert retry[0].user_attrs["crowd_id"] == v1.id and retry[0].user_attrs["retry_of"] == run.trial.number
    assert driver._launch_next(0) and driver.pool.tasks[2].config == driver.pool.tasks[0].config
    assert driver.pool.tasks[2].seed == driver.pool.tasks[0].seed


TINY = ("dt-m-quadra-deeptraffic-v04", "dt-rahulpawar1489-deeptraffic-v15")  # v2 (3,834 weights), v1 (8,725)


def test_replay_table_command_end_to_end(tmp_path: Path) -> None:
    """``tools/crowd_measurements.py replay`` on two selected configurations (one per engine) × 2 seeds, capped at
    200 iterations: the table ships claimed, each seed's official score, mean, sd, n and seconds; a rerun trains
    nothing; a seed retrained in this process gives the same score."""
    from dashboards import crowd_replay, extract, figures, measured

    out, work = tmp_path / "replay.json", tmp_path / "work"
    args = ["replay", "--ids", *TINY, "--seeds", "2", "--max-iterations", "200", "--work", str(work), "--out", str(out)]
    script = Path(__file__).resolve().parents[1] / "tools" / "crowd_measurements.py"
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, str(script), *args], cwd=tmp_path, capture_output=True, text=True,
                          timeout=600)  # fmt: skip
    seconds = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr
    table = measured.load_replay(out)
    assert table is not None and (table.seeds, table.max_iterations) == (2, 200)
    assert table.command == "python tools/crowd_measurements.py " + " ".join(args)
    subs = {s.id: s for s in crowd_data.load_submissions()}
    assert [e.crowd_id for e in table.entries] == list(TINY)
    for e in table.entries:
        sub = subs[e.crowd_id]
        assert (e.engine, e.protocol, e.train_iterations, e.claimed) == (
            sub.engine_version, {"v1": "v1-original", "v2": "v2-official"}[sub.engine_version], 200,
            sub.reported_score_mph,
        )  # fmt: skip
        assert e.other_agents == sub.other_agents and e.config_hash == sub.config_hash
        assert [(r.seed_index, r.seed, r.state) for r in e.runs] == [
            (k, replay_seed(e.crowd_id, k), "complete") for k in range(2)
        ]
        assert all(0 <= s < 90 for s in e.scores) and e.sd is not None and e.seconds > 0  # 200 iterations: any speed
    doc = json.loads(out.read_text())
    assert [(d["n"], d["mean"]) for d in doc["entries"]] == [(2, e.mean) for e in table.entries]
    assert len(list(work.glob("*.json"))) == 4
    print(f"\nreplay table of 2 configurations × 2 seeds (200 iterations): {seconds:.0f} s")
    # a rerun reads every seed from the work directory
    proc = subprocess.run([sys.executable, str(script), *args], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)  # fmt: skip
    assert proc.returncode == 0 and proc.stdout.count("(cached)") == 4, proc.stdout
    assert measured.load_replay(out) == table
    # the same seed trained here scores the same (the table is reproducible)
    (task, *_rest) = crowd_replay.replay_tasks([[subs[TINY[1]]]], 1, max_iterations=200)
    assert crowd_replay.run_task(task).score == table.entries[1].runs[0].score
    # and the report draws it: claim, each seed, mean ± sd, per engine
    fig = figures.replay_figure(extract.replay_table_rows(table))
    assert not isinstance(fig, extract.Empty) and sum(len(t.x) for t in fig.data) == 2 * (1 + 2 + 1)


def test_replay_table_command_rejects_bad_arguments(tmp_path: Path) -> None:
    script = Path(__file__).resolve().parents[1] / "tools" / "crowd_measurements.py"
    for args, message in (
        (["replay", "--ids", "dt-nobody-v00"], "--ids: dt-nobody-v00 not among the selected configurations"),
        (["replay", "--ids", TINY[0], "--seeds", "0"], "seeds: must be ≥ 1"),
        (["replay", "--ids", TINY[0], "--max-iterations", "0"], "max_iterations: must be ≥ 1"),
    ):
        proc = subprocess.run([sys.executable, str(script), *args, "--work", str(tmp_path / "w"), "--out",
                               str(tmp_path / "r.json")], capture_output=True, text=True, timeout=120)  # fmt: skip
        assert proc.returncode == 2 and message in proc.stderr and proc.stderr.count("\n") == 1, proc.stderr
    assert not (tmp_path / "r.json").exists()
