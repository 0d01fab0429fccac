"""Report data as values: extraction with provenance, the insights recomputed independently, the report.

The tests build studies with Optuna directly, as the search service would have stored them; the reports
see them only as plain records (``autotune.search.records``: ``snapshot`` / ``read_study``)."""

from __future__ import annotations

import dataclasses
import datetime as dt
import html
import math
import random
from pathlib import Path

import numpy as np
import optuna
import pytest
from scipy import stats

from autotune.learner.config import TrainConfig
from autotune.search.records import StudyRecord, read_study, snapshot, to_optuna_distribution
from autotune.search.storage import Storages, load_study, open_storage
from dashboards import crowd, extract, headline, insights, measured, report, spread
from dashboards import crowd_data as cd
from dashboards import provenance as pv
from dashboards.crowd_filter import FilterError, compile_filter
from dashboards.crowd_replay import enqueue_replay

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
        params = crowd.crowd_params(cfg)
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
            "param_count": cfg.param_count,
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
                distributions={k: to_optuna_distribution(d) for k, d in crowd.distributions([params]).items()},
                user_attrs=attrs,
                intermediate_values={0: 40.0},
            )
        )
    study.add_trials(trials)
    return study


def data_of(study: optuna.Study | StudyRecord) -> extract.StudyData:
    """What the report reads of a study: its plain records (an Optuna study is read as ``read_study`` would)."""
    return extract.study_data(study if isinstance(study, StudyRecord) else snapshot(study))


def replay_study(directory: Path) -> tuple[Storages, optuna.Study]:
    """An empty replay study in a journal under ``directory``: the storages and the Optuna study."""
    storages = open_storage(str(directory / "replay.log"), "crowd-replay")
    optuna.create_study(study_name="crowd-replay", storage=storages.storage, direction="maximize")
    return storages, load_study(storages, "crowd-replay")


@pytest.fixture(scope="module")
def crowd_study() -> StudyRecord:
    return crowd.crowd_study()


@pytest.fixture(scope="module")
def crowd_points(crowd_study: StudyRecord) -> extract.StudyData:
    return extract.study_data(crowd_study)


@pytest.fixture()
def sqlite(tmp_path: Path) -> str:
    return f"sqlite:///{tmp_path / 'studies.db'}"


def test_extraction_from_a_real_storage(sqlite: str) -> None:
    study = contract_study(sqlite, n=10, states={2: PRUNED, 6: FAIL})
    data = extract.study_data(read_study(open_storage(sqlite, "auto", heartbeat=False), "auto"))
    assert data.source == "autotune" and [t.state for t in data.trials].count("COMPLETE") == 8
    trials = study.get_trials()
    complete = [t for t in trials if t.state == COMPLETE]
    # every point says what its score is: engine from the stored config, agents (none in v1), measured by the search
    for t, point in zip(complete, data.scored, strict=True):
        config = t.user_attrs["config"]
        assert (point.engine, point.kind, point.confidence) == (config["ruleset"], pv.SEARCHED, "exact")
        assert point.other_agents == (config["other_agents"] if config["ruleset"] == "v2" else None)
    s = extract.progress(data)
    assert isinstance(s, extract.Progress)
    assert s.points.x == [t.number for t in complete] and s.points.y == [t.value for t in complete]
    for engine, (order, best, holder) in s.best.items():  # each engine's own running best, never pooled
        mine = [t for t in complete if t.user_attrs["config"]["ruleset"] == engine]
        assert order == [t.number for t in mine]
        assert best == list(np.maximum.accumulate([float(t.value or 0) for t in mine]))
        assert [h.value for h in holder] == best and {h.engine for h in holder} == {engine}
    assert set(s.best) == {"v1", "v2"}
    size = extract.size_scatter(data)
    assert isinstance(size, extract.SizeScatter)
    assert size.points.x == [t.user_attrs["param_count"] for t in complete]
    assert size.n_layers == [1] * 8
    panels = extract.hyperparameter_panels(data)
    gamma = panels["gamma"]
    assert isinstance(gamma, extract.Panel) and gamma.points.x == [t.user_attrs["config"]["gamma"] for t in complete]
    agents = panels["other_agents"]  # v1 trials have no agents: left out, not plotted at 0
    assert isinstance(agents, extract.Panel)
    assert len(agents.points.x) == sum(t.user_attrs["config"]["ruleset"] == "v2" for t in complete)
    assert panels["learning_rate"].log_x and not panels["gamma"].log_x  # type: ignore[union-attr]
    groups = gamma.points.groups()
    assert set(groups) == {("v1", pv.SEARCHED), ("v2", pv.SEARCHED)}
    assert sorted(i for idx in groups.values() for i in idx) == list(range(8))
    # compute: every finished trial's frames count, pruned and failed ones included; best per engine
    curve = extract.compute_curve(data)
    assert isinstance(curve, extract.ComputeCurve)
    cumulative = np.cumsum([t.user_attrs["frames_simulated"] for t in trials]).tolist()
    v2_order, v2_best, _holder = curve.best["v2"]
    v2_done = [k for k, t in enumerate(trials) if t.state == COMPLETE and t.user_attrs["config"]["ruleset"] == "v2"]
    assert v2_order == [cumulative[k] for k in v2_done]
    assert v2_best[-1] == max(float(trials[k].value or 0) for k in v2_done)
    assert curve.kinds == {"v1": [pv.SEARCHED], "v2": [pv.SEARCHED]}


def test_crowd_points_carry_engine_agents_kind_and_confidence(crowd_points: extract.StudyData) -> None:
    by_id = {s.id: s for s in cd.load_submissions()}
    assert len(crowd_points.scored) == 116 and not crowd_points.skipped
    for t in crowd_points.scored:
        sub = by_id[t.crowd_id]  # type: ignore[index]
        assert (t.engine, t.kind, t.confidence, t.config_key, t.repo) == (
            sub.engine_version, sub.score_kind, sub.score_confidence, sub.config_hash, sub.repo,
        )  # fmt: skip
        assert t.other_agents == sub.other_agents and not pv.is_measured(t.kind)
        assert t.custom()[1:4] == [
            pv.ENGINE_LABEL[sub.engine_version], pv.agents_label(sub.engine_version, sub.other_agents),
            pv.KIND_LABEL[str(sub.score_kind)],
        ]  # fmt: skip
    assert crowd_points.kinds == [pv.CLAIMED, pv.LOCAL, pv.APPROX, pv.EXAMPLE]
    # identical settings once: 116 scored rows, 108 configurations (8 rows repeat an earlier configuration)
    units = extract.configurations(crowd_points)
    assert len(units) == 108 == len({t.config_key for t in crowd_points.scored})
    jordanott = next(u for u in units if u.crowd_id == "dt-jordanott-deep-traffic-v03")
    assert jordanott.value == pytest.approx((75.86 + 75.26) / 2)  # darshanbagul retrained the same settings


def test_labels_name_one_thing_each() -> None:
    labels = [*pv.KIND_LABEL.values(), *pv.ENGINE_LABEL.values()]
    for a in labels:
        assert [b for b in labels if a in b] == [a], a  # a name that holds a label names that kind or engine
    assert pv.marker_symbol("v1", pv.CLAIMED) == "diamond-open" and pv.marker_symbol("v2", pv.OWN_WEIGHTS) == "circle"
    assert pv.agents_label("v1", None) == "no other agents (v1 engine)" and pv.agents_label("v2", 1) == "1 other agent"
    with pytest.raises(ValueError, match="score kind 'bragged'"):
        pv.is_measured("bragged")


def test_empty_states_are_explained() -> None:
    study = contract_study(None, n=3)
    data = data_of(study)
    assert isinstance(extract.importances(data), extract.Empty)
    assert "at least 8 scored configurations, have 3" in extract.importances(data).reason  # type: ignore[union-attr]
    assert isinstance(extract.tsne_map([data]), extract.Empty)
    empty = optuna.create_study(direction="maximize", study_name="none")
    none = data_of(empty)
    assert isinstance(extract.progress(none), extract.Empty)
    (result, *_rest) = insights.evaluate_study(none, "autotune")
    assert result.holds is None and "only 0 configuration" in result.note and result.p_value is None
    with pytest.raises(ValueError, match="minimizes"):
        data_of(optuna.create_study(direction="minimize"))
    # a trial whose engine is not recorded is left out with the reason, not guessed
    bare = optuna.create_study(direction="maximize", study_name="bare")
    bare.add_trial(optuna.trial.create_trial(value=1.0, params={}, distributions={}))
    assert data_of(bare).skipped == {0: "no engine recorded (user attr config.ruleset)"}


def test_importances_take_engine_and_agents_from_the_stored_config() -> None:
    study = contract_study(None, n=24, seed=3)
    data = data_of(study)
    a, b = extract.importances(data, seed=1), extract.importances(data, seed=1)
    assert isinstance(a, extract.Importances) and a == b
    assert {"engine", "other_agents", "patches_ahead", "gamma"} <= set(a.names)  # inputs from the stored config
    assert a.names[0] == "patches_ahead"  # the synthetic score is driven by patches_ahead (and gamma)
    assert sum(a.values) == pytest.approx(1.0) and all(v >= 0 for v in a.values)
    assert (a.n, a.engines, a.kinds) == (24, ["v1", "v2"], [pv.SEARCHED])
    # the score made of the engine alone: the engine is what matters, not a setting that happens to follow it
    engine_only = optuna.create_study(direction="maximize")
    for t in study.get_trials():
        v2 = t.user_attrs["config"]["ruleset"] == "v2"
        engine_only.add_trial(
            optuna.trial.create_trial(
                value=60.0 + 8.0 * v2 + 0.01 * t.number, params=t.params, distributions=t.distributions,
                user_attrs=t.user_attrs,
            )
        )  # fmt: skip
    imp = extract.importances(data_of(engine_only), seed=0)
    assert isinstance(imp, extract.Importances) and imp.names[0] == "engine", imp
    m1, m2 = extract.tsne_map([data], seed=5), extract.tsne_map([data], seed=5)
    assert isinstance(m1, extract.TsneMap) and m1 == m2 and len(m1.x) == 24


def test_crowd_study_import_is_idempotent(tmp_path: Path) -> None:
    storages = open_storage(str(tmp_path / "crowd.log"), "crowd")
    study, first = crowd.import_crowd(storages)
    assert (first.added, first.existing) == (116, 0)
    assert sum(r == "no reported score" for r in first.skipped.values()) == 47
    assert first.skipped["dt-lupuleasa-core-deeptraffic-v32"].startswith("experience_size: 0")
    again_study, again = crowd.import_crowd(storages)
    assert (again.added, again.existing) == (0, 116) and len(study.trials) == len(again_study.trials) == 116
    assert read_study(storages, "crowd") == again_study
    # what the value is: the study's metric name and each trial's value_is say it is a claim
    assert load_study(storages, "crowd").metric_names == [crowd.CROWD_METRIC]
    assert "claimed by the author, not measured" in crowd.CROWD_METRIC
    trials = study.trials
    dates = [t.user_attrs["version_date"] for t in trials if t.user_attrs["version_date"]]
    assert dates == sorted(dates)  # trial number = submission order
    best = study.best
    assert best is not None
    assert best.value == 75.86 and best.user_attrs["crowd_id"] == "dt-jordanott-deep-traffic-v03"
    assert best.params["n_layers"] == 5 and best.params["one_minus_gamma"] == pytest.approx(0.09)
    attrs = best.user_attrs
    assert (attrs["source"], attrs["score_kind"], attrs["score_confidence"], attrs["engine_version"]) == (
        "crowd",
        "claimed",
        "high",
        "v1",
    )
    assert attrs["value_is"] == "claimed: self-reported by the author, not measured (v1 engine, no other agents (v1 " \
        "engine))"  # fmt: skip
    assert attrs["config_hash"] == "6b0ef8eb94"
    # the shipped own-weight score sits beside the claim (measured: 73.57 in v1-original)
    assert (attrs["own_net_score"], attrs["own_net_protocol"]) == (73.57, "v1-original")
    assert study.user_attrs["own_net_scores"]["dt-jordanott-deep-traffic-v03"]["score"] == 73.57
    assert attrs["param_count"] == 39115 and attrs["frames_simulated"] == 30 * attrs["config"]["train_iterations"]
    assert TrainConfig.from_mapping(attrs["config"]) == cd.train_config(
        next(s for s in cd.load_submissions() if s.id == attrs["crowd_id"])
    )
    # the parameter names are the search's
    from autotune.search import space

    assert set(best.params) <= set(space.DEFAULT_SPACE) | {
        f"{p}_{i}" for p in ("neurons", "activation") for i in range(8)
    }


# --- the insights, recomputed from the CSV without the report's code ---------------------------------------


def _csv_units() -> list[dict]:
    """The crowd's configurations straight from the CSV: scored rows our learner accepts, one per config_hash (in
    submission order: by version date, then id), scored with the mean of their rows."""
    rows = []
    for sub in cd.load_submissions():
        if sub.reported_score_mph is None:
            continue
        try:
            cfg = cd.train_config(sub)
        except cd.CrowdDataError:
            continue
        rows.append((sub, cfg))
    rows.sort(key=lambda r: (r[0].version_date is None, r[0].version_date or dt.date.min, r[0].id))
    units: dict[str, dict] = {}
    for order, (sub, cfg) in enumerate(rows):
        unit = units.setdefault(
            sub.config_hash,
            {
                "param_count": cfg.param_count, "temporal_window": cfg.temporal_window,
                "patches_ahead": cfg.patches_ahead, "gamma": cfg.gamma, "engine": sub.engine_version,
                "agents": sub.other_agents or 0, "repo": sub.repo, "order": order, "scores": [],
            },
        )  # fmt: skip
        unit["scores"].append(sub.reported_score_mph)
    for unit in units.values():
        unit["score"] = float(np.mean(unit["scores"]))
    return list(units.values())


def _partial_by_precision(x, y, covariates) -> tuple[float, float]:  # noqa: ANN001
    """Partial Spearman from the inverse of the rank correlation matrix (no residualisation), p from t."""
    columns = [stats.rankdata(x), stats.rankdata(y), *(stats.rankdata(c) for c in covariates)]
    precision = np.linalg.inv(np.corrcoef(np.array(columns)))
    r = -precision[0, 1] / math.sqrt(precision[0, 0] * precision[1, 1])
    df = len(x) - 2 - len(covariates)
    t = r * math.sqrt(df / (1 - r * r))
    return float(r), float(2 * stats.t.sf(abs(t), df))


def _holm_by_hand(p: list[float]) -> list[float]:
    order = sorted(range(len(p)), key=lambda i: p[i])
    out = [0.0] * len(p)
    worst = 0.0
    for rank, i in enumerate(order):
        worst = max(worst, min(1.0, (len(p) - rank) * p[i]))
        out[i] = worst
    return out


def test_crowd_insights_recomputed_independently(crowd_points: extract.StudyData) -> None:
    """Per engine: scipy's Spearman; pooled: partial Spearman from the precision matrix of the ranks; by
    repository: the latest configuration of each repository; Holm by hand — all equal the report's values."""
    units = _csv_units()
    assert len(units) == 108
    latest: dict[str, dict] = {}
    for u in units:
        if u["repo"] not in latest or u["order"] > latest[u["repo"]]["order"]:
            latest[u["repo"]] = u
    groups = {
        "v1 engine": [u for u in units if u["engine"] == "v1"],
        "v2 engine": [u for u in units if u["engine"] == "v2"],
        "pooled": units,
        "pooled, one configuration per repository": list(latest.values()),
    }
    assert [len(g) for g in groups.values()] == [44, 64, 108, 32]
    results = insights.evaluate_all({"crowd": crowd_points})["crowd"]
    assert [(r.insight.name, r.group) for r in results] == [(i.name, g) for i in insights.INSIGHTS for g in groups]
    expected = []
    for insight in insights.INSIGHTS:
        for group, members in groups.items():
            x = [u[insight.variable] for u in members]
            y = [u["score"] for u in members]
            if group.startswith("pooled"):
                rho, p = _partial_by_precision(x, y, [[u["engine"] == "v2" for u in members],
                                                      [u["agents"] for u in members]])  # fmt: skip
            else:
                rho, p = stats.spearmanr(x, y)
            expected.append((float(rho), float(p), len(members)))
    for r, (rho, p, n) in zip(results, expected, strict=True):
        assert r.n == n and r.value == pytest.approx(rho, abs=1e-10) and r.p_value == pytest.approx(p, rel=1e-6)
    holm = _holm_by_hand([p for _r, p, _n in expected])
    assert [r.p_holm for r in results] == pytest.approx(holm, rel=1e-9)
    for r in results:
        assert r.holds == (r.value * r.insight.sign > 0 and r.p_holm < 0.05)  # type: ignore[operator]
        assert r.engines == (["v1"] if r.group == "v1 engine" else ["v2"] if r.group == "v2 engine" else ["v1", "v2"])
    # what the table says (configurations; Holm over the 16 crowd tests)
    table = {(r.insight.name, r.group): (round(r.value, 3), r.holds) for r in results}  # type: ignore[arg-type]
    assert table[("size matters", "v1 engine")] == (0.591, True)
    assert table[("size matters", "v2 engine")] == (0.219, False)  # the engine made it look general
    assert table[("size matters", "pooled")] == (0.342, True)
    assert table[("size matters", "pooled, one configuration per repository")] == (0.232, False)
    assert table[("live in the moment", "v2 engine")] == (-0.346, True)
    assert table[("plan for the future", "pooled")] == (0.544, True)


def test_partial_spearman_removes_a_confounder() -> None:
    """x and y both follow the engine and nothing else: pooled ρ is large, partial ρ given the engine is ~0."""
    rng = np.random.default_rng(4)
    engine = np.repeat([0.0, 1.0], 200)
    x = engine * 5 + rng.normal(size=400)
    y = engine * 5 + rng.normal(size=400)
    pooled, _p, _df = insights.partial_spearman(x, y, np.empty((400, 0)))
    partial, p, df = insights.partial_spearman(x, y, engine[:, None])
    assert pooled > 0.6 and abs(partial) < 0.12 and p > 0.05 and df == 397
    # a real within-engine correlation survives the control
    z = engine * 5 + 0.5 * (x - engine * 5) + rng.normal(size=400)
    kept, p_kept, _df = insights.partial_spearman(x, z, engine[:, None])
    assert kept > 0.3 and p_kept < 1e-6
    assert insights.holm([0.01, None, 0.04, 0.03]) == pytest.approx([0.03, None, 0.06, 0.06])


def test_insight_sign_and_constant_setting() -> None:
    study = optuna.create_study(direction="maximize")
    for k in range(8):
        cfg = TrainConfig(temporal_window=k % 4, patches_ahead=5, gamma=0.5 + k / 20, other_agents=0)
        study.add_trial(
            optuna.trial.create_trial(
                value=60.0 + k * 0.5 + (k % 4),
                params={"x": k},
                distributions={"x": optuna.distributions.IntDistribution(0, 10)},
                user_attrs={"config": cfg.to_mapping(), "param_count": 100 + k},
            )
        )
    results = insights.evaluate_all({"autotune": data_of(study)})["autotune"]
    # one engine, no agents: one test per insight (a pooled test would repeat it); no repository row
    assert [r.group for r in results] == ["v2 engine"] * 4
    size, window, ahead, gamma = results
    assert window.value is not None and window.value > 0 and window.holds is False  # positive: opposite of claim
    assert ahead.holds is None and "same in every configuration (5)" in ahead.note and ahead.p_holm is None
    assert gamma.holds is True and size.holds is True
    assert [r.p_holm for r in (size, window, gamma)] == pytest.approx(
        _holm_by_hand([r.p_value for r in (size, window, gamma)])  # type: ignore[misc]
    )


# --- the measured crowd in the report ----------------------------------------------------------------------


def test_replay_and_own_net_comparisons(tmp_path: Path, crowd_points: extract.StudyData) -> None:
    storages, replay = replay_study(tmp_path)
    subs = [s for s in cd.load_submissions() if s.id in ("dt-gsurma-deep-traffic-v00", "dt-jeremy26-deep-traffic-v00")]
    added, existing, skipped = enqueue_replay(storages, "crowd-replay", subs, seeds=2)
    assert (added, existing, skipped) == (4, 0, {})
    assert enqueue_replay(storages, "crowd-replay", subs, seeds=2)[:2] == (0, 4)  # idempotent
    assert replay.user_attrs["source"] == "crowd-replay" and replay.metric_names == [crowd.REPLAY_METRIC]
    for trial, value in zip(replay.get_trials(), (70.0, 72.0, 60.0, 61.0), strict=True):
        assert trial.state == optuna.trial.TrialState.WAITING
        fixed = crowd.crowd_params(TrainConfig.from_mapping(trial.user_attrs["config"]))
        assert trial.system_attrs["fixed_params"] == fixed
        t = replay.ask()
        assert t.user_attrs["crowd_id"] == trial.user_attrs["crowd_id"]
        replay.tell(t, value)
    data = data_of(replay)
    assert {t.kind for t in data.scored} == {pv.REPLAYED}
    rows = extract.replay_comparison(data, crowd_points)
    assert isinstance(rows, list)
    gsurma = {r.crowd_id: r for r in rows}["dt-gsurma-deep-traffic-v00"]
    assert (gsurma.claimed, gsurma.measured, gsurma.n, gsurma.engine, gsurma.other_agents) == (75.01, 71.0, 2, "v2", 10)
    assert (gsurma.claim_kind, gsurma.measured_kind, gsurma.scores) == (pv.CLAIMED, pv.REPLAYED, (70.0, 72.0))
    assert gsurma.sd == pytest.approx(math.sqrt(2))
    own = extract.own_net_rows(measured.load_own_nets())
    assert isinstance(own, list) and len(own) == 25
    row = {r.crowd_id: r for r in own}["dt-gsurma-deep-traffic-v00"]
    assert (row.claimed, row.measured, row.measured_kind, row.protocol) == (75.01, 75.0, pv.OWN_WEIGHTS, "v2-official")
    assert isinstance(extract.own_net_rows([]), extract.Empty)
    assert "tools/crowd_measurements.py replay" in extract.replay_table_rows(None).reason  # type: ignore[union-attr]


def test_headline_compares_like_with_like(crowd_points: extract.StudyData) -> None:
    own = measured.load_own_nets()
    mixed = data_of(contract_study(None, n=10))
    auto = dataclasses.replace(mixed, trials=tuple(t for t in mixed.trials if t.engine == "v2"))
    best = max(auto.scored, key=lambda t: t.value)  # type: ignore[arg-type,return-value]
    h = headline.headline(auto, crowd_points, own)
    assert h.automated == best
    # the best human net of the same engine measured with its own weights, not the best claim
    assert h.measured is not None and (h.measured.crowd_id, h.measured.score, h.measured.other_agents) == (
        "dt-jnorthrup-deeptraffic-v05", 75.80, 10,
    )  # fmt: skip
    assert h.claim_same_engine is not None and (h.claim_same_engine.value, h.claim_same_engine.engine) == (75.85, "v2")
    assert h.claim_any_engine is not None and (h.claim_any_engine.value, h.claim_any_engine.engine) == (75.86, "v1")
    text = "\n".join(h.lines)
    assert f"automated − human = {best.value - 75.80:+.2f} mph" in text  # type: ignore[operator]
    assert "(v2 engine, 10 other agents; measured: own weights, v2-official)" in text
    assert "Best claim of the same engine (self-reported, not measured): 75.85 mph" in text
    assert "another engine: not comparable): 75.86 mph — dt-jordanott-deep-traffic-v03 (v1 engine" in text
    assert len(h.lines) == 4
    # a v1 best: compared with the best v1 net, and the best claim is then of its own engine
    v1 = headline.headline(mixed, crowd_points, own)
    assert v1.automated is not None and v1.automated.engine == "v1"
    assert v1.measured is not None and (v1.measured.crowd_id, v1.measured.score) == (
        "dt-parilo-deeptraffic-solution-v00", 74.98,
    )  # fmt: skip
    assert v1.claim_same_engine is not None and v1.claim_same_engine.value == 75.86 and v1.claim_any_engine is None
    assert "no other agents (v1 engine)" in v1.lines[1] and len(v1.lines) == 3
    empty = headline.headline(data_of(optuna.create_study(direction="maximize")), crowd_points, own)
    assert empty.automated is None and "no scored trial yet" in empty.lines[0]


@pytest.fixture(scope="module")
def built_report(tmp_path_factory: pytest.TempPathFactory, crowd_study: StudyRecord) -> tuple[report.Report, str]:
    """A full report: a mixed-engine automated study, the crowd, a replay study, a small replay table, the shipped
    spread and own-net scores."""
    tmp = tmp_path_factory.mktemp("report")
    storage = f"sqlite:///{tmp / 'auto.db'}"
    study = snapshot(contract_study(storage, n=16, states={3: PRUNED}))
    storages, replay = replay_study(tmp)
    subs = [s for s in cd.load_submissions() if s.id in ("dt-gsurma-deep-traffic-v00", "dt-jeremy26-deep-traffic-v00")]
    enqueue_replay(storages, "crowd-replay", subs, seeds=1)
    for value in (73.0, 69.0):
        replay.tell(replay.ask(), value)
    table = _small_table()
    built = report.build_report(
        study, crowd_study, replay=snapshot(replay), spread=spread.load_spread(), replay_table=table
    )
    return built, storage


def _small_table() -> measured.ReplayTable:
    runs = (measured.ReplayRun(0, 11, "complete", 70.5, 12.0, None), measured.ReplayRun(1, 12, "complete", 71.5, 13.0,
            None))  # fmt: skip
    entries = []
    for rows in measured.replay_selection(1, 1):
        sub = rows[0]
        entries.append(
            measured.ReplayEntry(
                sub.id, sub.config_hash, tuple(r.id for r in rows), sub.engine_version, sub.other_agents,
                "v2-official" if sub.engine_version == "v2" else "v1-original", 100, sub.reported_score_mph or 0.0,
                sub.score_kind or "", sub.score_confidence or "", runs,
            )
        )  # fmt: skip
    return measured.ReplayTable("test", 2, 100, tuple(entries))


def test_no_trace_mixes_engines_or_score_kinds_without_naming_them(built_report: tuple[report.Report, str]) -> None:
    """Every trace of every figure names each engine and score kind its data holds, and its meta cannot lie: every
    point's own engine and kind (customdata) are among them."""
    built, _storage = built_report
    engine_labels, kind_labels = set(pv.ENGINE_LABEL.values()), set(pv.KIND_LABEL.values())
    seen_kinds, seen_engines, checked = set(), set(), 0
    for section in built.sections:
        assert not isinstance(section.figure, extract.Empty), (section.key, section.figure)
        for trace in section.figure.data:
            where = f"{section.key}: {trace.name!r}"
            meta = trace.meta
            assert isinstance(meta, dict) and trace.name, where
            if "reference" in meta:
                assert trace.name.startswith("reference") and trace.customdata is None, where
                continue
            engines, kinds = meta["engines"], meta["kinds"]
            assert engines and kinds, where
            for e in engines:
                assert pv.ENGINE_LABEL[e] in trace.name, where
            for k in kinds:
                assert pv.KIND_LABEL[k] in trace.name, where
            # labels of engines or kinds the trace does not hold are not in its name either
            assert {lab for lab in engine_labels if lab in trace.name} == {pv.ENGINE_LABEL[e] for e in engines}, where
            assert {lab for lab in kind_labels if lab in trace.name} == {pv.KIND_LABEL[k] for k in kinds}, where
            if trace.customdata is not None:
                assert len(trace.customdata) == len(trace.y if trace.y is not None else trace.x), where
                for row in trace.customdata:
                    assert row[1] in {pv.ENGINE_LABEL[e] for e in engines}, (where, row)
                    assert row[3] in {pv.KIND_LABEL[k] for k in kinds}, (where, row)
                    assert row[2].endswith(("other agents", "other agent", "(v1 engine)")), (where, row)
            else:
                assert section.key == "importances" and trace.type == "bar", where
            if getattr(trace, "mode", None) == "markers" and section.key not in ("claims",):
                assert len(engines) == 1 and len(kinds) == 1, where  # one point, one kind: marker traces never mix
            seen_kinds |= set(kinds)
            seen_engines |= set(engines)
            checked += 1
    assert checked > 60 and seen_engines == {"v1", "v2"}
    assert seen_kinds == set(pv.KIND_LABEL)  # every kind appears somewhere, each named
    # the insights table: each row names its engines and kinds
    for side in ("crowd", "autotune"):
        for r in built.insights[side]:
            name = report._row_name(r)
            assert all(pv.ENGINE_LABEL[e] in name for e in r.engines) and all(pv.KIND_LABEL[k] in name for k in r.kinds)


def test_report_sections_html_and_dashboard(built_report: tuple[report.Report, str]) -> None:
    built, storage = built_report
    keys = [s.key for s in built.sections]
    assert keys == [
        "progress",
        "size",
        "hyperparameters",
        "spread",
        "tsne",
        "compute",
        "importances",
        "claims",
        "replay",
    ]
    (panel,) = [s.figure for s in built.sections if s.key == "spread"]
    assert not isinstance(panel, extract.Empty)
    assert {t.name.split(" (")[0] for t in panel.data} == set(spread.DEFAULT_NETS)
    for s in built.sections:
        if not isinstance(s.figure, extract.Empty):
            assert s.figure.data and all(len(t.x) > 0 for t in s.figure.data if getattr(t, "x", None) is not None)
    replay_panel = next(s.figure for s in built.sections if s.key == "replay")
    assert not isinstance(replay_panel, extract.Empty)
    names = [t.name for t in replay_panel.data]  # the shipped table (2 configurations) + the study's 2 settings
    assert sum(len(t.x) for t in replay_panel.data if str(t.name).startswith("claimed by the author")) == 4
    assert any("v1 engine" in n for n in names) and any("v2 engine" in n for n in names)
    assert built.agents[0] == "no other agents (v1 engine)" and "10 other agents" in built.agents
    page = report.render_html(built)
    assert page.count("<script>/**\n* plotly.js v") == 1  # plotly.js inlined once
    assert "<script src=" not in page  # nothing fetched from the network
    assert "plan for the future" in page and html.escape(insights.METHOD) in page
    assert html.escape(report.IMPORTANCE_METHOD) in page
    assert "value='10 other agents'" in page and "id='agents-filter'" in page
    for line in built.headline.lines:
        assert html.escape(line) in page
    storages = open_storage(storage, "auto", heartbeat=False)
    ids = report.attach_to_dashboard(storages, "auto", built)
    assert ids == [f"autotune-{k}" for k in keys]
    from optuna_dashboard import get_note

    note = str(get_note(optuna.load_study(study_name="auto", storage=storage)))
    assert "## Headline" in note and built.headline.lines[1] in note
    assert "Its value: self-reported score [mph], claimed by the author and not measured" in note
    assert "### crowd (crowd; Holm over this table's 16 tests)" in note
    assert (
        "| size matters | crowd: v2 engine · claimed + local run (self-reported) + approximate or lower bound "
        "(self-reported) + official example (self-reported) | v2 engine | Spearman ρ(param_count, score) | 64 | +0.219 "
        in note
    )
    assert "partial Spearman ρ(param_count, score \\| engine, other agents) | 108 | +0.342" in note
    assert "measured: own weights: 14 net(s), best 75.80 mph (dt-jnorthrup-deeptraffic-v05, 10 other agents)" in note
    assert report.attach_to_dashboard(storages, "auto", built) == ids  # fixed ids: re-running replaces, not duplicates


def test_filter_expressions() -> None:
    columns = ["engine_version", "reported_score_mph", "lanesSide"]
    keep = compile_filter("engine_version == 'v2' and reported_score_mph > 70", columns)
    assert keep({"engine_version": "v2", "reported_score_mph": 71.0, "lanesSide": 1})
    assert not keep({"engine_version": "v2", "reported_score_mph": None, "lanesSide": 1})  # blank: not > 70
    assert not keep({"engine_version": "v1", "reported_score_mph": 75.0, "lanesSide": 1})
    assert compile_filter("lanesSide in [1, 3] or not reported_score_mph == None", columns)(
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


def test_refinement_runs_count_as_nets_not_as_settings() -> None:
    """A refinement run (``refine_of``) is a scored net — the headline's best can be one — but its score is its parent
    net's trained on: the settings panels, the size scatter, t-SNE and the configurations behind importances and
    insights leave it out."""
    study = contract_study(None, n=12)
    best = max(study.trials, key=lambda t: t.value if t.value is not None else -math.inf)
    assert best.value is not None
    attrs = {**best.user_attrs, "refine_of": {"trial": best.number, "budget": None, "score": best.value}}
    study.add_trial(optuna.trial.create_trial(value=best.value + 1.0, params=best.params,
                                              distributions=best.distributions, user_attrs=attrs))  # fmt: skip
    data = data_of(study)
    refined = [t for t in data.scored if t.refined_from is not None]
    assert [(t.number, t.refined_from) for t in refined] == [(12, best.number)]
    assert 12 not in {t.number for t in data.settings_scored} and len(data.settings_scored) == len(data.scored) - 1
    assert max(t.value or 0.0 for t in data.scored) == best.value + 1.0  # the best single net counts it
    assert 12 not in {t.number for t in extract.configurations(data)}
    panel = extract.hyperparameter_panels(data)["gamma"]
    assert isinstance(panel, extract.Panel) and len(panel.points.x) == len(data.settings_scored)
    scatter = extract.size_scatter(data)
    assert isinstance(scatter, extract.SizeScatter) and len(scatter.points.x) == len(data.settings_scored)
