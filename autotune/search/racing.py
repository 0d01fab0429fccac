"""Seed racing: the best configurations retrained with fresh seeds, the worse half dropped after each round.

A search result is a best-of-many, and one seed moves a DeepTraffic score by several mph (the same
settings score 75.15 and 71.06 with seeds 1 and 2), so the best trial's value overstates its
configuration. The last part of a study's time therefore races the best ``race_configs`` distinct
configurations: round j retrains every survivor with the same ``race_seeds`` fresh seeds (paired
comparisons: every configuration meets the same seeds), then keeps the better half — successive
halving over seeds. The seed that selected a configuration is left out. A race run is an ordinary
trial (its own net and official score).

Configurations are ranked by paired per-seed comparisons, Wilcoxon's signed ranks (``signed_rank``):
each pair's score differences on their shared seeds, ranked by size and summed with their signs, and
each configuration's sum against all the others; the mean breaks a tie. Why not the mean alone: one
seed in about ten collapses (a crowd-prior study's entrant scored 74.77, 74.79, 75.16 and 64.41 on its
race seeds, and 74.08–75.44 on 11 of 12 fresh seeds at 90k, 66.27 on the 12th), and one collapsed seed
out of four decides a mean — that race crowned a configuration that had scored 72.37–73.36 on the same
seeds and averaged 70.81 on 3 fresh ones. The signed ranks count a collapse as one lost seed, however
deep. With two seeds the comparison of two configurations is the mean's.

The winner is decided the same paired way: among the finalists (the survivors of the halving so
far), on the seeds every finalist with a result has one for. Once the halving leaves one configuration,
the race's remaining time may retrain it on further fresh seeds (``tail_run``), while its best run
reaches the study's best single net (``tail_reaches``): each such run is one more net at the
leaderboard's level and tightens the winner's mean; a winner whose runs trail the study's best leaves the
time to the search instead. Those seeds can overturn the halving (``tail_leader``): once the winner's mean
over all its seeds falls below that of a configuration it beat in the last round, that one leads, and takes
the tail. A run the study's deadline stopped is no result (missing for every finalist, not held against the
one it stopped); a run that failed, or that its own time limit stopped, is a result that ranks its
configuration last.

With ``[study] intensify_share``, the search retrains its incumbent on the race's seeds before the race
(``incumbent_run``; SMAC's intensification): the best candidate whose fresh runs — before its first, its selecting
score — reach the study's best single net takes the next fresh seed on a share of the workers. Each such run is a
race run like any other (same seeds, same records), so a configuration that enters the race has run part of it
already, and a good configuration found early gets many more fresh trainings — each one more net at the study's
top — than the race's tail alone gives it.

Pure functions of plain records, so the race's state is whatever the study holds: a resumed driver
rebuilds it from the trials' ``race_of`` / ``race_seed`` attributes.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import statistics
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from autotune.search.seeds import derived_seed

__all__ = [
    "Entrant", "RaceRun", "RaceStanding", "race_seed", "entrants", "field_order", "next_runs", "run_result",
    "signed_rank", "standings", "provisional_standings", "tail_leader", "tail_reaches", "tail_run", "incumbent_run",
    "RACE_SALT", "TAIL_REACH_MPH", "PROVISIONAL_SEEDS",
]  # fmt: skip

RACE_SALT = 0x5EED_2ACE
"""Mixed into the race seeds so they never coincide with a trial's own seed."""


TAIL_REACH_MPH = 0.5
"""The winner's tail goes on while its best fresh-seed run is at most this far below the study's best single
net. In the benchmark's ten stored races, the winner's best run was the study's best or 0.19 below it in
three crowd-prior studies (one-layer tanh nets; one scored 74.1–75.5 on 18 of its 20 trainings at 90k), and
0.45–1.63 below it in the seven others, where the search after the race found nets 0.08–0.9 below the
study's best (a cold study's best nets are lucky 10k–30k rungs, not a race winner's seeds)."""


PROVISIONAL_SEEDS = 3
"""Before the race, a configuration is ranked by its fresh seeds (``provisional_standings``) once it has this many
results. Why not the best single trial: a crowd-prior hour's best trial before the race (study seeds 1 and 2) was
a lucky seed of a linear configuration whose 64 fresh seeds had a median of 73.4 and 72.8; retrained on 3 more, it
averaged 71.51 — below gsurma's crowd setting (72.93) — while its seed runs, already in the study, said so."""


def race_seed(study_seed: int, index: int) -> int:
    """Fresh seed number ``index`` of a study's race (the same for every configuration)."""
    return derived_seed(study_seed, RACE_SALT, index)


@dataclasses.dataclass(frozen=True)
class Entrant:
    """A configuration in the race: the trial that selected it."""

    number: int
    """Trial number of the selecting trial (race runs point to it with ``race_of``)."""
    value: float
    """Its own score (selected by it, so left out of the race mean)."""
    key: str
    """The configuration, canonical JSON (identical settings race once)."""


@dataclasses.dataclass(frozen=True)
class RaceRun:
    """One race run to launch: entrant ``race_of`` with fresh seed number ``seed_index``."""

    race_of: int
    seed_index: int


@dataclasses.dataclass(frozen=True)
class RaceStanding:
    """A configuration's fresh-seed record so far."""

    number: int
    scores: tuple[float, ...]
    """Official scores of its finished race runs, by seed index (a failed or stopped run is missing)."""
    finalist: bool = False
    """Survived every finished round of the halving (the winner is a finalist)."""
    paired: tuple[float, ...] | None = None
    """A finalist's results on the seeds every finalist with a result has one for (−inf: a failed run); None
    otherwise."""

    @property
    def mean(self) -> float:
        return statistics.fmean(self.scores) if self.scores else -math.inf

    @property
    def sd(self) -> float:
        return statistics.stdev(self.scores) if len(self.scores) > 1 else 0.0

    @property
    def paired_mean(self) -> float | None:
        """The mean the finalists are ranked by (None: not a finalist, or no seed shared by all finalists)."""
        return statistics.fmean(self.paired) if self.paired else None


def config_key(config: Mapping[str, Any]) -> str:
    """Canonical JSON of a configuration mapping (the unit of the race)."""
    return json.dumps(config, sort_keys=True, separators=(",", ":"))


def entrants(candidates: Iterable[tuple[int, float, Mapping[str, Any]]], n: int) -> list[Entrant]:
    """The best ``n`` distinct configurations among (trial number, value, config), best first."""
    seen: set[str] = set()
    out: list[Entrant] = []
    for number, value, config in sorted(candidates, key=lambda c: (-c[1], c[0])):
        key = config_key(config)
        if key in seen or not math.isfinite(value):
            continue
        seen.add(key)
        out.append(Entrant(number, float(value), key))
        if len(out) == n:
            break
    return out


def field_order(
    candidates: Iterable[tuple[int, float, Mapping[str, Any]]],
    results: Mapping[tuple[int, int], float | None],
    min_seeds: int = PROVISIONAL_SEEDS,
) -> list[Entrant]:
    """The race's candidates (trial number, selecting score, config) in the order they join the field.

    A configuration measured on ``min_seeds`` fresh seeds or more (``provisional_standings`` over ``results``)
    ranks by its fresh mean; one measured less, by its selecting score less the study's optimism (the median, over
    the measured ones, of selecting score minus fresh mean; 0 while none is measured); the measured leader (the
    pick ``autotune best`` shows before the race) comes first whatever the others' estimates, and the best-scored
    configuration not yet measured second. Why: a selecting score is a best-of-many, a fresh mean is not. A
    crowd-prior hour (study seed 1) raced a linear neighbour on its selecting 75.10 although its 150 seed runs
    averaged 70.9; it tied its rival on the race's 4 seeds, won on their mean, and averaged 70.23 on 3 fresh seeds,
    while the leader, gsurma's setting at 73.2 over 5 seeds, never raced. The leader's seed runs are race runs, so
    it enters at no cost, and the race replaces the pick only by beating it on the same seeds. Why the best
    unmeasured one second: the race is the only measurement it gets, and a measured configuration below the leader
    has already lost to it on average. A 30-minute crowd-prior study (seed 0) raced the leader, gsurma's setting
    and two of its twins, not its best net's configuration (75.56, a γ neighbour of the crowd twin, not yet
    reseeded), and picked gsurma's adagrad twin (71.80 on 3 fresh seeds); its journal did not survive to say
    whether the order or the round's time count (``Driver._race_field``) left it out, and each is fixed."""
    pool = {c[0]: c for c in candidates if math.isfinite(c[1])}
    measured = [st for st in provisional_standings(results, min_seeds) if st.number in pool]
    means = {st.number: st.mean for st in measured}
    optimism = statistics.median(pool[n][1] - m for n, m in means.items()) if means else 0.0
    # one configuration, several trials (a crowd setting and a twin alike): it races as its measured trial, the
    # one whose seeds the race reuses, else as its best-scored
    by_key: dict[str, Entrant] = {}
    for number, value, config in sorted(pool.values(), key=lambda c: (c[0] not in means, -c[1], c[0])):
        key = config_key(config)
        by_key.setdefault(key, Entrant(number, float(value), key))
    leader = measured[0].number if measured else None
    unmeasured = [e for e in by_key.values() if e.number not in means]
    hope = min(unmeasured, key=lambda e: (-e.value, e.number)).number if unmeasured else None

    def rank(e: Entrant) -> tuple[bool, bool, float, int]:
        return e.number != leader, e.number != hope, -means.get(e.number, e.value - optimism), e.number

    return sorted(by_key.values(), key=rank)


def signed_rank(a: Sequence[float], b: Sequence[float]) -> float:
    """Wilcoxon's signed-rank statistic of paired results: Σ sign(d)·rank(|d|) over the differences d = a − b.

    Zero differences are dropped; tied |d| share their mean rank. Positive: ``a`` won its seeds by more
    rank than it lost. A seed's weight is its rank, not its size, so one collapsed training is one seed lost.
    """
    d = [round(x - y, 9) for x, y in zip(a, b, strict=True)]
    d = [x for x in d if x != 0.0]
    size = sorted(abs(x) for x in d)
    rank = {v: (size.index(v) + 1 + len(size) - size[::-1].index(v)) / 2 for v in set(size)}  # mean rank of ties
    return float(sum(math.copysign(rank[abs(x)], x) for x in d))


def _paired_order(ids: Sequence[int], table: Mapping[int, Sequence[float]], field: Sequence[int]) -> list[int]:
    """``ids`` best first by their paired results ``table[n]`` (the same seeds each; −inf: a failed run): a
    failed one last; the others by their summed signed ranks against one another, then mean, then field order."""
    ok = [n for n in ids if all(math.isfinite(x) for x in table[n])]
    total = {n: sum(signed_rank(table[n], table[m]) for m in ok if m != n) for n in ok}

    def key(n: int) -> tuple[float, ...]:
        mean = statistics.fmean(table[n]) if n in total and table[n] else -math.inf
        return (float(n not in total), -total.get(n, 0.0), -mean, float(field.index(n)))

    return sorted(ids, key=key)


def _survivors(
    field: Sequence[int], results: Mapping[tuple[int, int], float | None], seeds_per_round: int
) -> tuple[list[int], int, bool, list[int]]:
    """(survivors, current round, is the current round complete?, the configurations the last cut compared — the
    field before any) from the finished race runs."""
    alive = list(field)
    last = alive
    rnd = 0
    while True:
        seeds = range(rnd * seeds_per_round, (rnd + 1) * seeds_per_round)
        done = all((n, s) in results for n in alive for s in seeds)
        if not done or len(alive) <= 1:
            return alive, rnd, done, last
        upto = (rnd + 1) * seeds_per_round
        ranked = _paired_order(alive, {n: _results(n, results, range(upto)) for n in alive}, field)
        last = alive
        alive = ranked[: math.ceil(len(alive) / 2)]
        rnd += 1


def _results(number: int, results: Mapping[tuple[int, int], float | None], seeds: Iterable[int]) -> tuple[float, ...]:
    """Results on the fresh seeds ``seeds`` (−inf where a run failed: its configuration ranks last)."""
    scores = [results.get((number, s)) for s in seeds]
    return tuple(float(x) if x is not None and math.isfinite(x) else -math.inf for x in scores)


def next_runs(
    field: Sequence[int],
    results: Mapping[tuple[int, int], float | None],
    launched: Iterable[tuple[int, int]],
    seeds_per_round: int,
) -> tuple[list[RaceRun], bool]:
    """The race runs to launch now (not yet launched) and whether the race is over.

    ``field``: the entrants' trial numbers, best first; ``results``: (race_of, seed index) → score of
    finished race runs (None: the run failed or was stopped — the configuration then ranks last);
    ``launched``: race runs started (finished or running).
    """
    if len(field) == 0:
        return [], True
    alive, rnd, done, _last = _survivors(field, results, seeds_per_round)
    if len(alive) <= 1 and (done or rnd > 0):
        return [], True
    started = set(launched)
    seeds = range(rnd * seeds_per_round, (rnd + 1) * seeds_per_round)
    runs = [RaceRun(n, s) for s in seeds for n in alive if (n, s) not in started]
    return runs, False


def tail_run(
    field: Sequence[int],
    results: Mapping[tuple[int, int], float | None],
    launched: Iterable[tuple[int, int]],
    seeds_per_round: int,
) -> RaceRun | None:
    """The tail leader's next fresh seed (the first seed index it has not started; ``tail_leader``: the halving's
    winner, or a configuration of its last round whose mean the winner's tail fell below), once the halving is over
    (``next_runs`` says so) and one configuration is left; None before then or without a winner."""
    leader = tail_leader(field, results, seeds_per_round)
    if leader is None:
        return None
    started = {s for (n, s) in launched if n == leader}
    return RaceRun(leader, next(i for i in itertools.count() if i not in started))


def tail_leader(
    field: Sequence[int], results: Mapping[tuple[int, int], float | None], seeds_per_round: int
) -> int | None:
    """The race's pick once the halving is over (None before, or without a winner): its winner, until the
    winner's tail — its runs past the seeds the halving compared — brings its mean over all its seeds below that
    of a configuration it beat in the last round (over all of that one's fresh seeds: the race's, and any seed
    runs before it); then the one of that round with the best such mean (a failed run: no mean), which takes the
    tail's next seeds in turn.

    Why: the halving ranks by signed ranks so that one collapsed seed in four does not decide a mean; the tail's
    many seeds measure the collapses too. A crowd-prior hour (study seed 3) crowned a linear net that won 3 of the
    last round's 4 seeds (losing the fourth by 0.96) against one averaging 74.96 on them (74.52–75.13); the
    winner's 55 seeds then averaged 74.02 (4 under 70, the lowest 60.44), and it scored 72.70 on 3 fresh seeds
    (one 69.05), its rival 74.68. Of seven stored races this rule changes two picks: that one, and seed 1's (a
    27-seed mean of 74.37 against 74.85 on 4; on the fresh seeds 75.26 for the winner, 75.06 for the rival)."""
    return _leader(_survivors(list(field), results, seeds_per_round), results, seeds_per_round)


def _leader(
    survivors: tuple[list[int], int, bool, list[int]],
    results: Mapping[tuple[int, int], float | None],
    seeds_per_round: int,
) -> int | None:
    """``tail_leader`` from the halving's state (``_survivors``), which ``standings`` has already."""
    alive, rnd, done, last = survivors
    if len(alive) != 1 or not (done or rnd > 0):
        return None
    winner = alive[0]
    if not any(n == winner and s >= rnd * seeds_per_round for (n, s) in results):
        return winner  # no tail yet: the halving's verdict stands

    def mean(number: int) -> float:  # over all its seeds; a failed run (−inf, ``_results``) leaves it no mean
        scores = _results(number, results, [s for (n, s) in results if n == number])
        return statistics.fmean(scores) if scores else -math.inf

    return max(last, key=lambda n: (mean(n), n == winner, -last.index(n)))


def tail_reaches(scores: Iterable[float | None], best: float | None, reach: float = TAIL_REACH_MPH) -> bool:
    """Whether a winner with these fresh-seed ``scores`` (None: a failed run) earns more seeds: its best run is
    within ``reach`` mph of the study's ``best`` single net (None: the study has none)."""
    finite = [float(x) for x in scores if x is not None and math.isfinite(x)]
    return bool(finite) and (best is None or max(finite) >= best - reach)


def incumbent_run(
    candidates: Sequence[Entrant],
    results: Mapping[tuple[int, int], float | None],
    launched: Iterable[tuple[int, int]],
    best: float | None,
    reach: float = TAIL_REACH_MPH,
    max_runs: int | None = None,
) -> RaceRun | None:
    """The incumbent's next fresh seed before the race (SMAC's intensification), or None.

    ``candidates``: the race's possible entrants, best first (``entrants``); ``results`` and ``launched`` as
    ``next_runs``'s; ``best``: the study's best single net. The incumbent is the first candidate whose finished
    fresh runs reach ``best`` (``tail_reaches``: the best of them within ``reach`` mph, as the race winner's tail)
    or, before its first, whose selecting score does: a configuration whose fresh seeds trail the study's best
    leaves the time to the next one, or to the search. ``max_runs`` bounds a configuration's fresh runs before the
    race (None: unbounded): after n runs of one configuration the next beats their best with a chance of about
    1/(n+1), so its worker goes back to the next candidate or the search. Its next seed is the first index it has
    not started, so its runs are the seeds every entrant meets in the race."""
    started = set(launched)
    for e in candidates:
        mine = {s for (n, s) in started if n == e.number}
        if max_runs is not None and len(mine) >= max_runs:
            continue
        scores = [v for (n, _s), v in results.items() if n == e.number]
        if not tail_reaches(scores or [e.value], best, reach):
            continue
        return RaceRun(e.number, next(i for i in itertools.count() if i not in mine))
    return None


def run_result(
    state: str, value: float | None, cause: str | None, retryable: bool = False
) -> tuple[bool, float | None]:
    """(is it a result?, score) of a race run from its trial's state name, value and recorded cause.

    COMPLETE: its score. Stopped by the study's deadline (cause ``deadline…``), failed with a retry
    queued, or unfinished: no result — its seed is not compared, and a resumed race runs it again.
    Any other end (failed; stopped by its own time limit): a result of None, ranking it last.
    """
    if state == "COMPLETE":
        return True, (float(value) if value is not None and math.isfinite(value) else None)
    if state in ("RUNNING", "WAITING") or (cause or "").startswith("deadline") or (state == "FAIL" and retryable):
        return False, None
    return True, None


def standings(
    field: Sequence[int], results: Mapping[tuple[int, int], float | None], seeds_per_round: int = 1
) -> list[RaceStanding]:
    """Every entrant's fresh-seed record, the winner first (the tail's leader where the tail overturned the
    halving, ``tail_leader``).

    The finalists (``_survivors``) come first, ranked on the seeds every finalist with a result has one
    for by their signed ranks against one another, then their mean there (``_paired_order``, as the
    halving): a seed the deadline stopped for one finalist is left out for all instead of deciding the
    race by who finished more runs. Finalists without a result yet, then the others, follow by how far
    they got (fresh seeds finished), then their mean. Ties keep the field's order.
    """
    field = list(field)
    survivors = _survivors(field, results, seeds_per_round)
    alive = survivors[0]
    finalists = set(alive)
    compared = [n for n in alive if any(m == n for (m, _s) in results)]  # a finalist not yet run waits, not blocks
    common = sorted(s for s in {s for (_n, s) in results} if all((n, s) in results for n in compared))
    pairs = {n: _results(n, results, common) for n in compared} if common else {}
    order = {n: i for i, n in enumerate(_paired_order(list(pairs), pairs, field))}
    out = []
    for n in field:
        scores = tuple(v for (m, _s), v in sorted(results.items()) if m == n and v is not None and math.isfinite(v))
        out.append(RaceStanding(n, scores, n in finalists, pairs.get(n)))

    def rank(st: RaceStanding) -> tuple[float, ...]:
        return (-float(st.finalist), order.get(st.number, math.inf), -len(st.scores), -st.mean, field.index(st.number))

    ranked = sorted(out, key=rank)
    leader = _leader(survivors, results, seeds_per_round)
    if leader is not None and leader != ranked[0].number:  # the tail overturned the halving (``tail_leader``)
        ranked.sort(key=lambda st: st.number != leader)
    return ranked


def provisional_standings(
    results: Mapping[tuple[int, int], float | None], min_seeds: int = PROVISIONAL_SEEDS
) -> list[RaceStanding]:
    """Before the race: the configurations with at least ``min_seeds`` fresh-seed results (``results``: (race_of,
    seed index) → score, as for ``standings``; seed runs and the incumbent's runs start before the race), best
    first by their mean, then by more seeds, then the lower trial number.

    No halving has run, so no one is a finalist and there are no paired seeds: configurations hold different
    numbers of seeds (a linear one up to ``seed_soup_runs``, one with hidden layers up to 12), and a mean over
    many beats one over a lucky few only when it is higher. A failed or stopped run (None) is no score and does
    not count toward ``min_seeds``.
    """
    by_config: dict[int, list[tuple[int, float]]] = {}
    for (number, index), score in results.items():
        if score is not None and math.isfinite(score):
            by_config.setdefault(number, []).append((index, float(score)))
    out = [
        RaceStanding(number, tuple(score for _i, score in sorted(runs)))
        for number, runs in by_config.items()
        if len(runs) >= min_seeds
    ]
    return sorted(out, key=lambda st: (-st.mean, -len(st.scores), st.number))
