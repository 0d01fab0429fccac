"""A study shared through a real PostgreSQL server (``tests/postgres.py``): several drivers, heartbeats, inspection."""

from __future__ import annotations

import json
import time

import optuna
import pytest

from autotune import cli
from autotune.search.storage import GRACE_PERIOD_S, HEARTBEAT_INTERVAL_S, open_storage
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
