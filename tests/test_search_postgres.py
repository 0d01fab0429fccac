"""A study shared through a real PostgreSQL server (``tests/postgres.py``): several drivers, heartbeats,
inspection, `autotune launch` with 2 Ray workers, and a trial retrained to its exact score."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import optuna
import pytest
from optuna.trial import TrialState

from autotune import cli
from autotune.search.records import best_trial_record, study_summary
from autotune.search.storage import GRACE_PERIOD_S, HEARTBEAT_INTERVAL_S, load_study, open_storage
from tests.conftest import ROOT
from tests.postgres import PostgresServer
from tests.test_search_inspect import VALUES, make_study
from tests.test_search_storage import check_shared_study, run_two_drivers


def test_postgresql_storage_opens_with_psycopg3_and_heartbeats(postgres_url, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # its artifact store: runs/pg/artifacts
    st = open_storage(postgres_url, "pg")
    assert st.kind == "postgresql" and st.url == postgres_url
    assert st.storage.url.startswith("postgresql+psycopg://")  # the installed driver, not psycopg2
    assert st.storage.get_heartbeat_interval() == HEARTBEAT_INTERVAL_S and st.storage.grace_period == GRACE_PERIOD_S
    assert st.storage.engine_kwargs["pool_pre_ping"] is True


def test_two_drivers_share_one_study(postgres_url, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the drivers' artifact store: runs/shared/artifacts
    run_two_drivers(postgres_url, "shared", tmp_path)
    check_shared_study(postgres_url, "shared", tmp_path)


@pytest.mark.filterwarnings("ignore::UserWarning", "ignore::optuna.exceptions.ExperimentalWarning")
def test_stale_running_trial_is_failed_by_heartbeat(postgres_url, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    st = open_storage(postgres_url, "beat")
    study = optuna.create_study(study_name="beat", storage=st.storage)
    trial = study.ask()  # a driver that starts a trial, beats once, then dies
    st.storage.record_heartbeat(trial._trial_id)
    monkeypatch.setattr(st.storage, "grace_period", 1)  # instead of waiting GRACE_PERIOD_S
    time.sleep(2.2)
    assert optuna.storages.fail_stale_trials(study) is None
    assert study.trials[0].state == optuna.trial.TrialState.FAIL


def test_status_and_best_on_postgresql(postgres_url, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    make_study(open_storage(postgres_url, "inspect"), "inspect")
    assert cli.main(["status", "inspect", "--storage", postgres_url, "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["states"]["COMPLETE"] == 2 and summary["best"]["value"] == VALUES[1]
    assert cli.main(["best", "inspect", "--storage", postgres_url, "--export", "out"]) == 0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["net.config.json", "net.js", "net.json"]


@pytest.fixture(scope="module")
def pg_smoke(postgres_server: PostgresServer, tmp_path_factory: pytest.TempPathFactory) -> tuple[str, Path]:
    """The smoke study run by `autotune launch` with 2 Ray workers against PostgreSQL: (URL, working dir)."""
    url = postgres_server.create_database("smoke_launch")
    cwd = tmp_path_factory.mktemp("pg_smoke")
    proc = subprocess.run(
        [sys.executable, "-m", "autotune.cli", "launch", str(ROOT / "study_configs" / "smoke.toml"),
         "--storage", url, "--workers", "2", "--n-trials", "4", "--quiet"],
        cwd=cwd, env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    return url, cwd


def test_launch_with_two_workers_on_postgresql(pg_smoke):
    url, cwd = pg_smoke
    st = open_storage(url, "smoke", heartbeat=False, artifacts=cwd / "runs" / "smoke" / "artifacts")
    trials = load_study(st, "smoke").get_trials()
    assert len(trials) == 4
    assert all(t.state in (TrialState.COMPLETE, TrialState.PRUNED) for t in trials), [t.state for t in trials]
    assert len({t.user_attrs["worker"] for t in trials}) == 2  # both long-lived workers ran trials
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    assert complete and all(t.user_attrs["artifact_net_json"] and t.user_attrs["curve"] for t in complete)
    summary = study_summary(st, "smoke")
    assert summary["states"]["RUNNING"] == 0 and summary["best"]["value"] == max(t.value for t in complete)


def test_retrain_reproduces_a_trial_score_exactly(pg_smoke, capsys, monkeypatch):
    url, cwd = pg_smoke
    monkeypatch.chdir(cwd)  # the study's artifact store: runs/smoke/artifacts
    st = open_storage(url, "smoke", heartbeat=False)
    number = best_trial_record(st, "smoke")["number"]
    assert cli.main(["evaluate", "--trial", f"smoke:{number}", "--storage", url, "--retrain", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["how"] == "retrain" and rep["identical"] is True and rep["stored"] == rep["reproduced"]
    assert cli.main(["evaluate", "--trial", f"smoke:{number}", "--storage", url]) == 0  # the stored net, re-scored
    assert "— identical" in capsys.readouterr().out
