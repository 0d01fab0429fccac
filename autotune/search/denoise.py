"""The denoised history: a sampler wrapper that shows the sampler each trial at a model's estimate of its score.

Why: TPE splits the history into a "good" tenth and the rest by each trial's own score, and one
training's score is noisy (the same settings: sd ~3 mph over seeds). A region sampled 138 times fills
the good tenth by best-of-many although its median is lower, so TPE draws there again: the 30- and
60-minute cold studies spent most of their draws with 7 other agents while 9–10 scored ~3 mph more at
every rung (README, *Where a cold study's time still goes*). Optuna's own order (COMPLETE first, pruned
trials by the step they reached) adds a second error on a budget ladder: a trial that finished a short
ladder at 63 ranks above one pruned at 270k with 72.

What: before a draw, a regression forest is fitted on every finished rung of the study (the trial's
parameters in the sampler's coordinates, log scales as logs, plus log(1 + the rung's report step) → its score),
and the wrapped sampler sees each trial with a finished rung as COMPLETE, valued at the forest's
prediction for its parameters at ``reference_step`` (the ladder's ``min_top``, which every sampled trial
affords). A trial's neighbours thus vouch for it: a lucky seed in a poor region is pulled down, a trend
shared by many trials (more other agents, better) lifts the trials that follow it, and every trial is
ranked at one budget. Trials without a finished rung, running trials and the constraints told for nets
that never learn are shown as they are. Nothing is written to the storage: states and values stay what
the pruner, the seed race and the dashboard see. With fewer than ``min_rungs`` finished rungs the
history is shown unchanged.

``quantile`` (``[study] denoise_quantile``) values a trial at that quantile of its neighbourhood's scores
instead of their mean: a quantile regression forest (Meinshausen 2006), each finished rung weighted by how
often it shares a leaf with the trial at the reference step. Why: the leaderboard's number is a best
single net, a best-of-many, and the mean prefers a region whose scores are steady (a 60-minute cold study
settled on nets acting at random 60–70 % of the time: 73.3 mph on average, never above 73.9) to one whose
trainings vary more but reach higher (gsurma's setting at 90k: 73.6 on average, up to 74.9).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from optuna.distributions import BaseDistribution, CategoricalDistribution, FloatDistribution, IntDistribution
from optuna.samplers import BaseSampler
from optuna.study import Study
from optuna.trial import FrozenTrial, TrialState

from autotune.search.history import HistoryView

__all__ = ["DenoisedSampler", "encode", "leaf_quantile"]

_MISSING = -1.0e9
"""Feature value of a parameter a trial does not have (trees split it off; nothing in the spaces reaches it)."""


def encode(params: dict[str, Any], distributions: dict[str, BaseDistribution], names: Sequence[str]) -> list[float]:
    """``params`` as one feature row in the sampler's coordinates: logs of log-scaled numbers, a categorical's index."""
    row = []
    for name in names:
        d = distributions.get(name)
        v = params.get(name)
        if d is None or v is None:
            row.append(_MISSING)
        elif isinstance(d, CategoricalDistribution):
            row.append(float(d.choices.index(v)) if v in d.choices else _MISSING)
        elif isinstance(d, (FloatDistribution, IntDistribution)) and d.log:
            row.append(math.log(float(v)))
        else:
            row.append(float(v))
    return row


class _Model:
    """The forest of one history (refitted only when a rung finished since)."""

    def __init__(self, seed: int, min_rungs: int, reference_step: int, quantile: float | None = None) -> None:
        self._seed = seed
        self._min_rungs = min_rungs
        self._reference_step = reference_step
        self.quantile = quantile
        self._key: tuple[tuple[int, int], ...] | None = None
        self._values: dict[int, float] = {}

    def values(self, trials: Sequence[FrozenTrial]) -> dict[int, float]:
        """Trial number → the forest's score at the reference step, for every trial with a finished rung."""
        done = [t for t in trials if t.state in (TrialState.COMPLETE, TrialState.PRUNED) and t.intermediate_values]
        key = tuple(sorted((t.number, len(t.intermediate_values)) for t in done))
        if key == self._key:
            return self._values
        self._key = key
        self._values = {}
        distributions: dict[str, BaseDistribution] = {}
        for t in done:
            distributions.update(t.distributions)
        names = sorted(distributions)
        encoded = [encode(t.params, distributions, names) for t in done]
        x, y = [], []
        for t, base in zip(done, encoded, strict=True):
            for step, score in t.intermediate_values.items():
                if math.isfinite(score):
                    x.append([*base, math.log1p(step)])
                    y.append(score)
        if len(y) < self._min_rungs:  # a diverged net reports no finite score
            return self._values
        from sklearn.ensemble import ExtraTreesRegressor  # imported on first use: a second's import

        forest = ExtraTreesRegressor(
            n_estimators=100, min_samples_leaf=3, max_features=0.5, random_state=self._seed, n_jobs=1,
        )  # fmt: skip
        xs, ys = np.asarray(x), np.asarray(y)
        forest.fit(xs, ys)
        at = math.log1p(self._reference_step)
        query = np.asarray([[*base, at] for base in encoded])
        if self.quantile is None:
            estimates = forest.predict(query)
        else:
            estimates = leaf_quantile(forest.apply(xs), ys, forest.apply(query), self.quantile)
        self._values = dict(zip((t.number for t in done), estimates.tolist(), strict=True))
        return self._values


def leaf_quantile(train_leaves: np.ndarray, y: np.ndarray, query_leaves: np.ndarray, q: float) -> np.ndarray:
    """Quantile ``q`` of ``y`` per query row, each training row weighted by its share of the query's leaf in each
    tree, summed over trees (a quantile regression forest). ``*_leaves``: ``forest.apply`` (rows × trees).

    The weights stay sparse (a query row holds the few hundred rows its leaves share, not every rung of the study):
    a day's study of thousands of trials and rungs would need gigabytes as a dense query × train matrix."""
    from scipy import sparse

    n_train, n_trees = train_leaves.shape
    n_query = query_leaves.shape[0]
    # one column per (tree, leaf): node ids are per tree, so each tree's ids start past the previous tree's
    sizes = np.maximum(train_leaves.max(0), query_leaves.max(0)) + 1
    offsets = np.cumsum(sizes) - sizes
    cols_train = (train_leaves + offsets).ravel()
    cols_query = (query_leaves + offsets).ravel()
    counts = np.bincount(cols_train, minlength=int(sizes.sum())).astype(float)
    share = sparse.csr_matrix((1.0 / counts[cols_train], (np.repeat(np.arange(n_train), n_trees), cols_train)),
                              shape=(n_train, counts.size))  # fmt: skip
    member = sparse.csr_matrix((np.ones(cols_query.size), (np.repeat(np.arange(n_query), n_trees), cols_query)),
                               shape=(n_query, counts.size))  # fmt: skip
    weights = (member @ share.T).tocsr()  # query × train
    rank = np.empty(n_train, dtype=np.int64)
    rank[np.argsort(y, kind="stable")] = np.arange(n_train)
    out = np.empty(n_query)
    for i in range(n_query):  # every leaf holds training rows, so no row is empty
        lo, hi = weights.indptr[i], weights.indptr[i + 1]
        by_y = np.argsort(rank[weights.indices[lo:hi]])
        rows, cum = weights.indices[lo:hi][by_y], np.cumsum(weights.data[lo:hi][by_y])
        out[i] = y[rows[min(int((cum < q * cum[-1]).sum()), rows.size - 1)]]  # the first row where q is reached
    return out


class _DenoisedView(HistoryView):
    """A read-only view of ``study``: its finished trials COMPLETE at the model's value, the rest as stored."""

    def __init__(self, study: Study, model: _Model) -> None:
        super().__init__(study)
        self._model = model

    def shown(self, trials: list[FrozenTrial]) -> list[FrozenTrial]:
        values = self._model.values(trials)
        out = []
        for t in trials:
            if t.number in values:
                t = copy.copy(t)
                t.state = TrialState.COMPLETE
                t.value = values[t.number]
            out.append(t)
        return out


class DenoisedSampler(BaseSampler):
    """``base``, modelling each finished trial at a regression forest's score for its parameters (module docstring)."""

    def __init__(
        self, base: BaseSampler, reference_step: int, seed: int, min_rungs: int = 24, quantile: float | None = None
    ) -> None:
        if reference_step < 1:
            raise ValueError(f"reference_step must be ≥ 1, got {reference_step}")
        if quantile is not None and not 0.0 < quantile < 1.0:
            raise ValueError(f"quantile must lie in (0, 1), got {quantile}")
        self._base = base
        self._model = _Model(seed, min_rungs, reference_step, quantile)

    @property
    def base(self) -> BaseSampler:
        """The wrapped sampler."""
        return self._base

    @property
    def quantile(self) -> float | None:
        """The quantile of a trial's neighbourhood it is shown at (None: their mean)."""
        return self._model.quantile

    def shown(self, study: Study) -> list[FrozenTrial]:
        """The history as the wrapped sampler sees it (for diagnostics and tests)."""
        return self._view(study).get_trials(deepcopy=False)

    def _view(self, study: Study) -> Any:
        """``study`` as the wrapped sampler sees it (typed ``Any``: it stands in for a ``Study``)."""
        return _DenoisedView(study, self._model)

    def reseed_rng(self) -> None:
        self._base.reseed_rng()

    def infer_relative_search_space(self, study: Study, trial: FrozenTrial) -> dict[str, BaseDistribution]:
        return self._base.infer_relative_search_space(self._view(study), trial)

    def sample_relative(
        self, study: Study, trial: FrozenTrial, search_space: dict[str, BaseDistribution]
    ) -> dict[str, Any]:
        return self._base.sample_relative(self._view(study), trial, search_space)

    def sample_independent(
        self, study: Study, trial: FrozenTrial, param_name: str, param_distribution: BaseDistribution
    ) -> Any:
        return self._base.sample_independent(self._view(study), trial, param_name, param_distribution)

    def before_trial(self, study: Study, trial: FrozenTrial) -> None:
        self._base.before_trial(study, trial)

    def after_trial(self, study: Study, trial: FrozenTrial, state: TrialState, values: Sequence[float] | None) -> None:
        self._base.after_trial(study, trial, state, values)
