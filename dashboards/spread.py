"""How much the site's own score moves: the official protocol under many seeds, per net (issue 15 §4).

The site's number is not a mean: it is the lexicographic median (``sim.protocols.site_median``) of
one evaluation's runs, and the evaluation is deterministic for its ``Math.random`` seed. So the
spread of the number a resubmission would show is the spread of that statistic over protocol
seeds. For each net (scored in its own engine, with its own other agents) ``compute_net_spread``
runs the official protocol under ``seeds`` consecutive seeds from the protocol's own (the site's
number is seed 0's) and records, for every n of a grid of runs per evaluation, the site statistic
of the first n runs — an evaluation of n runs is exactly the first n runs of a longer one, since
the protocols are sequential. Per-seed evaluations are cached as JSON under ``runs/.spread-cache``
(resumable); the result ships as ``data/crowd/spread.json`` (``tools/crowd_measurements.py
spread`` regenerates it), because 50 seeds × 3 nets take about 15 minutes of CPU.

``SpreadData`` is plain data; ``spread_stats`` derives what the panel shows (spread of the site
statistic per n: sd, 2.5–97.5 % range, runs until the sd stays below 0.1 mph); ``spread_figure``
draws it.
"""

from __future__ import annotations

import dataclasses
import json
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dashboards import provenance as pv
from sim.config import ConfigError
from sim.protocols import OFFICIAL, PROTOCOLS, site_median

__all__ = [
    "SPREAD_FILE",
    "SPREAD_CACHE",
    "SPREAD_COMMAND",
    "DEFAULT_NETS",
    "DEFAULT_SEEDS",
    "SD_THRESHOLD",
    "NetSpread",
    "SpreadData",
    "SpreadStats",
    "runs_grid",
    "compute_net_spread",
    "crowd_spread",
    "spread_document",
    "load_spread",
    "load_spread_runs",
    "spread_stats",
    "runs_needed",
    "spread_figure",
]

FORMAT = 1
SPREAD_FILE = "spread.json"
SPREAD_CACHE = Path("runs") / ".spread-cache"
SPREAD_COMMAND = "python tools/crowd_measurements.py spread"
SD_THRESHOLD = 0.1  # mph: the resolution at which leaderboard scores are compared
DEFAULT_SEEDS = 50
DEFAULT_NETS = (  # dashboards/data/crowd/nets: a greedy v2 net, a v2 net exploring at test time, a v1 net
    "dt-jnorthrup-deeptraffic-v05",  # v2, 10 other agents, epsilon_test_time 0
    "dt-anirudhrbhat-deep-learning-for-self-driving-v00",  # v2, 4 other agents, epsilon_test_time 0.01
    "dt-anuj-dimri25-deep-traffic-v00",  # v1 (scored in v1-original), epsilon_test_time 0
)
BOOTSTRAP, BOOTSTRAP_SEED = 1000, 0


def runs_grid(runs: int) -> list[int]:
    """Runs per evaluation at which the statistic is recorded: 1, 2, 3, 5, 10, 20, 30, 50, … up to ``runs``."""
    grid = {runs}
    scale = 1
    while scale <= runs:
        grid.update(v * scale for v in (1, 2, 3, 5) if v * scale <= runs)
        scale *= 10
    return sorted(grid)


@dataclasses.dataclass(frozen=True)
class NetSpread:
    """One net's official protocol under many seeds: the site statistic of the first n runs, per seed."""

    name: str
    """The crowd id of the net."""
    engine: str
    """Engine the net was trained for and is scored in."""
    other_agents: int | None
    """Other agents on the road (the net's own; None in v1)."""
    protocol: str
    """Official protocol of the engine."""
    frames: int
    """Frames per run."""
    claimed: float | None
    """The author's reported score [mph] (for context; never pooled with the measurements)."""
    seeds: list[int]
    """Protocol seeds (the protocol's own first: its result is the number the site showed)."""
    n: list[int]
    """Runs per evaluation (``runs_grid`` of the protocol's runs)."""
    site: list[list[float]]
    """site[i][j]: the site statistic (lexicographic median) of the first n[j] runs under seeds[i] [mph]."""
    mean: list[list[float]]
    """mean[i][j]: the mean of those runs [mph] (for comparison)."""
    epsilon_test_time: float
    """The net's exploration at test time: the only use of Math.random in a v2 evaluation (v1 draws traffic too)."""
    own_runs: list[float]
    """Per-run scores of the evaluation under the protocol's own seed (the site's evaluation) [mph]."""


@dataclasses.dataclass(frozen=True)
class SpreadData:
    """The spread panel's data and how it was made."""

    command: str
    threshold: float
    """sd threshold [mph] for 'runs needed'."""
    nets: tuple[NetSpread, ...]


@dataclasses.dataclass(frozen=True)
class SpreadStats:
    """What the panel shows for one net: the spread over seeds of the site statistic, per n."""

    n: list[int]
    sd: list[float]
    """Sample sd over seeds of the site statistic of n runs [mph]."""
    lo: list[float]
    """2.5 % quantile over seeds [mph]."""
    hi: list[float]
    """97.5 % quantile over seeds [mph]."""
    mean_sd: list[float]
    """Sample sd over seeds of the mean of n runs [mph] (the statistic the site did not use)."""
    full: list[float]
    """The site statistic of the full protocol under each seed [mph]."""
    bootstrap_sd: list[float]
    """sd of the site statistic of n runs resampled (with replacement) from the site's own evaluation [mph]:
    how much the number would move on fresh traffic, which the v2 protocol's fixed per-run seeds never show."""
    runs_needed: int | None
    """Smallest n of the grid from which sd stays below the threshold; None if never within the protocol."""


def runs_needed(n: Sequence[int], sd: Sequence[float], threshold: float) -> int | None:
    """Smallest n such that sd < threshold at that n and every larger n of the grid; None if sd[-1] ≥ threshold."""
    needed = None
    for k in range(len(sd) - 1, -1, -1):
        if not sd[k] < threshold:
            break
        needed = n[k]
    return needed


def spread_stats(net: NetSpread, threshold: float = SD_THRESHOLD) -> SpreadStats:
    """The spread over seeds of the site statistic (and of the mean) at every n of the grid."""
    site = np.asarray(net.site, dtype=np.float64)
    mean = np.asarray(net.mean, dtype=np.float64)
    if site.ndim != 2 or site.shape[0] < 2 or site.shape != mean.shape or site.shape[1] != len(net.n):
        raise ConfigError(f"{net.name}: need ≥ 2 seeds and one value per seed and n, got {site.shape}")
    sd = site.std(axis=0, ddof=1)
    lo, hi = np.percentile(site, [2.5, 97.5], axis=0)
    return SpreadStats(
        n=list(net.n),
        sd=sd.tolist(),
        lo=lo.tolist(),
        hi=hi.tolist(),
        mean_sd=mean.std(axis=0, ddof=1).tolist(),
        full=site[:, -1].tolist(),
        bootstrap_sd=bootstrap_sd(net.own_runs, net.n),
        runs_needed=runs_needed(net.n, sd.tolist(), threshold),
    )


def bootstrap_sd(scores: Sequence[float], grid: Sequence[int], resamples: int = BOOTSTRAP) -> list[float]:
    """For each n of ``grid``: sd of the site statistic of n runs drawn with replacement from ``scores``
    (``numpy.random.default_rng(BOOTSTRAP_SEED)``, one generator per n so each n is reproducible alone)."""
    x = np.asarray(scores, dtype=np.float64)
    out = []
    for n in grid:
        rng = np.random.default_rng([BOOTSTRAP_SEED, n])
        draws = x[rng.integers(0, len(x), size=(resamples, n))]
        out.append(float(np.std(_site_medians(draws), ddof=1)))
    return out


def _site_medians(rows: np.ndarray) -> np.ndarray:
    """``site_median`` of each row. Scores in [10, 100) sort as strings exactly as numbers (same number of
    integer digits), so a numeric sort gives the same element; otherwise each row goes through ``site_median``."""
    if rows.size and 10.0 <= rows.min() and rows.max() < 100.0:
        return np.sort(rows, axis=1)[:, rows.shape[1] // 2]
    return np.array([site_median(row) for row in rows])


def _evaluate_seed(crowd_id: str, seed: int, cache: Path | None) -> list[float]:
    """Per-run scores of one net's official protocol under ``seed`` (from the cache when it holds them)."""
    from autotune.learner.brain_policy import evaluate_net
    from dashboards import crowd_data

    net, settings = crowd_data.load_net(crowd_id)
    protocol = OFFICIAL[settings.engine]
    path = None if cache is None else cache / f"{crowd_id}.{protocol}.seed{seed}.json"
    if path is not None and path.exists():
        try:
            stored = json.loads(path.read_text())
            if stored["protocol"] == protocol and stored["seed"] == seed:
                return [float(x) for x in stored["scores"]]
        except (OSError, ValueError, KeyError, TypeError):
            pass  # unreadable: evaluate again
    result = evaluate_net(net, settings, protocol, seed=seed)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps({"protocol": protocol, "seed": seed, "scores": result.scores}))
        tmp.replace(path)
    return list(result.scores)


def compute_net_spread(
    crowd_id: str,
    seeds: int = DEFAULT_SEEDS,
    *,
    cache: Path | None = SPREAD_CACHE,
    progress: Callable[[str], None] | None = None,
) -> NetSpread:
    """One packaged crowd net under its official protocol with ``seeds`` consecutive seeds from the protocol's own."""
    from dashboards import crowd_data

    if seeds < 2:
        raise ConfigError(f"seeds: need at least 2, got {seeds}")
    _net, settings = crowd_data.load_net(crowd_id)
    protocol = OFFICIAL[settings.engine]
    proto = PROTOCOLS[protocol]
    grid = runs_grid(proto.runs)
    seed_list = [proto.seed + k for k in range(seeds)]
    site, mean = [], []
    own_runs: list[float] = []
    for seed in seed_list:
        t0 = time.perf_counter()
        scores = _evaluate_seed(crowd_id, seed, cache)
        own_runs = own_runs or scores
        site.append([site_median(scores[:n]) for n in grid])
        mean.append([statistics.fmean(scores[:n]) for n in grid])
        if progress is not None:
            progress(f"{crowd_id} {protocol} seed {seed}: {site[-1][-1]:.2f} mph ({time.perf_counter() - t0:.1f} s)")
    sub = next(s for s in crowd_data.load_submissions() if s.id == crowd_id)
    return NetSpread(
        name=crowd_id,
        engine=settings.engine,
        other_agents=(settings.other_agents or 0) if settings.engine == "v2" else None,
        protocol=protocol,
        frames=proto.frames,
        claimed=sub.reported_score_mph,
        seeds=seed_list,
        n=grid,
        site=site,
        mean=mean,
        epsilon_test_time=float(settings.epsilon_test_time),
        own_runs=own_runs,
    )


def crowd_spread(
    ids: Sequence[str] = DEFAULT_NETS,
    seeds: int = DEFAULT_SEEDS,
    *,
    cache: Path | None = SPREAD_CACHE,
    progress: Callable[[str], None] | None = None,
) -> SpreadData:
    """``compute_net_spread`` for each net of ``ids``."""
    nets = tuple(compute_net_spread(nid, seeds, cache=cache, progress=progress) for nid in ids)
    return SpreadData(command=SPREAD_COMMAND, threshold=SD_THRESHOLD, nets=nets)


def spread_document(data: SpreadData) -> dict[str, Any]:
    """The JSON document of ``spread.json`` (with each net's derived statistics, for a reader without code)."""
    nets = []
    for net in data.nets:
        s = spread_stats(net, data.threshold)
        nets.append(
            {
                **dataclasses.asdict(net),
                "derived": {"sd": s.sd, "runs_needed": s.runs_needed, "full_min": min(s.full), "full_max": max(s.full)},
            }
        )
    return {
        "format": FORMAT,
        "what": "each net's official protocol (its own engine and agents) under consecutive Math.random seeds from "
        "the protocol's own; site[i][j] = the site's statistic (lexicographic median) of the first n[j] runs under "
        "seeds[i]",
        "command": data.command,
        "threshold": data.threshold,
        "nets": nets,
    }


def load_spread(path: Path | None = None) -> SpreadData:
    """The shipped spread data (default: the package's ``spread.json``), validated."""
    from dashboards import crowd_data

    path = crowd_data.data_dir() / SPREAD_FILE if path is None else path
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        nets = []
        for entry in doc["nets"]:
            fields = {f.name: entry[f.name] for f in dataclasses.fields(NetSpread)}
            net = NetSpread(**fields)
            if net.engine not in pv.ENGINES or net.protocol != OFFICIAL[net.engine]:
                raise ValueError(f"net {net.name}: engine {net.engine!r} with protocol {net.protocol!r}")
            spread_stats(net)  # shapes
            nets.append(net)
        return SpreadData(command=str(doc["command"]), threshold=float(doc["threshold"]), nets=tuple(nets))
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
    except (ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"{path}: not a spread file ({type(exc).__name__}: {exc})") from None


def load_spread_runs(max_runs: int | None = None, path: Path | None = None) -> SpreadData:
    """``load_spread`` keeping only the runs per evaluation n ≤ ``max_runs`` (at least the grid's first two)."""
    data = load_spread(path)
    if max_runs is None:
        return data
    nets = []
    for net in data.nets:
        keep = max(2, sum(1 for n in net.n if n <= max_runs))
        nets.append(
            dataclasses.replace(
                net, n=net.n[:keep], site=[row[:keep] for row in net.site], mean=[row[:keep] for row in net.mean]
            )
        )
    return dataclasses.replace(data, nets=tuple(nets))


def _net_label(net: NetSpread) -> str:
    return f"{net.name} ({pv.agents_label(net.engine, net.other_agents)})"


def spread_figure(data: SpreadData):  # noqa: ANN201 - plotly.graph_objects.Figure (plotly is imported lazily)
    """Left: the site's number under every seed, per net (and the claim); right: its sd over seeds against n."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    seeds = "/".join(str(k) for k in sorted({len(n.seeds) for n in data.nets}))
    fig = make_subplots(
        rows=1,
        cols=2,
        subplot_titles=(
            f"the site's number, {seeds} protocol seeds each",
            "its sd: over seeds (solid), over resampled runs (dashed)",
        ),
    )
    colors = ("#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#17becf")
    kind = pv.OWN_WEIGHTS
    for k, net in enumerate(data.nets):
        s = spread_stats(net, data.threshold)
        color = colors[k % len(colors)]
        engine, agents = pv.ENGINE_LABEL[net.engine], pv.agents_label(net.engine, net.other_agents)
        label = _net_label(net)
        parts = net.name.removeprefix("dt-").split("-")
        short = f"{parts[0]} {parts[-1]} ({pv.ENGINE_LABEL[net.engine]})"
        measured = pv.series_name(label, [net.engine], [kind], f"{net.protocol} site median of {net.n[-1]} runs")
        custom = [[f"{net.name}, seed {seed}", engine, agents, pv.KIND_LABEL[kind], "exact"] for seed in net.seeds]
        fig.add_trace(
            go.Box(
                x=[short] * len(s.full),
                y=s.full,
                name=measured,
                boxpoints="all",
                jitter=0.4,
                pointpos=0,
                marker={"color": color, "symbol": pv.marker_symbol(net.engine, kind), "size": 5},
                line={"color": color},
                customdata=custom,
                hovertemplate=pv.HOVER,
                legendgroup=net.name,
                meta=pv.series_meta([net.engine], [kind], filterable=True),
            ),
            row=1,
            col=1,
        )
        if net.claimed is not None:
            fig.add_trace(
                go.Scatter(
                    x=[short],
                    y=[net.claimed],
                    mode="markers",
                    name=pv.series_name(label, [net.engine], [pv.CLAIMED], "the author's report"),
                    marker={"color": color, "symbol": pv.marker_symbol(net.engine, pv.CLAIMED), "size": 12},
                    customdata=[[net.name, engine, agents, pv.KIND_LABEL[pv.CLAIMED], "see crowd data"]],
                    hovertemplate=pv.HOVER,
                    legendgroup=net.name,
                    meta=pv.series_meta([net.engine], [pv.CLAIMED], filterable=True),
                ),
                row=1,
                col=1,
            )
        needed = s.runs_needed or f"> {net.n[-1]}"
        fig.add_trace(
            go.Scatter(
                x=s.n,
                y=s.sd,
                mode="lines+markers",
                name=pv.series_name(label, [net.engine], [kind], f"sd < {data.threshold:g} mph from n = {needed}"),
                line={"color": color},
                marker={"symbol": pv.marker_symbol(net.engine, kind)},
                customdata=[[f"{net.name}, n = {n}", engine, agents, pv.KIND_LABEL[kind], "exact"] for n in s.n],
                hovertemplate="n = %{x}: sd %{y:.3f} mph<br>%{customdata[1]}, %{customdata[2]}"
                "<extra>%{fullData.name}</extra>",
                legendgroup=net.name,
                meta=pv.series_meta([net.engine], [kind]),
            ),
            row=1,
            col=2,
        )
        fig.add_trace(
            go.Scatter(
                x=s.n,
                y=s.bootstrap_sd,
                mode="lines",
                name=pv.series_name(label, [net.engine], [kind], "runs of the site's evaluation resampled"),
                line={"color": color, "dash": "dash"},
                customdata=[[f"{net.name}, n = {n}", engine, agents, pv.KIND_LABEL[kind], "bootstrap"] for n in s.n],
                hovertemplate="n = %{x}: bootstrap sd %{y:.3f} mph<br>%{customdata[1]}, %{customdata[2]}"
                "<extra>%{fullData.name}</extra>",
                legendgroup=net.name,
                meta=pv.series_meta([net.engine], [kind]),
            ),
            row=1,
            col=2,
        )
    fig.add_hline(y=data.threshold, line_dash="dash", line_color="gray", row=1, col=2)
    fig.update_yaxes(title_text="score [mph]", row=1, col=1)
    fig.update_xaxes(tickangle=0, row=1, col=1)
    fig.update_xaxes(title_text="runs per evaluation n (first n runs of the protocol)", type="log", row=1, col=2)
    fig.update_yaxes(title_text="sd [mph]", row=1, col=2)
    fig.update_layout(
        title="The site's number under different seeds: each net in its own engine and official protocol",
        legend={"orientation": "h", "y": -0.3},
        height=560,
        template="plotly_white",
    )
    return fig
