"""Fault tolerance with real processes: SIGKILL a Ray worker mid-trial, SIGKILL the driver mid-study, then resume.

Both run ``autotune launch`` as a subprocess on the embedded journal with one worker (cheap on a
2-core machine) and trials long enough (a few seconds) to be caught running. The worker's pid is
the one its actor reported (``TrialWorker.info``), read from the driver's session record.
"""

from __future__ import annotations

import json
import os
import signal
import uuid
from pathlib import Path
from typing import Any

import optuna

from tests.test_search_launch import (
    check_finished_trials,
    finish,
    launch,
    load,
    tagged_processes,
    wait_until,
    write_spec,
)

STATES = optuna.trial.TrialState


def _spec(tmp_path: Path, name: str, n_trials: int, iterations: int) -> Path:
    return write_spec(
        tmp_path,
        name,
        study={"n_trials": n_trials, "sampler": "random", "pruner": "none", "max_retries": 1, "timeout_s": 600},
        fixed={"trainIterations": iterations, "learning_steps_total": iterations},
        resources={"workers": 1},
    )


def _session(tmp_path: Path, name: str) -> dict[str, Any] | None:
    records = list((tmp_path / "runs" / name / "ray").glob("*.json"))
    if not records:
        return None
    info = json.loads(records[0].read_text())
    return info if info.get("workers") and all(info["workers"]) else None


def _trials(tmp_path: Path, name: str) -> list[optuna.trial.FrozenTrial]:
    if not (tmp_path / "runs" / name / "journal.log").exists():
        return []
    try:
        return load(tmp_path, name).trials
    except Exception:  # the study is being created
        return []


def _running_with_report(tmp_path: Path, name: str) -> optuna.trial.FrozenTrial | None:
    return next((t for t in _trials(tmp_path, name) if t.state == STATES.RUNNING and t.intermediate_values), None)


def test_worker_killed_mid_trial_fails_and_is_retried(tmp_path: Path) -> None:
    tag = uuid.uuid4().hex
    spec = _spec(tmp_path, "killworker", n_trials=2, iterations=12000)
    proc = launch(tmp_path, str(spec), tag=tag)
    try:
        session = wait_until(lambda: _session(tmp_path, "killworker"), 180, "the workers to start")
        victim = wait_until(lambda: _running_with_report(tmp_path, "killworker"), 120, "a trial to report")
        worker_pid = session["workers"][0]
        assert victim.user_attrs["worker"].endswith(f":{worker_pid}")
        os.kill(worker_pid, signal.SIGKILL)
        rc, out, err = finish(proc, 300)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert rc == 0, err[-3000:]
    study = load(tmp_path, "killworker")
    check_finished_trials(study)
    lost = study.trials[victim.number]
    assert lost.state == STATES.FAIL
    assert lost.user_attrs["cause"].startswith("worker lost: ") and str(worker_pid) in lost.user_attrs["cause"]
    retries = [t for t in study.trials if t.user_attrs.get("retry_of") == victim.number]
    assert len(retries) == 1
    retry = retries[0]
    assert retry.state == STATES.COMPLETE and retry.params == lost.params
    assert retry.user_attrs["seed"] == lost.user_attrs["seed"]
    assert not retry.user_attrs["worker"].endswith(f":{worker_pid}")  # a replacement worker ran it
    originals = [t for t in study.trials if "retry_of" not in t.user_attrs]
    assert len(originals) == 2 and len(study.trials) == 3  # the retry used no budget
    assert tagged_processes(tag) == []


def test_driver_killed_then_resumed(tmp_path: Path) -> None:
    tag = uuid.uuid4().hex
    spec = _spec(tmp_path, "killdriver", n_trials=3, iterations=8000)
    proc = launch(tmp_path, str(spec), tag=tag)
    try:
        wait_until(lambda: _session(tmp_path, "killdriver"), 180, "the workers to start")

        def one_done_one_running() -> optuna.trial.FrozenTrial | None:
            trials = _trials(tmp_path, "killdriver")  # one read: two could see the running trial finish between
            running = next((t for t in trials if t.state == STATES.RUNNING and t.intermediate_values), None)
            return running if any(t.state.is_finished() for t in trials) else None

        victim = wait_until(one_done_one_running, 180, "one finished trial and one running")
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
    orphans = tagged_processes(tag)  # Ray's agents (and maybe raylet/gcs) outlive a SIGKILLed driver
    print(f"processes left by the killed driver: {len(orphans)}")
    before = {t.number: t for t in load(tmp_path, "killdriver").trials}
    assert before[victim.number].state == STATES.RUNNING  # the dead driver left it so

    rc, out, err = finish(launch(tmp_path, str(spec), tag=tag), 300)
    assert rc == 0, err[-3000:]
    assert f"resumed: trials {victim.number} of a stopped driver" in out
    study = load(tmp_path, "killdriver")
    check_finished_trials(study)
    for number, old in before.items():  # nothing finished is lost or changed
        if old.state.is_finished():
            assert study.trials[number].state == old.state and study.trials[number].value == old.value
    failed = study.trials[victim.number]
    assert failed.state == STATES.FAIL and failed.user_attrs["cause"].startswith("driver lost: ")
    retry = [t for t in study.trials if t.user_attrs.get("retry_of") == victim.number]
    assert len(retry) == 1 and retry[0].state == STATES.COMPLETE and retry[0].params == failed.params
    assert len([t for t in study.trials if "retry_of" not in t.user_attrs]) == 3
    # nothing of either run is left: not the first run's Ray (killed on resume), not the second's
    assert tagged_processes(tag) == [], (orphans, tagged_processes(tag))
