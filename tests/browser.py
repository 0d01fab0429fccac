"""Open a local HTML report in Debian's headless Chromium and say what a reader would see.

Reports are checked as data elsewhere; this helper catches what only a browser shows: a console
error (a plotly.js exception, a script that failed to load), a figure with no traces, or traces
with no points. ``check_page`` collects a ``PageReport``; ``assert_page_ok`` fails with one
message listing every problem. Without ``/usr/bin/chromium`` + ``/usr/bin/chromedriver`` the
check is skipped, except on CI (``CI=true``), which installs both, so there it fails.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
CHROME_ARGS: tuple[str, ...] = (
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
)
WINDOW = (1400, 1000)  # px; the screenshot grows to the page height up to MAX_SCREENSHOT_HEIGHT
MAX_SCREENSHOT_HEIGHT = 6000

# Counts each trace's points from its data arrays: plain arrays, typed arrays, nested (heatmap z)
# and plotly's base64 form {dtype, bdata, shape} in case the figure was not decoded in place.
_COLLECT_JS = r"""
const ITEM = {i1: 1, u1: 1, u1c: 1, i2: 2, u2: 2, i4: 4, u4: 4, f4: 4, f8: 8};
function count(a) {
  if (a === null || a === undefined) return 0;
  if (typeof a === 'string') return 0;
  if (ArrayBuffer.isView(a)) return a.length;
  if (Array.isArray(a)) {
    let n = 0;
    for (const v of a) n += (Array.isArray(v) || ArrayBuffer.isView(v)) ? count(v) : 1;
    return n;
  }
  if (typeof a === 'object' && typeof a.bdata === 'string') {
    if (a.shape) return String(a.shape).split(',').reduce((p, s) => p * Number(s), 1);
    const bytes = Math.floor(a.bdata.replace(/=+$/, '').length * 3 / 4);
    return Math.floor(bytes / (ITEM[a.dtype] || 1));
  }
  return 0;
}
const KEYS = ['x', 'y', 'z', 'values', 'r', 'theta', 'lat', 'lon', 'a', 'b', 'c', 'cells', 'dimensions', 'source'];
function points(t) {
  let best = 0;
  for (const k of KEYS) {
    let v = t[k];
    if (k === 'cells' && v) v = v.values;
    if (k === 'dimensions' && Array.isArray(v)) { v = v.map(d => d.values || []); }
    if (k === 'source' && typeof v === 'string') { best = Math.max(best, v.length ? 1 : 0); continue; }
    best = Math.max(best, count(v));
  }
  return best;
}
return Array.from(document.querySelectorAll('.js-plotly-plot')).map((div, i) => ({
  id: div.id || ('#' + i),
  traces: (div.data || []).length,
  points: (div.data || []).map(points),
}));
"""

_READY_JS = r"""
if (document.readyState !== 'complete') return false;
const pending = Array.from(document.querySelectorAll('.plotly-graph-div'))
  .filter(d => !(d.classList.contains('js-plotly-plot') && d._fullLayout));
return pending.length === 0;
"""


@dataclass(frozen=True)
class Figure:
    """One rendered plotly graph div: its id, trace count and the number of data points of each trace."""

    id: str
    traces: int
    points: tuple[int, ...]


@dataclass(frozen=True)
class PageReport:
    """What the browser saw: console errors (SEVERE log lines), the plotly figures, the page title."""

    url: str
    title: str
    console_errors: tuple[str, ...]
    figures: tuple[Figure, ...]
    rendered: bool  # every plotly graph div finished rendering before the timeout
    screenshot: Path | None
    script_result: object = None  # what ``check_page(script=...)`` returned

    def problems(self) -> list[str]:
        """Human-readable problems: console errors, figures that did not render, have no traces or no points."""
        out = [f"console error: {msg}" for msg in self.console_errors]
        if not self.rendered:
            out.append("plotly figures did not finish rendering before the timeout")
        for fig in self.figures:
            if fig.traces == 0:
                out.append(f"figure {fig.id}: no traces")
            elif not any(fig.points):
                out.append(f"figure {fig.id}: {fig.traces} trace(s) without data points")
        return out


def browser_available() -> str | None:
    """None when headless Chromium can run here, else the reason it cannot."""
    for exe in (CHROMIUM, CHROMEDRIVER):
        if not (os.path.isfile(exe) and os.access(exe, os.X_OK)):
            return f"{exe} not installed (Debian packages chromium, chromium-driver)"
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium not installed"
    return None


def require_browser() -> None:
    """Skip the calling test when Chromium is missing; on CI (CI=true, which installs it) fail instead."""
    reason = browser_available()
    if reason is None:
        return
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(f"headless Chromium required on CI: {reason}")
    pytest.skip(reason)


def check_page(
    path: str | Path, screenshot: str | Path | None = None, *, timeout_s: float = 30.0, script: str | None = None
) -> PageReport:
    """Open ``path`` (a local HTML file) in headless Chromium, wait for plotly to render, report what it shows.

    Skips (or fails on CI) when Chromium is not installed. ``screenshot``: a PNG path to write.
    ``script``: JavaScript (a function body) run once the figures rendered, before the screenshot, as a reader's
    action; what it returns is ``PageReport.script_result``.
    """
    require_browser()
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    page = Path(path).resolve()
    if not page.is_file():
        raise FileNotFoundError(page)
    with tempfile.TemporaryDirectory(prefix="chromium-profile-") as profile:
        options = webdriver.ChromeOptions()
        options.binary_location = CHROMIUM
        for arg in CHROME_ARGS:
            options.add_argument(arg)
        options.add_argument(f"--user-data-dir={profile}")
        options.add_argument(f"--window-size={WINDOW[0]},{WINDOW[1]}")
        options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
        driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=options)
        try:
            driver.set_page_load_timeout(timeout_s)
            driver.get(page.as_uri())
            deadline = time.monotonic() + timeout_s
            rendered = False
            while time.monotonic() < deadline:
                if driver.execute_script(_READY_JS):
                    rendered = True
                    break
                time.sleep(0.1)
            result = driver.execute_script(script) if script is not None else None
            raw = driver.execute_script(_COLLECT_JS)
            figures = tuple(
                Figure(id=str(f["id"]), traces=int(f["traces"]), points=tuple(int(p) for p in f["points"])) for f in raw
            )
            shot: Path | None = None
            if screenshot is not None:
                height, chrome = driver.execute_script(
                    "return [document.documentElement.scrollHeight, window.outerHeight - window.innerHeight]"
                )
                total = int(height or WINDOW[1]) + int(chrome or 0)  # the window includes the browser's own bars
                driver.set_window_size(WINDOW[0], min(max(total, WINDOW[1]), MAX_SCREENSHOT_HEIGHT))
                time.sleep(0.3)  # let plotly's resize handlers settle
                shot = Path(screenshot)
                shot.parent.mkdir(parents=True, exist_ok=True)
                driver.save_screenshot(str(shot))
            errors = tuple(e["message"] for e in driver.get_log("browser") if e.get("level") == "SEVERE")
            title = str(driver.title)
        finally:
            driver.quit()
    return PageReport(
        url=page.as_uri(),
        title=title,
        console_errors=errors,
        figures=figures,
        rendered=rendered,
        screenshot=shot,
        script_result=result,
    )


def assert_report_ok(report: PageReport, *, min_figures: int = 1) -> PageReport:
    """Fail on any console error, unrendered/empty figure, or fewer than ``min_figures`` figures in ``report``."""
    problems = report.problems()
    if len(report.figures) < min_figures:
        problems.append(f"expected at least {min_figures} plotly figure(s), found {len(report.figures)}")
    if problems:
        raise AssertionError(f"{report.url}:\n  " + "\n  ".join(problems))
    return report


def assert_page_ok(
    path: str | Path, screenshot: str | Path | None = None, *, min_figures: int = 1, script: str | None = None
) -> PageReport:
    """``check_page`` then ``assert_report_ok``: the one-call check for a report page."""
    return assert_report_ok(check_page(path, screenshot, script=script), min_figures=min_figures)
