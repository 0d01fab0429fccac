"""``autotune status | best | dashboard`` on a study in a real storage, with trials shaped like the trial contract."""

from __future__ import annotations

import datetime as dt
import json
import os
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import optuna
import pytest
from optuna.distributions import FloatDistribution, IntDistribution
from optuna.trial import TrialState, create_trial

import autotune
from autotune import cli
from autotune.convnet.spec import init_convnet
from autotune.search.storage import Storages, open_storage
from tests.conftest import ROOT

T0 = dt.datetime(2025, 3, 1, 12, 0, 0)
FRAMES = (1_000_000, 2_000_000, 400_000, 100_000)  # frames_simulated of trials 0..3
VALUES = (61.25, 70.5)  # the COMPLETE trials' official scores; trial 1 is the best


def trial_config(lr: float) -> autotune.TrainConfig:
    """A small v2 training config (the values only need to be valid, nothing trains here)."""
    return autotune.preset("network_basic_v2").replace(otherAgents=3, learning_rate=lr, layers="fc:6:tanh|fc:4:relu")


def make_study(storages: Storages, name: str) -> optuna.Study:
    """A finished study: trials 0 and 1 COMPLETE (with net.json / net.js artifacts), 2 PRUNED, 3 FAIL.

    Trial i starts at T0 + i·15 min and lasts 10 min (so the study spans 55 min), as a driver
    following the trial contract would have stored them.
    """
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(study_name=name, storage=storages.storage, direction="maximize")
    dists = {"learning_rate": FloatDistribution(1e-4, 1e-1, log=True), "batch_size": IntDistribution(8, 128)}
    states = (TrialState.COMPLETE, TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL)
    for i, state in enumerate(states):
        lr = 0.001 * (i + 1)
        config = trial_config(lr)
        attrs: dict = {
            "source": "autotune",
            "config": config.to_mapping(),
            "settings": config.to_deepqlearn(),
            "seed": 1000 + i,
            "curve": [{"step": 0, "frames": 5000, "quick_score": 55.0 + i}],
            "input_size": config.net_inputs,
            "num_states": config.num_states,
            "param_count": 123 + i,
            "frames_simulated": FRAMES[i],
            "train_seconds": 500.0,
            "eval_seconds": 60.0,
            "worker": "host:1",
            "diverged": False,
        }
        if state == TrialState.COMPLETE:
            net = init_convnet(config.expanded_layers, seed=i)
            settings = config.settings
            files = {"net.json": autotune.dumps_net(net), "net.js": autotune.export_netjs(net, settings)}
            for fname, text in files.items():
                path = storages.artifact_dir.parent / f"upload-{i}-{fname}"
                path.write_text(text)
                key = "artifact_net_json" if fname == "net.json" else "artifact_net_js"
                attrs[key] = optuna.artifacts.upload_artifact(
                    artifact_store=storages.artifacts, file_path=str(path), study_or_trial=study
                )
                path.unlink()
            attrs.update(official_protocol="v2-official", official_mean=VALUES[i] - 0.5, official_std=3.0)
        else:
            attrs["cause"] = "pruned at step 1 (median)" if state == TrialState.PRUNED else "worker died (SIGKILL)"
        trial = create_trial(
            state=state,
            value=VALUES[i] if state == TrialState.COMPLETE else None,
            params={"learning_rate": lr, "batch_size": 32 + i},
            distributions=dists,
            user_attrs=attrs,
            intermediate_values={0: 55.0 + i},
        )
        trial.datetime_start = T0 + dt.timedelta(minutes=15 * i)
        trial.datetime_complete = trial.datetime_start + dt.timedelta(minutes=10)
        study.add_trial(trial)
    return study


@pytest.fixture
def journal_study(tmp_path: Path) -> tuple[str, str, Storages]:
    storage = str(tmp_path / "s" / "journal.log")
    storages = open_storage(storage, "demo")
    make_study(storages, "demo")
    return storage, "demo", storages


def run_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_status_counts_best_and_throughput(journal_study, capsys):
    storage, study, _ = journal_study
    code, out, err = run_cli(capsys, "status", study, "--storage", storage, "--json")
    assert code == 0, err
    s = json.loads(out)
    assert s["states"]["COMPLETE"] == 2 and s["states"]["PRUNED"] == 1 and s["states"]["FAIL"] == 1
    assert s["states"]["RUNNING"] == 0 and s["n_trials"] == 4
    assert s["best"]["number"] == 1 and s["best"]["value"] == VALUES[1]
    assert s["best"]["params"] == {"learning_rate": 0.002, "batch_size": 33}
    assert s["best"]["reached_s"] == 25 * 60  # trial 1 finished 25 min after trial 0 started
    assert s["wall_seconds"] == 55 * 60
    assert s["trials_per_hour"] == pytest.approx(4 / (55 / 60))
    assert s["frames_per_second"] == pytest.approx(sum(FRAMES) / (55 * 60))
    assert s["prune_rate"] == pytest.approx(1 / 3)
    assert s["first_start"] == "2025-03-01T12:00:00" and s["last_finish"] == "2025-03-01T12:55:00"

    code, out, err = run_cli(capsys, "status", study, "--storage", storage)
    assert code == 0, err
    assert "2 complete, 1 pruned, 1 failed, 0 running" in out
    assert "best: trial 1, 70.50 mph after 25.0 min" in out
    assert "4.4 trials/h" in out


def test_best_json_and_export(journal_study, capsys, tmp_path):
    storage, study, storages = journal_study
    out_dir = tmp_path / "export"
    code, out, err = run_cli(capsys, "best", study, "--storage", storage, "--export", str(out_dir), "--json")
    assert code == 0, err
    rec = json.loads(out)
    assert rec["number"] == 1 and rec["value"] == VALUES[1] and rec["seed"] == 1001
    assert rec["config"] == trial_config(0.002).to_mapping()
    assert rec["official_protocol"] == "v2-official" and rec["param_count"] == 124
    assert sorted(rec["exported"]) == ["net.config.json", "net.js", "net.json"]

    config = trial_config(0.002)
    net = init_convnet(config.expanded_layers, seed=1)
    assert (out_dir / "net.json").read_text() == autotune.dumps_net(net)  # the trained weights, unchanged
    assert (out_dir / "net.js").read_text() == autotune.export_netjs(net, config.settings)
    cfg = json.loads((out_dir / "net.config.json").read_text())
    assert cfg["lanesSide"] == 1 and cfg["otherAgents"] == 3 and cfg["learning_rate"] == 0.002
    assert cfg["hidden_layers"] == "fc:6:tanh|fc:4:relu" and cfg["engine_version"] == "v2"
    loaded_net, settings = autotune.load_net_and_settings(out_dir / "net.json")  # what `autotune evaluate` reads
    assert settings == config.settings
    assert autotune.dumps_net(loaded_net) == autotune.dumps_net(net)

    code, out, err = run_cli(capsys, "best", study, "--storage", storage)
    assert code == 0, err
    assert out.startswith("best trial 1 of demo: 70.50 mph (v2-official), seed 1001, 124 parameters")
    assert "  learning_rate = 0.002" in out


def test_embedded_default_storage(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    storages = open_storage("", "embedded")
    make_study(storages, "embedded")
    assert (tmp_path / "runs" / "embedded" / "journal.log").stat().st_size > 0
    assert any((tmp_path / "runs" / "embedded" / "artifacts").iterdir())
    code, out, err = run_cli(capsys, "best", "embedded", "--export", "out")
    assert code == 0, err
    assert (tmp_path / "out" / "net.js").exists()


def test_a_run_directory_names_its_study(journal_study, capsys, tmp_path):
    """STUDY with a '/' is a run directory: its journal.log and artifacts, the name from its study.toml (a
    benchmark's directory cold-s0 holds study sq-cold-s0), else the directory's name; no journal is one line."""
    storage, _, _ = journal_study
    run_dir = Path(storage).parent
    code, out, err = run_cli(capsys, "best", str(run_dir), "--export", str(tmp_path / "e"))
    assert code == 2 and "no study 's'" in err  # no study.toml: the directory's name, which holds no such study
    (run_dir / "study.toml").write_text('[study]\nname = "demo"\n')
    code, out, err = run_cli(capsys, "best", str(run_dir), "--export", str(tmp_path / "e"))
    assert code == 0, err
    assert out.startswith("best trial 1 of demo: 70.50 mph") and (tmp_path / "e" / "net.js").exists()
    code, out, err = run_cli(capsys, "status", str(run_dir) + "/", "--json")
    assert code == 0 and json.loads(out)["best"]["number"] == 1
    code, out, err = run_cli(capsys, "best", str(tmp_path / "nowhere"))
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "no journal.log in that directory; give a study name (runs/<study>/)" in err
    (run_dir / "study.toml").write_text("[study]\n")
    code, out, err = run_cli(capsys, "best", str(run_dir))
    assert code == 2 and "study.toml: no [study] name to read" in err


def test_unknown_study_lists_the_storage_studies(journal_study, capsys):
    storage, _, _ = journal_study
    code, out, err = run_cli(capsys, "status", "dmeo", "--storage", storage)
    assert code == 2 and out == ""
    assert err.count("\n") == 1
    assert "no study 'dmeo'; did you mean 'demo'? (studies there: demo)" in err


def test_best_without_a_complete_trial(tmp_path, capsys):
    storage = str(tmp_path / "j.log")
    storages = open_storage(storage, "empty")
    optuna.create_study(study_name="empty", storage=storages.storage, direction="maximize")
    code, out, err = run_cli(capsys, "best", "empty", "--storage", storage)
    assert code == 1 and err.startswith("error: study 'empty'") and "no COMPLETE trial yet" in err
    code, out, err = run_cli(capsys, "status", "empty", "--storage", storage)
    assert code == 0 and "best: no complete trial yet" in out


def test_unreachable_storage_is_one_line(capsys):
    t0 = time.perf_counter()
    code, out, err = run_cli(capsys, "status", "x", "--storage", "postgresql://u:secret@127.0.0.1:1/x")
    assert code == 2 and err.count("\n") == 1 and "secret" not in err
    assert err.startswith("error: storage 'postgresql+psycopg://u:***@127.0.0.1:1/x'") or "u:***@" in err
    assert time.perf_counter() - t0 < 10


def _get(url: str) -> bytes:
    with urllib.request.urlopen(url, timeout=10) as r:
        assert r.status == 200
        return r.read()


def test_dashboard_serves_the_study(journal_study):
    storage, study, storages = journal_study
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "autotune.cli", "dashboard", study, "--storage", storage, "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        env=env,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()  # printed once the socket listens
        assert "optuna-dashboard for" in line, proc.stderr.read() if proc.poll() is not None else line
        url = line.split(": ", 1)[1].split()[0]
        root = url.split("/dashboard/")[0]
        assert url == f"{root}/dashboard/studies/{storages.storage.get_study_id_from_name(study)}"
        assert b"<html" in _get(root + "/dashboard").lower()
        studies = json.loads(_get(root + "/api/studies"))["study_summaries"]
        assert [s["study_name"] for s in studies] == [study]
        detail = json.loads(_get(f"{root}/api/studies/{studies[0]['study_id']}?after=0"))
        assert len(detail["trials"]) == 4
        attrs = {a["key"]: a["value"] for a in detail["trials"][1]["user_attrs"]}
        net_id = attrs["artifact_net_json"]
        served = _get(f"{root}/artifacts/{studies[0]['study_id']}/{net_id}")  # the artifact store is attached
        assert served.decode() == autotune.dumps_net(init_convnet(trial_config(0.002).expanded_layers, seed=1))
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_evaluate_trial_rescores_and_says_when_the_score_differs(journal_study, capsys):
    storage, study, _ = journal_study
    # make_study stored untrained nets with made-up values: the exact re-score must not match them
    code, out, err = run_cli(capsys, "evaluate", "--trial", f"{study}:1", "--storage", storage, "--json")
    assert code == 1, err
    rep = json.loads(out)
    assert rep["stored"] == VALUES[1] and rep["reproduced"] != VALUES[1] and rep["identical"] is False
    assert rep["how"] == "rescore" and rep["protocol"] == "v2-official" and rep["seed"] == 1001


@pytest.mark.parametrize(
    ("argv", "expect"),
    [
        (["--trial", "demo:2"], "trial 2 is PRUNED; only COMPLETE trials have an official score to reproduce"),
        (["--trial", "demo:9"], "no trial 9 (trials are numbered 0 … 3)"),
        (["--trial", "demo"], "--trial: expected STUDY:N (e.g. quick:12), got 'demo'"),
        (["--trial", "dmeo:1"], "no study 'dmeo'; did you mean 'demo'?"),
        (["--retrain"], "--retrain: needs --trial STUDY:N"),
        (["--trial", "demo:1", "--net", "x.json"], "--trial: takes the net from the study; drop --net/--config"),
        ([], "--net: required (or --trial STUDY:N)"),
    ],
)
def test_evaluate_trial_bad_input(journal_study, capsys, argv, expect):
    storage, _, _ = journal_study
    code, out, err = run_cli(capsys, "evaluate", *argv, "--storage", storage)
    assert code == 2 and out == "" and err.count("\n") == 1 and expect in err


def test_read_only_commands_create_no_storage_for_a_missing_study(tmp_path: Path, monkeypatch, capsys) -> None:  # noqa: ANN001
    """status/best/dashboard/replay/compare on a study that was never launched: one line, exit 2, no runs/<name>/."""
    from autotune.cli import main as cli_main

    monkeypatch.chdir(tmp_path)
    for args in (
        ["status", "typo"],
        ["best", "typo"],
        ["replay", "typo", "--out", "r.html"],
        ["compare", "typo", "--out", "c.html"],
    ):
        assert cli_main(args, owns_process=False) == 2, args
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "no study 'typo'" in err[0], (args, err)
    assert not (tmp_path / "runs").exists()


def test_best_single_net_may_be_a_kept_rung(journal_study, capsys, tmp_path):
    """A pruned ladder trial's kept rung that outscored every trial's value is the best single net: ``best``
    names it and ``--export`` writes it with that rung's own settings (its budget, ε schedule scaled)."""
    from autotune.search.ladder import rung_config
    from autotune.search.records import best_net, read_study

    storage, name, storages = journal_study
    study = optuna.load_study(study_name=name, storage=storages.storage)
    top = trial_config(0.004).replace(train_iterations=9000, learning_steps_burnin=900, learning_steps_total=4500)
    net = init_convnet(top.expanded_layers, seed=7)
    path = tmp_path / "rung.json"
    path.write_text(autotune.dumps_net(net))
    rung_id = optuna.artifacts.upload_artifact(artifact_store=storages.artifacts, file_path=str(path),
                                               study_or_trial=study)  # fmt: skip
    attrs = {
        "config": top.to_mapping(), "seed": 77, "official_protocol": "v2-official",
        "rungs": [{"budget": 1000, "score": 71.0}, {"budget": 3000, "score": VALUES[1] + 1.5}],
        "artifact_rung_nets": {"3000": rung_id},  # the 1000 rung's net was not kept: not a candidate
        "cause": "pruned after rung 1 (3,000 iterations, 72.00 mph) by the pruner",
    }  # fmt: skip
    study.add_trial(create_trial(state=TrialState.PRUNED, user_attrs=attrs, intermediate_values={1: 71.0, 3: 72.0}))
    found = best_net(read_study(storages, name))
    assert found == {"trial": 4, "budget": 3000, "score": VALUES[1] + 1.5, "state": "PRUNED", "seed": 77,
                     "official_protocol": "v2-official", "epsilon_test_time": top.epsilon_test_time,
                     "lineage": []}  # fmt: skip

    out_dir = tmp_path / "export"
    code, out, err = run_cli(capsys, "best", name, "--storage", storage, "--export", str(out_dir), "--json")
    assert code == 0, err
    rec = json.loads(out)
    assert rec["number"] == 1 and rec["best_net"] == found  # the best trial stays the best value
    assert (out_dir / "net.json").read_text() == autotune.dumps_net(net)
    loaded, settings = autotune.load_net_and_settings(out_dir / "net.json")
    assert settings == rung_config(top, 3000).settings and settings.train_iterations == 3000
    assert (out_dir / "net.js").read_text() == autotune.export_netjs(loaded, settings)
    code, out, err = run_cli(capsys, "best", name, "--storage", storage)
    assert "best single net: trial 4's 3,000-iteration rung (pruned trial, seed 77), 72.00 mph" in out

    # under [ladder] reseed a rung records the seed it trained from, and that is the one reported
    rungs = [{"budget": 1000, "seed": 5, "score": 71.0}, {"budget": 3000, "seed": 91, "score": VALUES[1] + 2.0}]
    study.add_trial(create_trial(state=TrialState.PRUNED, user_attrs={**attrs, "rungs": rungs},
                                 intermediate_values={1: 71.0, 3: 72.5}))  # fmt: skip
    found = best_net(read_study(storages, name))
    assert found is not None and (found["trial"], found["budget"], found["seed"]) == (5, 3000, 91)

    # under [ladder] epsilon_test_grid a rung records the ε_test it chose for its net: reported, exported, printed
    rungs = [{"budget": 1000, "score": 71.0}, {"budget": 3000, "score": VALUES[1] + 2.5, "chosen_epsilon_test": 0.45}]
    study.add_trial(create_trial(state=TrialState.PRUNED, user_attrs={**attrs, "rungs": rungs},
                                 intermediate_values={1: 71.0, 3: 73.0}))  # fmt: skip
    found = best_net(read_study(storages, name))
    assert found is not None and (found["trial"], found["epsilon_test_time"]) == (6, 0.45)
    chosen = tmp_path / "chosen"
    code, out, err = run_cli(capsys, "best", name, "--storage", storage, "--export", str(chosen))
    assert code == 0, err
    assert "trial 6's 3,000-iteration rung (pruned trial, seed 77), 73.00 mph: a complete training at that " in out
    assert "scored officially at ε_test 0.45" in out
    _, settings = autotune.load_net_and_settings(chosen / "net.json")
    assert settings == rung_config(top, 3000).replace(epsilon_test_time=0.45).settings
