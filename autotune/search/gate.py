"""The cost gate: a sampler wrapper that refuses draws predicted to cost more than the study's cap, and redraws.

Why a wrapper that rejects and redraws, not a told constraint: a refused draw must not use up the
trial budget or the sampler's startup phase, and must not appear as a trial at all (it was never
trained, so it has no value and no cause worth a row in the dashboard). Optuna's constraint
machinery (``constraints_func``) only judges trials that ran and hold values, and telling a refused
trial FAIL/PRUNED would count it as a trial. Rejection sampling instead truncates the sampler's own
proposal distribution to the affordable region: TPE's l(x)/g(x) draws, GP's acquisition optimum or
CMA-ES's Gaussian are redrawn until one is affordable, so the sampler is steered away from what it
cannot pay for without its model being told anything false.

The wrapper samples the WHOLE fixed-shape space relatively (``space.dimensions``): during the base
sampler's startup phase (it returns nothing) the wrapper fills the gaps with its own seeded random
draws, so every parameter of a draw is known before it is priced. Enqueued trials (crowd prior,
retries, seed races) carry fixed params and are not gated here; the driver prices them itself. The history the
wrapped sampler sees leaves out the seed race's runs (``history.DrawsView``): re-measurements of a configuration
already in it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from optuna.distributions import BaseDistribution, CategoricalDistribution, FloatDistribution, IntDistribution
from optuna.samplers import BaseSampler, RandomSampler
from optuna.study import Study
from optuna.trial import FrozenTrial, TrialState

from autotune.search import space
from autotune.search.history import DrawsView
from autotune.search.spec import Dimension, StudySpec

__all__ = ["CostGatedSampler", "distributions", "MAX_DRAWS"]

MAX_DRAWS = 200
"""Draws tried per trial before the cheapest one is taken (it is then priced again by the driver)."""

Price = Callable[[dict[str, Any]], float | None]
"""``price(params)`` → predicted seconds of the draw (its ladder up to min_top), None if it cannot be built."""


def _distribution(d: Dimension) -> BaseDistribution:
    if d.kind == "categorical":
        return CategoricalDistribution(list(d.choices))
    assert d.low is not None and d.high is not None
    if d.kind == "int":
        return IntDistribution(int(d.low), int(d.high), log=d.log, step=int(d.step or 1))
    return FloatDistribution(float(d.low), float(d.high), log=d.log, step=d.step)


def distributions(spec: StudySpec) -> dict[str, BaseDistribution]:
    """Optuna's distribution of every parameter of the space (what ``space.sample`` suggests)."""
    return {name: _distribution(d) for name, d in space.dimensions(spec).items()}


class CostGatedSampler(BaseSampler):
    """``base``'s draws, refused and redrawn while ``price`` says the draw costs more than ``cap_s``.

    ``cap_s`` may be a function, asked once per trial: the driver's cap shrinks to the time left before the
    study's deadline, so a draw that the deadline would stop mid-ladder is refused like an unaffordable one.
    """

    def __init__(
        self, base: BaseSampler, spec: StudySpec, price: Price, cap_s: float | Callable[[], float], seed: int
    ) -> None:
        self._base = base
        self._space = distributions(spec)
        self._price = price
        self._cap = cap_s
        self._random = RandomSampler(seed=seed)
        self._refused: dict[int, int] = {}

    @property
    def base(self) -> BaseSampler:
        """The wrapped sampler."""
        return self._base

    def refused(self, number: int) -> int:
        """Draws refused before trial ``number``'s (0 when it was enqueued or never gated)."""
        return self._refused.get(number, 0)

    def reseed_rng(self) -> None:
        self._base.reseed_rng()
        self._random.reseed_rng()

    def infer_relative_search_space(self, study: Study, trial: FrozenTrial) -> dict[str, BaseDistribution]:
        if "fixed_params" in trial.system_attrs:  # enqueued: its params are given, nothing to gate
            return {}
        return dict(self._space)

    def sample_relative(
        self, study: Study, trial: FrozenTrial, search_space: dict[str, BaseDistribution]
    ) -> dict[str, Any]:
        if not search_space:
            return {}
        draws: Any = DrawsView(study)  # stands in for the study
        base_space = self._base.infer_relative_search_space(draws, trial)
        cap = self._cap() if callable(self._cap) else self._cap
        cheapest: tuple[float, dict[str, Any]] | None = None
        for refused in range(MAX_DRAWS):
            params = dict(self._base.sample_relative(draws, trial, base_space)) if base_space else {}
            for name, dist in search_space.items():
                if name not in params:
                    params[name] = self._random.sample_independent(study, trial, name, dist)
            cost = self._price(params)
            if cost is not None and cost <= cap:
                self._refused[trial.number] = refused
                return params
            if cost is not None and (cheapest is None or cost < cheapest[0]):
                cheapest = (cost, params)
        self._refused[trial.number] = MAX_DRAWS
        return cheapest[1] if cheapest is not None else params

    def sample_independent(
        self, study: Study, trial: FrozenTrial, param_name: str, param_distribution: BaseDistribution
    ) -> Any:
        draws: Any = DrawsView(study)
        return self._base.sample_independent(draws, trial, param_name, param_distribution)

    def before_trial(self, study: Study, trial: FrozenTrial) -> None:
        self._base.before_trial(study, trial)

    def after_trial(self, study: Study, trial: FrozenTrial, state: TrialState, values: Sequence[float] | None) -> None:
        self._base.after_trial(study, trial, state, values)
