"""Report data as values: extraction from real Optuna storages, the crowd study, the four insights, the report."""

from __future__ import annotations

import dataclasses
import math
import random
from pathlib import Path

import numpy as np
import optuna
import pytest

from autotune.learner.config import TrainConfig
from dashboards import crowd, extract, insights, report, spread
from dashboards import crowd_data as cd
from dashboards.crowd_cli import FilterError, cached_crowd_spread, compile_filter, enqueue_replay

optuna.logging.set_verbosity(optuna.logging.WARNING)
COMPLETE, PRUNED, FAIL = (
    optuna.trial.TrialState.COMPLETE,
    optuna.trial.TrialState.PRUNED,
    optuna.trial.TrialState.FAIL,
)


def contract_config(rng: random.Random, ruleset: str = "v2") -> TrainConfig:
    return TrainConfig(
        ruleset=ruleset,
        lanes_side=rng.randint(0, 4),
        patches_ahead=rng.randint(1, 40),
        patches_behind=rng.randint(0, 10),
        temporal_window=rng.randint(0, 3),
        other_agents=rng.randint(0, 5) if ruleset == "v2" else 0,
        gamma=round(rng.uniform(0.5, 0.99), 3),
        learning_rate=10 ** rng.uniform(-5, -2),
        batch_size=rng.choice([16, 32, 64]),
        train_iterations=rng.choice([5000, 10000, 20000]),
        layers=f"fc:{rng.randint(4, 64)}:relu",  # type: ignore[arg-type]
    )


def contract_study(
    storage: str | optuna.storages.BaseStorage | None, name: str = "auto", n: int = 12, seed: int = 0, states=None
) -> optuna.Study:
    """A study whose trials look like the search service's records (trial-record contract)."""
    rng = random.Random(seed)
    study = optuna.create_study(study_name=name, storage=storage, direction="maximize")
    study.set_user_attr("source", "autotune")
    trials = []
    for k in range(n):
        cfg = contract_config(rng, "v1" if k % 5 == 4 else "v2")
        params = crowd.encode_params(cfg)
        state = (states or {}).get(k, COMPLETE)
        value = 50 + 0.3 * cfg.patches_ahead + 10 * cfg.gamma + rng.gauss(0, 1) if state == COMPLETE else None
        attrs = {
            "source": "autotune",
            "config": cfg.to_mapping(),
            "settings": cfg.to_deepqlearn(),
            "seed": k,
            "curve": [{"step": 0, "frames": 1000, "quick_score": 40.0}],
            "input_size": cfg.net_inputs,
            "num_states": cfg.num_states,
            "param_count": cd.param_count(cfg),
            "frames_simulated": cfg.total_frames + 100_000,
            "official_protocol": "v2-official" if cfg.ruleset == "v2" else "v1-original",
            "diverged": False,
        }
        if state != COMPLETE:
            attrs["cause"] = "pruned at step 0" if state == PRUNED else "diverged"
        trials.append(
            optuna.trial.create_trial(
                state=state,
                value=value,
                params=params,
                distributions=crowd.distributions([params]),
                user_attrs=attrs,
                intermediate_values={0: 40.0},
            )
        )
    study.add_trials(trials)
    return study


@pytest.fixture(scope="module")
def crowd_study() -> optuna.Study:
    return crowd.crowd_study()


@pytest.fixture()
def sqlite(tmp_path: Path) -> str:
    return f"sqlite:///{tmp_path / 'studies.db'}"


def test_extraction_from_a_real_storage(sqlite: str) -> None:
    study = contract_study(sqlite, n=10, states={2: PRUNED, 6: FAIL})
    data = extract.study_data(optuna.load_study(study_name="auto", storage=sqlite))
    assert data.source == "autotune" and [t.state for t in data.trials].count("COMPLETE") == 8
    trials = study.get_trials()
    complete = [t for t in trials if t.state == COMPLETE]
    s = extract.progress(data)
    assert isinstance(s, extract.Series)
    assert s.order == [t.number for t in complete] and s.score == [t.value for t in complete]
    assert s.best == list(np.maximum.accumulate([float(t.value or 0) for t in complete]))
    size = extract.size_scatter(data)
    assert isinstance(size, extract.SizeScatter)
    assert size.param_count == [t.user_attrs["param_count"] for t in complete]
    assert size.n_layers == [1] * 8
    panels = extract.hyperparameter_panels(data)
    gamma = panels["gamma"]
    assert isinstance(gamma, extract.Panel) and gamma.x == [t.user_attrs["config"]["gamma"] for t in complete]
    agents = panels["other_agents"]  # v1 trials have no agents: left out, not plotted at 0
    assert isinstance(agents, extract.Panel)
    assert len(agents.x) == sum(t.user_attrs["config"]["ruleset"] == "v2" for t in complete)
    assert panels["learning_rate"].log_x and not panels["gamma"].log_x  # type: ignore[union-attr]
    # compute: every finished trial's frames count, pruned and failed ones included
    curve = extract.compute_curve(data)
    assert isinstance(curve, extract.Series)
    assert curve.order[-1] == sum(t.user_attrs["frames_simulated"] for t in trials)
    assert curve.best[-1] == max(float(t.value or 0) for t in complete)
    assert math.isnan(curve.score[curve.labels.index("trial 2")])


def test_empty_states_are_explained() -> None:
    study = contract_study(None, n=3)
    data = extract.study_data(study)
    assert isinstance(extract.importances(study), extract.Empty)
    assert "at least 4 complete trials, have 3" in extract.importances(study).reason  # type: ignore[union-attr]
    assert isinstance(extract.tsne_map([data]), extract.Empty)
    empty = optuna.create_study(direction="maximize", study_name="none")
    none = extract.study_data(empty)
    assert isinstance(extract.progress(none), extract.Empty)
    result = insights.evaluate(insights.INSIGHTS[0], none)
    assert result.holds is None and "only 0 scored" in result.note
    with pytest.raises(ValueError, match="minimizes"):
        extract.study_data(optuna.create_study(direction="minimize"))


def test_importances_and_tsne_are_seeded() -> None:
    study = contract_study(None, n=16, seed=3)
    a, b = extract.importances(study, seed=1), extract.importances(study, seed=1)
    assert isinstance(a, extract.Importances) and a == b
    assert a.names[0] == "patches_ahead"  # the synthetic score is driven by patches_ahead (and gamma)
    assert sum(a.values) == pytest.approx(1.0)
    data = extract.study_data(study)
    m1, m2 = extract.tsne_map([data], seed=5), extract.tsne_map([data], seed=5)
    assert isinstance(m1, extract.TsneMap) and m1 == m2 and len(m1.x) == 16


def test_crowd_study_import_is_idempotent(tmp_path: Path) -> None:
    storage = str(tmp_path / "crowd.log")
    journal = optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(storage))
    study, first = crowd.import_crowd(journal)
    assert (first.added, first.existing) == (116, 0)
    assert sum(r == "no reported score" for r in first.skipped.values()) == 47
    assert first.skipped["dt-lupuleasa-core-deeptraffic-v32"].startswith("experience_size: 0")
    _study, again = crowd.import_crowd(journal)
    assert (again.added, again.existing) == (0, 116) and len(study.get_trials()) == 116
    trials = study.get_trials()
    dates = [t.user_attrs["version_date"] for t in trials if t.user_attrs["version_date"]]
    assert dates == sorted(dates)  # trial number = submission order
    best = study.best_trial
    assert best.value == 75.86 and best.user_attrs["crowd_id"] == "dt-jordanott-deep-traffic-v03"
    assert best.params["n_layers"] == 5 and best.params["one_minus_gamma"] == pytest.approx(0.09)
    attrs = best.user_attrs
    assert (attrs["source"], attrs["score_kind"], attrs["score_confidence"], attrs["engine_version"]) == (
        "crowd",
        "claimed",
        "high",
        "v1",
    )
    assert attrs["param_count"] == 39115 and attrs["frames_simulated"] == 30 * attrs["config"]["train_iterations"]
    assert TrainConfig.from_mapping(attrs["config"]) == cd.train_config(
        next(s for s in cd.load_submissions() if s.id == attrs["crowd_id"])
    )
    # the parameter names are the search's
    from autotune.search import space

    assert set(best.params) <= set(space.DEFAULT_SPACE) | {
        f"{p}_{i}" for p in ("neurons", "activation") for i in range(8)
    }


def _ranks(x: list[float]) -> np.ndarray:
    """Average ranks (ties share the mean rank), written out rather than taken from scipy."""
    order = np.argsort(x, kind="mergesort")
    ranks = np.empty(len(x))
    xs = np.asarray(x)[order]
    i = 0
    while i < len(x):
        j = i
        while j + 1 < len(x) and xs[j + 1] == xs[i]:
            j += 1
        ranks[order[i : j + 1]] = (i + j) / 2 + 1
        i = j + 1
    return ranks


def test_crowd_insights_computed_independently(crowd_study: optuna.Study) -> None:
    """Spearman ρ from the CSV directly (Pearson of average ranks) equals the report's insight values."""
    rows = []
    for sub in cd.load_submissions():
        if sub.reported_score_mph is None:
            continue
        try:
            cfg = cd.train_config(sub)
        except cd.CrowdDataError:
            continue
        rows.append((cd.param_count(cfg), cfg.temporal_window, cfg.patches_ahead, cfg.gamma, sub.reported_score_mph))
    assert len(rows) == 116
    cols = list(zip(*rows, strict=True))
    score = _ranks(list(cols[4]))
    expected = [float(np.corrcoef(_ranks(list(c)), score)[0, 1]) for c in cols[:4]]
    results = insights.evaluate_all(extract.study_data(crowd_study))
    assert [r.n for r in results] == [116] * 4
    assert [r.value for r in results] == pytest.approx(expected, abs=1e-12)
    assert [round(r.value, 3) for r in results] == [0.276, -0.403, 0.382, 0.527]  # type: ignore[arg-type]
    assert [r.holds for r in results] == [True, True, True, True]
    assert all(r.p_value is not None and r.p_value < 0.003 for r in results)


def test_insight_sign_and_constant_setting() -> None:
    study = optuna.create_study(direction="maximize")
    for k in range(8):
        cfg = TrainConfig(temporal_window=k % 4, patches_ahead=5, gamma=0.5 + k / 20)
        study.add_trial(
            optuna.trial.create_trial(
                value=60.0 + k * 0.5 + (k % 4),
                params={"x": k},
                distributions={"x": optuna.distributions.IntDistribution(0, 10)},
                user_attrs={"config": cfg.to_mapping(), "param_count": 100 + k},
            )
        )
    data = extract.study_data(study)
    size, window, ahead, gamma = insights.evaluate_all(data)
    assert window.value is not None and window.value > 0 and window.holds is False  # positive: opposite of claim
    assert ahead.holds is None and "same in every trial (5)" in ahead.note
    assert gamma.holds is True and size.holds is True


def test_replay_and_own_net_comparisons(crowd_study: optuna.Study) -> None:
    replay = optuna.create_study(direction="maximize", study_name="crowd-replay")
    subs = [s for s in cd.load_submissions() if s.id in ("dt-gsurma-deep-traffic-v00", "dt-jeremy26-deep-traffic-v00")]
    added, existing, skipped = enqueue_replay(replay, subs, seeds=2)
    assert (added, existing, skipped) == (4, 0, {})
    assert enqueue_replay(replay, subs, seeds=2)[:2] == (0, 4)  # idempotent
    for trial, value in zip(replay.get_trials(), (70.0, 72.0, 60.0, 61.0), strict=True):
        assert trial.state == optuna.trial.TrialState.WAITING
        fixed = crowd.encode_params(TrainConfig.from_mapping(trial.user_attrs["config"]))
        assert trial.system_attrs["fixed_params"] == fixed
        t = replay.ask()
        assert t.user_attrs["crowd_id"] == trial.user_attrs["crowd_id"]
        replay.tell(t, value)
    crowd_data = extract.study_data(crowd_study)
    reported = {t.crowd_id: t.value for t in crowd_data.scored if t.crowd_id}
    rows = extract.replay_comparison(extract.study_data(replay), reported)  # type: ignore[arg-type]
    assert isinstance(rows, list)
    by_id = {r.crowd_id: r for r in rows}
    gsurma = by_id["dt-gsurma-deep-traffic-v00"]
    assert (gsurma.reported, gsurma.measured, gsurma.n) == (75.01, 71.0, 2)
    assert gsurma.std == pytest.approx(math.sqrt(2))
    assert isinstance(extract.own_net_comparison(crowd_data), extract.Empty)
    scored = crowd.import_crowd(
        optuna.storages.InMemoryStorage(), own_net_scores={"dt-gsurma-deep-traffic-v00": {"score": 74.1, "runs": 500}}
    )[0]
    own = extract.own_net_comparison(extract.study_data(scored))
    assert isinstance(own, list) and [(r.crowd_id, r.reported, r.measured) for r in own] == [
        ("dt-gsurma-deep-traffic-v00", 75.01, 74.1)
    ]
    assert scored.trials[[t.user_attrs["crowd_id"] for t in scored.trials].index(own[0].crowd_id)].user_attrs[
        "own_net_score"
    ] == pytest.approx(74.1)


def test_filter_expressions() -> None:
    columns = ["engine_version", "reported_score_mph", "lanesSide"]
    keep = compile_filter("engine_version == 'v2' and reported_score_mph > 70", columns)
    assert keep({"engine_version": "v2", "reported_score_mph": 71.0, "lanesSide": 1})
    assert not keep({"engine_version": "v2", "reported_score_mph": None, "lanesSide": 1})  # blank: not > 70
    assert not keep({"engine_version": "v1", "reported_score_mph": 75.0, "lanesSide": 1})
    assert compile_filter("lanesSide in [1, 3] or not reported_score_mph is None", columns)(
        {"engine_version": "v1", "reported_score_mph": None, "lanesSide": 3}
    )
    for bad, message in (
        ("__import__('os').system('x')", "Call is not allowed"),
        ("engine_version.upper()", "Call is not allowed"),
        ("score > 1", "unknown column 'score'"),
        ("lanesSide >", "not an expression"),
    ):
        with pytest.raises(FilterError, match=message):
            compile_filter(bad, columns)


def test_report_sections_html_and_dashboard(tmp_path: Path, crowd_study: optuna.Study) -> None:
    storage = f"sqlite:///{tmp_path / 'auto.db'}"
    study = contract_study(storage, n=12, states={3: PRUNED})
    built = report.build_report(study, crowd_study, spread=cached_crowd_spread(20, tmp_path))
    keys = [s.key for s in built.sections]
    assert keys == ["progress", "size", "hyperparameters", "spread", "tsne", "compute", "importances", "replay"]
    empty = {s.key: s.figure.reason for s in built.sections if isinstance(s.figure, extract.Empty)}
    assert set(empty) == {"replay"} and "no crowd replay study given" in empty["replay"]
    (panel,) = [s.figure for s in built.sections if s.key == "spread"]  # dashboards.spread's figure, real nets
    assert not isinstance(panel, extract.Empty)
    assert {t.name.split(" (")[0] for t in panel.data if t.name} == set(spread.DEFAULT_NETS)
    for s in built.sections:
        if not isinstance(s.figure, extract.Empty):
            assert s.figure.data and all(len(t.x) > 0 for t in s.figure.data if getattr(t, "x", None) is not None)
    page = report.render_html(built)
    assert page.count("<script>/**\n* plotly.js v") == 1  # plotly.js inlined once
    assert "<script src=" not in page  # nothing fetched from the network
    assert "Nothing to show: no crowd replay study given" in page and "plan for the future" in page
    ids = report.attach_to_dashboard(study, built)
    assert ids == [f"autotune-{k}" for k in keys if k != "replay"]
    from optuna_dashboard import get_note

    note = get_note(optuna.load_study(study_name="auto", storage=storage))
    assert "| size matters | Spearman ρ(param_count, score) | +0.276 (n=116)" in str(note)
    assert report.attach_to_dashboard(study, built) == ids  # fixed ids: re-running replaces, not duplicates


def test_spread_cache(tmp_path: Path, capsys) -> None:  # noqa: ANN001
    """compare's spread data: the three default crowd nets scored by the exact evaluator once, then read back."""
    first = cached_crowd_spread(20, tmp_path)
    assert "scored in" in capsys.readouterr().out
    assert [n.name for n in first.nets] == list(spread.DEFAULT_NETS) and first.runs == 20
    assert all(len(n.scores) == 20 and n.se[-1] > 0 for n in first.nets)
    again = cached_crowd_spread(20, tmp_path)
    assert "from " + str(tmp_path) in capsys.readouterr().out  # no scoring the second time
    assert again.nets[0].se[1:] == first.nets[0].se[1:] and math.isnan(again.nets[0].se[0])
    assert dataclasses.replace(again, nets=()) == dataclasses.replace(first, nets=())
    assert cached_crowd_spread(21, tmp_path).runs == 21 and len(list(tmp_path.glob("spread-*.json"))) == 2
