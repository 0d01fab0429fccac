"""The balance: a sampler wrapper that keeps every value of a categorical parameter (the trainer method), or named
values of an integer one (linear nets, a whole-road view), tried.

Why: TPE's estimate of a categorical parameter feeds on itself. Whichever trainer method the first
lucky draws used fills the "good" set, so TPE draws it again, so it fills the good set again: in the
cold full-space benchmark studies one method took 422 of 448 trials (study seed 0: adagrad, whose
best net scored 72.98), another study locked onto adadelta, and sgd, the method of every learning
net that scored 74.3 or more, got 9. The three methods need different learning rates (adadelta none),
so a method starved early never gets the draws that would show what it can do.

What: ``[study] balance`` names categorical parameters and ``[study] balance_min_share`` the share of
the sampled trials each of their values gets at least. Before each draw the wrapper counts the study's
sampled trials (enqueued ones — crowd settings, retries, seed races — are not draws and do not count)
by value. While a value is below its share, the draw is forced to it. Its parameters that depend on the
forced value (``OWN_PARAMETERS``: for the trainer method, the learning rate, momentum and weight decay) are
drawn by a second sampler of the same kind that sees only the trials with that value (so sgd's learning
rate is modelled from sgd's trials, not adagrad's); the others (view, other agents, γ, ε, layers, …) by the
base sampler, which models them on every trial. Otherwise the base sampler draws as it would without the
wrapper. The first draws of a study go round the values, so the startup phase is stratified too.
Only samplers whose model is their trial history (TPE, random) can be conditioned this way.

``every_draw`` (``[study] balance_every_draw``) conditions every draw, not only a forced one: whenever a draw's
value of a balanced parameter has a floor, the parameters it governs are redrawn from the trials sharing it (and
the values conditioned on before it: the layer count comes before the trainer method it governs), and a balanced
parameter among them keeps its share within those trials. A linear draw thus takes its method from the linear
trials, each method keeping a fifth of the linear draws, and its rate from the linear trials of its method. Why:
a crowd-prior hour's free draws took a linear net's method and rate from every trial's model, where gsurma's sgd
lineage leads: 43 of its 68 linear draws were sgd, and its 9 linear adagrad draws had a rate × inputs of
0.0007–0.66, where the linear adagrad nets that reached 75 in another hour had 1–10.

Why the split: a forced draw once took every parameter from its value's own trials, few and mostly
poor, so it lost what the study had learnt elsewhere. In the 20 cold benchmark studies with the balance
(10 to 60 minutes), 24 % of the forced draws after the startup had 9 or 10 other agents against 47 % of
the free draws, and no draw with 6 or fewer has scored 72 at any rung; the forced draws (a fifth of
the study) reached 72 at 9.9 % against 14.7 %.
"""

from __future__ import annotations

import math
import re
from collections.abc import Collection, Mapping, Sequence
from typing import Any

from optuna.distributions import BaseDistribution, CategoricalDistribution
from optuna.pruners import BasePruner
from optuna.samplers import BaseSampler
from optuna.study import Study
from optuna.trial import FrozenTrial, TrialState

from autotune.search.history import HistoryView

__all__ = ["ApartPruner", "BalancedSampler", "OWN_PARAMETERS", "conditional_startup", "forced_value"]

OWN_PARAMETERS: Mapping[str, frozenset[str]] = {
    "method": frozenset({"learning_rate", "learning_rate_x_inputs", "momentum", "l2_decay", "l1_decay"}),
    "n_layers": frozenset(
        {
            "neurons",
            "activation",
            "method",
            "learning_rate",
            "learning_rate_x_inputs",
            "momentum",
            "l2_decay",
            "l1_decay",
        }
    ),
    "lanes_side": frozenset(
        {
            "patches_ahead",
            "patches_behind",
            "one_minus_gamma",
            "gamma",
            "epsilon_min",
            "learning_rate",
            "learning_rate_x_inputs",
            "batch_size",
        }
    ),
}
"""For a balanced parameter, the parameters whose good values depend on its value: a forced draw models them on
the trials with the forced value alone, and every other parameter on all trials. The trainer methods scale a
step differently (sgd by the rate and momentum, adagrad by its gradient history, adadelta ignores the rate), so
each keeps its own rate; the view, the other agents, γ, ε and the layers mean the same under every method. A
balanced parameter not named here models every parameter on its value's trials. A layout slot (``neurons_2``,
``activation_0``) goes by its base name. For the layer count, a net's width, activations and step size depend on
how many layers it has, and so does which trainer method suits it: the linear nets that scored 75 all trained with
adagrad, while a crowd-prior study's best hidden-layer lineage is gsurma's sgd setting; with the method from every
trial's model, all 6 forced linear draws of such a study's first 20 minutes took sgd (none above 73.1), where
another run of that study found its 75-mph linear adagrad net at minute 10; what a net sees and how it is rewarded
do not depend on its depth. Without ``every_draw`` the sampler's free linear draws still take the method from
every trial's model. For the view's width (``lanes_side``; e.g. balanced on 6, the whole road from any lane, as the
best v2 human net, jnorthrup-v05, sees it), the patches ahead and behind, γ, the training ε floor, the rate and the
batch: offline, trial 166's linear adagrad settings (a crowd-prior hour's best family: 2 lanes a side, γ 0.763,
ε_min 0.0004, 1.5 per input) scored 74.9–75.4 on its own view and 65.9–70.4 on a whole-road one, while on the whole
road with γ 0.957, ε_min 0.5, batch 94 and 3.7 per input — its method, replay and decay kept — 21 seeds had a median
of 74.84 and soups of them 75.86; ε_min 0.5 on 166's own view did not help (74.26–75.01 on 4 seeds)."""


def _base_name(name: str) -> str:
    """``neurons_2`` → ``neurons``: the fixed-shape layout's slots share their parameter's entry."""
    return re.sub(r"_\d+$", "", name) if name.startswith(("neurons_", "activation_")) else name


def forced_value(counts: dict[Any, int], min_share: float, drawn: int | None = None) -> Any | None:
    """The value a draw must take so that each value keeps ``min_share`` of the draws, or None.

    ``counts`` holds every value with a floor (in the order of its choices) and how many sampled trials have it;
    ``drawn`` the number of sampled trials (default: the sum of ``counts``, when every value has a floor); the next
    draw makes ``drawn + 1`` of them. The value furthest below ``min_share × (drawn + 1)`` is forced (the first such
    in choice order on a tie), so the first draws of a study go round the values.
    """
    floor = min_share * ((sum(counts.values()) if drawn is None else drawn) + 1)
    short = [(c, i, v) for i, (v, c) in enumerate(counts.items()) if c < floor]
    return min(short)[2] if short else None


class _Subset(HistoryView):
    """A read-only view of ``study`` whose trials have ``params[name] == value`` for every ``(name, value)`` in
    ``conditions`` (a sampler's history)."""

    def __init__(self, study: Study, conditions: Sequence[tuple[str, Any]]) -> None:
        super().__init__(study)
        self._conditions = tuple(conditions)

    def shown(self, trials: list[FrozenTrial]) -> list[FrozenTrial]:
        return [t for t in trials if all(t.params.get(n) == v for n, v in self._conditions)]


def _sampled(trial: FrozenTrial) -> bool:
    """A trial the sampler drew (not enqueued with fixed params)."""
    return "fixed_params" not in trial.system_attrs


class BalancedSampler(BaseSampler):
    """``base``'s draws, except that each value of each parameter in ``balance`` keeps ``min_share`` of them.

    ``balance`` maps a parameter to the values given that floor: a categorical parameter's choices, or some
    values of an integer one (the layer count: ``{"n_layers": [1]}``); ``distributions`` holds the space's
    distribution of each balanced parameter (default: categorical over the values given).

    ``conditional`` draws a forced draw's parameters that depend on the forced value (``own``, by balanced
    parameter; default ``OWN_PARAMETERS``; a parameter not in it: all of them) from the trials sharing that
    value (a sampler of the same kind, its startup count scaled to one value's share); ``base`` draws the rest
    from every trial.
    """

    def __init__(
        self,
        base: BaseSampler,
        conditional: BaseSampler,
        balance: Mapping[str, Sequence[Any]],
        min_share: float,
        own: Mapping[str, Collection[str]] | None = None,
        distributions: Mapping[str, BaseDistribution] | None = None,
        every_draw: bool = False,
    ) -> None:
        if not balance:
            raise ValueError("balance: name at least one categorical parameter")
        for name, choices in balance.items():
            if not 0.0 < min_share * len(choices) <= 1.0:
                raise ValueError(f"balance: {name} has {len(choices)} values, so min_share must be in (0, "
                                 f"{1 / len(choices):.4g}]; got {min_share}")  # fmt: skip
        self._base = base
        self._conditional = conditional
        self._balance = {name: tuple(choices) for name, choices in balance.items()}
        self._min_share = float(min_share)
        own = OWN_PARAMETERS if own is None else own
        self._own = {name: frozenset(own[name]) for name in self._balance if name in own}
        given = dict(distributions or {})
        self._distributions = {n: given.get(n, CategoricalDistribution(list(c))) for n, c in self._balance.items()}
        self._forced: dict[int, tuple[str, Any]] = {}
        self._nested: dict[int, tuple[tuple[str, Any], ...]] = {}
        self._every_draw = bool(every_draw)
        # a balanced parameter before those its value governs (the layer count before the trainer method)
        names = list(self._balance)
        self._order = tuple(sorted(names, key=lambda n: -sum(1 for m in names if m in self._own.get(n, ()))))

    @property
    def base(self) -> BaseSampler:
        """The wrapped sampler (its draws when no value is short)."""
        return self._base

    def forced(self, number: int) -> tuple[str, Any] | None:
        """``(parameter, value)`` trial ``number`` was forced to, None when the base sampler drew it freely."""
        return self._forced.get(number)

    def forced_within(self, number: int) -> tuple[tuple[str, Any], ...]:
        """``(parameter, value)`` pairs trial ``number`` was forced to within its values' trials (``every_draw``:
        a linear draw's trainer method short of its share of the linear draws), in the order forced."""
        return self._nested.get(number, ())

    def reseed_rng(self) -> None:
        self._base.reseed_rng()
        self._conditional.reseed_rng()

    def _drawn(self, study: Study, trial: FrozenTrial) -> list[FrozenTrial]:
        """The study's sampled trials other than ``trial`` (enqueued ones are not draws)."""
        trials = study._get_trials(deepcopy=False, use_cache=False)  # noqa: SLF001
        return [t for t in trials if t.number != trial.number and _sampled(t)]

    def _short_in(self, drawn: Sequence[FrozenTrial], name: str) -> Any | None:
        """The value of ``name`` short of its floor among ``drawn``, or None."""
        counts = dict.fromkeys(self._balance[name], 0)
        for t in drawn:
            v = t.params.get(name)
            if v in counts:
                counts[v] += 1
        return forced_value(counts, self._min_share, sum(1 for t in drawn if name in t.params))

    def _short(self, study: Study, trial: FrozenTrial) -> tuple[str, Any] | None:
        drawn = self._drawn(study, trial)
        for name in self._balance:
            value = self._short_in(drawn, name)
            if value is not None:
                return name, value
        return None

    def infer_relative_search_space(self, study: Study, trial: FrozenTrial) -> dict[str, BaseDistribution]:
        # the balanced parameters always belong, so a forced value is set even while the base draws at random
        space = self._base.infer_relative_search_space(study, trial)
        return {**space, **{n: d for n, d in self._distributions.items() if n not in space}}

    def sample_relative(
        self, study: Study, trial: FrozenTrial, search_space: dict[str, BaseDistribution]
    ) -> dict[str, Any]:
        self._nested.pop(trial.number, None)
        short = self._short(study, trial)
        if short is None:
            self._forced.pop(trial.number, None)
            params = self._base.sample_relative(study, trial, search_space)
            return self._condition(study, trial, params, ()) if self._every_draw else params
        name, value = short
        self._forced[trial.number] = short
        own = self._own.get(name)
        params = {}
        shared = (
            {} if own is None else {k: d for k, d in search_space.items() if k != name and _base_name(k) not in own}
        )
        if shared:  # what every trial taught: the base's model of the parameters the forced value does not change
            params.update((k, v) for k, v in self._base.sample_relative(study, trial, shared).items() if k in shared)
        if self._every_draw:
            params[name] = value
            return self._condition(study, trial, params, (short,))
        params.update(self._redraw(study, trial, (short,), own))
        params[name] = value
        return params

    def _redraw(
        self,
        study: Study,
        trial: FrozenTrial,
        conditions: Sequence[tuple[str, Any]],
        own: frozenset[str] | None,
        fill: bool = False,
    ) -> dict[str, Any]:
        """``own``'s parameters (None: all but the conditions') drawn by the conditional sampler from the trials that
        share every value in ``conditions``; with ``fill``, those its relative draw leaves out too (its independent
        draw: at random while those trials are fewer than its startup), else the base draws them independently."""
        view: Any = _Subset(study, conditions)
        fixed = {n for n, _v in conditions}
        rest = {k: d for k, d in self._conditional.infer_relative_search_space(view, trial).items()
                if k not in fixed and (own is None or _base_name(k) in own)}  # fmt: skip
        if not rest:
            return {}
        out = {k: v for k, v in self._conditional.sample_relative(view, trial, rest).items() if k in rest}
        if fill:  # within those trials' startup (too few to model), at random, not from a wider model
            for k, d in rest.items():
                if k not in out:
                    out[k] = self._conditional.sample_independent(view, trial, k, d)
        return out

    def _condition(
        self,
        study: Study,
        trial: FrozenTrial,
        params: dict[str, Any],
        conditions: tuple[tuple[str, Any], ...],
    ) -> dict[str, Any]:
        """``[study] balance_every_draw``: each balanced parameter whose value has a floor (in the order where a
        parameter comes before those its value governs: the layer count, then the trainer method) has its own
        parameters redrawn from the trials sharing that value and the values conditioned on before it; a balanced
        parameter among them first keeps its floor within those trials (forced when short, as in the study)."""
        params = dict(params)
        nested: list[tuple[str, Any]] = []
        for name in self._order:
            value = params.get(name)
            if value not in self._balance[name]:
                continue
            if name not in {n for n, _v in conditions}:
                conditions = (*conditions, (name, value))
            own = self._own.get(name)
            forced_inside: dict[str, Any] = {}
            for inner in self._order:
                if inner in {n for n, _v in conditions} or (own is not None and inner not in own):
                    continue
                within = [t for t in self._drawn(study, trial) if all(t.params.get(n) == v for n, v in conditions)]
                short = self._short_in(within, inner)
                if short is not None:
                    forced_inside[inner] = short
                    nested.append((inner, short))
            params.update(forced_inside)
            fixed = (*conditions, *forced_inside.items())
            params.update(self._redraw(study, trial, fixed, own, fill=True))
        if nested:
            self._nested[trial.number] = tuple(nested)
        return params

    def sample_independent(
        self, study: Study, trial: FrozenTrial, param_name: str, param_distribution: BaseDistribution
    ) -> Any:
        forced = self._forced.get(trial.number)
        if forced is not None and forced[0] == param_name:
            return forced[1]
        return self._base.sample_independent(study, trial, param_name, param_distribution)

    def before_trial(self, study: Study, trial: FrozenTrial) -> None:
        self._base.before_trial(study, trial)

    def after_trial(self, study: Study, trial: FrozenTrial, state: TrialState, values: Sequence[float] | None) -> None:
        self._base.after_trial(study, trial, state, values)


def conditional_startup(startup: int, n_values: int) -> int:
    """The conditional sampler's startup count: the base's, split between the values (at least 1)."""
    return max(1, math.ceil(startup / max(1, n_values)))


class _Outside(HistoryView):
    """A read-only view of ``study`` without the trials whose value of a parameter in ``apart`` is one of its
    values."""

    def __init__(self, study: Study, apart: Mapping[str, tuple[Any, ...]]) -> None:
        super().__init__(study)
        self._apart = apart

    def shown(self, trials: list[FrozenTrial]) -> list[FrozenTrial]:
        return [t for t in trials if not any(t.params.get(n) in v for n, v in self._apart.items())]


class ApartPruner(BasePruner):
    """``base``, judging a trial whose value of a parameter in ``apart`` is one of the values named for it among the
    trials sharing that value, and every other trial among the trials with none of them (``[study]
    balance_prune_apart``). Why: a balanced value's share of the draws is wasted when the pruner ranks them against
    a region the study knows better. A crowd-prior hour (study seed 2) with a fifth of its draws forced to the whole
    road in view (``lanes_side = 6``) had all 11 of its first 16 minutes' pruned at 10k or 30k (the best 69.6), the
    crowd's region setting the bar; likewise the prior-free draws (``autotune.search.prior.PriorFreePruner``)."""

    def __init__(self, base: BasePruner, apart: Mapping[str, Sequence[Any]]) -> None:
        if not apart:
            raise ValueError("apart: name at least one parameter")
        self._base = base
        self._apart = {name: tuple(values) for name, values in apart.items()}

    @property
    def base(self) -> BasePruner:
        """The wrapped pruner."""
        return self._base

    def prune(self, study: Study, trial: FrozenTrial) -> bool:
        for name, values in self._apart.items():
            value = trial.params.get(name)
            if value in values:
                return self._base.prune(_Subset(study, ((name, value),)), trial)  # type: ignore[arg-type]
        return self._base.prune(_Outside(study, self._apart), trial)  # type: ignore[arg-type]
