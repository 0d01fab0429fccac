"""Run replays (issue 9 §4): the recorded arrays against the engine, then the GIF/MP4/HTML outputs end to end."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import autotune
from autotune.cli import main
from autotune.convnet.netjson import load
from autotune.convnet.settings import Settings
from autotune.convnet.spec import ConvNet, init_convnet
from autotune.learner.brain_policy import evaluate_net
from dashboards.replay import (
    KIND_AGENT,
    KIND_EGO,
    SAFE_LANE_BLOCK,
    SAFE_SPEED_BLOCK,
    Recording,
    record_run,
)
from sim.config import ConfigError
from tests.browser import assert_page_ok

NETS = Path(__file__).resolve().parents[1] / "dashboards" / "data" / "crowd" / "nets"
V2_NET = NETS / "dt-luyao777-self-driving-v02.json"  # v2, 9 agents, temporal window 1, 75 kB
V1_NET = NETS / "dt-anuj-dimri25-deep-traffic-v00.json"  # v1, temporal window 3
FRAMES = 300


@pytest.fixture(scope="module")
def v2_rec() -> Recording:
    net, settings = load(V2_NET)
    return record_run(net, settings, name="luyao777-v02", seed=3, frames=FRAMES, run_frames=FRAMES)


def _truncated_mean(values: np.ndarray) -> float:
    return math.floor(float(np.mean(values)) * 2000.0 / 20.0) / 100.0  # run_score of mph/20


@pytest.mark.parametrize("path", [V2_NET, V1_NET], ids=["v2", "v1"])
def test_score_is_the_engines_for_the_same_seeded_run(path: Path) -> None:
    net, settings = load(path)
    rec = record_run(net, settings, seed=5, frames=FRAMES, run_frames=FRAMES)
    ref = evaluate_net(net, settings, "custom", seed=5, runs=1, frames=FRAMES)
    assert (rec.score, rec.ego_score) == (ref.scores[0], ref.ego_scores[0])
    # the recorded speeds are what the score counts: mean over frames (v2: of ego and agents, floored at 0)
    controlled = rec.kind <= KIND_AGENT
    term = np.maximum(rec.mph[:, controlled], 0.0).mean(axis=1) if rec.ruleset == "v2" else rec.mph[:, 0]
    assert abs(_truncated_mean(term) - rec.score) <= 0.011
    assert rec.running_score[-1] == pytest.approx(float(np.mean(term)), abs=1e-9)


@pytest.mark.parametrize("ruleset", ["v2", "v1"])
def test_grid_holds_exactly_the_cars_footprints(v2_rec: Recording, ruleset: str) -> None:
    rec = v2_rec if ruleset == "v2" else record_run(*load(V1_NET), frames=FRAMES)
    for j in range(len(rec)):
        expected = np.zeros((7, 70), dtype=bool)
        for i in range(20):
            x, y = rec.x[j, i], rec.y[j, i]
            r0, r1 = math.floor(y / 10), math.floor((y + 30) / 10)
            for lane in {math.floor(x / 20), math.floor((x + 10) / 20)}:
                if 0 <= lane < 7 and r1 >= 0 and r0 < 70:
                    expected[lane, max(r0, 0) : min(r1, 69) + 1] = True
        occupied = rec.grid[j] != rec.free  # v1 draws the ego with 10·c·a, usually ≥ free (7)
        assert np.array_equal(occupied, expected), f"frame {rec.frame[j]}"
    assert rec.kind[0] == KIND_EGO and np.sum(rec.kind == KIND_AGENT) == (9 if ruleset == "v2" else 0)


def test_input_slice_is_what_the_policy_received(v2_rec: Recording) -> None:
    rec = v2_rec
    assert np.array_equal(rec.frame, np.arange(FRAMES))
    ego = rec.decision_car == 0
    assert np.array_equal(rec.decision_frame[ego], np.arange(0, FRAMES, 30))  # the ego decides every 30 frames
    agents = rec.decision_frame[~ego] % 30
    assert np.array_equal(agents, 3 * rec.decision_car[~ego])  # agent i on frames 3i mod 30
    for k in np.flatnonzero(ego):
        j = int(rec.decision_frame[k])
        assert np.array_equal(rec.inputs[j].ravel(), rec.decision_inputs[k])
        assert rec.action[j] == rec.decision_action[k] and rec.decider[j] == 0
    # and the slice is the grid around the ego, ÷ free, off-grid cells 0
    rows, width = rec.inputs.shape[1:]
    for j in range(0, len(rec), 7):
        padded = np.zeros((7 + 2 * width, 70 + 2 * rows + 2))
        padded[width : width + 7, rows : rows + 70] = rec.grid[j] / rec.free
        l0, r0 = int(rec.slice_lane0[j]) + width, int(rec.slice_row0[j]) + rows
        assert np.array_equal(rec.inputs[j], padded[l0 : l0 + width, r0 : r0 + rows].T)


def test_safety_view_agrees_with_the_engine(v2_rec: Recording) -> None:
    rec = v2_rec
    settled = np.abs(rec.x[:, 0] - (20 * rec.lane[:, 0] + 4)) < 0.5  # the lane-change rule's test
    speed_block = (rec.safety_cells == SAFE_SPEED_BLOCK).any(axis=(1, 2))
    assert np.array_equal(speed_block, rec.safety[:, 0] < 2.0)  # c < 2 exactly when a car sits in the 4 rows ahead
    for key, side in (("can_left", -1), ("can_right", 1)):
        allowed = getattr(rec, key)
        for j in range(len(rec)):
            col = int(rec.lane[j, 0]) + side
            if not settled[j] or not 0 <= col < 7:
                assert not allowed[j]
                continue
            blocked = (rec.safety_cells[j, col] == SAFE_LANE_BLOCK).any()
            assert allowed[j] == (not blocked), f"{key} at frame {rec.frame[j]}"
        assert allowed.any() and not allowed.all()  # this run exercises both outcomes


def test_every_and_frames_select_the_kept_frames() -> None:
    net, settings = load(V1_NET)
    rec = record_run(net, settings, frames=100, every=7)
    assert rec.frame.tolist() == list(range(0, 100, 7))
    assert rec.run_frames == 2000 and len(rec.decision_frame) == 4  # decisions 0, 30, 60, 90 of the kept span
    for bad in ({"frames": 0}, {"every": 0}, {"frames": 50, "run_frames": 40}):
        with pytest.raises(ConfigError):
            record_run(net, settings, **bad)  # type: ignore[arg-type]


def test_replay_command_html_opens_clean_in_chromium(tmp_path: Path) -> None:
    out = tmp_path / "run.html"
    assert main(["replay", "--net", str(V2_NET), "--out", str(out), "--frames", "90", "--every", "3"]) == 0
    report = assert_page_ok(out, screenshot=tmp_path / "run.png")
    (fig,) = report.figures
    assert fig.traces == 9  # traffic, agents, ego, car labels, grid, slice outline, safety, ego outline, slice
    assert all(p > 0 for p in fig.points)
    assert "replay" in report.title


def test_replay_command_gif_and_mp4(tmp_path: Path) -> None:
    gif = tmp_path / "run.gif"
    assert main(["replay", "--net", str(V1_NET), "--out", str(gif), "--frames", "30", "--every", "5"]) == 0
    with Image.open(gif) as im:
        assert im.format == "GIF" and getattr(im, "n_frames", 1) == 6 and im.width > 400
    mp4 = tmp_path / "run.mp4"
    assert main(["replay", "--net", str(V1_NET), "--out", str(mp4), "--frames", "30", "--every", "5"]) == 0
    assert mp4.read_bytes()[4:8] == b"ftyp"


def test_replay_command_bad_input_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", "--net", str(V1_NET), "--out", str(tmp_path / "x.png")]) == 2
    assert main(["replay", "--net", str(tmp_path / "none.json"), "--out", str(tmp_path / "x.gif")]) == 2
    assert main(["replay", "--out", str(tmp_path / "x.gif")]) == 2
    assert main(["replay", "--net", str(V1_NET), "--out", str(tmp_path / "x.gif"), "--every", "0"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 4 and all(line.startswith("error: ") for line in lines), lines
    assert "--out" in lines[0] and "--net" in lines[1] and "STUDY" in lines[2] and "every" in lines[3]


# -- a study's trial ---------------------------------------------------------------------------------
def _study_with_two_nets(storage: str) -> list[tuple[ConvNet, Settings]]:
    """Study 'demo' at ``storage``: trials 0 and 1 COMPLETE (1 the best), each with a net.json artifact."""
    import optuna
    from optuna.distributions import FloatDistribution
    from optuna.trial import TrialState, create_trial

    from autotune.search.storage import open_storage

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storages = open_storage(storage, "demo")
    study = optuna.create_study(study_name="demo", storage=storages.storage, direction="maximize")
    config = autotune.preset("network_basic_v2").replace(otherAgents=2, layers="fc:6:tanh")
    nets = []
    for i, value in enumerate((60.0, 70.0)):
        net = init_convnet(config.expanded_layers, seed=i)
        upload = Path(storage).parent / f"net-{i}.json"
        upload.write_text(autotune.dumps_net(net))
        artifact = optuna.artifacts.upload_artifact(
            artifact_store=storages.artifacts, file_path=str(upload), study_or_trial=study
        )
        study.add_trial(
            create_trial(
                state=TrialState.COMPLETE,
                value=value,
                params={"learning_rate": config.learning_rate},
                distributions={"learning_rate": FloatDistribution(1e-5, 1.0, log=True)},
                user_attrs={"source": "autotune", "config": config.to_mapping(), "artifact_net_json": artifact},
            )
        )
        nets.append((net, config.settings))
    return nets


def test_replay_command_draws_a_study_trial(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    storage = str(tmp_path / "s" / "journal.log")
    nets = _study_with_two_nets(storage)
    scores = [record_run(net, settings, frames=30).score for net, settings in nets]
    for extra, number in (([], 1), (["--trial", "0"], 0)):  # the best trial by default
        out = tmp_path / f"trial{number}.gif"
        argv = ["replay", "demo", "--storage", storage, "--out", str(out), "--frames", "30", "--every", "10", *extra]
        assert main(argv) == 0
        printed = capsys.readouterr().out
        assert f"run score {scores[number]:.2f} mph" in printed
        assert ("demo best" if number == 1 else "demo trial 0") in printed
        with Image.open(out) as im:
            assert getattr(im, "n_frames", 1) == 3
    assert main(["replay", "demo", "--storage", storage, "--trial", "7", "--out", str(tmp_path / "x.gif")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no trial 7" in err[0]
