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


def test_compare_report_renders_in_chromium(tmp_path: Path, capsys) -> None:  # noqa: ANN001
    require_browser()
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
    assert main(["compare", "auto", "--storage", storage, "--out", str(out)], owns_process=False) == 0
    printed = capsys.readouterr().out
    assert "wrote" in printed and "(7 of 8 panels with data)" in printed  # spread: no data supplied
    page = assert_page_ok(out, tmp_path / "report.png", min_figures=7)
    ids = {f.id for f in page.figures}
    assert ids == {
        f"fig-{k}" for k in ("progress", "size", "hyperparameters", "tsne", "compute", "importances", "replay")
    }
    assert page.title == "auto vs the crowd"
    assert page.screenshot is not None and page.screenshot.stat().st_size > 10_000
