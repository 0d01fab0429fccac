"""The paper's four insights, each tested by a Spearman rank correlation against the score.

* size matters — parameter count vs score, expected positive;
* live in the moment — temporal window vs score, expected negative (a short memory is better);
* look far forward — patches ahead vs score, expected positive;
* plan for the future — γ vs score, expected positive.

An insight *holds* in a study when the correlation has the expected sign and p < ``ALPHA``;
it is undecided (``holds=None``) when fewer than ``MIN_POINTS`` trials record it or it never varies.
Spearman, not Pearson: settings span orders of magnitude and scores are bounded, so ranks are the
robust choice.
"""

from __future__ import annotations

import dataclasses
import math

from scipy import stats

from dashboards.extract import StudyData, TrialPoint

__all__ = ["ALPHA", "MIN_POINTS", "INSIGHTS", "Insight", "InsightResult", "evaluate", "evaluate_all"]

ALPHA = 0.05
MIN_POINTS = 5


@dataclasses.dataclass(frozen=True)
class Insight:
    """One of the paper's claims: which setting, and the sign of its correlation with the score if it holds."""

    name: str
    variable: str
    sign: int
    claim: str


INSIGHTS = (
    Insight("size matters", "param_count", +1, "larger networks score higher"),
    Insight("live in the moment", "temporal_window", -1, "a shorter temporal window scores higher"),
    Insight("look far forward", "patches_ahead", +1, "seeing more patches ahead scores higher"),
    Insight("plan for the future", "gamma", +1, "a higher discount γ scores higher"),
)


@dataclasses.dataclass(frozen=True)
class InsightResult:
    """An insight tested in one study."""

    insight: Insight
    study: str
    statistic: str
    n: int
    value: float | None
    p_value: float | None
    holds: bool | None
    note: str


def _value(t: TrialPoint, variable: str) -> float | None:
    if variable == "param_count":
        return float(t.param_count) if t.param_count is not None else None
    return t.settings.get(variable)


def evaluate(insight: Insight, data: StudyData) -> InsightResult:
    """Spearman ρ of ``insight.variable`` against the score over ``data``'s scored trials."""
    pairs = [(v, float(t.value)) for t in data.scored if (v := _value(t, insight.variable)) is not None]  # type: ignore[arg-type]
    n = len(pairs)
    stat = f"Spearman ρ({insight.variable}, score)"

    def undecided(note: str) -> InsightResult:
        return InsightResult(insight, data.name, stat, n, None, None, None, note)

    if n < MIN_POINTS:
        return undecided(f"only {n} scored trial(s) record {insight.variable} (need {MIN_POINTS})")
    xs, ys = [p[0] for p in pairs], [p[1] for p in pairs]
    if len(set(xs)) < 2:
        return undecided(f"{insight.variable} is the same in every trial ({xs[0]:g})")
    if len(set(ys)) < 2:
        return undecided("every trial has the same score")
    result = stats.spearmanr(xs, ys)
    rho, p = float(result.statistic), float(result.pvalue)
    if math.isnan(rho):
        return undecided("correlation undefined")
    holds = rho * insight.sign > 0 and p < ALPHA
    if holds:
        note = f"{insight.claim} (ρ {rho:+.2f}, p {p:.2g})"
    elif p >= ALPHA:
        note = f"no significant rank correlation at α = {ALPHA}"
    else:
        note = "significant, but the opposite direction"
    return InsightResult(insight, data.name, stat, n, rho, p, holds, note)


def evaluate_all(data: StudyData) -> list[InsightResult]:
    """The four insights in ``data``."""
    return [evaluate(i, data) for i in INSIGHTS]
