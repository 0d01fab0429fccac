"""Draws free of the prior: a share of the sampled draws comes from a sampler that never sees the study's prior.

Why. A prior (the crowd's settings, ``--warm-start crowd``; another study's trials, ``--warm-start STUDY``) fills
the sampler's history before its first draw, and everything the study derives from it — linear twins and
neighbours of the crowd's best, their seed runs and soups — scores among the best all hour. TPE's good tenth is
then the prior's region, and its startup phase (``sampler_startup_trials``) is spent before the first draw, since
Optuna counts every finished trial. Measured: a crowd-prior hour (study seed 2) sampled 189 draws, all with
gsurma's narrow view (at most 5 lanes a side or under 30 patches ahead); a cold hour on seed 1 sampled 141, 104
of them seeing the whole road (6+ lanes a side, 30+ ahead), and its linear adagrad nets there souped to 75.91
(76.05 on unseen runs), above any crowd-prior hour's best (75.74). So with ``[study] prior_free_share`` that share
of the draws comes from a second sampler (its own seed) whose history is its own draws and the trials made from
them: a cold study inside the warm one, with its own random startup; the study's twins and neighbours follow its
best too (``autotune.search.driver``). Its history leaves out the first sampler's draws as well: those are drawn
near the prior, and a first try that showed the second sampler every trial not made from the prior had it back
in gsurma's view (0–8 lanes a side, mostly 0–3) after its startup. Without a prior in the study, every draw is
the first sampler's, as before.

Pure over trials; the sampler is a routing wrapper, deterministic in the trial number.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

from optuna.distributions import BaseDistribution
from optuna.pruners import BasePruner
from optuna.samplers import BaseSampler
from optuna.study import Study
from optuna.trial import FrozenTrial, TrialState

from autotune.search import keys
from autotune.search.history import HistoryView

__all__ = [
    "OwnView",
    "PriorFreePruner",
    "PriorFreeSampler",
    "WarmView",
    "from_prior",
    "made_from",
    "own_turn",
    "prior_free",
]

ROOTS = (keys.WARM_START, keys.COPIED_FROM)
"""A trial with one of these user attrs is the prior itself: an enqueued crowd setting, or a copied trial."""


def _parents(attrs: dict[str, Any]) -> Iterable[int]:
    """The trial numbers a trial was made from: the configuration it twins, moves, retries, retrains, soups or
    trains on from."""
    for key in (keys.TWIN_OF, keys.NEIGHBOUR_OF, keys.RETRY_OF, keys.RACE_OF, keys.SEED_SOUP_OF):
        if attrs.get(key) is not None:
            yield int(attrs[key])
    refine = attrs.get(keys.REFINE_OF)
    if isinstance(refine, dict) and refine.get("trial") is not None:
        yield int(refine["trial"])
    for n in attrs.get(keys.SOUP_OF) or ():
        yield int(n)


def made_from(trials: Sequence[FrozenTrial], roots: tuple[str, ...]) -> set[int]:
    """The numbers of the trials with one of the user attrs ``roots``, or made from one at any remove (a twin of
    it, that twin's neighbour, its seed runs and their soups). One pass in number order: a trial is made from
    trials that were there before it."""
    out: set[int] = set()
    for t in sorted(trials, key=lambda t: t.number):
        if any(k in t.user_attrs for k in roots) or any(n in out for n in _parents(t.user_attrs)):
            out.add(t.number)
    return out


def from_prior(trials: Sequence[FrozenTrial]) -> set[int]:
    """The numbers of the trials that are the prior (``ROOTS``) or were made from it."""
    return made_from(trials, ROOTS)


def prior_free(trials: Sequence[FrozenTrial]) -> list[FrozenTrial]:
    """The prior-free sampler's draws (``keys.PRIOR_FREE``) and the trials made from them, less any made from the
    prior too (a family soup with a crowd twin's seed in it): the history that sampler sees."""
    prior = from_prior(trials)
    own = made_from(trials, (keys.PRIOR_FREE,))
    return [t for t in trials if t.number in own and t.number not in prior]


def own_turn(number: int, share: float) -> bool:
    """Whether trial ``number``'s draw is the prior-free sampler's: ``share`` of the numbers, spread evenly
    (0.5: every odd one)."""
    return int((number + 1) * share) > int(number * share)


class OwnView(HistoryView):
    """The prior-free sampler's history: its own draws and the trials made from them (``prior_free``)."""

    def shown(self, trials: list[FrozenTrial]) -> list[FrozenTrial]:
        return prior_free(trials)


class WarmView(HistoryView):
    """The history without the prior-free draws and the trials made from them (the complement of ``OwnView``)."""

    def shown(self, trials: list[FrozenTrial]) -> list[FrozenTrial]:
        own = {t.number for t in prior_free(trials)}
        return [t for t in trials if t.number not in own]


class PriorFreePruner(BasePruner):
    """``base``, judging a prior-free draw (``keys.PRIOR_FREE``) among the prior-free sampler's trials
    (``OwnView``) and every other trial among the rest (``WarmView``). Why: successive halving keeps the top third
    of the trials that reached a rung, and at 10k the draws near the crowd's settings set a bar that the
    prior-free draws, spread over the whole space, did not pass: in a crowd-prior hour (seed 0) none of 95 reached
    its top rung (52 pruned at 10k, 17 at 30k, 2 at 90k), where a cold hour's draws, halved among themselves, made
    their way up (seed 1: the 75.28 draw and its 75.91 family)."""

    def __init__(self, base: BasePruner) -> None:
        self._base = base

    @property
    def base(self) -> BasePruner:
        """The wrapped pruner."""
        return self._base

    def prune(self, study: Study, trial: FrozenTrial) -> bool:
        view: Any = OwnView(study) if trial.user_attrs.get(keys.PRIOR_FREE) else WarmView(study)
        return self._base.prune(view, trial)


class PriorFreeSampler(BaseSampler):
    """``own`` draws ``share`` of the trials (``own_turn``) from the history without the prior (``OwnView``);
    ``base`` draws the rest from the whole history, and every trial while the study holds no prior."""

    def __init__(self, base: BaseSampler, own: BaseSampler, share: float) -> None:
        if not 0.0 < share <= 1.0:
            raise ValueError(f"share must lie in (0, 1], got {share}")
        self._base = base
        self._own = own
        self._share = share
        self._drawn: set[int] = set()

    @property
    def base(self) -> BaseSampler:
        """The sampler of the whole history."""
        return self._base

    @property
    def own(self) -> BaseSampler:
        """The sampler of the history without the prior."""
        return self._own

    def drew(self, number: int) -> bool:
        """Whether trial ``number``'s parameters came from ``own`` (this process's draws; the driver stores it on
        the trial as ``keys.PRIOR_FREE``, which is what ``OwnView`` reads)."""
        return number in self._drawn

    def route(self, study: Study, trial: FrozenTrial) -> tuple[BaseSampler, Any]:
        """(sampler, study or view) that draws ``trial``."""
        if own_turn(trial.number, self._share):
            trials = study._get_trials(deepcopy=False, states=None, use_cache=False)  # noqa: SLF001
            if any(any(k in t.user_attrs for k in ROOTS) for t in trials):
                return self._own, OwnView(study)
        return self._base, study

    def reseed_rng(self) -> None:
        self._base.reseed_rng()
        self._own.reseed_rng()

    def infer_relative_search_space(self, study: Study, trial: FrozenTrial) -> dict[str, BaseDistribution]:
        sampler, seen = self.route(study, trial)
        if sampler is self._own:  # asked for draws only (the cost gate never asks for an enqueued trial's)
            self._drawn.add(trial.number)
        return sampler.infer_relative_search_space(seen, trial)

    def sample_relative(
        self, study: Study, trial: FrozenTrial, search_space: dict[str, BaseDistribution]
    ) -> dict[str, Any]:
        sampler, seen = self.route(study, trial)
        return sampler.sample_relative(seen, trial, search_space)

    def sample_independent(
        self, study: Study, trial: FrozenTrial, param_name: str, param_distribution: BaseDistribution
    ) -> Any:
        sampler, seen = self.route(study, trial)
        return sampler.sample_independent(seen, trial, param_name, param_distribution)

    def before_trial(self, study: Study, trial: FrozenTrial) -> None:
        sampler, seen = self.route(study, trial)
        sampler.before_trial(seen, trial)

    def after_trial(self, study: Study, trial: FrozenTrial, state: TrialState, values: Sequence[float] | None) -> None:
        sampler, seen = self.route(study, trial)
        sampler.after_trial(seen, trial, state, values)
