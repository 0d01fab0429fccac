"""``open_storage``: the embedded journal, a journal path, SQLite; several processes on one study; one-line errors."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import optuna
import pytest

from autotune.search.storage import (
    GRACE_PERIOD_S,
    HEARTBEAT_INTERVAL_S,
    StorageError,
    UnknownStudyError,
    display_url,
    load_study,
    open_storage,
    study_names,
)
from tests.conftest import ROOT

# One driver process: opens the storage, joins (or creates) the study, finishes N trials, each with a
# user attr and an artifact — what two `autotune launch` on one study do to the storage.
DRIVER = """
import sys, optuna
from autotune.search.storage import open_storage
storage, study_name, n, tag = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
optuna.logging.set_verbosity(optuna.logging.WARNING)
st = open_storage(storage, study_name)
study = optuna.create_study(study_name=study_name, storage=st.storage, direction="maximize", load_if_exists=True)
for i in range(n):
    trial = study.ask()
    x = trial.suggest_float("x", 0.0, 1.0)
    trial.set_user_attr("worker", tag)
    path = st.artifact_dir.parent / f"{tag}-{i}.txt"
    path.write_text(f"{tag} {i}")
    trial.set_user_attr("artifact", optuna.artifacts.upload_artifact(
        artifact_store=st.artifacts, file_path=str(path), study_or_trial=trial))
    path.unlink()
    study.tell(trial, x)
"""


def run_two_drivers(storage: str, study_name: str, cwd: Path, n: int = 15) -> None:
    """Two driver processes appending to one study at the same time."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", DRIVER, storage, study_name, str(n), tag],
            cwd=cwd,
            env=env,
            stderr=subprocess.PIPE,
            text=True,
        )
        for tag in ("a", "b")
    ]
    for p in procs:
        _, err = p.communicate(timeout=120)
        assert p.returncode == 0, err


def check_shared_study(storage: str, study_name: str, cwd: Path, n: int = 15) -> None:
    """Every trial of both drivers is there, COMPLETE, numbered without gaps, its artifact readable."""
    st = open_storage(storage, study_name)
    study = load_study(st, study_name)
    trials = study.get_trials()
    assert [t.number for t in trials] == list(range(2 * n))
    assert all(t.state == optuna.trial.TrialState.COMPLETE for t in trials)
    assert sorted(t.user_attrs["worker"] for t in trials) == ["a"] * n + ["b"] * n
    for t in trials[:: n // 3]:
        out = cwd / "download.txt"
        optuna.artifacts.download_artifact(
            artifact_store=st.artifacts, file_path=str(out), artifact_id=t.user_attrs["artifact"]
        )
        assert out.read_text().split()[0] == t.user_attrs["worker"]
        out.unlink()


def test_embedded_journal_two_processes(tmp_path, monkeypatch):
    run_two_drivers("", "shared", tmp_path)
    assert (tmp_path / "runs" / "shared" / "journal.log").is_file()
    monkeypatch.chdir(tmp_path)  # the embedded storage is relative to the working directory
    check_shared_study("", "shared", tmp_path)


def test_journal_path_and_sibling_artifacts(tmp_path):
    storage = str(tmp_path / "studies" / "x.journal")
    st = open_storage(storage, "any-name")
    assert st.kind == "journal" and st.url == storage
    assert st.artifact_dir == tmp_path / "studies" / "artifacts" and st.artifact_dir.is_dir()
    run_two_drivers(storage, "j", tmp_path, n=6)
    check_shared_study(storage, "j", tmp_path, n=6)


def test_sqlite_round_trip_with_heartbeats(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    url = f"sqlite:///{tmp_path / 'study.db'}"
    st = open_storage(url, "lite")
    assert st.kind == "sqlite" and st.url == url
    assert st.artifact_dir == Path("runs/lite/artifacts") and st.artifact_dir.is_dir()
    assert st.storage.get_heartbeat_interval() == HEARTBEAT_INTERVAL_S
    assert st.storage.grace_period == GRACE_PERIOD_S
    assert open_storage(url, "lite", heartbeat=False).storage.get_heartbeat_interval() is None
    other = open_storage(url, "lite", artifacts=tmp_path / "elsewhere")
    assert other.artifact_dir == tmp_path / "elsewhere" and other.artifact_dir.is_dir()
    run_two_drivers(url, "lite", tmp_path, n=6)
    check_shared_study(url, "lite", tmp_path, n=6)
    assert study_names(open_storage(url, "lite")) == ["lite"]


def test_display_url_masks_the_password():
    assert (
        display_url("postgresql://me:s3cret@db.example:5432/studies") == "postgresql://me:***@db.example:5432/studies"
    )
    assert display_url("postgresql://me:s3cret@[bad/x") == "postgresql://me:***@[bad/x"
    assert display_url("runs/x/journal.log") == "runs/x/journal.log"


def test_unknown_study_names_the_nearest(tmp_path):
    st = open_storage(str(tmp_path / "j.log"), "s")
    for name in ("quick", "paper", "smoke"):
        optuna.create_study(study_name=name, storage=st.storage)
    with pytest.raises(UnknownStudyError, match=r"no study 'quik'; did you mean 'quick'\? \(studies there: quick, "):
        load_study(st, "quik")


@pytest.mark.parametrize(
    ("storage", "expect"),
    [
        ("postgresql://u:pw@127.0.0.1:1/x", "storage 'postgresql://u:***@127.0.0.1:1/x': cannot connect"),
        ("postgresql://u@127.0.0.1:1/x", "check host, port, user, password and database"),
        ("mysql://u@127.0.0.1:1/x", "storage 'mysql://u@127.0.0.1:1/x'"),
        ("sqlite:////nonexistent/dir/study.db", "the directory /nonexistent/dir of the SQLite file does not exist"),
        ("/dev/null/study.log", "cannot open the journal file (/dev/null is not a directory)"),
        ("study.db", "expected a journal file (*.log or *.journal) or an SQLAlchemy URL"),
        ("redis://localhost/0", "SQLAlchemy has no database driver 'redis'"),
        ("postgresql://u:pw@host:notaport/x", "storage 'postgresql://u:***@host:notaport/x': not an SQLAlchemy URL"),
    ],
)
def test_unusable_storage_is_one_quick_line(storage, expect, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    t0 = time.perf_counter()
    with pytest.raises(StorageError) as info:
        open_storage(storage, "s")
    message = str(info.value)
    assert expect in message
    assert "\n" not in message and "pw" not in message
    assert time.perf_counter() - t0 < 8


def test_embedded_storage_needs_a_path_safe_study_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(StorageError, match=r"study name '\.\./x': the embedded storage is runs/<study>/"):
        open_storage("", "../x")
    assert not (tmp_path / "runs").exists()
