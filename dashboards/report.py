"""The comparison report: automated search and the crowd side by side, as one self-contained HTML file.

``build_report`` extracts every panel's data (``dashboards.extract``, ``dashboards.insights``) and
draws it (``dashboards.figures``); ``write_html`` writes one file with plotly.js inlined, so it opens
without network access; ``attach_to_dashboard`` stores the same figures and a markdown note in the
study for optuna-dashboard. A panel without data is an explained note, never an empty figure.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import html
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import optuna
import plotly.graph_objects as go
import plotly.io as pio

from dashboards import extract, figures, insights
from dashboards.extract import Empty, StudyData

if TYPE_CHECKING:  # dashboards.spread imports the evaluator (numba): only when a spread is drawn
    from dashboards.spread import SpreadData

__all__ = ["Section", "Report", "build_report", "render_html", "write_html", "attach_to_dashboard"]


@dataclasses.dataclass(frozen=True)
class Section:
    """One report panel: a figure with data, or the reason there is none."""

    key: str
    title: str
    description: str
    figure: go.Figure | Empty


@dataclasses.dataclass(frozen=True)
class Report:
    """Everything the HTML page and the dashboard note show."""

    title: str
    studies: dict[str, StudyData]
    sections: list[Section]
    insights: dict[str, list[insights.InsightResult]]


def _side_label(data: StudyData) -> str:
    scored = data.scored
    best = max((t.value for t in scored if t.value is not None), default=None)
    states: dict[str, int] = {}
    for t in data.trials:
        states[t.state] = states.get(t.state, 0) + 1
    counts = ", ".join(f"{n} {s.lower()}" for s, n in sorted(states.items()))
    best_text = f"best {best:.2f} mph" if best is not None else "no score yet"
    return f"{data.name} ({data.source}): {counts or 'no finished trial'}; {best_text}"


def build_report(
    automated: optuna.Study,
    crowd: optuna.Study,
    *,
    replay: optuna.Study | None = None,
    spread: SpreadData | Empty | None = None,
    seed: int = 0,
) -> Report:
    """Extract and draw every panel of the comparison of ``automated`` with ``crowd`` (and its ``replay``)."""
    auto = extract.study_data(automated)
    crowd_data = extract.study_data(crowd)
    sides = {"autotune": auto, "crowd": crowd_data}
    sections = [
        Section(
            "progress",
            "Progress",
            "Score against trial number (automated) and submission order (crowd, by commit date), with the "
            "running best: the paper's progress figure.",
            figures.progress_figure({k: extract.progress(v) for k, v in sides.items()}),
        ),
        Section(
            "size",
            "Network size",
            "Parameter count (weights + biases) against score, coloured by the number of hidden layers and by "
            "the training length. Circles: automated trials; diamonds: crowd submissions.",
            figures.size_figure({k: extract.size_scatter(v) for k, v in sides.items()}),
        ),
        Section(
            "hyperparameters",
            "Each hyperparameter",
            "One panel per hyperparameter against score (real values; γ, not 1 − γ).",
            figures.hyperparameter_figure({k: extract.hyperparameter_panels(v) for k, v in sides.items()}),
        ),
        Section(
            "spread",
            "Evaluation spread",
            "Standard error of a net's evaluated score against the number of evaluation runs (exact evaluator, "
            "three crowd nets): how many runs until it stays below 0.1 mph, and the bootstrap band of the median.",
            _spread(spread),
        ),
        Section(
            "tsne",
            "Map of the settings",
            "A joint t-SNE of every scored setting (standardised; log scale for the wide settings), coloured by "
            "score. Nearby points are similar settings.",
            figures.tsne_figure(extract.tsne_map([auto, crowd_data], seed=seed)),
        ),
        Section(
            "compute",
            "Best score against compute",
            "Best score so far against the frames simulated so far. Automated: every finished trial's training "
            "and evaluation frames (pruned and failed trials count); crowd: 30·trainIterations per submission, "
            "in submission order (their evaluation frames are unknown).",
            figures.compute_figure({k: extract.compute_curve(v) for k, v in sides.items()}),
        ),
        Section(
            "importances",
            "Hyperparameter importances",
            "Optuna's fANOVA importances (fixed seed) over the parameters every complete trial shares.",
            figures.importance_figure(
                {"autotune": extract.importances(automated, seed=seed), "crowd": extract.importances(crowd, seed=seed)}
            ),
        ),
        Section(
            "replay",
            "Self-reported against measured",
            "Crowd settings retrained by our learner and scored by the exact engine (mean over seeds, official "
            "protocol of the setting's engine), and the human nets scored with their own weights.",
            figures.replay_figure(
                _replayed(replay, crowd_data) if replay is not None else Empty("no crowd replay study given"),
                extract.own_net_comparison(crowd_data),
            ),
        ),
    ]
    if replay is not None:
        sides["replay"] = extract.study_data(replay)
    return Report(
        title=f"{automated.study_name} vs the crowd",
        studies=sides,
        sections=sections,
        insights={"crowd": insights.evaluate_all(crowd_data), "autotune": insights.evaluate_all(auto)},
    )


def _replayed(replay: optuna.Study, crowd: StudyData) -> list[extract.ReplayRow] | Empty:
    reported = {t.crowd_id: float(t.value) for t in crowd.scored if t.crowd_id and t.value is not None}
    return extract.replay_comparison(extract.study_data(replay), reported)


def _spread(spread: SpreadData | Empty | None) -> go.Figure | Empty:
    if spread is None:
        return Empty("evaluation-spread data not supplied to this report")
    if isinstance(spread, Empty):
        return spread
    if not spread.nets:
        return Empty("no net in the evaluation-spread data")
    from dashboards.spread import spread_figure

    fig: go.Figure = spread_figure(spread)
    return fig


def _fmt(value: float | None, spec: str) -> str:
    return "—" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, spec)


def _holds(result: insights.InsightResult) -> str:
    return {True: "yes", False: "no", None: "undecided"}[result.holds]


def _insight_rows(report: Report) -> list[tuple[str, str, list[insights.InsightResult]]]:
    rows = []
    for i, insight in enumerate(insights.INSIGHTS):
        results = [report.insights[side][i] for side in ("crowd", "autotune")]
        rows.append((insight.name, results[0].statistic, results))
    return rows


def _insights_html(report: Report) -> str:
    head = (
        "<tr><th rowspan=2>insight</th><th rowspan=2>statistic</th>"
        + "".join(f"<th colspan=5>{html.escape(report.studies[s].name)} ({s})</th>" for s in ("crowd", "autotune"))
        + "</tr><tr>"
        + "<th>n</th><th>value</th><th>p-value</th><th>holds</th><th>note</th>" * 2
        + "</tr>"
    )
    body = []
    for name, stat, results in _insight_rows(report):
        cells = "".join(
            f"<td>{r.n}</td><td>{_fmt(r.value, '+.3f')}</td><td>{_fmt(r.p_value, '.2g')}</td>"
            f"<td class='holds-{_holds(r)}'>{_holds(r)}</td><td>{html.escape(r.note)}</td>"
            for r in results
        )
        body.append(f"<tr><td>{html.escape(name)}</td><td>{html.escape(stat)}</td>{cells}</tr>")
    return f"<table class='insights'>{head}{''.join(body)}</table>"


def insights_markdown(report: Report) -> str:
    """The insights table as markdown (optuna-dashboard note)."""
    lines = [
        "| insight | statistic | crowd value | crowd p | crowd holds "
        "| automated value | automated p | automated holds |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, stat, (c, a) in _insight_rows(report):
        lines.append(
            f"| {name} | {stat} | {_fmt(c.value, '+.3f')} (n={c.n}) | {_fmt(c.p_value, '.2g')} | {_holds(c)} | "
            f"{_fmt(a.value, '+.3f')} (n={a.n}) | {_fmt(a.p_value, '.2g')} | {_holds(a)} |"
        )
    return "\n".join(lines)


_CSS = """
body { font-family: system-ui, sans-serif; margin: 24px auto; max-width: 1300px; color: #222; }
h1 { margin-bottom: 4px; } h2 { margin-top: 36px; border-bottom: 1px solid #ddd; }
.meta { color: #555; } .empty { padding: 18px; background: #f6f6f6; border-left: 4px solid #999; color: #444; }
table.insights { border-collapse: collapse; font-size: 14px; }
table.insights td, table.insights th { border: 1px solid #ccc; padding: 4px 8px; text-align: left; }
.holds-yes { background: #e3f5e1; } .holds-no { background: #fbe3e1; } .holds-undecided { background: #f3f3f3; }
"""


def render_html(report: Report) -> str:
    """The report as one HTML document; plotly.js is inlined with the first figure (no network needed)."""
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(report.title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(report.title)}</h1>",
        f"<p class='meta'>Generated {dt.datetime.now().isoformat(timespec='seconds')} by autotune compare.</p><ul>",
        *(f"<li>{html.escape(_side_label(d))}</li>" for d in report.studies.values()),
        "</ul>",
        "<h2 id='insights'>The four insights</h2>",
        "<p>Each insight is tested by a Spearman rank correlation of the setting against the score; it holds when "
        f"the sign is the claimed one and p &lt; {insights.ALPHA}. Crowd scores are self-reported (v1 and v2 "
        "engines mixed).</p>",
        _insights_html(report),
    ]
    plotly_js_included = False
    for section in report.sections:
        parts.append(f"<h2 id='{section.key}'>{html.escape(section.title)}</h2>")
        parts.append(f"<p>{html.escape(section.description)}</p>")
        if isinstance(section.figure, Empty):
            parts.append(f"<div class='empty'>Nothing to show: {html.escape(section.figure.reason)}.</div>")
            continue
        parts.append(
            pio.to_html(
                section.figure,
                full_html=False,
                include_plotlyjs=not plotly_js_included,
                div_id=f"fig-{section.key}",
                config={"responsive": True},
            )
        )
        plotly_js_included = True
    parts.append("</body></html>")
    return "\n".join(parts)


def write_html(report: Report, path: str | Path) -> Path:
    """Write the self-contained HTML page; returns its path."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(render_html(report), encoding="utf-8")
    return out


def attach_to_dashboard(study: optuna.Study, report: Report, sections: Sequence[str] | None = None) -> list[str]:
    """Store the report's figures (fixed ids: re-running replaces them) and a markdown note in ``study``."""
    from optuna_dashboard import save_note, save_plotly_graph_object

    ids = []
    for section in report.sections:
        if isinstance(section.figure, Empty) or (sections is not None and section.key not in sections):
            continue
        ids.append(save_plotly_graph_object(study, section.figure, graph_object_id=f"autotune-{section.key}"))
    empty = [f"* {s.title}: {s.figure.reason}" for s in report.sections if isinstance(s.figure, Empty)]
    note = "\n".join(
        [
            f"# {report.title}",
            "",
            *(f"* {_side_label(d)}" for d in report.studies.values()),
            "",
            "## The four insights (Spearman ρ against score; holds: expected sign and p < 0.05)",
            "",
            insights_markdown(report),
            *(["", "## Panels without data", "", *empty] if empty else []),
        ]
    )
    save_note(study, note)
    return ids
