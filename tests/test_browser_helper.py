"""tests/browser.py on tiny pages: a good page passes; a console error, an empty figure, a trace without points fail."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import plotly.graph_objects as go
import pytest

from tests.browser import assert_page_ok, assert_report_ok, check_page, require_browser


@pytest.fixture(autouse=True)
def _browser() -> None:
    require_browser()


def _page(tmp_path: Path, name: str, figures: list[go.Figure], extra: str = "") -> Path:
    parts = [fig.to_html(full_html=False, include_plotlyjs=(i == 0)) for i, fig in enumerate(figures)]
    path = tmp_path / name
    path.write_text(f"<html><head><title>{name}</title></head><body>{''.join(parts)}{extra}</body></html>")
    return path


def test_good_page_reports_traces_and_points(tmp_path: Path) -> None:
    scatter = go.Figure(go.Scatter(x=[1, 2, 3], y=[4, 5, 6]))
    heat = go.Figure(go.Heatmap(z=np.arange(12.0).reshape(3, 4)))  # numpy: serialised as base64 typed arrays
    shot = tmp_path / "good.png"
    report = assert_page_ok(_page(tmp_path, "good.html", [scatter, heat]), screenshot=shot, min_figures=2)
    assert [(f.traces, f.points) for f in report.figures] == [(1, (3,)), (1, (12,))]
    assert report.console_errors == ()
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_console_error_empty_figure_and_pointless_trace_each_fail(tmp_path: Path) -> None:
    figures = [go.Figure(go.Bar(y=[1, 2])), go.Figure(), go.Figure(go.Scatter(x=[], y=[]))]
    page = _page(tmp_path, "bad.html", figures, "<script>throw new Error('boom-123')</script>")
    report = check_page(page)
    assert [f.traces for f in report.figures] == [1, 0, 1]
    problems = report.problems()
    assert len(problems) == 3, problems
    assert "boom-123" in problems[0]
    assert problems[1].endswith(": no traces")
    assert problems[2].endswith("trace(s) without data points")
    with pytest.raises(AssertionError, match="(?s)boom-123.*no traces.*without data points"):
        assert_report_ok(report)


def test_page_without_figures_fails_min_figures(tmp_path: Path) -> None:
    page = tmp_path / "plain.html"
    page.write_text("<html><body><p>no plots</p></body></html>")
    with pytest.raises(AssertionError, match="at least 1 plotly figure"):
        assert_page_ok(page)
