"""The comparison report: automated search and the crowd side by side, as one self-contained HTML file.

``build_report`` extracts every panel's data (``dashboards.extract``, ``dashboards.insights``,
``dashboards.headline``; the measured crowd from the package data, ``dashboards.measured``) and
draws it (``dashboards.figures``); ``write_html`` writes one file with plotly.js inlined, so it
opens without network access; ``attach_to_dashboard`` stores the same figures and a markdown
note in the study for optuna-dashboard (through ``autotune.search.dashboard``). The studies are
plain records (``autotune.search.records``). A panel without data is an explained note, never an
empty figure. Every score shown names its engine and kind (``dashboards.provenance``); the page
has an other-agents filter that hides the points of unticked agent counts in every figure.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import html
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import plotly.graph_objects as go
import plotly.io as pio

from autotune.search.records import StudyRecord
from autotune.search.storage import Storages
from dashboards import extract, figures, headline, insights, measured
from dashboards import provenance as pv
from dashboards.extract import Empty, StudyData

if TYPE_CHECKING:
    from dashboards.spread import SpreadData

__all__ = [
    "Section",
    "Report",
    "VALUE_IS",
    "IMPORTANCE_METHOD",
    "build_report",
    "render_html",
    "write_html",
    "dashboard_note",
    "attach_to_dashboard",
    "insights_markdown",
]

VALUE_IS = {
    "autotune": "official score [mph], measured: the trial's net trained by our learner, scored by the exact engine "
    "with its engine's official protocol (the site's median)",
    "crowd": "self-reported score [mph], claimed by the author and not measured (its kind: claimed, local run, "
    "approximate or lower bound, official example); v1 and v2 engines, told apart in every figure",
    "crowd-replay": "replayed score [mph], measured: a crowd setting retrained by our learner in its own engine and "
    "scored with that engine's official protocol",
}
"""What each kind of study's value is (also its Optuna metric name, ``crowd.CROWD_METRIC`` etc.)."""
IMPORTANCE_METHOD = (
    "Inputs: the stored config of each configuration (identical settings once) — every hyperparameter of the "
    "panels, hidden layers, log10 parameter count, the engine (v2 = 1) and the other agents (v1: 0) — not the "
    "sampling parameters. A random forest (100 trees, leaves ≥ 2, fixed seed) is fit on 3 of 4 shuffled folds; a "
    "setting's importance is the drop in held-out R² when its column is permuted (5 repeats), averaged over folds, "
    "clipped at 0 and normalised to sum 1. Correlated settings share importance; a self-reported side is explained "
    "as claimed."
)


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
    headline: headline.Headline
    agents: list[str]
    """Other-agent labels of every plotted point (the filter's choices)."""
    own_nets: list[measured.OwnNetScore]
    """The human nets' own-weight scores the report used."""


def _side_lines(data: StudyData) -> list[str]:
    """A study's counts and bests, per engine and score kind (never pooled across them)."""
    states: dict[str, int] = {}
    for t in data.trials:
        states[t.state] = states.get(t.state, 0) + 1
    counts = ", ".join(f"{n} {s.lower()}" for s, n in sorted(states.items())) or "no finished trial"
    value = VALUE_IS.get(data.source, VALUE_IS["autotune"])
    lines = [f"{data.name} ({figures.SIDE_NAMES.get(data.source, data.source)}): {counts}. Its value: {value}."]
    for engine in pv.ENGINES:
        for kind in pv.KIND_LABEL:
            mine = [t for t in data.scored if t.engine == engine and t.kind == kind]
            if mine:
                best = max(mine, key=lambda t: t.value)  # type: ignore[arg-type,return-value]
                lines.append(
                    f"  {pv.ENGINE_LABEL[engine]} · {pv.KIND_LABEL[kind]}: {len(mine)} score(s), best "
                    f"{best.value:.2f} mph ({best.label}, {pv.agents_label(engine, best.other_agents)})"
                )
    if data.skipped:
        lines.append(f"  left out: {len(data.skipped)} trial(s) ({next(iter(data.skipped.values()))})")
    return lines


def _own_nets_lines(own: Sequence[measured.OwnNetScore]) -> list[str]:
    lines = [
        f"human nets scored with their own weights (package data, {measured.OWN_NETS_COMMAND}): {len(own)} nets. "
        f"Their value: {pv.KIND_LABEL[pv.OWN_WEIGHTS]} [mph], the site's median of their engine's official protocol."
    ]
    for engine in pv.ENGINES:
        mine = [s for s in own if s.engine == engine]
        if mine:
            best = max(mine, key=lambda s: s.score)
            lines.append(
                f"  {pv.ENGINE_LABEL[engine]} · {pv.KIND_LABEL[pv.OWN_WEIGHTS]}: {len(mine)} net(s), best "
                f"{best.score:.2f} mph ({best.crowd_id}, {pv.agents_label(engine, best.other_agents)})"
            )
    return lines


def _unscored_replays(table: measured.ReplayTable | None) -> str:
    """A sentence naming the table's configurations with no scored seed, and why (they have no point to draw)."""
    if table is None:
        return ""
    lost = [e for e in table.entries if e.mean is None]
    if not lost:
        return ""
    parts = []
    for e in lost:
        causes = sorted({(r.cause or r.state).split(":")[0] for r in e.runs})
        parts.append(f"{e.crowd_id} ({e.engine}, claimed {e.claimed:.2f} mph): {' / '.join(causes)} in all "
                     f"{len(e.runs)} seeds")  # fmt: skip
    return f" Not drawn, no seed scored: {'; '.join(parts)}."


def _merge_replays(
    shipped: list[extract.ClaimRow] | Empty, studied: list[extract.ClaimRow] | Empty
) -> list[extract.ClaimRow] | Empty:
    """The shipped table's rows, plus a replay study's rows for configurations the table lacks."""
    if isinstance(shipped, Empty):
        return studied if not isinstance(studied, Empty) else Empty(f"{shipped.reason}; {studied.reason}")
    have = {r.crowd_id for r in shipped}
    extra = [] if isinstance(studied, Empty) else [r for r in studied if r.crowd_id not in have]
    return [*shipped, *extra]


def build_report(
    automated: StudyRecord,
    crowd: StudyRecord,
    *,
    replay: StudyRecord | None = None,
    spread: SpreadData | Empty | None = None,
    own_nets: Sequence[measured.OwnNetScore] | None = None,
    replay_table: measured.ReplayTable | None = None,
    seed: int = 0,
) -> Report:
    """Extract and draw every panel of the comparison of ``automated`` with ``crowd`` (and its ``replay``).

    ``own_nets`` defaults to the shipped ``own_nets.json``, ``replay_table`` to the shipped
    ``replay.json`` (which may not have been computed).
    """
    auto = extract.study_data(automated)
    crowd_data = extract.study_data(crowd)
    own = list(measured.load_own_nets() if own_nets is None else own_nets)
    table = measured.load_replay() if replay_table is None else replay_table
    sides = {"autotune": auto, "crowd": crowd_data}
    studied: list[extract.ClaimRow] | Empty = Empty("no crowd replay study given")
    if replay is not None:
        replay_data = extract.study_data(replay)
        studied = extract.replay_comparison(replay_data, crowd_data)
    replays = _merge_replays(extract.replay_table_rows(table), studied)
    own_rows = extract.own_net_rows(own)
    sections = [
        Section(
            "progress",
            "Progress",
            "Score against trial number (automated) and submission order (crowd, by commit date), with each "
            "engine's running best: the paper's progress figure. Crowd scores are claims (open markers).",
            figures.progress_figure({k: extract.progress(v) for k, v in sides.items()}),
        ),
        Section(
            "size",
            "Network size",
            "Parameter count (weights + biases) against score, coloured by the number of hidden layers and by the "
            "training length. Symbol = engine (circle v2, diamond v1); filled = measured, open = self-reported; "
            "outline colour = side.",
            figures.size_figure({k: extract.size_scatter(v) for k, v in sides.items()}),
        ),
        Section(
            "hyperparameters",
            "Each hyperparameter",
            "One panel per hyperparameter against score (real values; γ, not 1 − γ). v1 has no other agents, so v1 "
            "points are absent from that panel.",
            figures.hyperparameter_figure({k: extract.hyperparameter_panels(v) for k, v in sides.items()}),
        ),
        Section(
            "spread",
            "How much the site's number moves",
            "Each net in its own engine and official protocol, under consecutive Math.random seeds from the "
            "protocol's own (the site's number is the first): left, the site's statistic (lexicographic median) of "
            "each seed's evaluation; right, its sd over seeds against the runs per evaluation (an n-run evaluation is "
            "the first n runs). The v2 protocol fixes every run's traffic seed, so a net that never explores at test "
            "time (epsilon_test_time 0) gets the same number under every seed; the dashed lines resample the runs "
            "of the site's own evaluation (bootstrap): how much the number would move on fresh traffic.",
            _spread(spread),
        ),
        Section(
            "tsne",
            "Map of the settings",
            "A joint t-SNE of every scored setting (standardised; log scale for the wide settings), coloured by "
            "score (claims and measurements share the colour scale: the symbol says which). Nearby points are "
            "similar settings.",
            figures.tsne_figure(extract.tsne_map([auto, crowd_data], seed=seed)),
        ),
        Section(
            "compute",
            "Best score against compute",
            "Each engine's best score so far against the frames simulated so far. Automated: every finished "
            "trial's training and evaluation frames (pruned and failed trials count); crowd: 30·trainIterations per "
            "submission, in submission order (their evaluation frames are unknown), best of the claims.",
            figures.compute_figure({k: extract.compute_curve(v) for k, v in sides.items()}),
        ),
        Section(
            "importances",
            "Setting importances",
            IMPORTANCE_METHOD,
            figures.importance_figure({k: extract.importances(v, seed=seed) for k, v in sides.items()}),
        ),
        Section(
            "claims",
            "Claimed against measured",
            "Each human net scored with its own weights in its own engine and official protocol (exact, "
            f"deterministic; {measured.OWN_NETS_COMMAND}), and each replayed crowd setting's mean over seeds (bars: "
            "sd), against the score its author claimed. The dotted line is measured = claimed.",
            figures.claims_figure(own_rows, replays),
        ),
        Section(
            "replay",
            "Claimed against replayed",
            "The best-claimed crowd configurations (identical settings once), retrained by our learner in their own "
            "engine with their own settings and training length, several seeds each, scored with the engine's "
            f"official protocol (shipped table: {measured.REPLAY_COMMAND}); claim (open), each seed and the mean ± "
            f"sd over seeds.{_unscored_replays(table)}",
            figures.replay_figure(replays),
        ),
    ]
    if replay is not None:
        sides = {**sides, "replay": replay_data}
    results = insights.evaluate_all({"crowd": crowd_data, "autotune": auto})
    agents = sorted(
        {
            c[2]
            for s in sections
            if not isinstance(s.figure, Empty)
            for t in s.figure.data
            if t.customdata is not None
            for c in t.customdata
        },
        key=_agents_order,
    )
    return Report(
        title=f"{automated.name} vs the crowd",
        studies=sides,
        sections=sections,
        insights=results,
        headline=headline.headline(auto, crowd_data, own),
        agents=agents,
        own_nets=own,
    )


def _agents_order(label: str) -> tuple[int, str]:
    head = label.split(" ", 1)[0]
    return (int(head), label) if head.isdigit() else (-1 if label.startswith("no ") else 1000, label)


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


def _row_name(r: insights.InsightResult) -> str:
    if not r.engines:
        return f"{r.study}: no configuration"
    return pv.series_name(r.study, r.engines, r.kinds)


def _insights_html(report: Report, side: str) -> str:
    head = (
        "<tr><th>insight</th><th>data: study · engines · score kinds</th><th>test</th><th>statistic</th><th>n</th>"
        "<th>ρ</th><th>p</th><th>Holm p</th><th>holds</th><th>note</th></tr>"
    )
    body = []
    for r in report.insights.get(side, []):
        body.append(
            f"<tr><td>{html.escape(r.insight.name)}</td><td>{html.escape(_row_name(r))}</td>"
            f"<td>{html.escape(r.group)}</td><td>{html.escape(r.statistic)}</td><td>{r.n}</td>"
            f"<td>{_fmt(r.value, '+.3f')}</td><td>{_fmt(r.p_value, '.2g')}</td><td>{_fmt(r.p_holm, '.2g')}</td>"
            f"<td class='holds-{_holds(r)}'>{_holds(r)}</td><td>{html.escape(r.note)}</td></tr>"
        )
    return f"<table class='insights' id='insights-{side}'>{head}{''.join(body)}</table>"


def insights_markdown(report: Report) -> str:
    """The insights tables as markdown (optuna-dashboard note): one per study, each its own Holm family."""
    lines: list[str] = []
    for side in ("crowd", "autotune"):
        if side not in report.insights:
            continue
        tested = sum(r.p_value is not None for r in report.insights[side])
        lines += [
            f"### {report.studies[side].name} ({figures.SIDE_NAMES[side]}; Holm over this table's {tested} tests)",
            "",
            "| insight | data: study · engines · score kinds | test | statistic | n | ρ | p | Holm p | holds |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for r in report.insights[side]:
            lines.append(
                f"| {r.insight.name} | {_row_name(r)} | {r.group} | {r.statistic.replace('|', chr(92) + '|')} | {r.n} "
                f"| {_fmt(r.value, '+.3f')} "
                f"| {_fmt(r.p_value, '.2g')} | {_fmt(r.p_holm, '.2g')} | {_holds(r)} |"
            )
        lines.append("")
    return "\n".join(lines).rstrip()


_CSS = """
body { font-family: system-ui, sans-serif; margin: 24px auto; max-width: 1300px; color: #222; }
h1 { margin-bottom: 4px; } h2 { margin-top: 36px; border-bottom: 1px solid #ddd; }
.meta { color: #555; } .empty { padding: 18px; background: #f6f6f6; border-left: 4px solid #999; color: #444; }
.method { color: #333; font-size: 14px; background: #f7f9fc; padding: 8px 12px; border-left: 3px solid #9ab; }
.headline li { margin: 4px 0; } .sides { white-space: pre-wrap; font-family: ui-monospace, monospace; font-size: 13px; }
#agents-filter { position: sticky; top: 0; background: #fff; padding: 8px 0; border-bottom: 1px solid #ddd; }
#agents-filter label { margin-right: 14px; font-size: 14px; }
table.insights { border-collapse: collapse; font-size: 13px; }
table.insights td, table.insights th { border: 1px solid #ccc; padding: 4px 8px; text-align: left; }
.holds-yes { background: #e3f5e1; } .holds-no { background: #fbe3e1; } .holds-undecided { background: #f3f3f3; }
"""

# Hides, in every figure, the points whose other-agents label (customdata[2]) is unticked; traces whose
# meta is not filterable (lines, bars, reference lines) are left alone.
_FILTER_JS = """
(function () {
  function apply() {
    var keep = new Set(Array.from(document.querySelectorAll('#agents-filter input:checked')).map(function (b) {
      return b.value; }));
    document.querySelectorAll('.js-plotly-plot').forEach(function (div) {
      var idx = [], sel = [];
      (div.data || []).forEach(function (t, i) {
        if (!t.meta || !t.meta.filterable || !t.customdata) return;
        var s = [];
        for (var k = 0; k < t.customdata.length; k++) { if (keep.has(t.customdata[k][2])) s.push(k); }
        idx.push(i); sel.push(s.length === t.customdata.length ? null : s);
      });
      if (idx.length) Plotly.restyle(div, {selectedpoints: sel, 'unselected.marker.opacity': 0}, idx);
    });
  }
  document.querySelectorAll('#agents-filter input').forEach(function (b) { b.addEventListener('change', apply); });
})();
"""


def render_html(report: Report) -> str:
    """The report as one HTML document; plotly.js is inlined with the first figure (no network needed)."""
    sides = "\n".join(line for d in report.studies.values() for line in _side_lines(d))
    boxes = "".join(
        f"<label><input type='checkbox' checked value='{html.escape(a, quote=True)}'> {html.escape(a)}</label>"
        for a in report.agents
    )
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(report.title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(report.title)}</h1>",
        f"<p class='meta'>Generated {dt.datetime.now().isoformat(timespec='seconds')} by autotune compare.</p>",
        "<h2 id='headline'>Headline</h2><ul class='headline'>",
        *(f"<li>{html.escape(line)}</li>" for line in report.headline.lines),
        "</ul>",
        "<h2 id='studies'>What is compared</h2>",
        f"<div class='sides'>{html.escape(sides)}\n{html.escape(chr(10).join(_own_nets_lines(report.own_nets)))}</div>",
        "<p class='method'>Every score names its engine (v1: 2017, one car; v2: 2018–19, other agents sharing the "
        "net) and its kind: <b>measured</b> (a net scored by the exact engine with its engine's official protocol: "
        "the automated trials, the human nets' own weights, replayed crowd settings; filled markers) or "
        "<b>self-reported</b> (the crowd's claims — claimed, local run, approximate or lower bound, official "
        "example; open markers). Symbol: circle = v2 engine, diamond = v1 engine. Hover a point for its other "
        "agents and confidence.</p>",
        f"<div id='agents-filter'><b>Other agents:</b> {boxes}</div>",
        "<h2 id='insights'>The four insights</h2>",
        f"<p class='method'>{html.escape(insights.METHOD)}</p>",
        *(
            f"<h3>{html.escape(report.studies[side].name)} ({figures.SIDE_NAMES[side]}; Holm over this table's "
            f"{sum(r.p_value is not None for r in report.insights[side])} tests)</h3>{_insights_html(report, side)}"
            for side in ("crowd", "autotune")
            if side in report.insights
        ),
    ]
    plotly_js_included = False
    for section in report.sections:
        parts.append(f"<h2 id='{section.key}'>{html.escape(section.title)}</h2>")
        parts.append(f"<p class='method'>{html.escape(section.description)}</p>")
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
    parts.append(f"<script>{_FILTER_JS}</script></body></html>")
    return "\n".join(parts)


def write_html(report: Report, path: str | Path) -> Path:
    """Write the self-contained HTML page; returns its path."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(render_html(report), encoding="utf-8")
    return out


def dashboard_note(report: Report) -> str:
    """The markdown note optuna-dashboard shows beside the figures: headline, what each value is, insights."""
    empty = [f"* {s.title}: {s.figure.reason}" for s in report.sections if isinstance(s.figure, Empty)]
    sides = [line for d in report.studies.values() for line in _side_lines(d)] + _own_nets_lines(report.own_nets)
    return "\n".join(
        [
            f"# {report.title}",
            "",
            "## Headline",
            "",
            *(f"* {line}" for line in report.headline.lines),
            "",
            "## What each study's value is",
            "",
            *(f"* {line.strip()}" for line in sides),
            "",
            "Crowd trials are COMPLETE because Optuna needs a value: their value is a claim (user attr value_is), "
            "never a measurement; measured own-weight scores are in own_net_score.",
            "",
            "## The four insights",
            "",
            insights.METHOD,
            "",
            insights_markdown(report),
            *(["", "## Panels without data", "", *empty] if empty else []),
        ]
    )


def attach_to_dashboard(
    storages: Storages, study_name: str, report: Report, sections: Sequence[str] | None = None
) -> list[str]:
    """Store the report's figures (fixed ids: re-running replaces them) and its note in the stored study."""
    from autotune.search.dashboard import attach

    chosen = {
        f"autotune-{s.key}": s.figure
        for s in report.sections
        if not isinstance(s.figure, Empty) and (sections is None or s.key in sections)
    }
    return attach(storages, study_name, chosen, dashboard_note(report))
