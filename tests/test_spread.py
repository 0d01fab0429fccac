"""The evaluation-spread panel's data (issue 9 §3): standard error and median band against the number of runs."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from autotune.convnet.netjson import load
from autotune.learner.brain_policy import evaluate_net
from dashboards.spread import compute_spread, runs_needed, spread_figure, spread_from_scores
from sim.config import ConfigError

NETS = Path(__file__).resolve().parents[1] / "dashboards" / "data" / "crowd" / "nets"


def test_statistics_of_the_first_n_runs_computed_independently() -> None:
    x = np.random.default_rng(7).normal(70.0, 1.5, 120).round(2)
    s = spread_from_scores("synthetic", x, bootstrap=100, seed=3)
    assert s.n == list(range(1, 121)) and s.scores == x.tolist()
    assert math.isnan(s.se[0]) and math.isnan(s.sd[0])
    for n in range(2, 121):
        first = x[:n]
        assert s.mean[n - 1] == pytest.approx(first.mean(), abs=1e-12)
        assert s.sd[n - 1] == pytest.approx(np.std(first, ddof=1), rel=1e-9)
        assert s.se[n - 1] == pytest.approx(np.std(first, ddof=1) / math.sqrt(n), rel=1e-9)
        assert s.median[n - 1] == np.median(first)
        assert s.median_lo[n - 1] <= s.median_hi[n - 1]
    assert s.runs_projected == math.ceil((np.std(x, ddof=1) / 0.1) ** 2)
    # the band narrows as runs accumulate
    width = np.subtract(s.median_hi, s.median_lo)
    assert width[100:].mean() < width[5:20].mean()
    # seeded: the same seed gives the same band, another seed another one
    again = spread_from_scores("synthetic", x, bootstrap=100, seed=3)
    assert (again.median_lo, again.median_hi) == (s.median_lo, s.median_hi)
    assert spread_from_scores("synthetic", x, bootstrap=100, seed=4).median_lo != s.median_lo


def test_runs_needed_is_where_se_stays_below_the_threshold() -> None:
    nan = float("nan")
    assert runs_needed([nan, 0.3, 0.05, 0.2, 0.08, 0.07], 0.1) == 5
    assert runs_needed([nan, 0.09, 0.05], 0.1) == 2
    assert runs_needed([nan, 0.05, 0.12], 0.1) is None
    x = np.random.default_rng(1).normal(70.0, 0.6, 200)
    s = spread_from_scores("net", x)
    n = s.runs_needed
    assert n is not None and 2 <= n <= 200
    assert all(se < 0.1 for se in s.se[n - 1 :])
    assert n == 2 or s.se[n - 2] >= 0.1


def test_bad_input_names_the_argument() -> None:
    with pytest.raises(ConfigError, match="scores"):
        spread_from_scores("x", [70.0])
    with pytest.raises(ConfigError, match="threshold"):
        spread_from_scores("x", [70.0, 71.0], threshold=0)


def test_spread_of_a_crowd_net_with_the_exact_evaluator() -> None:
    net, settings = load(NETS / "dt-jnorthrup-deeptraffic-v05.json")
    data = compute_spread([("jnorthrup", net, settings)], runs=60, frames=500, bootstrap=50)
    ref = evaluate_net(net, settings, "v2-official", runs=60, frames=500)
    (s,) = data.nets
    assert s.scores == ref.scores  # the evaluator's per-run scores, in run order
    assert (data.protocol, data.runs, data.frames) == ("v2-official", 60, 500)
    assert np.mean(s.se[40:]) < np.mean(s.se[5:15])  # falls roughly as 1/√n
    assert s.se[-1] == pytest.approx(np.std(ref.scores, ddof=1) / math.sqrt(60), rel=1e-9)
    fig = spread_figure(data)
    assert len(fig.data) == 3 and all(len(t.x) > 0 for t in fig.data)
