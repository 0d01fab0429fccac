"""Plotly figures drawn from the extracted plot data (``dashboards.extract``); no computation here.

Every function takes the automated and the crowd side and returns a figure with data, or an
``Empty`` explaining why there is nothing to draw (a report never shows an empty figure).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import plotly.graph_objects as go
from plotly.subplots import make_subplots

from dashboards.extract import (
    HYPERPARAMETERS,
    Empty,
    Importances,
    Panel,
    ReplayRow,
    Series,
    SizeScatter,
    TsneMap,
)

__all__ = [
    "COLORS",
    "progress_figure",
    "size_figure",
    "hyperparameter_figure",
    "compute_figure",
    "tsne_figure",
    "importance_figure",
    "replay_figure",
]

COLORS = {"autotune": "#1f77b4", "crowd": "#d62728"}
SYMBOLS = {"autotune": "circle", "crowd": "diamond"}
LAYOUT: dict[str, Any] = {"template": "plotly_white", "margin": {"l": 60, "r": 30, "t": 60, "b": 50}}


def _name(source: str) -> str:
    return "automated" if source == "autotune" else "crowd"


def _empty_reason(*parts: Any) -> Empty:
    return Empty("; ".join(p.reason for p in parts if isinstance(p, Empty)))


def progress_figure(sides: dict[str, Series | Empty]) -> go.Figure | Empty:
    """Score against trial / submission order with the running best, one subplot per side."""
    present = {k: v for k, v in sides.items() if isinstance(v, Series)}
    if not present:
        return _empty_reason(*sides.values())
    fig = make_subplots(
        rows=1,
        cols=len(present),
        subplot_titles=[f"{_name(k)}: score by {'submission' if k == 'crowd' else 'trial'}" for k in present],
    )
    for col, (source, s) in enumerate(present.items(), start=1):
        fig.add_trace(
            go.Scatter(
                x=s.order,
                y=s.score,
                mode="markers",
                name=f"{_name(source)} score",
                text=s.labels,
                marker={"color": COLORS[source], "symbol": SYMBOLS[source], "size": 6, "opacity": 0.6},
            ),
            row=1,
            col=col,
        )
        fig.add_trace(
            go.Scatter(
                x=s.order,
                y=s.best,
                mode="lines",
                line={"shape": "hv", "color": COLORS[source]},
                name=f"{_name(source)} running best",
            ),
            row=1,
            col=col,
        )
        fig.update_xaxes(title_text="submission order" if source == "crowd" else "trial number", row=1, col=col)
        fig.update_yaxes(title_text="score [mph]", row=1, col=col)
    fig.update_layout(title="Progress: score and running best", height=420, **LAYOUT)
    return fig


def size_figure(sides: dict[str, SizeScatter | Empty]) -> go.Figure | Empty:
    """Parameter count against score, coloured by layer count (left) and training iterations (right)."""
    present = {k: v for k, v in sides.items() if isinstance(v, SizeScatter)}
    if not present:
        return _empty_reason(*sides.values())
    fig = make_subplots(
        rows=1, cols=2, subplot_titles=["coloured by hidden layers", "coloured by training iterations (log10)"]
    )
    for i, (source, s) in enumerate(present.items()):
        iters = [math.log10(v) if v and v > 0 else None for v in s.train_iterations]
        for col, color, scale, title in (
            (1, s.n_layers, "Viridis", "layers"),
            (2, iters, "Plasma", "log10 iters"),
        ):
            fig.add_trace(
                go.Scatter(
                    x=s.param_count,
                    y=s.score,
                    mode="markers",
                    name=f"{_name(source)}",
                    legendgroup=source,
                    showlegend=col == 1,
                    text=s.labels,
                    marker={
                        "color": color,
                        "colorscale": scale,
                        "symbol": SYMBOLS[source],
                        "size": 8,
                        "line": {"width": 1, "color": COLORS[source]},
                        "showscale": i == 0,
                        "colorbar": {"title": title, "x": 0.45 if col == 1 else 1.02, "len": 0.8},
                    },
                ),
                row=1,
                col=col,
            )
    fig.update_xaxes(type="log", title_text="parameters (weights + biases)")
    fig.update_yaxes(title_text="score [mph]")
    fig.update_layout(title="Size matters? Parameter count against score", height=450, **LAYOUT)
    return fig


def hyperparameter_figure(sides: dict[str, dict[str, Panel | Empty]]) -> go.Figure | Empty:
    """One subplot per hyperparameter (``HYPERPARAMETERS``) against score; both sides overlaid."""
    names = [n for n in HYPERPARAMETERS if any(isinstance(p.get(n), Panel) for p in sides.values())]
    if not names:
        return Empty("no hyperparameter recorded in any scored trial")
    cols = 3
    rows = math.ceil(len(names) / cols)
    fig = make_subplots(rows=rows, cols=cols, subplot_titles=names, vertical_spacing=0.08)
    for k, name in enumerate(names):
        row, col = k // cols + 1, k % cols + 1
        log = True
        for source, panels in sides.items():
            panel = panels.get(name)
            if not isinstance(panel, Panel):
                continue
            log = log and panel.log_x
            fig.add_trace(
                go.Scatter(
                    x=panel.x,
                    y=panel.score,
                    mode="markers",
                    name=_name(source),
                    legendgroup=source,
                    showlegend=k == 0,
                    text=panel.labels,
                    marker={"color": COLORS[source], "symbol": SYMBOLS[source], "size": 6, "opacity": 0.6},
                ),
                row=row,
                col=col,
            )
        if log:
            fig.update_xaxes(type="log", row=row, col=col)
    fig.update_yaxes(title_text="mph", col=1)
    fig.update_layout(title="Each hyperparameter against score", height=300 * rows, **LAYOUT)
    return fig


def compute_figure(sides: dict[str, Series | Empty]) -> go.Figure | Empty:
    """Best score against cumulative frames simulated, both sides on one log axis."""
    present = {k: v for k, v in sides.items() if isinstance(v, Series)}
    if not present:
        return _empty_reason(*sides.values())
    fig = go.Figure()
    for source, s in present.items():
        fig.add_trace(
            go.Scatter(
                x=s.order,
                y=s.best,
                mode="lines+markers",
                line={"shape": "hv", "color": COLORS[source]},
                marker={"size": 4},
                name=f"{_name(source)} best so far",
                text=s.labels,
            )
        )
    fig.update_xaxes(type="log", title_text="frames simulated (cumulative)")
    fig.update_yaxes(title_text="best score [mph]")
    fig.update_layout(title="Best score against compute spent", height=420, **LAYOUT)
    return fig


def tsne_figure(tsne: TsneMap | Empty) -> go.Figure | Empty:
    """The joint t-SNE map coloured by score, one marker symbol per side."""
    if isinstance(tsne, Empty):
        return tsne
    fig = go.Figure()
    lo, hi = min(tsne.score), max(tsne.score)
    for source in dict.fromkeys(tsne.source):
        idx = [i for i, s in enumerate(tsne.source) if s == source]
        fig.add_trace(
            go.Scatter(
                x=[tsne.x[i] for i in idx],
                y=[tsne.y[i] for i in idx],
                mode="markers",
                name=_name(source),
                text=[f"{tsne.labels[i]}: {tsne.score[i]:.2f} mph" for i in idx],
                marker={
                    "color": [tsne.score[i] for i in idx],
                    "cmin": lo,
                    "cmax": hi,
                    "colorscale": "Viridis",
                    "symbol": SYMBOLS[source],
                    "size": 9,
                    "showscale": source == tsne.source[0],
                    "colorbar": {"title": "mph"},
                },
            )
        )
    fig.update_layout(
        title=f"t-SNE of the settings (seed {tsne.seed}; features: {', '.join(tsne.features)})",
        height=520,
        legend={"orientation": "h", "y": -0.1},
        **LAYOUT,
    )
    fig.update_xaxes(showticklabels=False)
    fig.update_yaxes(showticklabels=False)
    return fig


def importance_figure(sides: dict[str, Importances | Empty]) -> go.Figure | Empty:
    """Horizontal bars of each side's hyperparameter importances."""
    present = {k: v for k, v in sides.items() if isinstance(v, Importances)}
    if not present:
        return _empty_reason(*sides.values())
    fig = make_subplots(
        rows=1, cols=len(present), subplot_titles=[f"{_name(k)} ({v.evaluator})" for k, v in present.items()]
    )
    for col, (source, imp) in enumerate(present.items(), start=1):
        fig.add_trace(
            go.Bar(
                x=imp.values[::-1],
                y=imp.names[::-1],
                orientation="h",
                marker={"color": COLORS[source]},
                name=_name(source),
            ),
            row=1,
            col=col,
        )
        fig.update_xaxes(title_text="importance", row=1, col=col)
    height = max(350, 22 * max(len(v.names) for v in present.values()) + 120)
    fig.update_layout(title="Hyperparameter importances", height=height, showlegend=False, **LAYOUT)
    return fig


def replay_figure(replayed: Sequence[ReplayRow] | Empty, own_nets: Sequence[ReplayRow] | Empty) -> go.Figure | Empty:
    """Self-reported against measured score: crowd settings retrained by us, and the human nets' own weights."""
    traces = []
    for rows, name, color, symbol in (
        (replayed, "crowd setting retrained (mean over seeds)", COLORS["autotune"], "circle"),
        (own_nets, "human net, own weights", COLORS["crowd"], "diamond"),
    ):
        if isinstance(rows, Empty):
            continue
        traces.append(
            go.Scatter(
                x=[r.reported for r in rows],
                y=[r.measured for r in rows],
                error_y={"type": "data", "array": [r.std for r in rows], "visible": any(r.n > 1 for r in rows)},
                mode="markers",
                name=name,
                text=[f"{r.crowd_id} (n={r.n})" for r in rows],
                marker={"color": color, "symbol": symbol, "size": 9},
            )
        )
    if not traces:
        return _empty_reason(replayed, own_nets)
    values = [v for t in traces for v in (*t.x, *t.y)]
    lo, hi = min(values) - 2, max(values) + 2
    fig = go.Figure(traces)
    fig.add_trace(
        go.Scatter(
            x=[lo, hi], y=[lo, hi], mode="lines", line={"dash": "dot", "color": "grey"}, name="measured = reported"
        )
    )
    fig.update_xaxes(title_text="self-reported score [mph]")
    fig.update_yaxes(title_text="measured score [mph] (exact engine, official protocol)")
    fig.update_layout(title="Self-reported against measured score", height=480, **LAYOUT)
    return fig
