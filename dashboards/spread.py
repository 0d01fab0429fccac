"""How many evaluation runs a score needs: its spread against the number of runs (issue 9 §3, the paper's figure).

A DeepTraffic score is a statistic over runs (the site: the median of 500 runs of 2,000 frames).
For a few nets, ``compute_spread`` scores N runs with the exact evaluator and, for n = 1…N,
reports the standard error of the mean of the first n runs, a seeded bootstrap band of their
median, and how many runs it takes until the standard error stays below 0.1 mph. Plain data
(``SpreadData``), then ``spread_figure`` draws it. Scoring goes through
``autotune.learner.brain_policy.evaluate_net`` (numba; no torch, no ray).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from autotune.convnet.netjson import NetSettings
from autotune.convnet.spec import ConvNet
from autotune.learner.brain_policy import evaluate_net
from sim.config import ConfigError
from sim.protocols import V2_OFFICIAL

SE_THRESHOLD = 0.1  # mph: the resolution at which leaderboard scores are compared
DEFAULT_NETS = (  # three crowd nets of different sizes and engines (dashboards/data/crowd/nets)
    "dt-jnorthrup-deeptraffic-v05",
    "dt-luyao777-self-driving-v02",
    "dt-anuj-dimri25-deep-traffic-v00",
)


@dataclasses.dataclass(frozen=True)
class NetSpread:
    """One net's per-run scores and, for n = 1…N runs, the statistics of the first n."""

    name: str
    """The net's name."""
    scores: list[float]
    """Per-run scores in run order [mph]."""
    n: list[int]
    """1…N."""
    mean: list[float]
    """Mean of the first n runs [mph]."""
    sd: list[float]
    """Sample standard deviation (ddof = 1) of the first n runs; NaN at n = 1 [mph]."""
    se: list[float]
    """Standard error of the mean, sd/√n; NaN at n = 1 [mph]."""
    median: list[float]
    """Median of the first n runs [mph]."""
    median_lo: list[float]
    """2.5 % bootstrap percentile of the median of n runs resampled from the first n [mph]."""
    median_hi: list[float]
    """97.5 % bootstrap percentile [mph]."""
    runs_needed: int | None
    """Smallest n ≥ 2 from which se stays below the threshold up to N; None if never within N."""
    runs_projected: int
    """⌈(sd_N / threshold)²⌉: the runs the full sample's spread implies (also when N is too small)."""


@dataclasses.dataclass(frozen=True)
class SpreadData:
    """The spread panel's data: one ``NetSpread`` per net, and how they were scored."""

    protocol: str
    """Evaluation protocol (``sim.protocols``) the runs come from."""
    runs: int
    """N, runs per net."""
    frames: int
    """Frames per run."""
    seed: int | None
    """Protocol seed (None: the protocol's own)."""
    threshold: float
    """Standard-error threshold [mph]."""
    bootstrap: int
    """Bootstrap resamples per n."""
    bootstrap_seed: int
    """Seed of the bootstrap's generator."""
    nets: tuple[NetSpread, ...]
    """One entry per net, in the order given."""


def runs_needed(se: Sequence[float], threshold: float) -> int | None:
    """Smallest n (1-based, n ≥ 2) such that se[m − 1] < threshold for every m ≥ n; None if se[-1] ≥ threshold."""
    needed = None
    for k in range(len(se) - 1, 0, -1):  # from the end backwards while below
        if not se[k] < threshold:
            break
        needed = k + 1
    return needed


def spread_from_scores(
    name: str,
    scores: Sequence[float] | np.ndarray,
    *,
    threshold: float = SE_THRESHOLD,
    bootstrap: int = 200,
    seed: int = 0,
) -> NetSpread:
    """The statistics of the first n of ``scores`` for n = 1…N (bootstrap from ``numpy.random.default_rng(seed)``)."""
    x = np.asarray(scores, dtype=np.float64)
    if x.ndim != 1 or len(x) < 2:
        raise ConfigError(f"scores: need at least 2 runs, got {x.shape}")
    if threshold <= 0:
        raise ConfigError(f"threshold: must be > 0, got {threshold}")
    if bootstrap < 1:
        raise ConfigError(f"bootstrap: must be ≥ 1, got {bootstrap}")
    n = np.arange(1, len(x) + 1)
    csum = np.cumsum(x)
    mean = csum / n
    # running sample variance from sums of the data shifted by its first value (no cancellation at ~70 mph)
    d = x - x[0]
    dmean = np.cumsum(d) / n
    with np.errstate(invalid="ignore", divide="ignore"):
        var = (np.cumsum(d * d) - n * dmean * dmean) / (n - 1)
    sd = np.sqrt(np.maximum(var, 0.0))
    sd[0] = np.nan
    se = sd / np.sqrt(n)
    median = np.array([np.median(x[:k]) for k in n])
    rng = np.random.default_rng(seed)
    lo = np.empty(len(x))
    hi = np.empty(len(x))
    for k in n:
        sample = x[:k][rng.integers(0, k, size=(bootstrap, k))]
        meds = np.median(sample, axis=1)
        lo[k - 1], hi[k - 1] = np.percentile(meds, [2.5, 97.5])
    return NetSpread(
        name=name,
        scores=x.tolist(),
        n=n.tolist(),
        mean=mean.tolist(),
        sd=sd.tolist(),
        se=se.tolist(),
        median=median.tolist(),
        median_lo=lo.tolist(),
        median_hi=hi.tolist(),
        runs_needed=runs_needed(se.tolist(), threshold),
        runs_projected=max(1, math.ceil((sd[-1] / threshold) ** 2)),
    )


def compute_spread(
    nets: Sequence[tuple[str, ConvNet, NetSettings]],
    *,
    protocol: str = V2_OFFICIAL,
    runs: int = 500,
    frames: int = 2000,
    seed: int | None = None,
    ruleset: str | None = None,
    threshold: float = SE_THRESHOLD,
    bootstrap: int = 200,
    bootstrap_seed: int = 0,
) -> SpreadData:
    """Score every ``(name, net, settings)`` over ``runs`` runs with the exact evaluator and tabulate the spread.

    Default: the site's v2 protocol (run k ↦ Park–Miller seed k + 1), its own compiled loop —
    the fastest exact path for one net (~1 s per 100 runs); ``protocol="custom"`` runs
    independent worlds instead (world i ↦ seed + i).
    """
    if runs < 2:
        raise ConfigError(f"runs: need at least 2, got {runs}")
    out = []
    for name, net, settings in nets:
        result = evaluate_net(net, settings, protocol, ruleset=ruleset, seed=seed, runs=runs, frames=frames, name=name)
        out.append(
            spread_from_scores(name, result.scores, threshold=threshold, bootstrap=bootstrap, seed=bootstrap_seed)
        )
    return SpreadData(
        protocol=protocol,
        runs=runs,
        frames=frames,
        seed=seed,
        threshold=threshold,
        bootstrap=bootstrap,
        bootstrap_seed=bootstrap_seed,
        nets=tuple(out),
    )


def crowd_spread(ids: Sequence[str] = DEFAULT_NETS, **kwargs: object) -> SpreadData:
    """``compute_spread`` for crowd nets shipped with the package (default: three of different sizes)."""
    from dashboards import crowd_data

    nets = [(nid, *crowd_data.load_net(nid)) for nid in ids]
    return compute_spread(nets, **kwargs)  # type: ignore[arg-type]


def spread_figure(data: SpreadData):  # noqa: ANN201 - plotly.graph_objects.Figure (plotly is imported lazily)
    """Two panels: standard error against runs (threshold line, first n below it) and the median's bootstrap band."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    fig = make_subplots(
        rows=1,
        cols=2,
        subplot_titles=("standard error of the mean score", "median score, 95 % bootstrap band"),
    )
    colors = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b")
    for k, net in enumerate(data.nets):
        color = colors[k % len(colors)]
        label = f"{net.name} (se < {data.threshold:g} from n = {net.runs_needed or '>' + str(data.runs)})"
        fig.add_trace(
            go.Scatter(x=net.n[1:], y=net.se[1:], name=label, line={"color": color}, legendgroup=net.name),
            row=1,
            col=1,
        )
        fig.add_trace(
            go.Scatter(
                x=net.n + net.n[::-1],
                y=net.median_hi + net.median_lo[::-1],
                fill="toself",
                line={"width": 0},
                fillcolor=color,
                opacity=0.2,
                showlegend=False,
                legendgroup=net.name,
                hoverinfo="skip",
            ),
            row=1,
            col=2,
        )
        fig.add_trace(
            go.Scatter(x=net.n, y=net.median, line={"color": color}, showlegend=False, legendgroup=net.name),
            row=1,
            col=2,
        )
    fig.add_hline(y=data.threshold, line_dash="dash", line_color="gray", row=1, col=1)
    fig.update_xaxes(title_text="evaluation runs n", type="log")
    fig.update_yaxes(title_text="mph", type="log", row=1, col=1)
    fig.update_yaxes(title_text="mph", row=1, col=2)
    fig.update_layout(
        title=f"Score spread against evaluation runs ({data.protocol}, {data.frames} frames per run)",
        legend={"orientation": "h", "y": -0.2},
    )
    return fig


__all__ = [
    "DEFAULT_NETS",
    "NetSpread",
    "SE_THRESHOLD",
    "SpreadData",
    "compute_spread",
    "crowd_spread",
    "runs_needed",
    "spread_figure",
    "spread_from_scores",
]
