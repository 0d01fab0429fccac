"""Plotly figures drawn from the extracted plot data (``dashboards.extract``); no computation here.

Every function returns a figure with data, or an ``Empty`` explaining why there is nothing to draw
(a report never shows an empty figure). No trace mixes engines or score kinds without naming them:
marker traces hold one (side, engine, score kind) each; a line or bar over several kinds names
them all (``provenance.series_name``). Marker symbol = engine, filled = measured, open =
self-reported; colour = side. Every data point carries its provenance as ``customdata``
(``provenance.CUSTOMDATA``), shown on hover and read by the report's agents filter; every trace's
``meta`` lists the engines and kinds it holds (reference lines: ``{"reference": ...}``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import plotly.graph_objects as go
from plotly.subplots import make_subplots

from dashboards import provenance as pv
from dashboards.extract import (
    HYPERPARAMETERS,
    ClaimRow,
    ComputeCurve,
    Empty,
    Importances,
    Panel,
    Points,
    Progress,
    SizeScatter,
    TrialPoint,
    TsneMap,
)

__all__ = [
    "COLORS",
    "SIDE_NAMES",
    "progress_figure",
    "size_figure",
    "hyperparameter_figure",
    "compute_figure",
    "tsne_figure",
    "importance_figure",
    "claims_figure",
    "replay_figure",
]

COLORS = {"autotune": "#1f77b4", "crowd": "#d62728", pv.OWN_WEIGHTS: "#2ca02c", pv.REPLAYED: "#9467bd"}
SIDE_NAMES = {"autotune": "automated", "crowd": "crowd", "crowd-replay": "crowd replay"}
LAYOUT: dict[str, Any] = {"template": "plotly_white", "margin": {"l": 60, "r": 30, "t": 60, "b": 50}}


def _side(source: str) -> str:
    return SIDE_NAMES.get(source, source)


def _empty_reason(*parts: Any) -> Empty:
    return Empty("; ".join(p.reason for p in parts if isinstance(p, Empty)))


def _custom(trials: Sequence[TrialPoint]) -> list[list[str]]:
    return [t.custom() for t in trials]


def _marker_traces(
    pts: Points, source: str, *, legend_seen: set[str] | None = None, marker: dict[str, Any] | None = None,
    colors: Sequence[Any] | None = None,
) -> list[go.Scatter]:  # fmt: skip
    """One marker trace per (engine, kind) of ``pts``: symbol by engine, open when self-reported."""
    traces = []
    for (engine, kind), idx in pts.groups().items():
        name = pv.series_name(_side(source), [engine], [kind])
        group = f"{source}|{engine}|{kind}"
        show = legend_seen is None or group not in legend_seen
        if legend_seen is not None:
            legend_seen.add(group)
        style: dict[str, Any] = {"color": COLORS[source], "size": 7, "opacity": 0.75, **(marker or {})}
        style["symbol"] = pv.marker_symbol(engine, kind)
        if colors is not None:
            style["color"] = [colors[i] for i in idx]
            style["line"] = {"width": 1.5, "color": COLORS[source]}
        traces.append(
            go.Scatter(
                x=[pts.x[i] for i in idx],
                y=[pts.y[i] for i in idx],
                mode="markers",
                name=name,
                legendgroup=group,
                showlegend=show,
                customdata=_custom([pts.trials[i] for i in idx]),
                hovertemplate=pv.HOVER,
                marker=style,
                meta=pv.series_meta([engine], [kind], filterable=True),
            )
        )
    return traces


def _kinds_of(trials: Sequence[TrialPoint]) -> list[str]:
    return [k for k in pv.KIND_LABEL if any(t.kind == k for t in trials)]


def progress_figure(sides: dict[str, Progress | Empty]) -> go.Figure | Empty:
    """Score against trial / submission order with each engine's running best, one subplot per side."""
    present = {k: v for k, v in sides.items() if isinstance(v, Progress)}
    if not present:
        return _empty_reason(*sides.values())
    fig = make_subplots(
        rows=1,
        cols=len(present),
        subplot_titles=[f"{_side(k)}: score by {'submission' if k == 'crowd' else 'trial'}" for k in present],
    )
    for col, (source, s) in enumerate(present.items(), start=1):
        for trace in _marker_traces(s.points, source):
            fig.add_trace(trace, row=1, col=col)
        for engine, (order, best, holder) in s.best.items():
            kinds = _kinds_of([t for t in s.points.trials if t.engine == engine])
            fig.add_trace(
                go.Scatter(
                    x=order,
                    y=best,
                    mode="lines",
                    line={"shape": "hv", "color": COLORS[source], "dash": "solid" if engine == "v2" else "dot"},
                    name=pv.series_name(_side(source), [engine], kinds, "running best"),
                    customdata=_custom(holder),
                    hovertemplate=pv.HOVER,
                    meta=pv.series_meta([engine], kinds),
                ),
                row=1,
                col=col,
            )
        fig.update_xaxes(title_text="submission order" if source == "crowd" else "trial number", row=1, col=col)
        fig.update_yaxes(title_text="score [mph] (kind: see legend)", row=1, col=col)
    fig.update_layout(
        title="Progress: score and each engine's running best", height=560, legend={"orientation": "h", "y": -0.2},
        **LAYOUT,
    )  # fmt: skip
    return fig


def size_figure(sides: dict[str, SizeScatter | Empty]) -> go.Figure | Empty:
    """Parameter count against score, coloured by layer count (left) and training iterations (right)."""
    present = {k: v for k, v in sides.items() if isinstance(v, SizeScatter)}
    if not present:
        return _empty_reason(*sides.values())
    fig = make_subplots(
        rows=1, cols=2, subplot_titles=["coloured by hidden layers", "coloured by training iterations (log10)"]
    )
    layers = [v for s in present.values() for v in s.n_layers]
    iters_all = [math.log10(v) for s in present.values() for v in s.train_iterations if v and v > 0]
    seen: set[str] = set()
    first = {1: True, 2: True}
    for source, s in present.items():
        iters = [math.log10(v) if v and v > 0 else None for v in s.train_iterations]
        for col, color, scale, title, (lo, hi) in (
            (1, s.n_layers, "Viridis", "layers", (min(layers), max(layers))),
            (2, iters, "Plasma", "log10 iters", (min(iters_all, default=0), max(iters_all, default=1))),
        ):
            bar = {"title": title, "x": 0.45 if col == 1 else 1.02, "len": 0.8}
            for trace in _marker_traces(
                s.points, source, legend_seen=seen if col == 1 else set(), colors=color,
                marker={"size": 9, "colorscale": scale, "cmin": lo, "cmax": hi, "colorbar": bar},
            ):  # fmt: skip
                trace.marker.showscale = first[col]
                first[col] = False
                if col == 2:
                    trace.showlegend = False
                fig.add_trace(trace, row=1, col=col)
    fig.update_xaxes(type="log", title_text="parameters (weights + biases)")
    fig.update_yaxes(title_text="score [mph] (kind: see legend)")
    fig.update_layout(
        title="Size matters? Parameter count against score", height=480, legend={"orientation": "h", "y": -0.2},
        **LAYOUT,
    )  # fmt: skip
    return fig


def hyperparameter_figure(sides: dict[str, dict[str, Panel | Empty]]) -> go.Figure | Empty:
    """One subplot per hyperparameter (``HYPERPARAMETERS``) against score; both sides overlaid."""
    names = [n for n in HYPERPARAMETERS if any(isinstance(p.get(n), Panel) for p in sides.values())]
    if not names:
        return Empty("no hyperparameter recorded in any scored trial")
    cols = 3
    rows = math.ceil(len(names) / cols)
    fig = make_subplots(rows=rows, cols=cols, subplot_titles=names, vertical_spacing=0.08)
    seen: set[str] = set()
    for k, name in enumerate(names):
        row, col = k // cols + 1, k % cols + 1
        log = True
        for source, panels in sides.items():
            panel = panels.get(name)
            if not isinstance(panel, Panel):
                continue
            log = log and panel.log_x
            for trace in _marker_traces(panel.points, source, legend_seen=seen, marker={"size": 6}):
                fig.add_trace(trace, row=row, col=col)
        if log:
            fig.update_xaxes(type="log", row=row, col=col)
    fig.update_yaxes(title_text="mph", col=1)
    fig.update_layout(
        title="Each hyperparameter against score", height=300 * rows, legend={"orientation": "h", "y": -0.05},
        **LAYOUT,
    )  # fmt: skip
    return fig


def compute_figure(sides: dict[str, ComputeCurve | Empty]) -> go.Figure | Empty:
    """Each engine's best score against the side's cumulative frames simulated, on one log axis."""
    present = {k: v for k, v in sides.items() if isinstance(v, ComputeCurve)}
    if not present:
        return _empty_reason(*sides.values())
    fig = go.Figure()
    for source, c in present.items():
        for engine, (order, best, holder) in c.best.items():
            fig.add_trace(
                go.Scatter(
                    x=order,
                    y=best,
                    mode="lines+markers",
                    line={"shape": "hv", "color": COLORS[source], "dash": "solid" if engine == "v2" else "dot"},
                    marker={"size": 5, "symbol": pv.marker_symbol(engine, holder[0].kind)},
                    name=pv.series_name(_side(source), [engine], c.kinds[engine], "best so far"),
                    customdata=_custom(holder),
                    hovertemplate=pv.HOVER,
                    meta=pv.series_meta([engine], c.kinds[engine]),
                )
            )
    fig.update_xaxes(type="log", title_text="frames simulated (cumulative, all of the side's trials)")
    fig.update_yaxes(title_text="best score [mph] (kind: see legend)")
    fig.update_layout(
        title="Best score against compute spent", height=440, legend={"orientation": "h", "y": -0.2}, **LAYOUT
    )
    return fig


def tsne_figure(tsne: TsneMap | Empty) -> go.Figure | Empty:
    """The joint t-SNE map coloured by score; one trace per (side, engine, kind)."""
    if isinstance(tsne, Empty):
        return tsne
    fig = go.Figure()
    lo, hi = min(tsne.score), max(tsne.score)
    first = True
    for source in dict.fromkeys(tsne.source):
        idx = [i for i, s in enumerate(tsne.source) if s == source]
        pts = Points([tsne.x[i] for i in idx], [tsne.y[i] for i in idx], [tsne.trials[i] for i in idx])
        for trace in _marker_traces(
            pts, source, colors=[tsne.score[i] for i in idx],
            marker={"size": 9, "colorscale": "Viridis", "cmin": lo, "cmax": hi, "colorbar": {"title": "mph"}},
        ):  # fmt: skip
            trace.marker.showscale = first
            first = False
            trace.hovertemplate = pv.HOVER.replace("%{y:.2f} mph", "score on colour scale")
            fig.add_trace(trace)
    fig.update_layout(
        title=f"t-SNE of the settings (seed {tsne.seed}; features: {', '.join(tsne.features)})",
        height=560,
        legend={"orientation": "h", "y": -0.1},
        **LAYOUT,
    )
    fig.update_xaxes(showticklabels=False)
    fig.update_yaxes(showticklabels=False)
    return fig


def importance_figure(sides: dict[str, Importances | Empty]) -> go.Figure | Empty:
    """Horizontal bars of each side's importances (engine and other agents among the inputs)."""
    present = {k: v for k, v in sides.items() if isinstance(v, Importances)}
    if not present:
        return _empty_reason(*sides.values())
    titles = [f"{_side(k)} ({v.n} configurations)" for k, v in present.items()]
    fig = make_subplots(rows=1, cols=len(present), subplot_titles=titles)
    for col, (source, imp) in enumerate(present.items(), start=1):
        fig.add_trace(
            go.Bar(
                x=imp.values[::-1],
                y=imp.names[::-1],
                orientation="h",
                marker={"color": COLORS[source]},
                name=pv.series_name(_side(source), imp.engines, imp.kinds, f"{imp.n} configurations"),
                meta=pv.series_meta(imp.engines, imp.kinds),
            ),
            row=1,
            col=col,
        )
        fig.update_xaxes(title_text="importance (share of held-out R² lost)", row=1, col=col)
    height = max(350, 22 * max(len(v.names) for v in present.values()) + 140)
    fig.update_layout(
        title=f"Setting importances: {next(iter(present.values())).evaluator}", height=height,
        legend={"orientation": "h", "y": -0.15}, **LAYOUT,
    )  # fmt: skip
    return fig


def _claim_custom(rows: Sequence[ClaimRow]) -> list[list[str]]:
    return [
        [
            f"{r.crowd_id}: claimed {r.claimed:.2f} mph ({pv.KIND_LABEL[r.claim_kind]})"
            + (f"; {r.n} seeds" if r.measured_kind == pv.REPLAYED else ""),
            pv.ENGINE_LABEL[r.engine],
            pv.agents_label(r.engine, r.other_agents),
            pv.KIND_LABEL[r.measured_kind],
            r.claim_confidence,
        ]
        for r in rows
    ]


def claims_figure(*sources: Sequence[ClaimRow] | Empty) -> go.Figure | Empty:
    """Claimed (x) against measured (y) score, one trace per (measurement, engine); y = x for reference."""
    traces = []
    for rows in sources:
        if isinstance(rows, Empty):
            continue
        for engine in pv.ENGINES:
            for measured in (pv.OWN_WEIGHTS, pv.REPLAYED):
                mine = [r for r in rows if r.engine == engine and r.measured_kind == measured]
                if not mine:
                    continue
                claim_kinds = [k for k in pv.KIND_LABEL if any(r.claim_kind == k for r in mine)]
                who = "human nets" if measured == pv.OWN_WEIGHTS else "crowd settings"
                traces.append(
                    go.Scatter(
                        x=[r.claimed for r in mine],
                        y=[r.measured for r in mine],
                        error_y={
                            "type": "data",
                            "array": [r.sd or 0.0 for r in mine],
                            "visible": any(r.sd is not None for r in mine),
                        },
                        mode="markers",
                        name=pv.series_name(who, [engine], [measured, *claim_kinds], "measured against claimed"),
                        customdata=_claim_custom(mine),
                        hovertemplate="%{customdata[0]}<br>measured %{y:.2f} mph · %{customdata[3]}"
                        "<br>%{customdata[1]}, %{customdata[2]}<extra>%{fullData.name}</extra>",
                        marker={"color": COLORS[measured], "symbol": pv.marker_symbol(engine, measured), "size": 9},
                        meta=pv.series_meta([engine], [measured, *claim_kinds], filterable=True),
                    )
                )
    if not traces:
        return _empty_reason(*sources)
    values = [v for t in traces for v in (*t.x, *t.y)]
    lo, hi = min(values) - 2, max(values) + 2
    fig = go.Figure(traces)
    fig.add_trace(
        go.Scatter(
            x=[lo, hi],
            y=[lo, hi],
            mode="lines",
            line={"dash": "dot", "color": "grey"},
            name="reference: measured = claimed",
            meta={"reference": "identity line"},
            hoverinfo="skip",
        )
    )
    fig.update_xaxes(title_text="claimed score [mph] (self-reported by the author)")
    fig.update_yaxes(title_text="measured score [mph] (exact engine, official protocol of the net's engine)")
    fig.update_layout(
        title="Claimed against measured, each net in its own engine", height=520,
        legend={"orientation": "h", "y": -0.2}, **LAYOUT,
    )  # fmt: skip
    return fig


def replay_figure(rows: Sequence[ClaimRow] | Empty) -> go.Figure | Empty:
    """Per replayed configuration (x, by claim within engine): the claim, every seed's score and mean ± sd."""
    if isinstance(rows, Empty):
        return rows
    engines = [e for e in pv.ENGINES if any(r.engine == e for r in rows)]
    fig = make_subplots(
        rows=1, cols=len(engines), subplot_titles=[pv.ENGINE_LABEL[e] for e in engines], shared_yaxes=True
    )
    for col, engine in enumerate(engines, start=1):
        mine = sorted((r for r in rows if r.engine == engine), key=lambda r: -r.claimed)
        labels = [r.crowd_id.removeprefix("dt-") for r in mine]
        claim_kinds = [k for k in pv.KIND_LABEL if any(r.claim_kind == k for r in mine)]
        custom = _claim_custom(mine)
        claim_custom = [[*c[:3], pv.KIND_LABEL[r.claim_kind], c[4]] for c, r in zip(custom, mine, strict=True)]
        fig.add_trace(
            go.Scatter(
                x=labels,
                y=[r.claimed for r in mine],
                mode="markers",
                name=pv.series_name("claimed by the author", [engine], claim_kinds),
                marker={"color": COLORS["crowd"], "symbol": pv.marker_symbol(engine, pv.CLAIMED), "size": 11},
                customdata=claim_custom,
                hovertemplate=pv.HOVER,
                meta=pv.series_meta([engine], claim_kinds, filterable=True),
            ),
            row=1,
            col=col,
        )
        seeds_x = [lab for lab, r in zip(labels, mine, strict=True) for _s in r.scores]
        seeds_custom = [c for c, r in zip(custom, mine, strict=True) for _s in r.scores]
        fig.add_trace(
            go.Scatter(
                x=seeds_x,
                y=[s for r in mine for s in r.scores],
                mode="markers",
                name=pv.series_name("replayed, each seed", [engine], [pv.REPLAYED]),
                marker={"color": COLORS[pv.REPLAYED], "symbol": pv.marker_symbol(engine, pv.REPLAYED), "size": 5},
                customdata=seeds_custom,
                hovertemplate=pv.HOVER,
                meta=pv.series_meta([engine], [pv.REPLAYED], filterable=True),
            ),
            row=1,
            col=col,
        )
        fig.add_trace(
            go.Scatter(
                x=labels,
                y=[r.measured for r in mine],
                error_y={"type": "data", "array": [r.sd or 0.0 for r in mine]},
                mode="markers",
                name=pv.series_name("replayed, mean ± sd over seeds", [engine], [pv.REPLAYED]),
                marker={"color": COLORS[pv.REPLAYED], "symbol": "line-ew", "size": 16, "line": {"width": 2}},
                customdata=custom,
                hovertemplate=pv.HOVER,
                meta=pv.series_meta([engine], [pv.REPLAYED], filterable=True),
            ),
            row=1,
            col=col,
        )
        fig.update_xaxes(tickangle=-60, row=1, col=col)
    fig.update_yaxes(title_text="score [mph]", col=1)
    fig.update_layout(
        title="Claimed against replayed: each configuration retrained by our learner in its own engine",
        height=560, legend={"orientation": "h", "y": -0.45}, **LAYOUT,
    )  # fmt: skip
    return fig
