"""The report's headline: the automated best against the best *measured* human net of the same engine.

A claim is not a measurement, and a v1 score is not a v2 score. The headline therefore compares
the automated study's best (measured, official protocol) with the best human net of the same
engine scored with its own weights (``measured.OwnNetScore``), naming both nets' other agents;
then, separately and labelled as claims, the best claimed score of the same engine and — if it is
another engine's — the best claim of all. Plain data: ``Headline.lines`` is what the page and the
dashboard note print.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

from dashboards import provenance as pv
from dashboards.extract import StudyData, TrialPoint
from dashboards.measured import OwnNetScore

__all__ = ["Headline", "headline"]


@dataclasses.dataclass(frozen=True)
class Headline:
    """The compared scores (None where a side has none) and the sentences that state them."""

    automated: TrialPoint | None
    measured: OwnNetScore | None
    """Best human net of the automated best's engine, scored with its own weights."""
    claim_same_engine: TrialPoint | None
    claim_any_engine: TrialPoint | None
    """The best claim of all, when its engine differs from the automated best's (else None)."""
    lines: list[str]


def _who(t: TrialPoint) -> str:
    return f"{pv.ENGINE_LABEL[t.engine]}, {pv.agents_label(t.engine, t.other_agents)}"


def headline(automated: StudyData, crowd: StudyData, own_nets: Sequence[OwnNetScore]) -> Headline:
    """The headline of the comparison of ``automated`` with the crowd (claims) and the measured human nets."""
    auto = max(automated.scored, key=lambda t: (t.value, -t.number), default=None)
    claims = [t for t in crowd.scored if not pv.is_measured(t.kind)]
    best_claim = max(claims, key=lambda t: (t.value, -t.number), default=None)
    if auto is None:
        lines = [f"{automated.name}: no scored trial yet, so nothing to compare."]
        return Headline(None, None, None, best_claim, lines)
    engine = auto.engine
    lines = [
        f"Automated best ({automated.name}): {auto.value:.2f} mph — {auto.label} ({_who(auto)}; "
        f"{pv.KIND_LABEL[auto.kind]}, official protocol of the {pv.ENGINE_LABEL[engine]})."
    ]
    measured = max((s for s in own_nets if s.engine == engine), key=lambda s: (s.score, s.crowd_id), default=None)
    if measured is None:
        lines.append(f"No human net of the {pv.ENGINE_LABEL[engine]} has been measured with its own weights.")
    else:
        agents = pv.agents_label(engine, measured.other_agents)
        diff = auto.value - measured.score  # type: ignore[operator]
        same = "" if measured.other_agents == auto.other_agents else f" (other agents differ: {agents} there)"
        lines.append(
            f"Best measured human net of the same engine: {measured.score:.2f} mph — {measured.crowd_id} "
            f"({pv.ENGINE_LABEL[engine]}, {agents}; {pv.KIND_LABEL[pv.OWN_WEIGHTS]}, {measured.protocol}); "
            f"automated − human = {diff:+.2f} mph{same}."
        )
    same_engine = max((t for t in claims if t.engine == engine), key=lambda t: (t.value, -t.number), default=None)
    if same_engine is not None:
        lines.append(
            f"Best claim of the same engine (self-reported, not measured): {same_engine.value:.2f} mph — "
            f"{same_engine.label} ({_who(same_engine)}; {pv.KIND_LABEL[same_engine.kind]}, confidence "
            f"{same_engine.confidence})."
        )
    other = best_claim if best_claim is not None and best_claim.engine != engine else None
    if other is not None:
        lines.append(
            f"Best claim of any engine (self-reported, another engine: not comparable): {other.value:.2f} mph — "
            f"{other.label} ({_who(other)}; {pv.KIND_LABEL[other.kind]}, confidence {other.confidence})."
        )
    return Headline(auto, measured, same_engine, other, lines)
