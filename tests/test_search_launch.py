"""``autotune launch`` end to end: the smoke study through the real CLI (real Ray, real journal file), and bad input.

The helpers here (a spec writer, a launcher that tags the driver's environment, the study loader
and the leftover-process finder) are shared by the fault and cluster tests. Every process Ray
starts for a driver inherits the driver's environment, so a unique tag in it finds them all — and
nothing another user's Ray runs.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import tomllib
import uuid
from pathlib import Path
from typing import Any

import optuna
import pytest

from autotune import loads_net
from autotune.cli import main
from tests.conftest import SmokeLaunch

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "study_configs" / "smoke.toml"
CONTRACT_ATTRS = {
    "source", "config", "settings", "seed", "curve", "input_size", "num_states", "param_count", "frames_simulated",
    "train_seconds", "eval_seconds", "official_protocol", "official_mean", "official_std", "diverged", "worker",
    "artifact_net_json", "artifact_net_js",
}  # fmt: skip


# -- helpers (shared with test_search_faults.py and test_search_cluster.py) -------------------------
def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(v)


def write_spec(directory: Path, name: str, **tables: dict[str, Any]) -> Path:
    """smoke.toml with some keys of some tables changed, written to ``directory/<name>.toml``."""
    data = tomllib.loads(SMOKE.read_text())
    data["study"]["name"] = name
    for table, changes in tables.items():
        data.setdefault(table, {}).update(changes)
    text = "\n".join(
        f"[{table}]\n" + "".join(f"{k} = {_toml_value(v)}\n" for k, v in values.items())
        for table, values in data.items()
    )
    path = directory / f"{name}.toml"
    path.write_text(text)
    return path


def launch(cwd: Path, *args: str, tag: str) -> subprocess.Popen[str]:
    """``autotune launch ARGS`` in ``cwd`` (its runs/ lands there); ``tag`` marks every process it starts."""
    env = {**os.environ, "AUTOTUNE_TEST_TAG": tag, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen(
        [sys.executable, "-m", "autotune.cli", "launch", *args, "--quiet"],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def finish(proc: subprocess.Popen[str], timeout: float = 300) -> tuple[int, str, str]:
    """Wait for a launch; (exit status, stdout, stderr)."""
    out, err = proc.communicate(timeout=timeout)
    return proc.returncode, out, err


def load(cwd: Path, name: str, storage: str = "") -> optuna.Study:
    """The study as stored (embedded journal by default)."""
    from autotune.search.storage import load_study, open_storage

    journal = str(cwd / "runs" / name / "journal.log")
    opened = open_storage(storage or journal, name, heartbeat=False, artifacts=cwd / "runs" / name / "artifacts")
    return load_study(opened, name)


def tagged_processes(tag: str) -> list[int]:
    """Live processes (not this one) whose environment carries ``AUTOTUNE_TEST_TAG=tag``."""
    needle = f"AUTOTUNE_TEST_TAG={tag}".encode()
    found = []
    for env in Path("/proc").glob("[0-9]*/environ"):
        try:
            if needle in env.read_bytes().split(b"\0") and int(env.parent.name) != os.getpid():
                stat = (env.parent / "stat").read_text()
                if stat[stat.rindex(")") + 2] != "Z":  # a zombie is already dead
                    found.append(int(env.parent.name))
        except OSError:
            continue
    return found


def wait_until(predicate: Any, timeout: float, what: str, poll: float = 0.25) -> Any:
    """Poll ``predicate`` until it returns something truthy; fail naming ``what`` after ``timeout`` s."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(poll)
    pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}")


def check_finished_trials(study: optuna.Study) -> None:
    """Contract checks on every trial: none RUNNING; records and curves of the finished ones; causes."""
    states = optuna.trial.TrialState
    assert not [t.number for t in study.trials if t.state == states.RUNNING]
    for t in study.trials:
        if t.state == states.COMPLETE:
            assert CONTRACT_ATTRS <= set(t.user_attrs), (t.number, CONTRACT_ATTRS - set(t.user_attrs))
            curve = t.user_attrs["curve"]
            assert [p["step"] for p in curve] == sorted(t.intermediate_values)
            assert [p["quick_score"] for p in curve] == [t.intermediate_values[p["step"]] for p in curve]
            host, _, pid = t.user_attrs["worker"].rpartition(":")
            assert host and pid.isdigit()
        elif t.state == states.PRUNED:
            assert t.user_attrs["cause"]
        elif t.state == states.FAIL:
            assert t.user_attrs.get("cause"), t.number


# -- the smoke study ------------------------------------------------------------------------------
def test_smoke_study_end_to_end(smoke_launch: SmokeLaunch) -> None:
    tmp_path, tag, rc, out, err, wall = (smoke_launch.cwd, smoke_launch.tag, smoke_launch.rc, smoke_launch.out,
                                         smoke_launch.err, smoke_launch.wall)  # fmt: skip
    assert rc == 0, err[-3000:]
    assert "Traceback" not in err
    study = load(tmp_path, "smoke")
    states = [t.state for t in study.trials]
    assert len(states) == 4 and all(s.is_finished() for s in states)
    assert states.count(optuna.trial.TrialState.COMPLETE) >= 2
    check_finished_trials(study)
    spec = study.user_attrs["spec"]
    assert spec["study"]["name"] == "smoke" and spec["evaluation"]["report_points"] == 3

    from optuna.artifacts import FileSystemArtifactStore, download_artifact

    store = FileSystemArtifactStore(str(tmp_path / "runs" / "smoke" / "artifacts"))
    best = study.best_trial
    net_path = tmp_path / "best.json"
    download_artifact(artifact_store=store, file_path=str(net_path), artifact_id=best.user_attrs["artifact_net_json"])
    net = loads_net(net_path.read_text())
    assert net.params[0][0].shape[1] == best.user_attrs["input_size"]
    js_path = tmp_path / "best.js"
    download_artifact(artifact_store=store, file_path=str(js_path), artifact_id=best.user_attrs["artifact_net_js"])
    assert "layer_defs" in js_path.read_text()
    assert best.user_attrs["seed"] != study.trials[0].user_attrs["seed"] or best.number == 0

    assert f"best: trial {best.number}: {best.value:.2f} mph" in out
    assert "dashboard: autotune dashboard smoke" in out
    assert tagged_processes(tag) == [], "Ray processes left after a normal exit"
    assert not list((tmp_path / "runs" / "smoke" / "ray").glob("*.json")), "session record left behind"
    print(f"smoke study: {wall:.1f} s wall")

    # the budget is spent: a rerun starts no trial and exits 0 at once (no Ray either)
    rc, out, err = finish(launch(tmp_path, str(SMOKE), tag=tag))
    assert rc == 0, err[-2000:]
    assert len(load(tmp_path, "smoke").trials) == 4


# -- bad input: one line on stderr, exit 2, before any worker starts -----------------------------
def _bad(tmp_path: Path, capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        rc = main(["launch", *argv, "--quiet"], owns_process=False)
    finally:
        os.chdir(cwd)
    captured = capsys.readouterr()
    assert rc == 2, captured.err
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), captured.err
    assert not (tmp_path / "runs").exists() or not list((tmp_path / "runs").rglob("ray/*.json"))
    return lines[0]


@pytest.mark.parametrize(
    ("text", "expect"),
    [
        ("[study]\nname = 'x'\nn_trials = 2\nsampler = \n", ["bad.toml"]),
        ("[study]\nn_trials = 2\nsampler = 'tpee'\n", ["bad.toml", "[study]", "sampler", "tpe"]),
        ("[study]\nn_trials = 2\npruner = 'meridian'\n", ["bad.toml", "[study]", "pruner"]),
        ("[study]\nn_trials = 2\n[space]\nlearning_rate = { low = 0.1, high = 0.01 }\n", ["[space]", "learning_rate"]),
        ("[study]\nn_trials = 2\n[fixed]\nlanesSidee = 2\n", ["[fixed]", "lanesSidee", "lanesSide"]),
        ("[study]\nn_trials = 2\n[fixed]\ngamma = 1.5\n", ["[fixed]", "gamma"]),
    ],
)
def test_bad_spec_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, expect: list[str]) -> None:
    (tmp_path / "bad.toml").write_text(text)
    line = _bad(tmp_path, capsys, str(tmp_path / "bad.toml"))
    for word in expect:
        assert word in line, line


def test_unreachable_storage_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    t0 = time.perf_counter()
    line = _bad(tmp_path, capsys, str(SMOKE), "--storage", "postgresql://u@127.0.0.1:1/x")
    assert "postgresql://u@127.0.0.1:1/x" in line and time.perf_counter() - t0 < 30


def test_bad_arguments_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert "--workers" in _bad(tmp_path, capsys, str(SMOKE), "--workers", "0")
    assert "--address" in _bad(tmp_path, capsys, str(SMOKE), "--address", "nowhere")
    assert "missing.toml" in _bad(tmp_path, capsys, str(tmp_path / "missing.toml"))


def test_timeout_budget_stops_starting_trials(tmp_path: Path) -> None:
    """--timeout: no trial starts after it (the Ray start and warm-up count), running ones finish; exit 0."""
    tag = uuid.uuid4().hex
    spec = write_spec(tmp_path, "timed", study={"n_trials": 1000, "pruner": "none"}, resources={"workers": 1})
    t0 = time.perf_counter()
    rc, out, err = finish(launch(tmp_path, str(spec), "--timeout", "20", tag=tag))
    wall = time.perf_counter() - t0
    assert rc == 0, err[-3000:]
    study = load(tmp_path, "timed")
    check_finished_trials(study)
    assert len(study.trials) < 1000 and all(t.state.is_finished() for t in study.trials)
    last_start = max((t.datetime_start for t in study.trials if t.datetime_start), default=None)
    if last_start is not None:  # nothing started later than the timeout after the driver began
        first = min(t.datetime_start for t in study.trials if t.datetime_start)
        assert (last_start - first).total_seconds() < 20
    assert wall < 20 + 60 and tagged_processes(tag) == []
