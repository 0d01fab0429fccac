"""The spread panel (issue 15 §4): the site's own statistic under many protocol seeds, per net in its own engine."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from dashboards import crowd_data, spread
from dashboards import provenance as pv
from sim.config import ConfigError
from sim.protocols import site_median


@pytest.fixture(scope="module")
def shipped() -> spread.SpreadData:
    return spread.load_spread()


def test_runs_grid() -> None:
    assert spread.runs_grid(500) == [1, 2, 3, 5, 10, 20, 30, 50, 100, 200, 300, 500]
    assert spread.runs_grid(10) == [1, 2, 3, 5, 10]
    assert spread.runs_grid(7) == [1, 2, 3, 5, 7]


def test_shipped_spread_covers_each_net_in_its_own_engine(shipped: spread.SpreadData) -> None:
    assert [n.name for n in shipped.nets] == list(spread.DEFAULT_NETS)
    subs = {s.id: s for s in crowd_data.load_submissions()}
    for net in shipped.nets:
        _model, settings = crowd_data.load_net(net.name)
        assert net.engine == settings.engine == subs[net.name].engine_version  # no v1 net scored in v2
        assert net.protocol == {"v1": "v1-original", "v2": "v2-official"}[net.engine]
        assert net.other_agents == (settings.other_agents if net.engine == "v2" else None)
        assert len(net.seeds) >= 50 and net.seeds == list(range(net.seeds[0], net.seeds[0] + len(net.seeds)))
        assert net.seeds[0] == {"v1": 2000, "v2": 1}[net.engine]  # the protocol's own seed first: the site's number
        assert net.n == spread.runs_grid(net.n[-1]) and net.n[-1] == {"v1": 10, "v2": 500}[net.engine]
        assert len(net.own_runs) == net.n[-1] and net.site[0][-1] == site_median(net.own_runs)
        assert net.claimed == subs[net.name].reported_score_mph
    assert {n.engine for n in shipped.nets} == {"v1", "v2"}


def test_shipped_numbers_recompute_exactly(shipped: spread.SpreadData, tmp_path: Path) -> None:
    """Two seeds of the v1 net and one of a v2 net, evaluated again with the exact evaluator (short prefixes: an
    n-run evaluation is the first n runs of a longer one), match the shipped statistics to the last digit."""
    v1 = next(n for n in shipped.nets if n.engine == "v1")
    recomputed = spread.compute_net_spread(v1.name, 2, cache=tmp_path)
    assert recomputed.site == v1.site[:2] and recomputed.mean == v1.mean[:2] and recomputed.own_runs == v1.own_runs
    assert len(list(tmp_path.glob("*.json"))) == 2  # per-seed cache
    again = spread.compute_net_spread(v1.name, 2, cache=tmp_path)  # read back, not evaluated again
    assert again == recomputed
    from autotune.learner.brain_policy import evaluate_net

    v2 = next(n for n in shipped.nets if n.engine == "v2" and n.epsilon_test_time > 0)
    net, settings = crowd_data.load_net(v2.name)
    k = 7  # the 8th seed
    result = evaluate_net(net, settings, v2.protocol, seed=v2.seeds[k], runs=20)
    assert [site_median(result.scores[:n]) for n in v2.n if n <= 20] == v2.site[k][: v2.n.index(20) + 1]


def test_spread_statistics_recomputed(shipped: spread.SpreadData) -> None:
    for net in shipped.nets:
        s = spread.spread_stats(net, shipped.threshold)
        site = np.array(net.site)
        assert s.sd == pytest.approx([float(np.std(site[:, j], ddof=1)) for j in range(len(net.n))], abs=1e-12)
        assert s.full == [row[-1] for row in net.site]
        assert s.runs_needed == spread.runs_needed(net.n, s.sd, shipped.threshold)
        assert len(s.bootstrap_sd) == len(net.n) and s.bootstrap_sd == spread.bootstrap_sd(net.own_runs, net.n)
        assert s.bootstrap_sd[-1] < s.bootstrap_sd[0]  # more runs per evaluation, less spread
    greedy = next(n for n in shipped.nets if n.engine == "v2" and n.epsilon_test_time == 0)
    exploring = next(n for n in shipped.nets if n.engine == "v2" and n.epsilon_test_time > 0)
    # the v2 protocol fixes each run's traffic seed: a net that never explores gets one number under every seed
    assert len({tuple(row) for row in greedy.site}) == 1  # the same statistic under all 50 seeds, for every n
    assert max(spread.spread_stats(greedy).sd) < 1e-12 and spread.spread_stats(greedy).runs_needed == 1
    assert spread.spread_stats(exploring).sd[-1] > 0 and len(set(spread.spread_stats(exploring).full)) > 1


def test_site_median_fast_path_is_the_site_median() -> None:
    rows = np.random.default_rng(2).uniform(10.0, 99.99, size=(50, 21)).round(2)
    assert spread._site_medians(rows).tolist() == [site_median(r) for r in rows]
    low = rows.copy()
    low[:, 0] = 9.5  # "9.5" sorts after "10...": the slow path
    assert spread._site_medians(low).tolist() == [site_median(r) for r in low]


def test_runs_needed_is_where_sd_stays_below_the_threshold() -> None:
    n = [1, 2, 3, 5, 10]
    assert spread.runs_needed(n, [0.3, 0.05, 0.2, 0.08, 0.07], 0.1) == 5
    assert spread.runs_needed(n, [0.09, 0.09, 0.05, 0.0, 0.0], 0.1) == 1
    assert spread.runs_needed(n, [0.05, 0.05, 0.05, 0.05, 0.12], 0.1) is None


def test_load_errors_name_the_file(tmp_path: Path, shipped: spread.SpreadData) -> None:
    bad = tmp_path / "spread.json"
    bad.write_text("{")
    with pytest.raises(ConfigError, match="spread.json: not a spread file"):
        spread.load_spread(bad)
    doc = spread.spread_document(shipped)
    doc["nets"][2]["protocol"] = "v2-official"  # a v1 net claimed to be scored in v2
    bad.write_text(json.dumps(doc))
    with pytest.raises(ConfigError, match="engine 'v1' with protocol 'v2-official'"):
        spread.load_spread(bad)
    with pytest.raises(ConfigError, match="cannot read"):
        spread.load_spread(tmp_path / "absent.json")
    with pytest.raises(ConfigError, match="seeds: need at least 2"):
        spread.compute_net_spread(spread.DEFAULT_NETS[0], 1, cache=None)


def test_truncated_runs_and_figure(shipped: spread.SpreadData) -> None:
    short = spread.load_spread_runs(50)
    for net, full in zip(short.nets, shipped.nets, strict=True):
        assert net.n == [n for n in full.n if n <= 50] or (net.n == full.n[:2])
        assert [row[: len(net.n)] for row in full.site] == net.site
    assert dataclasses.replace(spread.load_spread_runs(None), nets=()) == dataclasses.replace(shipped, nets=())
    fig = spread.spread_figure(shipped)
    assert len(fig.data) == 4 * len(shipped.nets)  # seeds box, the claim, sd over seeds, bootstrap sd
    for trace in fig.data:
        assert len(trace.y) > 0 and pv.ENGINE_LABEL[trace.meta["engines"][0]] in trace.name
