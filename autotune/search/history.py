"""A read-only view of a study's trial history, for sampler wrappers that show their sampler a changed history.

Why: Optuna's samplers read the history through ``study._get_trials`` (and ``get_trials``/``trials``); a
wrapper that filters it (``balance``: one value's trials) or revalues it (``denoise``: a model's estimates)
passes a view instead of the study. Everything but the trials — directions, storage, ids — is the real
study's, and nothing is written back.
"""

from __future__ import annotations

from collections.abc import Container
from typing import Any

from optuna.study import Study
from optuna.trial import FrozenTrial, TrialState

from autotune.search.keys import RACE_OF, REFINE_OF

__all__ = ["DrawsView", "HistoryView"]


class HistoryView:
    """``study`` with its trials passed through ``shown`` (override it); the rest is the real study's."""

    def __init__(self, study: Study) -> None:
        self._study = study

    def shown(self, trials: list[FrozenTrial]) -> list[FrozenTrial]:
        """The history the sampler sees, from the stored one (all states)."""
        return trials

    def _get_trials(
        self, deepcopy: bool = True, states: Container[TrialState] | None = None, use_cache: bool = False
    ) -> list[FrozenTrial]:
        trials = self._study._get_trials(deepcopy=deepcopy, states=None, use_cache=use_cache)  # noqa: SLF001
        shown = self.shown(trials)
        return shown if states is None else [t for t in shown if t.state in states]

    def get_trials(self, deepcopy: bool = True, states: Container[TrialState] | None = None) -> list[FrozenTrial]:
        return self._get_trials(deepcopy=deepcopy, states=states)

    @property
    def trials(self) -> list[FrozenTrial]:
        return self.get_trials()

    def __getattr__(self, attr: str) -> Any:  # directions, storage, ids: the real study's
        return getattr(self._study, attr)


class DrawsView(HistoryView):
    """The history without its seed-race runs (``race_of``) and refinement runs (``refine_of``): each retrains a
    configuration the history holds already, under the trial that selected it. Shown as trials of their own, the
    incumbent's many fresh runs before the race (``[study] intensify_share``) would fill TPE's good tenth with
    copies of one configuration, and a refinement run's score is its parent net's trained on, not a draw's."""

    def shown(self, trials: list[FrozenTrial]) -> list[FrozenTrial]:
        return [t for t in trials if RACE_OF not in t.user_attrs and REFINE_OF not in t.user_attrs]
