"""The packaged crowd sample: typed, validated records, their training configs and the 25 nets."""

from __future__ import annotations

import concurrent.futures
import csv
import dataclasses
import io
import json
import multiprocessing
import statistics
from pathlib import Path

import pytest

from autotune.learner.config import TrainConfig
from dashboards import crowd_data as cd
from dashboards import measured
from dashboards.crowd_replay import _configure_worker, replay_seed, replay_tasks, run_task
from tests.conftest import CROWD


@pytest.fixture(scope="module")
def subs() -> tuple[cd.Submission, ...]:
    return cd.load_submissions()


def _csv_text() -> str:
    return (cd.data_dir() / "submissions.csv").read_text(encoding="utf-8")


def test_known_counts(subs: tuple[cd.Submission, ...]) -> None:
    assert len(subs) == 164
    assert len({s.repo for s in subs}) == 46
    assert len({s.config_hash for s in subs}) == 155
    assert sum(s.engine_version == "v1" for s in subs) == 74
    scored = [s.reported_score_mph for s in subs if s.reported_score_mph is not None]
    assert len(scored) == 117
    assert statistics.median(scored) == pytest.approx(69.62)
    best = max((s for s in subs if s.scored), key=lambda s: s.reported_score_mph or 0)
    assert (best.id, best.reported_score_mph, best.engine_version) == ("dt-jordanott-deep-traffic-v03", 75.86, "v1")
    assert best.version_date is not None and best.version_date.year == 2017
    assert sum(s.in_nets_dir for s in subs) == 25 == len(cd.net_ids())


def test_package_copy_is_the_shared_data() -> None:
    if not CROWD.is_dir():
        pytest.skip("../shared/crowd not beside the checkout")
    assert _csv_text() == (CROWD / "submissions.csv").read_text(encoding="utf-8")
    assert sorted(p.name for p in (cd.data_dir() / "nets").iterdir()) == sorted(
        p.name for p in (CROWD / "nets").iterdir()
    )


def test_every_column_is_kept_and_typed(subs: tuple[cd.Submission, ...]) -> None:
    raw = list(csv.DictReader(io.StringIO(_csv_text())))
    columns = [c for c, _f, _k in cd.COLUMNS]
    assert set(raw[0]) <= set(columns) and len(columns) == len(set(columns))
    assert set(columns) - set(raw[0]) == {"ro", "eps"}  # settings of sim.fields the crowd files never set
    for sub, row in zip(subs, raw, strict=True):
        back = sub.row()
        for column, text in row.items():
            value = back[column]
            if text == "":
                assert value in (None, ""), (sub.id, column)
            elif isinstance(value, bool):
                assert text == str(value).lower()
            elif isinstance(value, (int, float)):
                assert float(text) == value, (sub.id, column)
            else:
                assert value == text, (sub.id, column)
    gsurma = next(s for s in subs if s.id == "dt-gsurma-deep-traffic-v00")
    s = gsurma.settings
    assert (s.lanes_side, s.patches_ahead, s.patches_behind, s.other_agents, s.ruleset) == (2, 15, 7, 10, "v2")
    assert s.l1_decay is None and gsurma.weights_match_config is True and gsurma.same_config_as is None
    assert gsurma.row()["lanesSide"] == 2 and gsurma.namespace()["lanes_side"] == 2


def test_blanks_take_the_library_defaults(subs: tuple[cd.Submission, ...]) -> None:
    """A blank cell = not set in the file: deepqlearn's opt defaults, convnetjs Trainer defaults for options."""
    checked = set()
    for sub in subs:
        try:
            cfg = cd.train_config(sub)
        except cd.CrowdDataError:
            continue
        for field, default in (
            ("gamma", 0.8),
            ("epsilon_min", 0.05),
            ("epsilon_test_time", 0.01),
            ("learning_steps_total", 100000),
            ("learning_steps_burnin", 3000),
            ("learning_rate", 0.01),
            ("momentum", 0.9),  # the files give tdtrainer_options, so the Trainer's momentum applies
            ("l2_decay", 0.0),
        ):
            if getattr(sub.settings, field) is None:
                assert getattr(cfg, field) == default, (sub.id, field)
                checked.add(field)
            else:
                assert getattr(cfg, field) == pytest.approx(getattr(sub.settings, field)), (sub.id, field)
        if sub.settings.start_learn_threshold is None:
            assert cfg.start_learn_threshold == min(cfg.experience_size // 10, 1000)
        assert cfg.ruleset == sub.engine_version
        assert cfg.other_agents == (sub.settings.other_agents or 0)
    assert checked >= {"learning_rate", "momentum", "l2_decay", "epsilon_min"}


def test_configs_and_param_counts(subs: tuple[cd.Submission, ...]) -> None:
    failed = {}
    mismatched = []
    for sub in subs:
        try:
            cfg = cd.train_config(sub)
        except cd.CrowdDataError as exc:
            failed[sub.id] = str(exc)
            continue
        if cfg.param_count != sub.n_params:
            mismatched.append(sub.id)
    # outside the learner's ranges: an empty replay memory and momentum 5
    assert set(failed) == {"dt-lupuleasa-core-deeptraffic-v32", "dt-peachpower-deeptraffic-v00"}
    assert "experience_size: 0" in failed["dt-lupuleasa-core-deeptraffic-v32"]
    assert "momentum: 5.0" in failed["dt-peachpower-deeptraffic-v00"]
    # the crowd counted 4-action nets (lupuleasa v01-v03) with 4 outputs and merged m-quadra's fc(5)+regression;
    # our learner builds 5 outputs and convnetjs inserts an fc(5) before the regression
    assert sorted(mismatched) == [f"dt-lupuleasa-core-deeptraffic-v0{i}" for i in (1, 2, 3)] + [
        "dt-m-quadra-deeptraffic-v05"
    ]
    linear = next(s for s in subs if s.id == "dt-deveshtarasia-deeptraffic-v02")
    assert linear.layer_defs_missing and cd.train_config(linear).layers == ()


def test_the_25_nets_load_and_match_their_rows(subs: tuple[cd.Submission, ...]) -> None:
    by_id = {s.id: s for s in subs}
    for nid in cd.net_ids():
        net, settings = cd.load_net(nid)
        sub = by_id[nid]
        assert sub.in_nets_dir and sub.scored and sub.weights_match_config
        cfg = cd.train_config(sub)
        assert net.input_size == cfg.net_inputs == sub.net_inputs_std, nid
        assert settings.engine == sub.engine_version
        assert net.n_params == cfg.param_count == sub.n_params, nid
        config = json.loads((cd.data_dir() / "nets" / f"{nid}.config.json").read_text())
        assert config["reported_score_mph"] == sub.reported_score_mph


def _mutate(column: str, value: str, row: int = 3) -> str:
    rows = list(csv.DictReader(io.StringIO(_csv_text())))
    rows[row - 1][column] = value
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    return out.getvalue()


@pytest.mark.parametrize(
    ("column", "value", "message"),
    [
        ("gamma", "high", "column gamma: 'high' is not a number"),
        ("batch_size", "12.5", "column batch_size: '12.5' is not an integer"),
        ("lanesSide", "", "column lanesSide: is blank"),
        ("has_weights", "yes", "column has_weights: 'yes' is not true/false"),
        ("engine_version", "v3", "column engine_version: 'v3' is not allowed; did you mean 'v2'? (use one of v1, v2)"),
        ("engine_version", "", "column engine_version: is blank"),
        ("trainer_method", "adam", "column trainer_method: 'adam' is not allowed; did you mean 'adagrad'?"),
        ("score_kind", "bragged", "column score_kind: 'bragged' is not one of"),
        ("version_date", "2017-13-01", "column version_date: '2017-13-01' is not a YYYY-MM-DD date"),
        ("num_hidden_layers", "9", "column num_hidden_layers: 9 ≠"),
    ],
)
def test_bad_cells_name_row_and_column(column: str, value: str, message: str) -> None:
    with pytest.raises(cd.CrowdDataError) as err:
        cd.parse_submissions(_mutate(column, value))
    assert "row 3 (id " in str(err.value) and message in str(err.value)


def test_bad_header_and_duplicates() -> None:
    text = _csv_text()
    with pytest.raises(cd.CrowdDataError, match="gama.*did you mean 'gamma'"):
        cd.parse_submissions(text.replace(",gamma,", ",gama,", 1))
    first_id = next(csv.DictReader(io.StringIO(text)))["id"]
    with pytest.raises(cd.CrowdDataError, match="row 2, column id: .* repeats row 1"):
        cd.parse_submissions(_mutate("id", first_id, row=2))
    with pytest.raises(Exception, match="crowd net.*dt-gsurma-deep-traffic-v00"):
        cd.net_path("dt-gsurma-deep-trafic-v00")


def test_frames_estimate(subs: tuple[cd.Submission, ...]) -> None:
    assert cd.frames_estimate(subs[0]) == 30 * 500000
    assert sum(cd.frames_estimate(s) is None for s in subs) == 1


# --- the measured crowd shipped beside the data (issue 15 §3) ------------------------------------------------


def test_shipped_own_net_scores(subs: tuple[cd.Submission, ...]) -> None:
    """25 nets, each scored in its own engine with its official protocol, its own agents, beside its claim."""
    shipped = measured.load_own_nets()
    assert [s.crowd_id for s in shipped] == list(cd.net_ids())
    by_id = {s.id: s for s in subs}
    for s in shipped:
        sub = by_id[s.crowd_id]
        assert s.engine == sub.engine_version and s.protocol == {"v1": "v1-original", "v2": "v2-official"}[s.engine]
        assert (s.seed, s.runs, s.frames) == {"v1": (2000, 10, 100_000), "v2": (1, 500, 2000)}[s.engine]
        assert s.other_agents == sub.other_agents  # None in v1
        assert (s.claimed, s.claim_kind, s.claim_confidence) == (
            sub.reported_score_mph, sub.score_kind, sub.score_confidence,
        )  # fmt: skip
    doc = json.loads((cd.data_dir() / measured.OWN_NETS_FILE).read_text())
    assert doc["command"] == measured.OWN_NETS_COMMAND == "python tools/crowd_measurements.py own-nets"
    best_v2 = max((s for s in shipped if s.engine == "v2"), key=lambda s: s.score)
    assert (best_v2.crowd_id, best_v2.score, best_v2.other_agents) == ("dt-jnorthrup-deeptraffic-v05", 75.80, 10)


@pytest.mark.parametrize(
    "nid", ["dt-huaweiren-deeptraffic-v01", "dt-vol0324-deeptraffic-v00", "dt-jeremy26-deep-traffic-v00"]
)
def test_shipped_own_net_scores_recompute_exactly(nid: str) -> None:
    shipped = {s.crowd_id: s for s in measured.load_own_nets()}[nid]
    again = measured.score_own_net(nid)
    assert dataclasses.replace(again, seconds=0.0) == dataclasses.replace(shipped, seconds=0.0)


def test_shipped_replay_table_holds_every_selected_configuration() -> None:
    """All 35 selected configurations (20 best-claimed v2, 15 v1), each retrained at its own trainIterations
    (no cap) in its own engine from ≥ 2 seeds, every seed scored; the command that regenerates it is recorded."""
    table = measured.load_replay()
    assert table is not None, "replay.json is not shipped: python tools/crowd_measurements.py replay --workers N"
    groups = measured.replay_selection()
    assert [e.crowd_id for e in table.entries] == [g[0].id for g in groups]
    assert table.max_iterations is None and table.seeds >= 2
    assert table.command.startswith("python tools/crowd_measurements.py replay")
    for e, rows in zip(table.entries, groups, strict=True):
        sub = rows[0]
        assert e.train_iterations == cd.train_config(sub).train_iterations and e.engine == sub.engine_version
        assert e.protocol == {"v1": "v1-original", "v2": "v2-official"}[e.engine]
        assert [r.seed_index for r in e.runs] == list(range(table.seeds))
        assert [r.seed for r in e.runs] == [replay_seed(e.crowd_id, k) for k in range(table.seeds)]
        for r in e.runs:  # every seed scored, or stopped by a divergence the learner detected (a trial state)
            assert (r.state, r.cause) == ("complete", None) or (r.state == "pruned" and "diverged" in str(r.cause))
    unscored = {e.crowd_id for e in table.entries if not e.scores}
    assert unscored == {"dt-blackvitriol-rl-v00", "dt-jordanott-deep-traffic-v03"}  # NaN in both seeds
    assert all(len(e.scores) == table.seeds for e in table.entries if e.crowd_id not in unscored)
    from dashboards.report import _unscored_replays

    named = _unscored_replays(table)  # the report's replay panel says which have no point, and why
    assert all(f"{i} (" in named for i in unscored) and named.count("diverged in all 2 seeds") == 2


def test_shipped_replay_scores_recompute_exactly() -> None:
    """The cheapest entry's first seed, trained again by the same task: the same official score, to the digit."""
    from autotune.search.cost import CostModel

    table = measured.load_replay()
    assert table is not None
    tasks = {(t.crowd_id, t.seed_index): t for t in replay_tasks(measured.replay_selection(), table.seeds)}
    prior = CostModel.prior()
    scored = [e for e in table.entries if e.runs[0].score is not None]
    cheapest = min(scored, key=lambda e: prior.predict(TrainConfig.from_mapping(tasks[e.crowd_id, 0].config)))
    context = multiprocessing.get_context("spawn")  # as the table was made: a fresh worker, one thread
    with concurrent.futures.ProcessPoolExecutor(1, mp_context=context, initializer=_configure_worker) as pool:
        again = pool.submit(run_task, tasks[cheapest.crowd_id, 0]).result()
    assert (again.state, again.score, again.seed) == ("complete", cheapest.runs[0].score, cheapest.runs[0].seed)


def test_measured_files_fail_with_the_file_entry_and_key(tmp_path: Path) -> None:
    doc = json.loads((cd.data_dir() / measured.OWN_NETS_FILE).read_text())
    path = tmp_path / "own_nets.json"
    del doc["nets"][3]["protocol"]
    path.write_text(json.dumps(doc))
    with pytest.raises(measured.MeasuredDataError, match=r"own_nets.json: nets\[3\]: missing key 'protocol'"):
        measured.load_own_nets(path)
    doc["nets"][3]["protocol"] = "v2-official"
    doc["nets"][1]["score"] = "fast"
    path.write_text(json.dumps(doc))
    with pytest.raises(measured.MeasuredDataError, match=r"nets\[1\], key 'score': 'fast' is not a float"):
        measured.load_own_nets(path)
    path.write_text("[1, 2")
    with pytest.raises(measured.MeasuredDataError, match="own_nets.json: not JSON"):
        measured.load_own_nets(path)
    assert measured.load_replay(tmp_path / "absent.json") is None  # the replay table is optional


def test_replay_selection_and_table_round_trip(tmp_path: Path) -> None:
    groups = measured.replay_selection()
    assert [g[0].engine_version for g in groups] == ["v2"] * 20 + ["v1"] * 15
    hashes = [g[0].config_hash for g in groups]
    assert len(set(hashes)) == 35  # identical settings once
    for g in groups:
        assert {s.config_hash for s in g} == {g[0].config_hash} and g[0].reported_score_mph == max(
            s.reported_score_mph or 0 for s in g
        )
    v2 = [g[0].reported_score_mph or 0 for g in groups[:20]]
    assert v2 == sorted(v2, reverse=True) and v2[0] == 75.85
    others = [s for s in cd.load_submissions() if s.scored and s.engine_version == "v2" and s.config_hash not in hashes]
    assert max(s.reported_score_mph or 0 for s in others) <= v2[-1]  # nothing better-claimed left out
    jordanott = next(g for g in groups if g[0].id == "dt-jordanott-deep-traffic-v03")
    assert [s.id for s in jordanott] == [
        "dt-jordanott-deep-traffic-v03",
        "dt-darshanbagul-mit-6-s094-selfdrivingcars-v00",
    ]
    run = measured.ReplayRun(0, 5, "complete", 70.25, 3.5, None)
    failed = measured.ReplayRun(1, 6, "failed", None, 1.0, "RuntimeError: boom")
    entry = measured.ReplayEntry(
        "dt-x-v00", "abc", ("dt-x-v00",), "v2", 3, "v2-official", 100, 71.0, "claimed", "high", (run, failed)
    )
    table = measured.ReplayTable("python tools/crowd_measurements.py replay", 2, None, (entry,))
    path = measured.write_document(measured.replay_document(table), tmp_path / "replay.json")
    assert measured.load_replay(path) == table
    assert (entry.mean, entry.sd, entry.scores, entry.seconds) == (70.25, None, [70.25], 4.5)
    doc = json.loads(path.read_text())
    assert doc["entries"][0]["n"] == 1 and doc["entries"][0]["mean"] == 70.25
