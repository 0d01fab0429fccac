"""The paper's four insights, tested so that the engine and the other agents cannot fake them.

* size matters — parameter count vs score, expected positive;
* live in the moment — temporal window vs score, expected negative (a short memory is better);
* look far forward — patches ahead vs score, expected positive;
* plan for the future — γ vs score, expected positive.

The engine is the strongest covariate of a crowd score (v1 claims run higher than v2 ones), so a
pooled correlation partly measures the engine. Each insight is therefore tested

* per engine: Spearman ρ over that engine's configurations;
* pooled: partial Spearman ρ controlling for the engine and the other agents — the Pearson
  correlation of the ranks of the setting and of the score after each is residualised (least
  squares) on an intercept, the engine (v2 = 1) and the rank of the other agents (v1 has none: 0);
  covariates that do not vary are left out; p from Student's t with n − 2 − k degrees of freedom
  (k covariates);
* and, for the crowd, a sensitivity row: the pooled test on one configuration per repository (its
  latest), since two repositories hold half the rows.

The unit is the configuration: identical settings count once (``extract.configurations``, score =
mean of its rows). The p-values of every test of one study's table are Holm-adjusted together; an insight
*holds* in a row when the correlation has the expected sign and the adjusted p < ``ALPHA``. A row
with fewer than ``MIN_POINTS`` configurations, or a constant setting or score, is undecided and
takes no part in the correction. Spearman, not Pearson: settings span orders of magnitude and
scores are bounded, so ranks are the robust choice.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from scipy import stats

from dashboards import provenance as pv
from dashboards.extract import StudyData, TrialPoint, configurations

__all__ = [
    "ALPHA",
    "MIN_POINTS",
    "INSIGHTS",
    "GROUPS",
    "METHOD",
    "Insight",
    "InsightResult",
    "partial_spearman",
    "holm",
    "evaluate",
    "evaluate_study",
    "evaluate_all",
    "one_per_repository",
]

ALPHA = 0.05
MIN_POINTS = 5
GROUPS = ("v1 engine", "v2 engine", "pooled", "pooled, one configuration per repository")
METHOD = (
    "Unit: the configuration (identical settings once; a repeated setting scores the mean of its rows). "
    "Per engine: Spearman ρ of the setting against the score. Pooled: partial Spearman ρ controlling for the engine "
    "(v2 = 1) and the other agents (ranked; v1 has none: 0) — the Pearson correlation of the ranks of setting and "
    "score after least-squares residualisation on those covariates (those that vary), p from Student's t with "
    "n − 2 − k degrees of freedom. Crowd sensitivity: the pooled test on each repository's latest configuration. "
    "The p-values of all the tests in a study's table are Holm-adjusted together; an insight holds in a row when ρ has "
    "the claimed sign and "
    f"the adjusted p < {ALPHA}. Rows with fewer than {MIN_POINTS} configurations, or a constant setting, are undecided "
    "and not counted in the correction."
)


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
    """An insight tested on one group of one study's configurations."""

    insight: Insight
    study: str
    side: str
    """'crowd' or 'autotune' (the report's sides)."""
    group: str
    """One of ``GROUPS``."""
    engines: list[str]
    """Engines of the configurations tested."""
    kinds: list[str]
    """Score kinds of the scores tested."""
    statistic: str
    covariates: list[str]
    """Covariates partialled out (empty: plain Spearman)."""
    n: int
    value: float | None
    p_value: float | None
    p_holm: float | None
    """Holm-adjusted p over every test of the table (``evaluate_all``)."""
    holds: bool | None
    note: str

    @property
    def name(self) -> str:
        """The row's name: study, engines and score kinds."""
        return pv.series_name(self.study, self.engines or ["v2"], self.kinds) if self.engines else self.study


def _value(t: TrialPoint, variable: str) -> float | None:
    if variable == "param_count":
        return float(t.param_count) if t.param_count is not None else None
    return t.settings.get(variable)


def partial_spearman(
    x: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray, covariates: np.ndarray
) -> tuple[float, float, int]:
    """(ρ, two-sided p, degrees of freedom) of x and y given the covariate columns (n × k, any k ≥ 0), on ranks."""
    rx, ry = stats.rankdata(x), stats.rankdata(y)
    n = len(rx)
    z = np.ones((n, 1))
    if covariates.size:
        z = np.column_stack([z, np.apply_along_axis(stats.rankdata, 0, covariates)])
    ex = rx - z @ np.linalg.lstsq(z, rx, rcond=None)[0]
    ey = ry - z @ np.linalg.lstsq(z, ry, rcond=None)[0]
    denom = math.sqrt(float(ex @ ex) * float(ey @ ey))
    if denom == 0:
        return math.nan, math.nan, 0
    r = float(ex @ ey) / denom
    r = max(-1.0, min(1.0, r))
    df = n - 2 - (z.shape[1] - 1)
    if df < 1:
        return r, math.nan, df
    if abs(r) == 1.0:
        return r, 0.0, df
    t = r * math.sqrt(df / (1.0 - r * r))
    return r, float(2.0 * stats.t.sf(abs(t), df)), df


def holm(p_values: Sequence[float | None]) -> list[float | None]:
    """Holm's step-down adjustment of the p-values given (None stays None and does not count)."""
    present = sorted((p, i) for i, p in enumerate(p_values) if p is not None)
    m = len(present)
    out: list[float | None] = [None] * len(p_values)
    running = 0.0
    for rank, (p, i) in enumerate(present):
        running = max(running, min(1.0, (m - rank) * p))
        out[i] = running
    return out


def one_per_repository(units: Sequence[TrialPoint]) -> list[TrialPoint]:
    """Each repository's latest configuration (highest trial number = latest submission); units without a
    repository are kept."""
    latest: dict[str, TrialPoint] = {}
    out = []
    for t in units:
        if t.repo is None:
            out.append(t)
        elif t.repo not in latest or t.number > latest[t.repo].number:
            latest[t.repo] = t
    return sorted([*out, *latest.values()], key=lambda t: t.number)


def evaluate(
    insight: Insight, units: Sequence[TrialPoint], *, study: str, side: str, group: str, kinds: Sequence[str]
) -> InsightResult:
    """One test of ``insight`` on ``units`` (configurations): Spearman within one engine, else partial Spearman."""
    pairs = [(t, v) for t in units if (v := _value(t, insight.variable)) is not None]
    n = len(pairs)
    engines = [e for e in pv.ENGINES if any(t.engine == e for t, _v in pairs)]
    pooled = group.startswith("pooled")
    covariates: list[str] = []
    columns = []
    if pooled:
        for name, column in (
            ("engine", [1.0 if t.engine == "v2" else 0.0 for t, _v in pairs]),
            ("other agents", [float(t.other_agents or 0) for t, _v in pairs]),
        ):
            if len(set(column)) > 1:
                covariates.append(name)
                columns.append(column)
    stat = f"Spearman ρ({insight.variable}, score)"
    if covariates:
        stat = f"partial Spearman ρ({insight.variable}, score | {', '.join(covariates)})"

    def result(value: float | None, p: float | None, holds: bool | None, note: str) -> InsightResult:
        return InsightResult(
            insight, study, side, group, engines, list(kinds), stat, covariates, n, value, p, None, holds, note
        )

    if n < MIN_POINTS:
        return result(None, None, None, f"only {n} configuration(s) record {insight.variable} (need {MIN_POINTS})")
    xs, ys = [v for _t, v in pairs], [float(t.value) for t, _v in pairs]  # type: ignore[arg-type]
    if len(set(xs)) < 2:
        return result(None, None, None, f"{insight.variable} is the same in every configuration ({xs[0]:g})")
    if len(set(ys)) < 2:
        return result(None, None, None, "every configuration has the same score")
    z = np.array(columns, dtype=float).T if columns else np.empty((n, 0))
    rho, p, _df = partial_spearman(xs, ys, z)
    if math.isnan(rho) or math.isnan(p):
        return result(None, None, None, "correlation undefined (no variation left after the covariates)")
    return result(rho, p, None, "")


def _decide(r: InsightResult, p_holm: float | None) -> InsightResult:
    if r.value is None or p_holm is None:
        return r
    holds = r.value * r.insight.sign > 0 and p_holm < ALPHA
    if holds:
        note = f"{r.insight.claim} (ρ {r.value:+.2f}, Holm p {p_holm:.2g})"
    elif p_holm >= ALPHA:
        note = f"no significant rank correlation after Holm at α = {ALPHA}"
    else:
        note = "significant, but the opposite direction"
    return dataclasses.replace(r, p_holm=p_holm, holds=holds, note=note)


def evaluate_study(data: StudyData, side: str, *, by_repository: bool | None = None) -> list[InsightResult]:
    """Every test of every insight on one study, unadjusted (p_holm None): per engine present, pooled and
    (crowd; ``by_repository``) pooled on one configuration per repository. Order: insight, then ``GROUPS``."""
    units = configurations(data)
    by_repository = side == "crowd" if by_repository is None else by_repository
    groups: list[tuple[str, list[TrialPoint]]] = [
        (f"{e} engine", [t for t in units if t.engine == e]) for e in pv.ENGINES if any(t.engine == e for t in units)
    ]
    if len(groups) != 1 or any(t.other_agents for t in units):
        groups.append(("pooled", units))
    if by_repository:
        groups.append(("pooled, one configuration per repository", one_per_repository(units)))
    out = []
    group_kinds = []
    for group, members in groups:  # the score kinds of the trials behind each group's configurations
        member_keys = {m.config_key for m in members}
        present = {t.kind for t in data.settings_scored if t.config_key in member_keys}
        group_kinds.append((group, members, [k for k in pv.KIND_LABEL if k in present]))
    for insight in INSIGHTS:
        for group, members, kinds in group_kinds:
            out.append(evaluate(insight, members, study=data.name, side=side, group=group, kinds=kinds))
    return out


def evaluate_all(sides: dict[str, StudyData]) -> dict[str, list[InsightResult]]:
    """``evaluate_study`` for every side, each side's tests Holm-adjusted together (one table, one family)."""
    out: dict[str, list[InsightResult]] = {}
    for side, data in sides.items():
        results = evaluate_study(data, side)
        adjusted = holm([r.p_value for r in results])
        out[side] = [_decide(r, p) for r, p in zip(results, adjusted, strict=True)]
    return out
