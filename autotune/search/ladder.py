"""Training length as a budget ladder: rung r of a trial is a fresh, complete training at B_r iterations.

Why not prefixes of one long run: deepqlearn's ε schedule (``learning_steps_burnin``,
``learning_steps_total``) and train.js's split into runs depend on the absolute decision count, so
30,000 decisions into a 1,000,000-iteration run the net is still exploring, and a pruner comparing
prefixes of runs of different lengths compares unequal things. A rung is therefore a complete
training at its budget, with the length-bound settings scaled to it (``rung_config``):

* ``learning_steps_burnin`` and ``learning_steps_total`` keep their fraction of the budget (the space
  searches them as fractions, ``learning_steps_burnin_fraction`` / ``learning_steps_total_fraction``);
* ``start_learn_threshold`` is capped at ``START_LEARN_CAP`` of the budget (and below the memory size),
  so every rung learns for most of its length.

A trial trains rung 0, 1, … and reports rung r's official score at step
``B_r / B_0`` (1, 3, 9, 27, 81 for the default ladder), so Optuna's successive halving
(min_resource 1, reduction factor B_1/B_0) promotes exactly at the ladder. Its value is its top rung's
score; the top is the ladder's last rung, lowered by the study's cost cap and its time left, or, for a
crowd setting, the first rung that covers its ``trainIterations``. The cost gate refuses a sampled draw
that cannot afford the rungs up to ``[ladder] min_top`` (the whole ladder by default), so every sampled
value is a score at ``min_top`` or above, while cheap configurations climb past it.

Which seed a rung trains from (``rung_seed``): the top rung always from the trial's own seed, so the
trial's value reproduces from its config and seed alone. With ``[ladder] reseed = true`` each rung below
the top trains from a seed of its own, derived from the trial's: one seed moves a score by several mph,
and rungs that share it share its luck (measured: race entrants whose same-seed rungs scored 73.65,
72.89 and 71.19 scored 61.56 and 24.53 on two fresh seeds), so successive halving then compares each
configuration on a new seed at every rung instead of promoting one lucky seed up the ladder.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

from autotune import TrainConfig
from autotune.search import keys
from autotune.search.seeds import derived_seed

__all__ = [
    "DEFAULT_RUNGS", "START_LEARN_CAP", "RUNG_SALT", "Ladder", "rung_config", "trained_rung_config", "rung_epsilon",
    "rung_seed", "relative_schedule",
]  # fmt: skip

DEFAULT_RUNGS: tuple[int, ...] = (10_000, 30_000, 90_000, 270_000, 810_000)
"""The default ladder [iterations]: ×3 per rung, from a quick look to the crowd's longest trainings."""
START_LEARN_CAP = 0.25
"""``start_learn_threshold`` ≤ this fraction of a rung's budget (learning starts within its first quarter)."""


@dataclasses.dataclass(frozen=True)
class Ladder:
    """The budgets a trial climbs [iterations], strictly increasing, each a multiple of the first."""

    rungs: tuple[int, ...] = DEFAULT_RUNGS

    def __post_init__(self) -> None:
        r = self.rungs
        if not r or any(not isinstance(b, int) or isinstance(b, bool) or b < 1 for b in r):
            raise ValueError(f"rungs: positive integers needed, got {list(r)}")
        if any(b <= a for a, b in zip(r, r[1:], strict=False)):
            raise ValueError(f"rungs: must increase strictly, got {list(r)}")
        if any(b % r[0] for b in r):
            raise ValueError(f"rungs: each must be a multiple of the first ({r[0]}), got {list(r)}")

    @property
    def steps(self) -> tuple[int, ...]:
        """The report step of each rung, ``B_r / B_0``."""
        return tuple(b // self.rungs[0] for b in self.rungs)

    @property
    def reduction_factor(self) -> int:
        """``B_1 / B_0`` (successive halving's η); 3 for a one-rung ladder."""
        return max(2, self.rungs[1] // self.rungs[0]) if len(self.rungs) > 1 else 3

    def top_for(self, iterations: int) -> int:
        """Index of the first rung whose budget covers ``iterations`` (the last rung if none does)."""
        for i, b in enumerate(self.rungs):
            if b >= iterations:
                return i
        return len(self.rungs) - 1

    def budgets(self, top: int) -> tuple[int, ...]:
        """The budgets of rungs 0 … top."""
        return self.rungs[: top + 1]


def relative_schedule(budget: int, burnin_fraction: float, total_fraction: float) -> tuple[int, int]:
    """``(learning_steps_burnin, learning_steps_total)`` at ``budget`` from their fractions of it.

    Not reordered: a total at or below the burn-in is what deepqlearn's formula then makes of it (ε stays 1,
    JS arithmetic), as it was for the crowd."""
    return max(0, round(burnin_fraction * budget)), max(0, round(total_fraction * budget))


def rung_config(config: TrainConfig, budget: int) -> TrainConfig:
    """``config`` (its top rung) trained at ``budget`` iterations, the length-bound settings scaled to it.

    Scaling goes from the top rung's values, so the fractions the trial drew hold at every rung; at
    the top rung's own budget the config comes back unchanged (only the threshold cap could bite,
    and the top config was built under it).
    """
    if budget == config.train_iterations:
        return config
    scale = budget / config.train_iterations
    burnin = max(0, round(config.learning_steps_burnin * scale))
    total = max(0, round(config.learning_steps_total * scale))  # < burnin allowed: deepqlearn then never decays ε
    return config.replace(
        train_iterations=int(budget),
        learning_steps_burnin=burnin,
        learning_steps_total=total,
        start_learn_threshold=cap_start(config.start_learn_threshold, config.experience_size, budget),
    )


def trained_rung_config(config: TrainConfig, budget: int, rungs: Sequence[Mapping[str, Any]] | None) -> TrainConfig:
    """What the rung of ``budget`` iterations of a trial (``config``: its stored config; ``rungs``: its rung
    records) trained and was scored with: ``rung_config``, with the ε_test that rung chose for its net where
    ``[ladder] epsilon_test_grid`` chose one (``keys.EPSILON_TEST``)."""
    out = rung_config(config, budget)
    epsilon = rung_epsilon(rungs, budget)
    return out if epsilon is None else out.replace(epsilon_test_time=epsilon)


def rung_epsilon(rungs: Sequence[Mapping[str, Any]] | None, budget: int) -> float | None:
    """The ε_test the rung of ``budget`` iterations chose for its net (``keys.EPSILON_TEST``); None where it
    chose none (no ``[ladder] epsilon_test_grid``: the trial config's ε_test holds)."""
    for rung in rungs or ():
        if rung.get(keys.BUDGET) == budget and isinstance(rung.get(keys.EPSILON_TEST), (int, float)):
            return float(rung[keys.EPSILON_TEST])
    return None


RUNG_SALT = 0x2B_5EED
"""Mixed into a reseeded rung's seed so it never coincides with a trial's or a race run's seed."""


def rung_seed(seed: int, budget: int, top: int, reseed: bool) -> int:
    """The seed the rung of ``budget`` iterations trains from, in a trial of ``seed`` whose top rung is ``top``.

    The top rung (and every rung without ``reseed``) trains from the trial's seed; with ``reseed`` a lower rung
    trains from a seed derived from (seed, budget), independent of the others and the same on a retry."""
    if not reseed or budget == top:
        return int(seed)
    return derived_seed(seed, RUNG_SALT, budget)


def cap_start(start_learn_threshold: int, experience_size: int, budget: int) -> int:
    """The threshold a rung of ``budget`` trains with: below the memory and ≤ ``START_LEARN_CAP`` · budget."""
    return max(0, min(start_learn_threshold, experience_size - 1, int(START_LEARN_CAP * budget)))


def ladder_of(rungs: Sequence[int] | None) -> Ladder:
    """A ``Ladder`` from a spec's rungs (None: the default)."""
    return Ladder(tuple(int(b) for b in rungs) if rungs else DEFAULT_RUNGS)
