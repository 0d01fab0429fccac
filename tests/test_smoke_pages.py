"""Issue 9's end-to-end check: the smoke study, launched for real, gives a report and a replay page that render.

`autotune launch study_configs/smoke.toml` (real Ray, embedded journal; the session's one launch, the
``smoke_launch`` fixture, copied), then `autotune crowd import`,
`autotune compare` and `autotune replay` on that study; both pages open in headless Chromium, which
fails the test on any console error, any figure without traces and any trace without data points.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

from tests.browser import assert_page_ok, require_browser
from tests.conftest import SmokeLaunch
from tests.test_search_launch import check_finished_trials, load, tagged_processes


def _autotune(cwd: Path, *args: str) -> str:
    done = subprocess.run(
        [sys.executable, "-m", "autotune.cli", *args], cwd=cwd, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, (args, done.stdout, done.stderr)
    return done.stdout


def test_smoke_study_report_and_replay_render(smoke_launch: SmokeLaunch, tmp_path: Path) -> None:
    require_browser()
    assert smoke_launch.rc == 0, (smoke_launch.out, smoke_launch.err)
    shutil.copytree(smoke_launch.cwd / "runs", tmp_path / "runs")  # the crowd import below writes beside it
    study = load(tmp_path, "smoke")
    check_finished_trials(study)
    assert study.best_value > 0
    assert not tagged_processes(smoke_launch.tag)

    _autotune(tmp_path, "crowd", "import")
    report = tmp_path / "report.html"
    printed = _autotune(tmp_path, "compare", "smoke", "--out", str(report), "--spread-runs", "20")
    assert "wrote" in printed and "panels with data" in printed
    page = assert_page_ok(report, min_figures=6)
    ids = {f.id for f in page.figures}
    for key in ("progress", "size", "hyperparameters", "spread", "tsne", "compute"):
        assert f"fig-{key}" in ids, (key, sorted(ids))

    replay = tmp_path / "run.html"
    printed = _autotune(tmp_path, "replay", "smoke", "--out", str(replay), "--frames", "60", "--every", "3")
    assert f"{replay.name}" in printed
    page = assert_page_ok(replay, min_figures=1)
    assert sum(f.traces for f in page.figures) >= 4  # the road, the grid, the safety view, the input slice
