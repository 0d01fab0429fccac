"""The packaged crowd sample: typed, validated records, their training configs and the 25 nets."""

from __future__ import annotations

import csv
import io
import json
import statistics

import pytest

from dashboards import crowd_data as cd
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
    assert [c for c, _f, _k in cd.COLUMNS] == list(raw[0])
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
    assert (gsurma.lanes_side, gsurma.patches_ahead, gsurma.patches_behind, gsurma.other_agents) == (2, 15, 7, 10)
    assert gsurma.l1_decay is None and gsurma.weights_match_config is True and gsurma.same_config_as is None


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
            if getattr(sub, field) is None:
                assert getattr(cfg, field) == default, (sub.id, field)
                checked.add(field)
            else:
                assert getattr(cfg, field) == pytest.approx(getattr(sub, field)), (sub.id, field)
        if sub.start_learn_threshold is None:
            assert cfg.start_learn_threshold == min(cfg.experience_size // 10, 1000)
        assert cfg.ruleset == sub.engine_version
        assert cfg.other_agents == (sub.other_agents or 0)
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
        if cd.param_count(cfg) != sub.n_params:
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
        assert net.n_params == cd.param_count(cfg) == sub.n_params, nid
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
        ("engine_version", "v3", "column engine_version: 'v3' is not one of v1, v2"),
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
