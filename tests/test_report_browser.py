"""End to end: `autotune compare` writes the report from a stored study; headless Chromium renders every figure.

The automated study is written to a real SQLite storage with trials shaped like the search service's
records; the crowd study is imported by `autotune crowd import` into the same storage. Fails on any
console error, on a figure without traces or data points, and on a missing panel.
"""

from __future__ import annotations

from pathlib import Path

import optuna

from autotune.cli import main
from tests.browser import assert_page_ok, require_browser
from tests.test_report_data import PRUNED, contract_study


def test_compare_report_renders_in_chromium(tmp_path: Path, capsys, monkeypatch) -> None:  # noqa: ANN001
    require_browser()
    monkeypatch.chdir(tmp_path)  # the spread cache goes to ./runs/
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
    assert "wrote" in printed and "(8 of 8 panels with data)" in printed, printed
    assert "evaluation spread: 3 nets × 50 runs scored" in printed
    assert list((tmp_path / "runs" / ".spread-cache").glob("spread-*.json"))
    page = assert_page_ok(out, tmp_path / "report.png", min_figures=8)
    ids = {f.id for f in page.figures}
    keys = ("progress", "size", "hyperparameters", "spread", "tsne", "compute", "importances", "replay")
    assert ids == {f"fig-{k}" for k in keys}
    assert page.title == "auto vs the crowd"
    assert page.screenshot is not None and page.screenshot.stat().st_size > 10_000
