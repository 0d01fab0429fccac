"""End to end: `autotune compare` writes the report from a stored study; headless Chromium renders every figure.

The automated study is written to a real SQLite storage with trials shaped like the search service's
records; the crowd study is imported by `autotune crowd import` into the same storage. Fails on any
console error, on a figure without traces or data points, and on a missing panel; then a reader unticks
"10 other agents" in the filter and every point of that many agents, and only those, disappears.
"""

from __future__ import annotations

from pathlib import Path

import optuna

from autotune.cli import main
from tests.browser import assert_page_ok, require_browser
from tests.test_report_data import PRUNED, contract_study

UNTICK_10_AGENTS = """
const box = Array.from(document.querySelectorAll('#agents-filter input')).find(b => b.value === '10 other agents');
if (!box) return null;
box.checked = false;
box.dispatchEvent(new Event('change'));
let hidden = 0, kept = 0, wrong = 0, traces = 0;
document.querySelectorAll('.js-plotly-plot').forEach(div => (div.data || []).forEach(t => {
  if (!t.meta || !t.meta.filterable || !t.customdata) return;
  traces++;
  const sel = (t.selectedpoints === undefined || t.selectedpoints === null) ? null
    : new Set(Array.from(t.selectedpoints));
  t.customdata.forEach((c, k) => {
    const shown = sel === null || sel.has(k);
    if (c[2] === '10 other agents') { if (shown) wrong++; else hidden++; } else { if (shown) kept++; else wrong++; }
  });
}));
return {hidden: hidden, kept: kept, wrong: wrong, traces: traces};
"""


def test_compare_report_renders_in_chromium(tmp_path: Path, capsys, monkeypatch) -> None:  # noqa: ANN001
    require_browser()
    monkeypatch.chdir(tmp_path)
    storage = f"sqlite:///{tmp_path / 'studies.db'}"
    contract_study(storage, name="auto", n=12, states={4: PRUNED})
    assert main(["crowd", "import", "--storage", storage], owns_process=False) == 0
    enqueue = ["crowd", "replay", "--storage", storage, "--filter", "in_nets_dir", "--limit", "2", "--enqueue-only"]
    assert main(enqueue) == 0
    replay = optuna.load_study(study_name="crowd-replay", storage=storage)
    for value in (70.0, 71.5):  # the driver would train and score these; here they finish with a given score
        trial = replay.ask()
        replay.tell(trial, value)
    out = tmp_path / "report.html"
    compare = ["compare", "auto", "--storage", storage, "--out", str(out), "--spread-runs", "50"]
    assert main(compare, owns_process=False) == 0
    printed = capsys.readouterr().out
    assert "wrote" in printed and "(9 of 9 panels with data)" in printed, printed
    assert not (tmp_path / "runs" / ".spread-cache").exists()  # the spread ships as package data: no net scored
    page = assert_page_ok(out, tmp_path / "report.png", min_figures=9, script=UNTICK_10_AGENTS)
    ids = {f.id for f in page.figures}
    keys = ("progress", "size", "hyperparameters", "spread", "tsne", "compute", "importances", "claims", "replay")
    assert ids == {f"fig-{k}" for k in keys}
    assert page.title == "auto vs the crowd"
    assert page.screenshot is not None and page.screenshot.stat().st_size > 10_000
    result = page.script_result
    assert isinstance(result, dict) and result["wrong"] == 0, result
    assert result["hidden"] > 20 and result["kept"] > 100 and result["traces"] > 30, result
