"""The crowd prior: the shipped crowd settings a study tries first (``autotune launch --warm-start crowd``).

Humans spent ~24,000 submissions finding the good corner of the space; enqueuing a few of their
settings lifts a cold search within minutes. Which settings: for the study's engine, each
repository's best-scored version (the crowd iterated — a repository's versions are one person's
path through the space, so one per repository), best claim first. The claims only order the queue:
every enqueued setting is trained and measured by the study, no claimed score becomes a value.
"""

from __future__ import annotations

import dataclasses

from autotune import TrainConfig
from dashboards import crowd_data as cd

__all__ = ["PriorSetting", "prior_settings"]


@dataclasses.dataclass(frozen=True)
class PriorSetting:
    """One crowd setting for the prior."""

    source: str
    """``crowd:<submission id>``."""
    claimed: float
    """The self-reported score [mph] (orders the queue; never stored as a value)."""
    config: TrainConfig


def prior_settings(ruleset: str) -> list[PriorSetting]:
    """Each repository's best-scored, usable submission of ``ruleset``'s engine, best claim first."""
    best: dict[str, tuple[float, cd.Submission, TrainConfig]] = {}
    for sub in cd.load_submissions():
        if not sub.scored or sub.engine_version != ruleset or sub.reported_score_mph is None:
            continue
        try:
            config = cd.train_config(sub)
        except Exception:  # noqa: BLE001 - settings deepqlearn refuses (2 rows) are not part of the prior
            continue
        score = float(sub.reported_score_mph)
        if sub.repo not in best or score > best[sub.repo][0]:
            best[sub.repo] = (score, sub, config)
    ranked = sorted(best.values(), key=lambda b: (-b[0], b[1].id))
    return [PriorSetting(f"crowd:{sub.id}", score, config) for score, sub, config in ranked]
