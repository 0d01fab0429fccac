"""Refinement: training on from the study's best single net, as the DeepTraffic page let its users do.

A page that appended trained weights to its net.js (``brain.value_net.fromJSON(...)``) trained on from them
at its own settings: the leaderboard's best v2 net re-scored here (jnorthrup-v05, 75.80 with 10 other
agents) is such a net — a linear net whose weights were carried through six versions of its file, the last
one training at a learning rate of 1e-8. No fresh training of any configuration the search has measured
reaches it (the best of 54 trainings of the two best found: 75.57). A refinement run is that step: the
best single net's config, trained for ``[study] refine_iterations`` from the best net's weights and a fresh
seed, and scored with the official protocol like any trial.

What it changes in the config (``refine_config``), and why:

* exploration: ε falls from 1 to the config's ε_min over the first ``EXPLORE_DECISIONS`` decisions
  (``learning_steps_burnin`` ``BURNIN``, ``learning_steps_total`` ``EXPLORE_DECISIONS``). Measured on
  gsurma's setting (a 74.39 net, 10 runs of 20k each): the net's own schedule — ε near 1 for most of a short
  run — took every run below the parent (66.35–72.89), the short one left 7 of 10 at or above 74.1;
* learning starts once ``START_LEARN`` transitions are stored (or the config's own threshold, if lower);
* the learning rate is ``[study] refine_learning_rate`` × the config's (sgd and adagrad step by it;
  adadelta has none): a tenth kept the runs' median at 74.66 and reached 75.22 (the parent's own rate:
  74.52 and 75.03). That is the rate of the lineage's fresh training: a run refined from a refinement run keeps
  its parent's rate (a tenth more each generation froze a cold study's climbs: 1.9e-9 → 1.9e-11 in two).

The study's best net is the parent of each run (``choose_parent``) — of the fresh trainings only those at the seed
race's floor (``min_top``) or above: a cold study's best net, a 10k rung whose weights had moved 7.7 % from their
initial values (its score their luck), gave 210 runs none above it. A run that beats it is the next parent, so
the runs climb (a (1 + λ) search whose mutation is deepqlearn training). A net gets at most ``[study]
refine_runs`` runs: in a crowd-prior study the first runs from gsurma's 74.95 net gave 75.22
within a minute, and the next 208 runs from that one found +0.01 (median 74.9): the climb stalls where the runs'
spread around their parent no longer reaches above it. Then the next best net within ``PARENT_SPAN`` mph of the
best has its runs (another lineage may climb where that one stalled; a run that did not beat its own parent is
never one), and once those had theirs too the worker goes back to the search. Refinement starts after the
search's ``[study] refine_start`` share of the study's budget: from minute 0, a cold study refined weak nets on
half its workers while the search had found no good one.
With ``[study] refine_soups`` a parent's best runs are also averaged into a weight soup (``autotune.search.soup``),
scored with no training: a parent too once it beats its own.
Each run is an ordinary trial (``refine_of``: its parent's trial and rung), never shown to the sampler, never a
race entrant and never using the trial budget; its net reproduces from its parent's net, its config and its seed
(``autotune evaluate --trial S:N --retrain``).
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Iterable, Mapping
from typing import Any

from autotune import TrainConfig
from autotune.search import keys
from autotune.search.records import net_rank, scored_nets
from autotune.search.seeds import derived_seed

__all__ = [
    "BURNIN", "EXPLORE_DECISIONS", "START_LEARN", "PARENT_SPAN", "REFINE_SALT", "Parent", "ranked_parents",
    "choose_parent", "refine_config", "refine_seed", "is_refinement",
]  # fmt: skip

EXPLORE_DECISIONS = 1_000
"""``learning_steps_total`` of a refinement run: ε reaches the config's ε_min after this many decisions."""
BURNIN = 100
"""``learning_steps_burnin`` of a refinement run (at most the config's own)."""
START_LEARN = 500
"""``start_learn_threshold`` of a refinement run (at most the config's own)."""
PARENT_SPAN = 0.5
"""mph below the study's best net within which a net that had fewer runs is the next parent once the better ones
had their ``[study] refine_runs``: other lineages climb where the best one stalled."""
REFINE_SALT = 0x2EF1_4E
"""Mixed into a refinement run's seed so it never coincides with a trial's, a rung's or a race run's."""


@dataclasses.dataclass(frozen=True)
class Parent:
    """The net a refinement run trains on from: a trial's value (``budget`` None) or one of its kept rungs."""

    trial: int
    budget: int | None
    score: float

    def to_attr(self) -> dict[str, Any]:
        """The ``refine_of`` user attr of a run trained from it."""
        return {"trial": self.trial, "budget": self.budget, "score": self.score}

    @classmethod
    def from_attr(cls, attr: Mapping[str, Any]) -> Parent:
        budget = attr.get("budget")
        return cls(int(attr["trial"]), None if budget is None else int(budget), float(attr["score"]))


def ranked_parents(
    trials: Iterable[tuple[int, Mapping[str, Any], float | None, bool]], min_budget: int = 0
) -> list[Parent]:
    """The stored nets of ``trials`` (number, user attrs, value, COMPLETE?), best first by ``records.net_rank``:
    ``scored_nets`` (kept rungs too), refinement runs included, among the nets the study stores (a trial's value
    needs its ``artifact_net_json``: history copied from another study has none), each once (a COMPLETE trial's
    top rung is its value's net: a cold study's refinement gave one net's two entries 32 runs each), of the
    refinement runs only those that beat their parent, and of the fresh trainings only those of ``min_budget``
    iterations or more (the race's floor, ``min_top``: a rung below it screens, and its best scores are often its
    initial weights' luck — a cold study's best, a 10k rung whose weights moved 7.7 %, gave 210 runs none above it)."""
    ranked: list[tuple[tuple[float, int, int], Parent]] = []
    for number, attrs, value, complete in trials:
        origin = attrs.get(keys.REFINE_OF)
        if origin is not None and (value is None or value <= float(origin["score"])):
            continue  # a run that did not beat its parent: that parent is the better start (a cold study gave four
            # such children of one net 32 runs each, none above it)
        nets = scored_nets(attrs, value, complete)
        rungs = [budget for _, budget in nets if budget is not None]
        trained = [int(r[keys.BUDGET]) for r in attrs.get(keys.RUNGS) or () if keys.BUDGET in r]
        for score, budget in nets:
            length = budget if budget is not None else max(trained, default=None)  # a value: its top rung's
            if origin is None and length is not None and length < min_budget:
                continue
            if budget is None and not attrs.get(keys.ARTIFACT_NET_JSON):
                continue
            top = budget is not None and budget == max(rungs) and attrs.get(keys.ARTIFACT_NET_JSON)
            if top and (score, None) in nets:
                continue  # a COMPLETE trial's top rung is the net of its value: one parent, not two
            ranked.append((net_rank(score, budget, number), Parent(number, budget, score)))
    ranked.sort(key=lambda r: r[0], reverse=True)
    return [p for _, p in ranked]


def choose_parent(
    trials: Iterable[tuple[int, Mapping[str, Any], float | None, bool]],
    refine_ofs: Iterable[Mapping[str, Any] | None],
    max_runs: int,
    min_budget: int = 0,
) -> Parent | None:
    """The net the next refinement run trains on from: the best stored net (``ranked_parents``) that had fewer than
    ``max_runs`` runs (0: no bound) among those within ``PARENT_SPAN`` mph of the best; None when there is none (no
    net yet, or every such net had its runs: the worker goes back to the search). ``refine_ofs``: the ``refine_of``
    attrs of the study's trials (None: not a refinement run); a run counts for its parent's trial and rung;
    ``min_budget``: the shortest fresh training that is a parent (``ranked_parents``)."""
    ranked = ranked_parents(trials, min_budget)
    if not ranked:
        return None
    if not max_runs:
        return ranked[0]
    counts = Counter((r.get("trial"), r.get("budget")) for r in refine_ofs if r is not None)
    for parent in ranked:
        if parent.score < ranked[0].score - PARENT_SPAN:
            return None
        if counts[(parent.trial, parent.budget)] < max_runs:
            return parent
    return None


def refine_config(parent: TrainConfig, iterations: int, learning_rate: float) -> TrainConfig:
    """The config of a refinement run of a net trained with ``parent``: ``iterations`` long, a short ε schedule
    (``EXPLORE_DECISIONS``), learning from ``START_LEARN`` stored transitions, ``learning_rate`` × its rate; the
    rest — inputs, layers, γ, the trainer, batch, memory, ε_min and ε_test — is the parent's."""
    return parent.replace(
        train_iterations=int(iterations),
        learning_steps_burnin=min(BURNIN, parent.learning_steps_burnin),
        learning_steps_total=EXPLORE_DECISIONS,
        start_learn_threshold=min(START_LEARN, parent.start_learn_threshold),
        learning_rate=parent.learning_rate * learning_rate,
    )


def refine_seed(study_seed: int, index: int) -> int:
    """The training seed of a study's refinement run number ``index`` (0, 1, …: in the order they were started)."""
    return derived_seed(study_seed, REFINE_SALT, index)


def is_refinement(user_attrs: Mapping[str, Any]) -> bool:
    """Whether a trial is a refinement run (``refine_of``)."""
    return keys.REFINE_OF in user_attrs
