"""Seed soups: the nets a configuration without hidden layers trained from different seeds, averaged into one net.

A net with no hidden layer computes Q(s, ·) = W·x(s) + b, so the mean of k such nets' weights computes the mean of
their Q-values exactly: the soup *is* the ensemble of its k trainings, in one convnetjs net the page loads. A hidden
layer breaks this — independent trainings order their units differently, so their mean mixes unrelated units —
which is why refinement soups (``autotune.search.soup``) only average runs of one parent. Measured on a crowd-prior
hour's race winner (study seed 0; a linear adagrad net on 4 lanes a side, 7 patches ahead, 6 behind; 19 fresh
seeds at 270k, best 75.25, 75.16, 75.05, 75.03, …): the soups of its best 2, 3, 4, 6 and 8 scored 75.54, 75.69,
75.54, 75.56 and 75.51 (on 500 unseen runs 75.82, 75.89, 75.78, 75.82, 75.81, where its best run scored 75.39),
while the study's refinement of its best hidden-layer net had stalled at 75.38; the soup of all 19, down to 73.64,
75.20: ingredients come from within ``[study] refine_soup_span`` of the configuration's best net.

Two rules, both pure functions of the study's trials:

* ``next_seed_soup``: whenever a linear configuration's best k nets (``[study] seed_soups`` = the sizes k) form a
  set no soup of it had, its soup is scored — an evaluation, no training (seconds), on any free worker; then
  (``[study] seed_soup_greedy``) a greedy soup: its best set so far plus one more of its nets, kept when it scores
  higher. On the 61 seeds of a crowd-prior hour's linear configuration (best 75.29, 75.28, 75.22, 75.07, …) its
  best 2, 3, 4, 6, 8 souped at 75.54, 75.62, 75.54, 75.56, 75.38, and the greedy soup took the best 3 and then
  the 74.98 and 74.82 seeds to 75.77 (on 500 unseen runs: best net 75.24, best 3 75.52, greedy 75.64); with
  ``[study] seed_soup_swap_span`` it goes on by swaps once no addition is left (``greedy_step``).
* ``next_seed_run``: before the race, a linear configuration whose best net or soup is within
  ``refine.PARENT_SPAN`` of the study's best gets fresh seeds — the race's (``racing.race_seed``), so they count
  in its race — on the refinement's workers, up to ``[study] seed_soup_runs``: a single training of one is
  seldom the study's best net, but its soups are. With ``[study] seed_ensembles`` a configuration with hidden
  layers gets up to ``STACK_SEED_RUNS`` when its net or stack is that near the best net, or its net that near the
  best fresh training (``member_best``): soups put the best net 0.5–1 mph above every training, and a crowd-prior
  hour's ``fc:344:tanh`` configuration (74.72, found at 27.7 min, later 74.70 ± 0.37 on fresh seeds) waited for
  the race for seeds, 0.85 below a linear soup's 75.57 but 0.07 below the best training.

A configuration's nets are its selecting trial's value and its race runs' (``race_of`` it): one training each.
With ``[study] seed_soup_families`` the linear configurations that see the same inputs and are scored alike
(``family_key``: a configuration's linear twins, trained by other methods) pool their nets: a crowd-prior hour's
twins of one configuration scored 75.24 (sgd) and 75.13 (adagrad), and their soup 75.51, where neither one's own
four seeds (to 73.76) souped as high. With ``[study] seed_soup_views`` too, the view is left out of the family: a
soup's nets are moved onto the union of their views first (``autotune.convnet.widen``), so a configuration's view
neighbours (``autotune.search.twins``) soup with it.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from autotune.convnet.widen import View
from autotune.learner.config import TrainConfig, parse_layers
from autotune.search import keys
from autotune.search.racing import Entrant, RaceRun
from autotune.search.soup import next_soup
from sim.config import ConfigError

__all__ = [
    "SeedSoup", "STACK_SEED_RUNS", "MAX_STACK_NEURONS", "STACK_SPAN", "is_linear", "family_key", "VIEW_FIELDS",
    "view_of", "seed_nets", "seed_groups", "next_seed_soup", "greedy_step", "next_seed_run", "best_net_configs",
    "contender_configs",
]  # fmt: skip

STACK_SEED_RUNS = 12
"""The most fresh seeds a configuration with hidden layers gets before the race (``[study] seed_ensembles``), fewer
than a linear one's ``seed_soup_runs``: one trains for longer (gsurma's setting at 90k: ~50 s, a linear net ~25 s),
and its stacks hold only ``MAX_STACK_NEURONS`` // its width nets (21 of gsurma's); the refinement's worker then
goes back to refining."""

MAX_STACK_NEURONS = 8192
"""The widest hidden layer a seed soup of a configuration with hidden layers (a stack) may have: a stack of k nets
is k times as wide as one, and as slow to score (~6 s per 593 units). At 4,096 a crowd-prior hour's race winner
(``fc:593:tanh``, 24 seeds, 74.01–75.34) stacked at most 6 and its greedy stacks stopped at 75.46; its best 8
(4,744 units, 51 s to score) scored 75.58, its best 10 75.46."""

STACK_SPAN = 1.25
"""mph below a configuration's best net within which its seeds are a stack's members (``[study] refine_soup_span``
when wider): averaging Q-values forgives weaker members more than a greedy linear soup's few. gsurma's setting at
90k, 15 seeds (74.81, 74.36, 74.33, 74.03, 74.02, 73.80, …): its best 2, 4, 8 stacked at 75.05, 75.19, 75.26; a
crowd-prior hour's ``fc:593:tanh`` race winner (24 seeds from 75.34): its best 8, down to 75.01, at 75.58. Within
0.5 mph only gsurma's best 2 (74.97, 74.95) were members, and its stacks stopped at 75.20."""

SeedSoup = tuple[int, tuple[int, ...]]
"""(configuration's trial number, ingredients: trial numbers ascending) of a seed soup to score."""


def is_linear(config: Mapping[str, Any] | None) -> bool:
    """Whether a stored config (``keys.CONFIG``) has no hidden layer: its net's Q-values are affine in its inputs."""
    if not isinstance(config, Mapping):
        return False
    try:
        return not parse_layers(config.get("layers", ""))
    except ConfigError:
        return False


Trials = Iterable[tuple[int, Mapping[str, Any], float | None, bool]]
"""(number, user attrs, value, COMPLETE?) of a study's trials."""


def family_key(config: Mapping[str, Any] | None, views: bool = False) -> tuple[Any, ...] | None:
    """What a linear net's official score depends on besides its weights — the engine (ruleset, view, other agents),
    the temporal window and ε_test — or None for a config that is not linear: two linear nets with one key take the
    same inputs and are scored alike, so their mean is their ensemble whatever trained them. ``views`` (``[study]
    seed_soup_views``): the view left out — nets moved onto the union of their views (``autotune.convnet.widen``)
    keep their Q-values, so their mean is their ensemble too."""
    if not is_linear(config):
        return None
    assert config is not None
    try:
        c = TrainConfig.from_mapping(config)
    except (ConfigError, TypeError, ValueError):
        return None
    engine = dataclasses.asdict(c.engine_config)
    if views:
        for name in VIEW_FIELDS:
            del engine[name]
    return (*engine.values(), c.temporal_window, c.epsilon_test_time)


VIEW_FIELDS = ("lanes_side", "patches_ahead", "patches_behind")
"""The settings of a DeepTraffic view (``widen.View``'s order)."""


def view_of(config: Mapping[str, Any] | TrainConfig) -> View:
    """(lanes_side, patches_ahead, patches_behind) of a config or a stored one (``keys.CONFIG``)."""
    c = config if isinstance(config, TrainConfig) else TrainConfig.from_mapping(config)
    lanes, ahead, behind = (int(getattr(c, name)) for name in VIEW_FIELDS)
    return (lanes, ahead, behind)


Groups = dict[int, list[tuple[int, float]]]
"""Fresh-seed nets (trial number, score) by configuration (``seed_nets``)."""


def seed_nets(trials: Trials, families: bool = False, hidden: bool = False, views: bool = False) -> Groups:
    """The fresh-seed nets of each linear configuration among ``trials`` (number, user attrs, value, COMPLETE?): its
    selecting trial's value and its race runs' — COMPLETE, with a stored net — keyed by the selecting trial's
    number, as (trial number, score). Refinement runs and soups, retries and copied history are none of them.
    ``families`` (``[study] seed_soup_families``): the nets of every linear configuration with one ``family_key``
    (a configuration's linear twins, whose trainers differ) in one group, keyed by its first configuration
    (``seed_groups``). ``hidden`` (``[study] seed_ensembles``): configurations with hidden layers too, each its
    own group (their soups are stacks, ``autotune.convnet.stack``). ``views`` (``[study] seed_soup_views``): with
    ``families``, linear configurations of any view in one family (``family_key``)."""
    return seed_groups(trials, families, hidden, views)[0]


def _merged(groups: Groups, family: Mapping[int, int]) -> Groups:
    merged: Groups = {}
    for owner in sorted(groups):
        merged.setdefault(family[owner], []).extend(groups[owner])
    return merged


def seed_groups(
    trials: Trials, families: bool = False, hidden: bool = False, views: bool = False
) -> tuple[Groups, dict[int, int]]:
    """``seed_nets(trials, families, hidden, views)`` and the family of each configuration with seed nets: the
    lowest-numbered configuration sharing its ``family_key`` — stable as the study grows, so a family's soups stay
    recorded under one number; one with hidden layers (with ``hidden``) is its own."""
    groups, family = _grouped(trials, hidden, views)
    return (_merged(groups, family) if families else groups), family


def _grouped(trials: Trials, hidden: bool = False, views: bool = False) -> tuple[Groups, dict[int, int]]:
    groups: Groups = {}
    keyed: dict[int, tuple[Any, ...] | None] = {}
    for number, attrs, value, complete in trials:
        if not complete or value is None or not attrs.get(keys.ARTIFACT_NET_JSON):
            continue
        if not isinstance(attrs.get(keys.CONFIG), Mapping) or not (hidden or is_linear(attrs.get(keys.CONFIG))):
            continue
        if any(k in attrs for k in (keys.REFINE_OF, keys.SOUP_OF, keys.RETRY_OF, keys.COPIED_FROM)):
            continue
        owner = int(attrs[keys.RACE_OF]) if keys.RACE_OF in attrs else number
        groups.setdefault(owner, []).append((number, float(value)))
        keyed.setdefault(owner, family_key(attrs.get(keys.CONFIG), views))
    first: dict[tuple[Any, ...], int] = {}
    family = {}
    for owner in sorted(groups):
        key = keyed[owner]
        family[owner] = owner if key is None else first.setdefault(key, owner)
    return groups, family


def next_seed_soup(
    groups: Mapping[int, Sequence[tuple[int, float]]],
    tried: Mapping[int, Iterable[Iterable[int]]],
    sizes: Sequence[int],
    span: float,
    best: float | None,
    reach: float,
    scored: Mapping[int, Iterable[tuple[Iterable[int], float]]] | None = None,
    most: Mapping[int, int] | None = None,
    swap_span: float = 0.0,
) -> SeedSoup | None:
    """The next seed soup to score, or None: over the configurations of ``groups`` (``seed_nets``) whose best net is
    within ``reach`` mph of the study's ``best`` net, best first, the first whose best k nets (k in ``sizes``, in
    order; nets within ``span`` mph of its best, a stack's within ``STACK_SPAN`` when wider) form a set none of its
    soups (``tried``: ingredient sets by configuration) had; then, given ``scored`` (its finished soups' ingredients
    and scores, by configuration), its greedy soup's next step (``greedy_step``). ``most``: the most ingredients a
    configuration's soup may have (a stack's width grows with them, ``autotune.convnet.stack``), by configuration,
    given for exactly the configurations with hidden layers (the stacks). ``swap_span`` > 0: the greedy soups of
    the others (nets without hidden layers, whose soups score in seconds; a stack's take tens) go on by swaps over
    their nets within ``swap_span`` of their best."""
    order = sorted(groups.items(), key=lambda g: (-max(s for _, s in g[1]), g[0]))
    for owner, nets in order:
        top = max(s for _, s in nets)
        if best is not None and top < best - reach:
            break
        cap = (most or {}).get(owner)
        fits = [k for k in sizes if cap is None or k <= cap]
        floor = top - (span if cap is None else max(span, STACK_SPAN))
        ingredients = next_soup(nets, fits, tried.get(owner, ()), floor)
        if ingredients is None and scored is not None:
            swap_floor = top - swap_span if swap_span > 0 and cap is None else None
            ingredients = greedy_step(nets, tried.get(owner, ()), scored.get(owner, ()), floor, cap, swap_floor)
        if ingredients is not None:
            return owner, ingredients
    return None


def greedy_step(
    nets: Iterable[tuple[int, float]],
    tried: Iterable[Iterable[int]],
    scored: Iterable[tuple[Iterable[int], float]],
    floor: float,
    most: int | None = None,
    swap_floor: float | None = None,
) -> tuple[int, ...] | None:
    """The next step of a greedy soup ("greedy soup", Wortsman et al., 2022) as a hill climb over ingredient sets,
    or None: the best-scoring set so far — a single net (``nets``: number, score) or a finished soup (``scored``;
    ties to the smaller set) — plus the best net scoring ``floor`` or more that is not in it, the first whose union
    no soup in ``tried`` had (of at most ``most`` nets, when given). A set that beats the best becomes the one the
    next steps add to; so every net near the top is tried once against each new best set, and a new seed against
    the current one.

    ``swap_floor`` (``[study] seed_soup_swap_span``): once no such addition is left, the climb goes on over the
    rest of the best set's neighbours, nets scoring ``swap_floor`` or more: one added, one member left out (a set
    keeps two), one member replaced by another — best net first, weakest member first. An addition can lower a
    soup that a swap then lifts: on a crowd-prior hour's 58 seeds of one linear configuration the additions had
    stopped at 75.72 (5 seeds); 202 neighbours on (~1.5 s each) a swap gave 75.74 and an addition 75.80."""
    lowest = floor if swap_floor is None else min(floor, swap_floor)
    ranked = sorted((r for r in nets if r[1] >= lowest), key=lambda r: (-r[1], r[0]))
    if not ranked:
        return None
    sets = [(frozenset([n]), s) for n, s in ranked] + [(frozenset(i), float(s)) for i, s in scored]
    current = min(sets, key=lambda c: (-c[1], len(c[0]), sorted(c[0])))[0]
    seen = {frozenset(t) for t in tried}

    def fits(step: frozenset[int]) -> bool:
        return step not in seen and (most is None or len(step) <= most)

    near = [n for n, s in ranked if s >= floor]
    for n in near:
        if n not in current and fits(current | {n}):
            return tuple(sorted(current | {n}))
    if swap_floor is None:
        return None
    value = {n: s for n, s in ranked}
    wide = [n for n, _ in ranked if n not in current]
    members = sorted(current, key=lambda m: (value.get(m, math.inf), m))  # weakest first
    steps = [current | {n} for n in wide]
    steps += [current - {m} for m in members if len(current) > 2]
    steps += [(current - {m}) | {n} for m in members for n in wide]
    for step in steps:
        if len(step) > 1 and fits(step):
            return tuple(sorted(step))
    return None


PROBE_SEEDS = 4
"""Seeds a linear configuration within ``[study] seed_soup_reach`` of the best net gets first, ahead of the others'
(``driver._launch_refine``): by level alone, one configuration's 64 seeds (best 74.45, soups to 75.26) held the
refinement's worker for 15 minutes while a later one, first seed 74.49, waited; given seeds, it scored 75.22 and
75.10 and souped to 75.56. They rank configurations by their own nets, not their family's soups
(``driver._launch_seed_run``'s ``own``)."""


def next_seed_run(
    candidates: Sequence[Entrant],
    launched: Iterable[tuple[int, int]],
    level: Mapping[int, float],
    best: float | None,
    reach: float,
    max_runs: int,
    most: Mapping[int, int] | None = None,
    member_best: float | None = None,
) -> RaceRun | None:
    """The next fresh-seed run for a configuration's seed soups, or None: of ``candidates`` (the race's possible
    entrants that may have seeds) within ``reach`` mph of the study's ``best`` net that started fewer than ``max_runs``
    race seeds (``launched``: (race_of, seed index) of every race run so far), the one with the highest ``level``
    (its best net or seed soup; else its entrant score; ties in the candidates' order); its next seed is the first
    index it has not started (the race's seeds, so the race reuses them). ``most``: a lower cap than ``max_runs`` for
    some configurations (by number; those with hidden layers, ``STACK_SEED_RUNS``). ``member_best``: the best fresh
    training's score; a configuration capped by ``most`` is near the best also when its own net (its entrant score)
    is within ``reach`` of that one, member against member."""
    started = set(launched)
    ranked = sorted(enumerate(candidates), key=lambda c: (-level.get(c[1].number, c[1].value), c[0]))
    for _i, e in ranked:
        mine = {s for (n, s) in started if n == e.number}
        if len(mine) >= min(max_runs, (most or {}).get(e.number, max_runs)):
            continue
        if best is not None and level.get(e.number, e.value) < best - reach:
            if not (member_best is not None and e.number in (most or {}) and e.value >= member_best - reach):
                continue
        return RaceRun(e.number, next(i for i in itertools.count() if i not in mine))
    return None


def best_net_configs(number: int, attrs: Sequence[Mapping[str, Any]]) -> list[int]:
    """The configurations whose fresh-seed nets make the net of trial ``number`` (``attrs``: every trial's user
    attrs, by number), ascending, each its selecting trial's number: a seed soup's ingredients' (a family soup's can
    be several), a fresh training's own; none for a refinement run or its soup (trained on from other nets).

    ``[study] seed_soup_best`` gives them seeds: their next seeds are the next greedy steps' candidates for the best
    net itself. A crowd-prior hour's (study seed 2) best net was a family soup of 6 nets from 4 linear
    configurations (75.64 at 15.6 min); they had 1-5 seeds each (their probe seeds, while each new neighbour in
    reach took its own), and nothing beat it in the 44 minutes left."""
    mine = attrs[number]
    if keys.SOUP_OF in mine and keys.SEED_SOUP_OF in mine:
        numbers = [int(n) for n in mine[keys.SOUP_OF]]
    elif keys.REFINE_OF in mine:
        return []
    else:
        numbers = [number]
    return sorted({int(attrs[n].get(keys.RACE_OF, n)) for n in numbers})


def contender_configs(
    attrs: Sequence[Mapping[str, Any]],
    values: Sequence[float | None],
    floor: float,
    seeds: Mapping[int, int],
    skip: Iterable[int] = (),
    views: bool = False,
) -> list[list[int]]:
    """For each family (``family_key``; a configuration with hidden layers is its own) whose best net scores
    ``floor`` or more, the configurations whose seeds make that net (``best_net_configs``: a fresh training or a
    seed soup; ``attrs``/``values``: every trial's user attrs and COMPLETE value, None otherwise, by number), those
    in ``skip`` left out; the family with the fewest fresh seeds (``seeds``: runs launched per configuration) first,
    then the higher best net. ``views``: families of any view (``family_key``).

    ``[study] seed_soup_best_span`` gives them the best net's family's turns every other time: a family's soups
    gain little past ~10-20 seeds (in four crowd-prior hours the best family's soups stopped at 75.61-75.74 with 46
    to 88 nets, where runners-up reached 75.57-75.61 with 8-11), and the official 500 runs favour one family's
    policy over another's by a few tenths (two soups' official scores sat 0.30 above and 0.15 below their scores on
    unseen runs), so near the top a second family's soup is the likelier next best net."""
    best: dict[Any, tuple[float, int, list[int]]] = {}
    for number, value in enumerate(values):
        if value is None or not math.isfinite(value) or value < floor:
            continue
        owners = best_net_configs(number, attrs)
        if not owners:
            continue
        key = family_key(attrs[number].get(keys.CONFIG), views) or ("hidden", *owners)
        if key not in best or (value, -number) > (best[key][0], -best[key][1]):
            best[key] = (float(value), number, owners)
    left = set(skip)
    groups = [(sum(seeds.get(o, 0) for o in owners), -value, number, [o for o in owners if o not in left])
              for value, number, owners in best.values()]  # fmt: skip
    return [owners for *_rank, owners in sorted(groups) if owners]
