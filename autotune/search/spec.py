"""A study spec: one TOML file → frozen, typed dataclasses, every table validated before any worker starts.

Five tables, every key optional unless said otherwise::

    [study]       name, ruleset, sampler, pruner, n_trials, timeout_s, seed, storage, max_retries, trial_timeout_s,
                  sampler_startup_trials, max_trial_cost_s, race_fraction, race_configs, race_seeds,
                  balance, balance_values, balance_min_share, denoise, denoise_quantile, max_trial_memory_gb,
                  intensify_share, intensify_runs, refine_share, refine_iterations, refine_learning_rate,
                  refine_runs, refine_start, refine_soups, refine_soup_span, seed_soups, seed_soup_greedy,
                  seed_soup_families, seed_soup_runs, seed_soup_reach, balance_every_draw, linear_twins,
                  linear_twin_span, seed_ensembles, seed_soup_swap_span, linear_neighbours, seed_soup_leader,
                  seed_soup_best, seed_soup_best_span, prior_free_share, seed_soup_views, balance_prune_apart,
                  side_share, max_side_cost_s
    [fixed]       any TrainConfig field (snake_case or DeepTraffic camelCase), e.g. otherAgents = 10
    [space]       name = { low = …, high = …, log = true|false, step = … }  or  name = { choices = [...] }
    [evaluation]  report_points, quick_runs, quick_frames, final_protocol, n_startup_trials, n_warmup_steps
    [resources]   workers, cpus_per_trial, gpus_per_trial
    [ladder]      rungs = [10000, 30000, …]: training length as a budget ladder (``autotune.search.ladder``),
                  min_top, prune_static, min_weight_change, reseed, epsilon_test_grid, epsilon_test_screen_runs
    [warm_start]  crowd = true: enqueue the shipped crowd settings of the study's engine first; study, crowd_twins

Every problem raises ``SpecError`` with ONE line naming the file, the table, the key and the fix
(``study_configs/x.toml: [space] learning_rate: low 0.1 > high 0.01; swap them``), so the CLI can print
it and exit 2 before Ray or a storage is touched. The [space] vocabulary (``PARAMS``) and the
field bounds come from ``sim.fields`` — the one table of DeepTraffic settings — not from a copy here.
This module only parses: turning parameters into configurations is ``autotune.search.space``'s job
(it imports this module, never the other way round), and ``space.check(spec)`` is the last check of a
loaded spec — the corners of its space, with [fixed], must build configurations deepqlearn accepts.

``start_learn_threshold`` must stay below ``experience_size`` (deepqlearn would never learn). When it
is not in [fixed], every trial's value is capped at ``experience_size − 1`` (``space.to_config``):
both can then be searched over the crowd's independent ranges, and the stored config holds the
value actually trained with. A [fixed] threshold is never changed: it must lie below the lowest
experience size the space can draw.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from autotune import OFFICIAL_PROTOCOL, TrainConfig
from autotune.search.refine import PARENT_SPAN
from autotune.search.soup import SOUP_SPAN
from sim import fields
from sim.config import V1_NO_AGENTS, ConfigError, FieldValueError, check, check_other_agents, did_you_mean

__all__ = [
    "SpecError",
    "SAMPLERS",
    "PRUNERS",
    "PARAMS",
    "LAYOUT",
    "StudySection",
    "Dimension",
    "EvaluationSection",
    "ResourcesSection",
    "StudySpec",
    "load_spec",
    "parse_spec",
    "param_bounds",
    "one_minus",
    "shift_epsilon",
    "unshift_epsilon",
    "EPSILON_TEST_SHIFTED",
]

SAMPLERS = ("tpe", "cmaes", "gp", "random", "qmc")
PRUNERS = ("median", "hyperband", "sha", "wilcoxon", "none")
SECTIONS = ("study", "fixed", "space", "evaluation", "resources", "ladder", "warm_start")
LAYOUT = ("n_layers", "neurons", "activation")
"""The hidden-layer layout, fixed-shape: n_layers, then neurons_i and activation_i for every i below the
largest n_layers (the first n_layers are used), so every trial has the same parameters."""
MIN_WEIGHT_CHANGE = 0.01
"""Default ``[ladder] min_weight_change``: 1 % of the weights' norm. Measured on the stored 10k-rung nets of four
benchmark studies on the full space (1,042 trials): every net that scored 74.3 or more at some rung had moved
5–175 % at 10k, except four adagrad nets at learning rates of 1e-8 to 1e-7 (under 0.05 %); 56 % of all trials —
570 of them adagrad at 1e-8 to 1e-5 — moved under 0.1 %. Such a net's score is its initial weights' luck: the
cold studies' leaders were of this kind, and on fresh seeds their settings scored 16 to 73."""
EPSILON_SCREEN_RUNS = (50, 100)
"""Default ``[ladder] epsilon_test_screen_runs``: every grid value on the first 50 of v2-official's 500 runs, the
better half on to 100 (a prefix of the protocol: the same traffic and draws as its first runs; ~1.2 s a 100-run
screen against ~5 s for the whole evaluation); a protocol with 100 runs or fewer (v1-original's 10) on half of them,
then on all (``default_screen_runs``). The site's median over 100 runs
moves ~0.35 mph with the evaluation's random stream (``spread.json``: a net at ε_test 0.01), enough to tell ε_test
0 from 0.3 apart on one net, not 0 from 0.05. The halving: on 36 stored rung nets of two cold studies (the 12
best of each and 6 drawn at random), all five values on 100 runs chose what 50 → the best 2 on 100 chose on 34,
and the two others lost 0.03 and 0.11 mph (mean −0.004) for 250 screened runs instead of 400 (a rung's
evaluation: 750 runs' worth instead of 900); screening on 50 runs alone lost 0.047 on the mean and up to 0.67."""
REFINE_ITERATIONS = 20_000
"""Default ``[study] refine_iterations``: measured on gsurma's setting, 20k-iteration runs from a 74.39 net took
about 10 s each on one core (training and the official score), and their best of 8–10 passed the parent by 0.6–0.8
mph (``autotune.search.refine``)."""
REFINE_LEARNING_RATE = 0.1
"""Default ``[study] refine_learning_rate``: a tenth of the best net's own rate (``autotune.search.refine``)."""
REFINE_RUNS = 32
"""Default ``[study] refine_runs``: measured outside a study, the climbs from gsurma's setting passed their parent
within 8–32 runs or not at all (``bench/refine.py``); in a crowd-prior study 116 runs of one net found nothing
above it."""
SEED_RUN_REACH = PARENT_SPAN
"""Default ``[study] seed_soup_reach`` [mph]: a linear configuration within it of the study's best net takes the
refinement's worker for its fresh seeds (the refinement's own reach of a parent, ``refine.PARENT_SPAN``)."""
SEED_SOUP_REACH = 1.0
"""[mph] A linear configuration's seed soups are scored while its best net is within this of the study's best (or
``seed_soup_reach``, when wider): a soup of seeds scored up to 0.44 above its best one (75.25 → 75.69)."""
BALANCE_MIN_SHARE = 0.2
"""Default ``[study] balance_min_share``: each value of a balanced parameter (3 trainer methods) at least a fifth
of the sampled trials, so the sampler's favourite keeps up to 60 %."""
BALANCEABLE_SAMPLERS = ("tpe", "random")
"""Samplers ``[study] balance`` works with: their model is the history a value's subset restricts."""
FRACTIONS = ("learning_steps_burnin_fraction", "learning_steps_total_fraction")
"""Ladder studies: ε's burn-in and decay length as fractions of the rung's budget (``autotune.search.ladder``)."""
LR_X_INPUTS = "learning_rate_x_inputs"
"""The learning rate searched as learning_rate × the net's input width (``net_inputs``). One sgd step changes a
first-layer output by about learning_rate × the sum of the squared inputs, which grows with the width, so the rate
at which training diverges falls as the view widens. Measured (30k iterations, sgd, one seed): a linear net on
1,135 inputs diverges at 3e-4 and learns at 1e-4, one on 4 inputs learns at 1e-2; relu layers on 1,135 inputs
diverge at 1e-3. In learning_rate a good value moves with the view, a diagonal ridge for the sampler; per input
the ridge is much flatter (a cold study's best sgd nets: 0.003–0.004 on 1,264 to 5,594 inputs), though momentum
and the other settings still move its edge."""
EPSILON_TEST_SHIFTED = "epsilon_test_time_shifted"
EPSILON_TEST_SHIFT = 0.005
"""``[space] epsilon_test_time_shifted``: ε_test searched as ε_test + 0.005 on a log scale (0 stays reachable, at
0.005), for a study that should spend its draws on nets that drive greedily. Uniform on [0, 0.9] (paper.toml), 89 %
of the draws make the car act at random at least 10 % of the time at test; on [0.005, 0.905] shifted, about 58 % of
them fall below 0.1. The crowd drove greedily (ε_test 0 in 139 of 162 submissions) and every rung of the last
benchmark studies that scored 74.5 or more had ε_test below 0.08, while the cold studies' samplers stayed at 0.4 or
more (nets that score about 73 without learning). Measured, it did not move a cold study to greedy nets: after its
startup only 9 of 146 draws had ε_test below 0.1, because a greedy net scored 13–67 (median 58) at the 10k rung,
where a mostly random one scores 70–73, and its best net (74.27 at 30 minutes, study seed 0; 74.14 uniform) had
ε_test 0.40. Without the 10k rung (30k first) the study stayed on greedy nets that had learned little (72.96). So
paper.toml keeps the uniform scale."""
# [space] names that set a TrainConfig field of another name (sampling coordinates)
_FIELD_OF = {
    "one_minus_gamma": "gamma", "n_layers": "layers", "neurons": "layers", "activation": "layers",
    "learning_steps_burnin_fraction": "learning_steps_burnin", "learning_steps_total_fraction": "learning_steps_total",
    LR_X_INPUTS: "learning_rate", EPSILON_TEST_SHIFTED: "epsilon_test_time",
}  # fmt: skip
PARAMS: tuple[str, ...] = (
    *(f.name for f in fields.FIELDS if f.name != "gamma" and f.group != "site"),
    "one_minus_gamma",
    LR_X_INPUTS,
    EPSILON_TEST_SHIFTED,
    *FRACTIONS,
    *LAYOUT,
)
"""Every name a [space] table may search (the shared search-space vocabulary): every setting of ``sim.fields`` but
the ruleset ([study]) and gamma (searched as ``one_minus_gamma``), the learning rate per input, ε_test shifted
onto a log scale, the ladder's fractions, and the layout."""

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
_TRAIN_FIELDS = tuple(f.name for f in dataclasses.fields(TrainConfig))
_FIXED_KEYS = (
    *(n for n in _TRAIN_FIELDS if n != "ruleset"),
    *(alias for alias, name in fields.ALIASES.items() if name != "ruleset"),
)
_DEFAULT_TRIAL_TIMEOUT_S = 1800.0


def one_minus(value: float) -> float:
    """``1 − value`` to 15 significant digits: gamma ↔ ``one_minus_gamma``, either way (0.3 stays 0.3)."""
    return float(f"{1.0 - value:.15g}")


def shift_epsilon(epsilon_test_time: float) -> float:
    """ε_test → ``epsilon_test_time_shifted``, to 12 decimals (so 0.02 maps to 0.025 and back to 0.02)."""
    return round(epsilon_test_time + EPSILON_TEST_SHIFT, 12)


def unshift_epsilon(shifted: float) -> float:
    """``epsilon_test_time_shifted`` → ε_test, to 12 decimals (a fixed grid, so the two maps are each other's
    inverse on it); never below 0."""
    return max(0.0, round(shifted - EPSILON_TEST_SHIFT, 12))


class SpecError(ConfigError):
    """A study spec is invalid; the one-line message names the file, the table, the key and the fix."""


# --------------------------------------------------------------------------------------------
# the dataclasses
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class StudySection:
    """[study]: what to optimise with which algorithms, for how long, stored where."""

    name: str
    """Optuna study name; also the folder runs/<name>/ of the embedded storage (default: the file's stem)."""
    ruleset: str = "v2"
    """Engine rules every trial trains and is scored in: 'v2' (2018 site) or 'v1' (2017 engine)."""
    sampler: str = "tpe"
    """Optuna sampler: tpe, cmaes, gp, random or qmc (all seeded with ``seed``)."""
    pruner: str = "median"
    """Optuna pruner on the intermediate quick scores: median, hyperband, sha, wilcoxon or none."""
    n_trials: int | None = None
    """Trials to finish (COMPLETE, PRUNED or FAIL) before the study stops; None: until timeout_s."""
    timeout_s: float | None = None
    """Wall-time budget [s] after which no new trial starts; None: until n_trials."""
    seed: int = 0
    """Seed of the sampler; trial i trains with a seed derived from it (explicit seeds only)."""
    storage: str = ""
    """'' = embedded journal file runs/<name>/journal.log; else a journal file path or an SQLAlchemy URL."""
    max_retries: int = 2
    """How many times a FAILed trial (worker died, timeout) is re-run with the same settings."""
    trial_timeout_s: float = _DEFAULT_TRIAL_TIMEOUT_S
    """Wall-time limit [s] of one trial (training + evaluations); beyond it the trial is PRUNED (cause: timeout)."""
    sampler_startup_trials: int = 10
    """Trials the sampler draws at random before modelling (TPE/GP/CMA-ES ``n_startup_trials``; not the pruner's)."""
    max_trial_cost_s: float | None = None
    """Cost cap [s]: a sampled draw whose ladder up to [ladder] min_top (training + scoring) is predicted to cost
    more is refused and redrawn; a trial's top rung is the highest whose rungs fit under it (None:
    trial_timeout_s)."""
    race_fraction: float = 0.25
    """Last fraction of timeout_s spent racing the best configurations over fresh seeds (0: no race)."""
    race_configs: int = 4
    """Configurations entering the seed race (the best distinct ones by value)."""
    race_seeds: int = 1
    """Fresh seeds per configuration per race round (the same seeds for every configuration)."""
    balance: tuple[str, ...] = ()
    """[space] parameters whose every value (an integer one's named in balance_values) keeps balance_min_share of
    the sampled trials (``autotune.search.balance``; e.g. ["method"]: TPE cannot starve a trainer method)."""
    balance_min_share: float = BALANCE_MIN_SHARE
    """Share of the sampled trials each value of a balanced parameter gets at least (≤ 1 / its choices)."""
    balance_values: tuple[tuple[str, tuple[Any, ...]], ...] = ()
    """For a balanced parameter, the values given that share (default: every choice); an integer one (the layer
    count, lanes_side) is balanced only on the values named here (e.g. {n_layers = [1]}: a fifth of the draws with
    one hidden layer; {lanes_side = [6]}: a fifth seeing the whole road, with their own γ, ε floor and rate)."""
    denoise: bool = False
    """Show the sampler each finished trial at a regression forest's score for its parameters at the ladder's
    min_top, not at its own noisy score (``autotune.search.denoise``; TPE and random samplers)."""
    denoise_quantile: float | None = None
    """With denoise: value each trial at this quantile of its neighbourhood's scores (0.9: a region's upper tail,
    which a best single net is drawn from), not their mean (None)."""
    max_trial_memory_gb: float | None = None
    """Memory cap [GB] of one rung (its replay memory and net, ``cost.rung_memory_bytes``): a draw whose rungs up
    to [ladder] min_top need more is refused and redrawn, and no trial climbs to a rung that does (None: 60 % of
    the driver machine's memory shared among the workers)."""
    intensify_share: float = 0.0
    """Share of the workers that, before the seed race, retrain the incumbent on the race's fresh seeds
    (``racing.incumbent_run``; at least one worker when above 0, never all of them; 0: the race alone retrains)."""
    intensify_runs: int | None = None
    """With intensify_share: the most fresh runs one configuration gets before the race (None: while its runs reach
    the study's best net); the next run of a configuration run n times beats their best with chance ≈ 1/(n+1)."""
    refine_share: float = 0.0
    """Share of the workers that train on from the study's best single net (``autotune.search.refine``; at least one
    worker when above 0, never all of them, and not while the seed race runs its rounds; 0: no refinement)."""
    refine_iterations: int = REFINE_ITERATIONS
    """Length [iterations] of one refinement run: a training on from the best net's weights at its own settings,
    exploring at its ε_min after ``refine.EXPLORE_DECISIONS`` decisions."""
    refine_learning_rate: float = REFINE_LEARNING_RATE
    """A refinement run's learning rate as a multiple of the rate its lineage's fresh training used (sgd, adagrad;
    adadelta has none): a run refined from a refinement run keeps its parent's rate."""
    refine_runs: int = REFINE_RUNS
    """The most refinement runs one net gets (0: no bound, while it is the best); then its worker trains on from the
    next best net within ``refine.PARENT_SPAN`` mph of the best (a refinement run only if it beat its parent), or goes
    back to the search."""
    refine_start: float = 0.0
    """Share of the study's budget — its time (``timeout_s``), else its trials (``n_trials``) — the search has to
    itself before refinement starts (0: from the first stored net); with the crowd prior, refinement starts once
    the crowd's settings have all started."""
    refine_soups: tuple[int, ...] = ()
    """Sizes k of the weight soups scored from each parent's refinement runs (``autotune.search.soup``): whenever a
    parent's best k runs form a new set, a refinement worker scores the mean of their weights (no training); ()
    none."""
    refine_soup_span: float = SOUP_SPAN
    """mph below its parent's score within which a refinement run is a soup ingredient (a soup with two collapsed
    runs among its 4 scored 73.37 against its parent's 75.29); of a seed soup, below its configuration's best net."""
    seed_soups: tuple[int, ...] = ()
    """Sizes k of the seed soups of each configuration without hidden layers (``autotune.search.ensemble``): whenever
    its best k fresh-seed nets form a new set, any free worker scores the mean of their weights — exactly their
    Q-values' mean — with no training; () none."""
    seed_soup_greedy: bool = False
    """With seed_soups: once a linear configuration's best-k soups are scored, its greedy soup — the best set so far
    plus one more of its nets within refine_soup_span of its best, kept when it scores higher (``ensemble.
    greedy_step``)."""
    seed_soup_families: bool = False
    """With seed_soups: soup the nets of every linear configuration with one view, traffic, temporal window and
    ε_test together (a configuration's linear twins, trained by other methods), not each configuration's alone."""
    seed_soup_runs: int = 0
    """With seed_soups and refine_share: the most fresh seeds a linear configuration near the study's best gets on
    the refinement's workers before the race, for its soups (0: only the race's)."""
    seed_soup_reach: float = SEED_RUN_REACH
    """With seed_soup_runs: mph below the study's best net within which a linear configuration's level (its best seed
    or soup) gets fresh seeds — beyond 0.5 only every other run of the refinement's worker, refinement runs the
    others — and its soups are scored (within 1.0 at least)."""
    balance_every_draw: bool = False
    """With balance: every draw, not only a forced one, takes the parameters a balanced value governs (a linear
    net's trainer method; a method's learning rate) from the trials sharing its values, and a balanced parameter
    keeps its share within them (each method a share of the linear draws); false: only forced draws."""
    linear_twins: tuple[tuple[str, tuple[float, ...]], ...] = ()
    """Trainer methods and learning rates per input (``learning_rate_x_inputs``) for the linear twins of each new
    best configuration: its parameters with no hidden layer, once per (method, rate), enqueued as ordinary trials
    (``autotune.search.twins``); () none."""
    linear_twin_span: float = 0.0
    """With linear_twins: mph below the best configuration (by its best net at min_top or above) within which every
    configuration gets its twins too, once, best first; 0: only each new best."""
    seed_ensembles: bool = False
    """With seed_soups: configurations with hidden layers get seeds and seed soups too, each soup their nets side by
    side in one wider net whose Q-values are the mean of theirs (``autotune.convnet.stack``); false: linear only."""
    seed_soup_swap_span: float = 0.0
    """With seed_soup_greedy: mph below a linear configuration's best net within which its greedy soup, once no net
    added to its best set scores higher, goes on by swaps — one member replaced, left out, or a lower net added
    (``ensemble.greedy_step``); 0: additions only."""
    linear_neighbours: bool = False
    """With seed_soups: whenever a linear configuration's net (its own or its seed soup) is the study's best, or it
    leads by mean over its fresh seeds (3 or more), its neighbours — its parameters with the temporal window dropped,
    or one of γ, the view or the rate moved a step (``twins.NEIGHBOUR_STEPS``) — are enqueued once, each trained like
    a linear twin; false: none."""
    seed_soup_leader: bool = False
    """With seed_soup_runs: the configuration that leads by mean over its fresh seeds (3 or more) takes every other
    run of the refinement's worker, and any run it would leave idle, up to its seed_soup_runs (12 with hidden
    layers); false: seeds go by level alone (each new linear configuration's probe seeds first)."""
    seed_soup_best: bool = False
    """With seed_soup_runs: the configurations whose nets make the study's best net (a seed soup's ingredients, or a
    fresh training's own) take every other run of the refinement's worker, the best of them by mean over its nets
    first, up to their seed_soup_runs; with seed_soup_leader too, the leader by mean when none of them can take one."""
    seed_soup_best_span: float = 0.0
    """With seed_soup_best: mph below the study's best net within which another family's best net (a fresh training
    or a seed soup of linear configurations with one view, traffic, temporal window and ε_test) makes its
    configurations share those turns — every other one goes to such a family, the fewest seeds first; 0: none."""
    prior_free_share: float = 0.0
    """With a prior (``--warm-start crowd`` or ``STUDY``): the share of the sampled draws that come from a second
    sampler whose history is only its own draws and the trials made from them, halved among themselves
    (``autotune.search.prior``), and whose best configuration gets its linear twins and neighbours too; 0: every
    draw sees the whole history."""
    seed_soup_views: bool = False
    """With seed_soup_families: linear configurations of any view in one family (traffic, temporal window and
    ε_test alike): a soup's nets are moved onto the union of their views (``autotune.convnet.widen``: the same
    Q-values), so a configuration's view neighbours soup with it."""
    balance_prune_apart: tuple[str, ...] = ()
    """Balanced parameters whose floored values' trials the pruner judges among themselves (a whole-road view's
    draws halved against whole-road draws, not the crowd's region; ``balance.ApartPruner``), every other trial
    among the rest; (): all together."""
    side_share: float = 1.0
    """With linear_twins or linear_neighbours: the most of the workers' time so far that twins and neighbours may
    have taken when the next one starts; the rest wait, the newest parent's first (``driver.next_side_entry``),
    while the search draws; 1: each starts as soon as it is enqueued, before the sampler's next draw."""
    max_side_cost_s: float | None = None
    """With linear_twins or linear_neighbours: the cost cap [s] of one twin's or neighbour's training, priced alone
    at its parent's budget (it climbs no ladder below it; over the cap it trains at the highest rung that fits);
    None: max_trial_cost_s, which caps a sampled trial's whole ladder."""

    @property
    def cost_cap_s(self) -> float:
        """The cap the cost gate uses [s]: max_trial_cost_s, else the trial limit."""
        return self.max_trial_cost_s if self.max_trial_cost_s is not None else self.trial_timeout_s

    @property
    def side_cost_cap_s(self) -> float:
        """The cap of one linear twin's or neighbour's training [s]: max_side_cost_s, else the cost gate's cap."""
        return self.max_side_cost_s if self.max_side_cost_s is not None else self.cost_cap_s

    def cap_s(self, side: bool = False) -> float:
        """The cost cap of one draw: ``side_cost_cap_s`` for a twin or neighbour (``side``), else ``cost_cap_s``."""
        return self.side_cost_cap_s if side else self.cost_cap_s

    def cap_key(self, side: bool = False) -> str:
        """The [study] key that sets ``side_cost_cap_s`` (``side``) or ``cost_cap_s``, for a refusal's message."""
        if side and self.max_side_cost_s is not None:
            return "max_side_cost_s"
        return "max_trial_cost_s" if self.max_trial_cost_s is not None else "trial_timeout_s"


@dataclasses.dataclass(frozen=True)
class Dimension:
    """One searched parameter in Optuna's terms: a numeric range or a list of choices."""

    name: str
    """A name of ``PARAMS`` (e.g. 'learning_rate', 'one_minus_gamma', 'neurons')."""
    kind: str
    """'int' (suggest_int), 'float' (suggest_float) or 'categorical' (suggest_categorical)."""
    low: float | None = None
    """Smallest value (inclusive), in the parameter's own unit; None for categorical."""
    high: float | None = None
    """Largest value (inclusive); None for categorical."""
    log: bool = False
    """Sample uniformly in log(value) (low must be > 0)."""
    step: float | None = None
    """Grid step from low (not with log); None: continuous (floats) or 1 (ints)."""
    choices: tuple[Any, ...] = ()
    """The categories (categorical only)."""

    def to_dict(self) -> dict[str, Any]:
        """The TOML entry ({low, high, log[, step]} or {choices}); ``parse_spec`` reads it back."""
        if self.kind == "categorical":
            return {"choices": list(self.choices)}
        out: dict[str, Any] = {"low": self.low, "high": self.high, "log": self.log}
        if self.step is not None:
            out["step"] = self.step
        return out


@dataclasses.dataclass(frozen=True)
class EvaluationSection:
    """[evaluation]: the intermediate (quick) scores the pruner sees and the final, official score."""

    report_points: int = 10
    """Intermediate scores per trial, at (k+1)/report_points of training, k = 0 … report_points−1."""
    quick_runs: int = 20
    """Runs averaged into one intermediate score (the curve is noisy: more runs, steadier pruning)."""
    quick_frames: int = 2000
    """Frames per quick run [frames] (the official v2 runs are 2,000 frames long too)."""
    final_protocol: str = ""
    """Protocol of the objective: the ruleset's official one (v2-official, v1-original); '' = that one."""
    n_startup_trials: int = 5
    """Trials that finish before any pruning (median/wilcoxon pruners)."""
    n_warmup_steps: int = 3
    """Report steps of a trial before it may be pruned (median; sha/hyperband min_resource = this + 1)."""


@dataclasses.dataclass(frozen=True)
class ResourcesSection:
    """[resources]: how many trials run at once and what each one holds."""

    workers: int
    """Long-lived workers = trials in parallel (default: the machine's CPUs / cpus_per_trial)."""
    cpus_per_trial: float = 1.0
    """CPUs a worker reserves (Ray num_cpus); training is single-threaded."""
    gpus_per_trial: float = 0.0
    """GPUs a worker reserves (Ray num_gpus; fractions share one GPU)."""


@dataclasses.dataclass(frozen=True)
class WarmStartSection:
    """[warm_start]: what the sampler knows before its first draw."""

    crowd: bool = False
    """Enqueue the shipped crowd settings of the study's engine (each repository's best-scored version, mapped
    into the space; every one is trained and measured, no claimed score becomes a value)."""
    study: str = ""
    """Copy this earlier study's measured trials (same storage) into the sampler's history, no retraining."""
    crowd_twins: bool = False
    """With crowd and [study] linear_twins: each crowd setting without hidden layers also gets its linear twins (its
    settings at each listed method and rate per input), trained at the ladder's top rung the cost cap affords: such
    a net was trained on loaded weights (a fine-tuning rate, its last session's trainIterations), so its own setting
    does not learn from a fresh start; false: none."""


@dataclasses.dataclass(frozen=True)
class StudySpec:
    """A validated study: [study], [fixed], [space], [evaluation] and [resources]."""

    study: StudySection
    """What to optimise with which algorithms, for how long, stored where."""
    fixed: tuple[tuple[str, Any], ...]
    """(TrainConfig field, value) pairs every trial uses, normalised (snake_case, layers as a crowd string)."""
    space: tuple[Dimension, ...]
    """The searched parameters, in file order."""
    evaluation: EvaluationSection
    """Intermediate and final scoring."""
    resources: ResourcesSection
    """Workers and what each holds."""
    ladder: tuple[int, ...] = ()
    """[ladder] rungs [iterations]: each trial climbs them (fresh training per rung); () = one training."""
    ladder_min_top: int = 0
    """[ladder] min_top [iterations]: the rung every sampled draw must afford (the cost gate prices the ladder up
    to it); above it a trial climbs while its predicted cost fits the cap. 0 = the last rung (the whole ladder)."""
    ladder_prune_static: bool = True
    """[ladder] prune_static: prune a trial at a rung whose policy is static — one action in ≥ 99 % of the net's
    greedy choices (with an ε_test grid, judged on the screens first: such a net is not scored officially), or the
    previous rung's official score to the digit — and tell samplers it is infeasible."""
    ladder_min_weight_change: float = MIN_WEIGHT_CHANGE
    """[ladder] min_weight_change [fraction of ‖θ₀‖]: prune a trial at a rung whose training moved the net's weights
    less than this from their initialisation (it does not learn; not scored officially), and tell samplers it is
    infeasible; 0 = off."""
    ladder_reseed: bool = False
    """[ladder] reseed: train each rung below a trial's top from a seed of its own (``ladder.rung_seed``), so
    successive halving meets every configuration on a new seed per rung; false (the default when the key is left
    out): every rung from the trial's seed."""
    ladder_epsilon_grid: tuple[float, ...] = ()
    """[ladder] epsilon_test_grid: ε_test is chosen per trained net, not searched: each rung's net is screened at
    these values (on ``ladder_epsilon_screen_runs`` of the official runs) and scored officially at the best; ()
    = off (ε_test is whatever the trial's config says)."""
    ladder_epsilon_screen_runs: tuple[int, ...] = EPSILON_SCREEN_RUNS
    """[ladder] epsilon_test_screen_runs: the official protocol's first runs of each stage of the screens: every
    grid value on the first, the better half of them on to the next (``autotune.screen_epsilons``)."""
    warm_start: WarmStartSection = WarmStartSection()
    """Crowd prior / earlier study copied into the sampler's history."""
    source: str = ""
    """Where the spec came from (the TOML path), used in error messages."""

    # -- views ----------------------------------------------------------------------------
    @property
    def fixed_values(self) -> dict[str, Any]:
        """[fixed] as a dict of TrainConfig field → value."""
        return dict(self.fixed)

    @property
    def dimensions(self) -> dict[str, Dimension]:
        """[space] as a dict name → Dimension."""
        return {d.name: d for d in self.space}

    @property
    def searches_layout(self) -> bool:
        """True when the hidden layers are searched (n_layers, neurons, activation)."""
        return any(d.name in LAYOUT for d in self.space)

    @property
    def ruleset(self) -> str:
        """The study's engine rules ('v1' or 'v2')."""
        return self.study.ruleset

    @property
    def max_layers(self) -> int:
        """The largest n_layers the space can draw (the fixed-shape layout has this many neurons_i/activation_i)."""
        d = self.dimensions.get("n_layers")
        if d is None:
            return 0
        return int(max(d.choices)) if d.kind == "categorical" else int(d.high or 0)

    @property
    def race_min_budget(self) -> int:
        """Iterations below which a net does not enter the seed race: the gated top (``min_top``, else the last
        rung); 0 without a ladder. Lower rungs only screen (why: ``driver.race_entry``)."""
        return self.ladder[self.gated_rungs - 1] if self.ladder else 0

    @property
    def ladder_epsilon_screen_share(self) -> float:
        """The share of the official protocol's runs an ε_test screen evaluates, on average over the grid's values
        (the halving's later stages screen only some of them); 0 without a grid."""
        if not self.ladder_epsilon_grid:
            return 0.0
        from autotune.learner.official import screen_survivors

        stages = self.ladder_epsilon_screen_runs
        kept = screen_survivors(len(self.ladder_epsilon_grid), len(stages))
        runs = sum(k * (b - a) for k, a, b in zip(kept, (0, *stages), stages, strict=False))
        return runs / len(self.ladder_epsilon_grid) / self._official_runs

    @property
    def ladder_epsilon_carried_share(self) -> float:
        """The share of the official protocol's runs the chosen screen ran (its last stage), which the official
        evaluation carries on from; 0 without a grid."""
        return self.ladder_epsilon_screen_runs[-1] / self._official_runs if self.ladder_epsilon_grid else 0.0

    @property
    def _official_runs(self) -> int:
        from sim.protocols import PROTOCOLS

        return PROTOCOLS[OFFICIAL_PROTOCOL[self.ruleset]].runs

    @property
    def gated_rungs(self) -> int:
        """How many of the ladder's rungs the cost gate prices a draw at (all of them unless ``min_top``)."""
        if not self.ladder_min_top:
            return len(self.ladder)
        return self.ladder.index(self.ladder_min_top) + 1

    # -- (de)serialisation ------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready tables (stored as a study user attr); ``parse_spec`` rebuilds the same spec."""
        ladder: dict[str, Any] = {"rungs": list(self.ladder)}
        if self.ladder_min_top:  # left out at its default, so a study stored before the key existed still matches
            ladder["min_top"] = self.ladder_min_top
        if not self.ladder_prune_static:  # likewise
            ladder["prune_static"] = False
        if self.ladder_min_weight_change != MIN_WEIGHT_CHANGE:  # likewise
            ladder["min_weight_change"] = self.ladder_min_weight_change
        if self.ladder_reseed:  # likewise (a study stored before the key existed trained every rung from one seed)
            ladder["reseed"] = True
        if self.ladder_epsilon_grid:  # likewise
            ladder["epsilon_test_grid"] = list(self.ladder_epsilon_grid)
            stages = self.ladder_epsilon_screen_runs  # one stage as a number, as stored before the halving
            ladder["epsilon_test_screen_runs"] = stages[0] if len(stages) == 1 else list(stages)
        study = dataclasses.asdict(self.study)
        values = study.pop("balance_values")
        if values:  # left out when empty, so a study stored before the key existed still matches
            study["balance_values"] = {name: list(v) for name, v in values}
        twins = study.pop("linear_twins")
        if twins:  # likewise
            study["linear_twins"] = {method: list(rates) for method, rates in twins}
        optional = ("linear_twin_span", "seed_soup_families", "seed_ensembles", "seed_soup_swap_span",
                    "linear_neighbours", "seed_soup_leader", "seed_soup_best", "seed_soup_best_span",
                    "prior_free_share", "seed_soup_views", "balance_prune_apart")  # fmt: skip
        for key in optional:  # likewise
            if not study[key]:
                del study[key]
        if study["side_share"] == 1.0:  # likewise (its default: no cap)
            del study["side_share"]
        if study["max_side_cost_s"] is None:  # likewise
            del study["max_side_cost_s"]
        warm = dataclasses.asdict(self.warm_start)
        if not warm["crowd_twins"]:  # likewise
            del warm["crowd_twins"]
        return {
            "study": study,
            "fixed": dict(self.fixed),
            "space": {d.name: d.to_dict() for d in self.space},
            "evaluation": dataclasses.asdict(self.evaluation),
            "resources": dataclasses.asdict(self.resources),
            **({"ladder": ladder} if self.ladder else {}),
            "warm_start": warm,
        }

    def with_overrides(
        self,
        *,
        storage: str | None = None,
        name: str | None = None,
        workers: int | None = None,
        n_trials: int | None = None,
        timeout_s: float | None = None,
        warm_start: str | None = None,
    ) -> StudySpec:
        """A copy with command-line overrides applied (None: keep); each is validated like the TOML key."""
        study = self.study
        resources = self.resources
        src = self.source or "spec"
        if storage is not None:
            study = dataclasses.replace(study, storage=_check_str(storage, "--storage"))
        if name is not None:
            study = dataclasses.replace(study, name=_check_name(name, "--study-name"))
        if n_trials is not None:
            study = dataclasses.replace(
                study, n_trials=_pos_int(n_trials, f"--n-trials (overrides {src} [study] n_trials)")
            )
        if timeout_s is not None:
            study = dataclasses.replace(
                study, timeout_s=_pos_float(timeout_s, f"--timeout (overrides {src} [study] timeout_s)")
            )
        if workers is not None:
            resources = dataclasses.replace(
                resources, workers=_pos_int(workers, f"--workers (overrides {src} [resources] workers)")
            )
        warm = self.warm_start
        if warm_start is not None:
            if warm_start == "crowd":
                warm = dataclasses.replace(warm, crowd=True)
            else:
                warm = dataclasses.replace(warm, study=_check_name(warm_start, "--warm-start (crowd or a study name)"))
        return dataclasses.replace(self, study=study, resources=resources, warm_start=warm)


# --------------------------------------------------------------------------------------------
# loading
# --------------------------------------------------------------------------------------------


def load_spec(path: str | Path) -> StudySpec:
    """Read and validate a study TOML (``SpecError`` with a one-line message on any problem)."""
    p = Path(path)
    source = str(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SpecError(f"{source}: file not found; check the path") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SpecError(f"{source}: cannot read the file ({_one_line(str(exc))}); check the path") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(_toml_error(source, text, exc)) from None
    return parse_spec(data, source=source, default_name=p.stem)


def parse_spec(data: Mapping[str, Any], *, source: str = "spec", default_name: str | None = None) -> StudySpec:
    """Validate the tables of a study (a parsed TOML or ``StudySpec.to_dict()``) into a ``StudySpec``."""
    for key, value in data.items():
        if key not in SECTIONS:
            if not isinstance(value, Mapping):
                owner = next((s for s in _SECTION_KEYS if key in _SECTION_KEYS[s]), None)
                owner = owner or ("fixed" if key in _FIXED_KEYS else None)
                fix = f"move it under [{owner}]" if owner else f"put it in one of the tables {', '.join(SECTIONS)}"
                raise SpecError(f"{source}: {key}: a key outside any table; {fix}")
            raise SpecError(f"{source}: [{key}]: unknown table{_hint(key, SECTIONS)} (tables: {', '.join(SECTIONS)})")
        if not isinstance(value, Mapping):
            raise SpecError(f"{source}: [{key}]: must be a table, got {value!r}; write it as [{key}] with keys below")
    study = _parse_study(data.get("study", {}), source, default_name)
    evaluation = _parse_evaluation(data.get("evaluation", {}), source, study.ruleset, ladder="ladder" in data)
    resources = _parse_resources(data.get("resources", {}), source)
    space = tuple(_parse_dimension(name, entry, source, study.ruleset) for name, entry in data.get("space", {}).items())
    ladder, min_top, prune_static, min_change, reseed, grid, screen_runs = _parse_ladder(
        data.get("ladder"), source, study.ruleset
    )
    warm = _parse_warm_start(data.get("warm_start", {}), source)
    if warm.crowd_twins and not study.linear_twins:
        raise SpecError(
            f"{source}: [warm_start] crowd_twins: twins the crowd's linear settings, but [study] "
            "linear_twins is empty; set linear_twins (e.g. { adagrad = [3.0] }), or remove crowd_twins"
        )
    fixed = _parse_fixed(data.get("fixed", {}), source, study.ruleset, {d.name for d in space})
    spec = StudySpec(
        study, fixed, space, evaluation, resources, ladder, min_top, prune_static, min_change, reseed, grid,
        screen_runs, warm, source,
    )  # fmt: skip
    _check_combination(spec)
    return spec


_SECTION_KEYS: dict[str, tuple[str, ...]] = {
    "study": tuple(f.name for f in dataclasses.fields(StudySection)),
    "evaluation": tuple(f.name for f in dataclasses.fields(EvaluationSection)),
    "resources": tuple(f.name for f in dataclasses.fields(ResourcesSection)),
    "ladder": (
        "rungs",
        "min_top",
        "prune_static",
        "min_weight_change",
        "reseed",
        "epsilon_test_grid",
        "epsilon_test_screen_runs",
    ),  # fmt: skip
    "warm_start": tuple(f.name for f in dataclasses.fields(WarmStartSection)),
}


def _parse_study(table: Mapping[str, Any], src: str, default_name: str | None) -> StudySection:
    _check_keys(table, "study", src)
    where = _Where(src, "study")
    name = table.get("name", default_name)
    if name is None:
        raise SpecError(f'{src}: [study] name: missing; add name = "my-study"')
    name = _check_name(name, f"{src}: [study] name")
    ruleset = table.get("ruleset", "v2")
    try:
        check(fields.field("ruleset"), ruleset)
    except FieldValueError as exc:
        raise where.error("ruleset", exc.problem, 'write ruleset = "v2" (2018 site) or "v1" (2017 engine)') from None
    sampler = table.get("sampler", "tpe")
    if sampler not in SAMPLERS:
        raise where.error(
            "sampler",
            f"unknown sampler {sampler!r}{_hint(str(sampler), SAMPLERS)}",
            f"use one of {', '.join(SAMPLERS)}",
        )
    pruner = table.get("pruner", "median")
    if pruner not in PRUNERS:
        raise where.error(
            "pruner", f"unknown pruner {pruner!r}{_hint(str(pruner), PRUNERS)}", f"use one of {', '.join(PRUNERS)}"
        )
    n_trials = table.get("n_trials")
    if n_trials is not None:
        n_trials = _pos_int(n_trials, f"{src}: [study] n_trials")
    timeout_s = table.get("timeout_s")
    if timeout_s is not None:
        timeout_s = _pos_float(timeout_s, f"{src}: [study] timeout_s")
    if n_trials is None and timeout_s is None:
        raise where.error("n_trials", "neither n_trials nor timeout_s is set, so the study would never end",
                          "set n_trials = 100 or timeout_s = 3600 (or both)")  # fmt: skip
    seed = _int(table.get("seed", 0), f"{src}: [study] seed", 0, 2**32 - 1)
    storage = _check_str(table.get("storage", ""), f"{src}: [study] storage")
    max_retries = _int(table.get("max_retries", 2), f"{src}: [study] max_retries", 0, 100)
    trial_timeout_s = _pos_float(
        table.get("trial_timeout_s", _DEFAULT_TRIAL_TIMEOUT_S), f"{src}: [study] trial_timeout_s"
    )
    d = StudySection(name)
    startup = _int(table.get("sampler_startup_trials", d.sampler_startup_trials),
                   f"{src}: [study] sampler_startup_trials", 0, 1_000_000)  # fmt: skip
    cap = table.get("max_trial_cost_s")
    if cap is not None:
        cap = _pos_float(cap, f"{src}: [study] max_trial_cost_s")
    race = _float(table.get("race_fraction", d.race_fraction), f"{src}: [study] race_fraction", 0.0, 0.9)
    race_configs = _int(table.get("race_configs", d.race_configs), f"{src}: [study] race_configs", 2, 1000)
    race_seeds = _int(table.get("race_seeds", d.race_seeds), f"{src}: [study] race_seeds", 1, 100)
    balance = table.get("balance", [])
    if not isinstance(balance, list | tuple) or not all(isinstance(b, str) for b in balance):
        raise where.error("balance", f"must be a list of categorical [space] parameters, got {balance!r}",
                          'write balance = ["method"]')  # fmt: skip
    if len(set(balance)) != len(balance):
        raise where.error("balance", f"names a parameter twice: {list(balance)!r}", "name each parameter once")
    values = table.get("balance_values", {})
    if not isinstance(values, dict) or not all(isinstance(v, list) and v for v in values.values()):
        raise where.error("balance_values", f"must be a table of non-empty lists of values, got {values!r}",
                          "write balance_values = { n_layers = [1] }")  # fmt: skip
    _check_balanced("balance_values", values, balance, where)
    for key in values:
        if len(set(map(repr, values[key]))) != len(values[key]):
            raise where.error("balance_values", f"{key} names a value twice: {values[key]!r}", "name each value once")
    share = _float(table.get("balance_min_share", d.balance_min_share), f"{src}: [study] balance_min_share", 0.0, 1.0)
    if share <= 0.0:
        raise where.error("balance_min_share", f"must be above 0, got {share}",
                          "e.g. balance_min_share = 0.2 (each value at least a fifth of the draws)")  # fmt: skip
    denoise = table.get("denoise", d.denoise)
    if not isinstance(denoise, bool):
        raise where.error("denoise", f"must be true or false, got {denoise!r}", "write denoise = true")
    quantile = table.get("denoise_quantile")
    if quantile is not None:
        quantile = _float(quantile, f"{src}: [study] denoise_quantile", 0.0, 1.0)
        if not 0.0 < quantile < 1.0:
            raise where.error("denoise_quantile", f"must lie strictly between 0 and 1, got {quantile}",
                              "e.g. denoise_quantile = 0.9 (the upper tail), or leave it out (the mean)")  # fmt: skip
        if not denoise:
            raise where.error("denoise_quantile", "needs denoise = true (it sets how denoise values a trial)",
                              "add denoise = true, or remove denoise_quantile")  # fmt: skip
    memory = table.get("max_trial_memory_gb")
    if memory is not None:
        memory = _pos_float(memory, f"{src}: [study] max_trial_memory_gb")
    intensify = _float(table.get("intensify_share", d.intensify_share), f"{src}: [study] intensify_share", 0.0, 1.0)
    if intensify > 0.0 and race <= 0.0:
        raise where.error("intensify_share", "retrains the incumbent on the seed race's seeds, but race_fraction = 0",
                          "set race_fraction (e.g. 0.25), or intensify_share = 0")  # fmt: skip
    intensify_runs = table.get("intensify_runs")
    if intensify_runs is not None:
        intensify_runs = _pos_int(intensify_runs, f"{src}: [study] intensify_runs")
        if intensify <= 0.0:
            raise where.error("intensify_runs", "bounds the incumbent's runs before the race, but intensify_share = 0",
                              "set intensify_share (e.g. 0.25), or remove intensify_runs")  # fmt: skip
    refine = _float(table.get("refine_share", d.refine_share), f"{src}: [study] refine_share", 0.0, 1.0)
    refine_iterations = _int(table.get("refine_iterations", d.refine_iterations),
                             f"{src}: [study] refine_iterations", 1_000, 10_000_000)  # fmt: skip
    refine_lr = _float(table.get("refine_learning_rate", d.refine_learning_rate),
                       f"{src}: [study] refine_learning_rate", 0.0, 100.0)  # fmt: skip
    if refine_lr <= 0.0:
        raise where.error("refine_learning_rate", f"must be above 0, got {refine_lr}",
                          "e.g. refine_learning_rate = 0.1 (a tenth of the best net's own)")  # fmt: skip
    refine_runs = _int(table.get("refine_runs", d.refine_runs), f"{src}: [study] refine_runs", 0, 1_000_000)
    refine_start = _float(table.get("refine_start", d.refine_start), f"{src}: [study] refine_start", 0.0, 0.99)
    soups = _soup_sizes(table.get("refine_soups", list(d.refine_soups)), where, "refine_soups",
                        "soups of a parent's best 2 and best 4 runs")  # fmt: skip
    span = _float(table.get("refine_soup_span", d.refine_soup_span), f"{src}: [study] refine_soup_span", 0.0, 100.0)
    if span <= 0.0:
        raise where.error("refine_soup_span", f"must be above 0, got {span}",
                          "e.g. refine_soup_span = 0.5 (runs within half a mph of their parent)")  # fmt: skip
    seed_soups = _soup_sizes(table.get("seed_soups", list(d.seed_soups)), where, "seed_soups",
                             "soups of a linear configuration's best 2 and best 3 seeds")  # fmt: skip
    if not soups and not seed_soups and span != d.refine_soup_span:
        raise where.error("refine_soup_span", "sets the weight soups' ingredients, but refine_soups and seed_soups "
                          "are empty", "set refine_soups (e.g. [2, 4]), or remove refine_soup_span")  # fmt: skip
    greedy = _flag(table, "seed_soup_greedy", d.seed_soup_greedy, where)
    if greedy and not seed_soups:
        raise where.error("seed_soup_greedy", "grows the seed soups, but seed_soups is empty",
                          "set seed_soups (e.g. [2, 3]), or remove seed_soup_greedy")  # fmt: skip
    families = _flag(table, "seed_soup_families", d.seed_soup_families, where)
    if families and not seed_soups:
        raise where.error("seed_soup_families", "soups linear configurations together, but seed_soups is empty",
                          "set seed_soups (e.g. [2, 3]), or remove seed_soup_families")  # fmt: skip
    seed_runs = _int(table.get("seed_soup_runs", d.seed_soup_runs), f"{src}: [study] seed_soup_runs", 0, 1_000)
    if seed_runs and not seed_soups:
        raise where.error("seed_soup_runs", "trains seeds for the seed soups, but seed_soups is empty",
                          "set seed_soups (e.g. [2, 3, 4]), or remove seed_soup_runs")  # fmt: skip
    reach = _float(table.get("seed_soup_reach", d.seed_soup_reach), f"{src}: [study] seed_soup_reach", 0.0, 100.0)
    if reach < SEED_RUN_REACH:
        raise where.error("seed_soup_reach", f"must be {SEED_RUN_REACH} mph or more, got {reach}",
                          f"e.g. seed_soup_reach = 2.0, or leave it out ({SEED_RUN_REACH})")  # fmt: skip
    if reach != d.seed_soup_reach and not seed_runs:
        raise where.error("seed_soup_reach", "sets which linear configurations get seed runs, but seed_soup_runs = 0",
                          "set seed_soup_runs (e.g. 64), or remove seed_soup_reach")  # fmt: skip
    for key, value in (("refine_iterations", refine_iterations), ("refine_learning_rate", refine_lr),
                       ("refine_runs", refine_runs), ("refine_start", refine_start),
                       ("refine_soups", soups), ("refine_soup_span", span if not seed_soups else d.refine_soup_span),
                       ("seed_soup_runs", seed_runs)):  # fmt: skip
        if refine <= 0.0 and value != getattr(d, key):  # (a spec written out whole carries the defaults)
            raise where.error(key, "sets the refinement runs, but refine_share = 0",
                              f"set refine_share (e.g. 0.5), or remove {key}")  # fmt: skip
    every_draw = _flag(table, "balance_every_draw", d.balance_every_draw, where)
    if every_draw and not balance:
        raise where.error("balance_every_draw", "conditions the draws on the balanced parameters, but balance is "
                          "empty", 'set balance (e.g. ["method"]), or remove balance_every_draw')  # fmt: skip
    twins = _linear_twins(table.get("linear_twins", {}), where)
    twin_span = _float(table.get("linear_twin_span", d.linear_twin_span), f"{src}: [study] linear_twin_span", 0.0,
                       100.0)  # fmt: skip
    if twin_span and not twins:
        raise where.error("linear_twin_span", "sets which configurations get linear twins, but linear_twins is empty",
                          "set linear_twins (e.g. { adagrad = [3.0] }), or remove linear_twin_span")  # fmt: skip
    stacks = _flag(table, "seed_ensembles", d.seed_ensembles, where)
    if stacks and not seed_soups:
        raise where.error("seed_ensembles", "stacks the seeds of configurations with hidden layers, but seed_soups is "
                          "empty", "set seed_soups (e.g. [2, 3, 4]), or remove seed_ensembles")  # fmt: skip
    swap_span = _float(table.get("seed_soup_swap_span", d.seed_soup_swap_span), f"{src}: [study] seed_soup_swap_span",
                       0.0, 100.0)  # fmt: skip
    if swap_span and not greedy:
        raise where.error("seed_soup_swap_span", "swaps the greedy seed soups' ingredients, but seed_soup_greedy is "
                          "off", "set seed_soup_greedy = true, or remove seed_soup_swap_span")  # fmt: skip
    neighbours = _flag(table, "linear_neighbours", d.linear_neighbours, where)
    if neighbours and not seed_soups:
        raise where.error("linear_neighbours", "retries the configuration of the best seed soup, but seed_soups is "
                          "empty", "set seed_soups (e.g. [2, 3, 4]), or remove linear_neighbours")  # fmt: skip
    leader = _flag(table, "seed_soup_leader", d.seed_soup_leader, where)
    if leader and not seed_runs:
        raise where.error("seed_soup_leader", "gives the leader by mean more fresh seeds, but seed_soup_runs = 0",
                          "set seed_soup_runs (e.g. 64), or remove seed_soup_leader")  # fmt: skip
    best_seeds = _flag(table, "seed_soup_best", d.seed_soup_best, where)
    if best_seeds and not seed_runs:
        raise where.error("seed_soup_best", "gives the best net's configurations more fresh seeds, but seed_soup_runs "
                          "= 0", "set seed_soup_runs (e.g. 64), or remove seed_soup_best")  # fmt: skip
    best_span = _float(table.get("seed_soup_best_span", d.seed_soup_best_span), f"{src}: [study] seed_soup_best_span",
                       0.0, 100.0)  # fmt: skip
    if best_span and not best_seeds:
        raise where.error("seed_soup_best_span", "shares the best net's seed turns with other families, but "
                          "seed_soup_best is off",
                          "set seed_soup_best = true, or remove seed_soup_best_span")  # fmt: skip
    prior_free = _float(table.get("prior_free_share", d.prior_free_share), f"{src}: [study] prior_free_share", 0.0,
                        1.0)  # fmt: skip
    views = _flag(table, "seed_soup_views", d.seed_soup_views, where)
    if views and not families:
        raise where.error(
            "seed_soup_views",
            "soups linear configurations of other views together, but seed_soup_families is off",
            "set seed_soup_families = true, or remove seed_soup_views",
        )
    apart = table.get("balance_prune_apart", [])
    names = isinstance(apart, list | tuple) and all(isinstance(a, str) for a in apart)
    if not names or len(set(apart)) < len(apart):
        raise where.error("balance_prune_apart", f"must be a list of balanced parameters, each once, got {apart!r}",
                          'write balance_prune_apart = ["lanes_side"]')  # fmt: skip
    _check_balanced("balance_prune_apart", apart, balance, where)
    side = _float(table.get("side_share", d.side_share), f"{src}: [study] side_share", 0.0, 1.0)
    if side <= 0.0:
        raise where.error("side_share", "0 would never start a linear twin or neighbour",
                          "turn them off instead (linear_twins = {}, linear_neighbours = false), or give a share "
                          "such as 0.33")  # fmt: skip
    if side < 1.0 and not (twins or neighbours):
        raise where.error("side_share", "caps the time of linear twins and neighbours, but neither is on",
                          "set linear_twins or linear_neighbours = true, or remove side_share")  # fmt: skip
    side_cap = table.get("max_side_cost_s")
    if side_cap is not None:
        side_cap = _pos_float(side_cap, f"{src}: [study] max_side_cost_s")
        if not (twins or neighbours):
            raise where.error("max_side_cost_s", "caps the training of a linear twin or neighbour, but neither is on",
                              "set linear_twins or linear_neighbours = true, or remove max_side_cost_s")  # fmt: skip
    return StudySection(
        name, ruleset, sampler, pruner, n_trials, timeout_s, seed, storage, max_retries, trial_timeout_s,
        startup, cap, race, race_configs, race_seeds, tuple(balance), share,
        tuple((k, tuple(v)) for k, v in values.items()), denoise, quantile, memory, intensify,
        intensify_runs, refine, refine_iterations, refine_lr, refine_runs, refine_start, soups, span, seed_soups,
        greedy, families, seed_runs, reach, every_draw, twins, twin_span, stacks, swap_span, neighbours, leader,
        best_seeds, best_span, prior_free, views, tuple(apart), side, side_cap,
    )  # fmt: skip


def _check_balanced(key: str, names: Iterable[str], balance: Sequence[str], where: _Where) -> None:
    """Every parameter [study] ``key`` names is in [study] balance."""
    for name in names:
        if name not in balance:
            raise where.error(key, f"{name!r} is not in balance{_hint(name, list(balance))}",
                              f'add it: balance = {[*balance, name]!r}'.replace("'", '"'))  # fmt: skip


def _linear_twins(table: Any, where: _Where) -> tuple[tuple[str, tuple[float, ...]], ...]:
    """[study] linear_twins: a table of trainer methods, each a non-empty list of positive learning rates per input
    (checked against the space by ``_check_twins``)."""
    example = "e.g. linear_twins = { adagrad = [3.0, 10.0], sgd = [0.03] }"
    if not isinstance(table, dict):
        raise where.error("linear_twins", f"must be a table of trainer methods, got {table!r}", example)
    out = []
    for method, rates in table.items():
        numbers = isinstance(rates, list) and all(isinstance(r, int | float) and not isinstance(r, bool) for r in rates)
        if not numbers or not rates or any(not r > 0 for r in rates):
            raise where.error("linear_twins", f"{method}: must be a non-empty list of positive learning rates per "
                              f"input, got {rates!r}", example)  # fmt: skip
        if len(set(rates)) != len(rates):
            raise where.error("linear_twins", f"{method} names a rate twice: {rates!r}", "name each rate once")
        out.append((str(method), tuple(float(r) for r in rates)))
    return tuple(out)


def _soup_sizes(sizes: Any, where: _Where, key: str, example: str) -> tuple[int, ...]:
    """[study] ``key``: soup sizes, distinct integers in [2, 64] (``[]``: none)."""
    if not isinstance(sizes, (list, tuple)) or not all(isinstance(k, int) and not isinstance(k, bool) for k in sizes):
        raise where.error(key, f"must be a list of integers, got {sizes!r}", f"e.g. {key} = [2, 4] ({example}), or [] "
                          "for none")  # fmt: skip
    if any(not 2 <= k <= 64 for k in sizes) or len(set(sizes)) != len(sizes):
        raise where.error(key, f"sizes must be distinct and in [2, 64], got {list(sizes)!r}", f"e.g. {key} = [2, 4]")
    return tuple(sizes)


def _parse_ladder(
    table: Any, src: str, ruleset: str
) -> tuple[tuple[int, ...], int, bool, float, bool, tuple[float, ...], tuple[int, ...]]:
    """``(rungs, min_top, prune_static, min_weight_change, reseed, epsilon_test_grid, epsilon_test_screen_runs)``;
    min_top 0 when the table leaves it out (the last rung)."""
    if table is None:
        return (), 0, True, MIN_WEIGHT_CHANGE, False, (), EPSILON_SCREEN_RUNS
    _check_keys(table, "ladder", src)
    rungs = table.get("rungs")
    what = f"{src}: [ladder] rungs"
    if not isinstance(rungs, list) or not rungs:
        raise SpecError(f"{what}: must be a non-empty list of iterations, got {rungs!r}; e.g. rungs = [10000, 30000]")
    values = [_int(b, what, 1, int(fields.bounds("train_iterations")[1])) for b in rungs]
    from autotune.search.ladder import Ladder

    try:
        Ladder(tuple(values))
    except ValueError as exc:
        raise SpecError(f"{what}: {str(exc).removeprefix('rungs: ')}; e.g. rungs = [10000, 30000, 90000]") from None
    min_top = table.get("min_top", 0)
    if min_top != 0 and (isinstance(min_top, bool) or min_top not in values):
        raise SpecError(
            f"{src}: [ladder] min_top: must be one of the rungs {values}, got {min_top!r}; e.g. "
            f"min_top = {values[min(2, len(values) - 1)]}, or leave it out (the last rung)"
        )
    prune = table.get("prune_static", True)
    if not isinstance(prune, bool):
        raise SpecError(f"{src}: [ladder] prune_static: must be true or false, got {prune!r}")
    change = table.get("min_weight_change", MIN_WEIGHT_CHANGE)
    change = _float(change, f"{src}: [ladder] min_weight_change (a fraction of the weights' norm; 0 = off)", 0.0, 1.0)
    reseed = table.get("reseed", False)
    if not isinstance(reseed, bool):
        raise SpecError(f"{src}: [ladder] reseed: must be true or false, got {reseed!r}; write reseed = true")
    grid, screen_runs = _parse_epsilon_grid(table, src, ruleset)
    return tuple(values), (0 if min_top == values[-1] else int(min_top)), prune, change, reseed, grid, screen_runs


def default_screen_runs(runs: int) -> tuple[int, ...]:
    """``EPSILON_SCREEN_RUNS`` for a protocol of ``runs`` runs: (50, 100) on v2-official's 500; on 100 runs or
    fewer, half of them, then all (v1-original's 10: (5, 10))."""
    last = min(EPSILON_SCREEN_RUNS[-1], runs)
    return (last // 2, last) if last >= 2 else (last,)


def _parse_epsilon_grid(table: Mapping[str, Any], src: str, ruleset: str) -> tuple[tuple[float, ...], tuple[int, ...]]:
    """``[ladder] epsilon_test_grid`` (distinct values in ε_test's range, sorted) and ``epsilon_test_screen_runs``
    (a number, or increasing numbers: 1 … the official protocol's runs)."""
    from sim.protocols import PROTOCOLS

    where = f"{src}: [ladder] epsilon_test_grid"
    raw = table.get("epsilon_test_grid", [])
    if not isinstance(raw, list) or any(isinstance(e, bool) or not isinstance(e, (int, float)) for e in raw):
        raise SpecError(f"{where}: must be a list of ε_test values, got {raw!r}; e.g. epsilon_test_grid = [0.0, 0.1, "
                        "0.3, 0.6]")  # fmt: skip
    lo, hi = fields.bounds("epsilon_test_time")
    grid = tuple(sorted({_float(e, where, float(lo), float(hi or 1.0)) for e in raw}))
    if len(grid) == 1:
        raise SpecError(f"{where}: one value ({grid[0]:g}) is no choice; fix it with [fixed] epsilon_test_time = "
                        f"{grid[0]:g}, or list two or more values")  # fmt: skip
    runs = PROTOCOLS[OFFICIAL_PROTOCOL[ruleset]].runs
    what = f"{src}: [ladder] epsilon_test_screen_runs (the official protocol's first runs of each screening stage)"
    raw_runs = table.get("epsilon_test_screen_runs", list(default_screen_runs(runs)))
    if isinstance(raw_runs, list):
        if not raw_runs:
            raise SpecError(f"{what}: an empty list screens nothing; write e.g. [50, 100] or 100")
        stages = tuple(_int(r, what, 1, runs) for r in raw_runs)
        if any(b <= a for a, b in zip(stages, stages[1:], strict=False)):
            raise SpecError(f"{what}: {list(stages)} must increase (every value on the first, the better half on to "
                            f"the next); e.g. [{runs // 10 or 1}, {runs // 5 or 2}]")  # fmt: skip
    else:
        stages = (_int(raw_runs, what, 1, runs),)
    return grid, stages


def _parse_warm_start(table: Mapping[str, Any], src: str) -> WarmStartSection:
    _check_keys(table, "warm_start", src)
    crowd = table.get("crowd", False)
    if not isinstance(crowd, bool):
        raise SpecError(f"{src}: [warm_start] crowd: must be true or false, got {crowd!r}; write crowd = true")
    study = table.get("study", "")
    if study:
        study = _check_name(study, f"{src}: [warm_start] study")
    crowd_twins = table.get("crowd_twins", False)
    if not isinstance(crowd_twins, bool):
        raise SpecError(f"{src}: [warm_start] crowd_twins: must be true or false, got {crowd_twins!r}; write "
                        "crowd_twins = true")  # fmt: skip
    return WarmStartSection(crowd, study, crowd_twins)


def _parse_evaluation(table: Mapping[str, Any], src: str, ruleset: str, *, ladder: bool) -> EvaluationSection:
    _check_keys(table, "evaluation", src)
    where = _Where(src, "evaluation")
    d = EvaluationSection()
    report_points = _int(table.get("report_points", d.report_points), f"{src}: [evaluation] report_points", 1, 1000)
    quick_runs = _int(table.get("quick_runs", d.quick_runs), f"{src}: [evaluation] quick_runs", 1, 100_000)
    quick_frames = _int(table.get("quick_frames", d.quick_frames), f"{src}: [evaluation] quick_frames", 1, 10_000_000)
    official = OFFICIAL_PROTOCOL[ruleset]
    final_protocol = table.get("final_protocol", "") or official
    if final_protocol != official:
        raise where.error(
            "final_protocol",
            f"{final_protocol!r} is not the official protocol of ruleset {ruleset!r}",
            f"use '{official}' (or leave it out)",
        )
    n_startup = _int(
        table.get("n_startup_trials", d.n_startup_trials), f"{src}: [evaluation] n_startup_trials", 0, 1_000_000
    )
    n_warmup = _int(table.get("n_warmup_steps", d.n_warmup_steps), f"{src}: [evaluation] n_warmup_steps", 0, 1000)
    if n_warmup >= report_points and not ladder:  # a ladder's reports are its rungs, not report_points
        raise where.error(
            "n_warmup_steps",
            f"{n_warmup} ≥ report_points {report_points}, so no trial could ever be pruned",
            f'use 0–{report_points - 1} (or pruner = "none")',
        )
    return EvaluationSection(report_points, quick_runs, quick_frames, final_protocol, n_startup, n_warmup)


def _parse_resources(table: Mapping[str, Any], src: str) -> ResourcesSection:
    _check_keys(table, "resources", src)
    cpus = _pos_float(table.get("cpus_per_trial", 1.0), f"{src}: [resources] cpus_per_trial")
    gpus = _float(table.get("gpus_per_trial", 0.0), f"{src}: [resources] gpus_per_trial", 0.0, 1024.0)
    default_workers = max(1, int((os.cpu_count() or 1) // cpus))
    workers = _pos_int(table.get("workers", default_workers), f"{src}: [resources] workers")
    return ResourcesSection(workers, cpus, gpus)


def _parse_fixed(table: Mapping[str, Any], src: str, ruleset: str, searched: set[str]) -> tuple[tuple[str, Any], ...]:
    given: dict[str, Any] = {}
    for key, value in table.items():
        if fields.name_of(key) == "ruleset":
            raise SpecError(f"{src}: [fixed] {key}: the ruleset is a study setting; move it to [study] ruleset")
        if key not in _FIXED_KEYS:
            raise SpecError(f"{src}: [fixed] {key}: unknown key{_hint(key, _FIXED_KEYS)} (any TrainConfig field)")
        name = fields.name_of(key) or key
        if name in given:
            raise SpecError(f"{src}: [fixed] {key}: given twice (as {name} and its alias); keep one")
        given[name] = value
    probe = dict(given)
    if "start_learn_threshold" in given and "experience_size" in searched:
        probe["experience_size"] = fields.bounds("experience_size")[1]  # checked against the space later
    try:
        config = build_config(ruleset, probe, cap_start="start_learn_threshold" not in given)
    except ConfigError as exc:
        raise SpecError(f"{src}: [fixed] {_one_line(str(exc))}") from None
    real = config.to_mapping()
    return tuple((name, real[name]) for name in given)


def _parse_dimension(name: str, entry: Any, src: str, ruleset: str) -> Dimension:
    where = _Where(src, "space")
    if name not in PARAMS:
        if name == "gamma":
            raise where.error(name, "gamma is searched as one_minus_gamma (gamma = 1 − one_minus_gamma, log scale)",
                              "write one_minus_gamma = { low = 0.01, high = 0.5, log = true }")  # fmt: skip
        if name == "layers":
            raise where.error(name, "the layout is searched as n_layers, neurons and activation",
                              "write n_layers = {…}, neurons = {…}, activation = { choices = [...] }")  # fmt: skip
        raise where.error(name, f"unknown parameter{_hint(name, PARAMS)}", f"searchable: {', '.join(PARAMS)}")
    if not isinstance(entry, Mapping):
        raise where.error(name, f"expected {{ low = …, high = … }} or {{ choices = [...] }}, got {entry!r}",
                          f"to keep one value put {name} in [fixed]")  # fmt: skip
    allowed = ("low", "high", "log", "step", "choices")
    for key in entry:
        if key not in allowed:
            raise where.error(f"{name}.{key}", f"unknown key{_hint(key, allowed)}", f"use {', '.join(allowed)}")
    kind, lo_ok, hi_ok = param_bounds(name)
    if "choices" in entry:
        extra = [k for k in ("low", "high", "log", "step") if k in entry]
        if extra:
            raise where.error(name, f"choices and {extra[0]} given together", "use either a range or choices")
        choices = entry["choices"]
        if not isinstance(choices, list) or not choices:
            raise where.error(
                name, f"choices must be a non-empty list, got {choices!r}", f"e.g. {name} = {{ choices = [...] }}"
            )
        seen: list[Any] = []
        for c in choices:
            value = _check_value(name, c, kind, lo_ok, hi_ok, where, "choice", ruleset)
            if value in seen:
                raise where.error(name, f"choice {c!r} is listed twice", "list each choice once")
            seen.append(value)
        return Dimension(name, "categorical", choices=tuple(seen))
    if kind == "str":
        raise where.error(
            name, "a categorical parameter needs choices", f'write {name} = {{ choices = ["relu", "tanh"] }}'
        )
    for key in ("low", "high"):
        if key not in entry:
            raise where.error(name, f"{key} is missing", f"write {name} = {{ low = …, high = … }}")
    low = _check_value(name, entry["low"], kind, lo_ok, hi_ok, where, "low", ruleset)
    high = _check_value(name, entry["high"], kind, lo_ok, hi_ok, where, "high", ruleset)
    if low > high:
        raise where.error(name, f"low {low!r} > high {high!r}", "swap them")
    if low == high:
        raise where.error(name, f"low = high = {low!r} searches nothing", f"put {name} = {low!r} in [fixed]")
    log = entry.get("log", False)
    if not isinstance(log, bool):
        raise where.error(name, f"log must be true or false, got {log!r}", "write log = true")
    if log and low <= 0:
        raise where.error(name, f"log scale needs low > 0, got low {low!r}", "raise low above 0 or set log = false")
    step = entry.get("step")
    if step is not None:
        if log:
            raise where.error(name, "step and log = true cannot be combined", "drop step or set log = false")
        if kind == "int" and (isinstance(step, bool) or not isinstance(step, int) or step < 1):
            raise where.error(name, f"step must be a positive integer, got {step!r}", "e.g. step = 2")
        if isinstance(step, bool) or not isinstance(step, (int, float)) or not step > 0:
            raise where.error(name, f"step must be a positive number, got {step!r}", "e.g. step = 0.1")
        n = (high - low) / step
        if abs(n - round(n)) > 1e-9 * max(1.0, abs(n)):
            fit = low + math.floor(n) * step
            raise where.error(
                name, f"high − low = {high - low!r} is not a multiple of step {step!r}", f"set high = {fit!r}"
            )
        step = int(step) if kind == "int" else float(step)
    return Dimension(name, kind, low, high, log, step)


def param_bounds(name: str) -> tuple[str, float, float | None]:
    """(kind, smallest, largest accepted value) of a [space] name: 'int', 'float' or 'str' (choices), the range
    from sim.fields in sampling coordinates (the layout's open-ended)."""
    if name == "one_minus_gamma":
        g_lo, g_hi = fields.bounds("gamma")
        return "float", one_minus(g_hi), one_minus(g_lo)
    if name == EPSILON_TEST_SHIFTED:
        e_lo, e_hi = fields.bounds("epsilon_test_time")
        return "float", shift_epsilon(e_lo), shift_epsilon(e_hi)
    if name == "n_layers":
        return "int", 0, None
    if name == "neurons":
        return "int", 1, None
    if name == "activation":
        return "str", 0, None
    if name in FRACTIONS:
        return "float", 0.0, 10.0
    if name == LR_X_INPUTS:  # learning_rate ≤ its field's high is checked on the decoded corners (space.check)
        return "float", 0.0, None
    f = fields.field(name)
    if f.kind is str:
        return "str", 0, None
    assert f.low is not None and f.high is not None
    return f.kind.__name__, f.low, f.high


def _check_value(
    name: str, value: Any, kind: str, lo: float, hi: float | None, where: _Where, what: str, ruleset: str
) -> Any:
    """One bound or choice, of the right type and inside what deepqlearn accepts."""
    if kind == "str" and name != "activation":
        try:
            return check(fields.field(name), value)
        except FieldValueError as exc:
            raise where.error(name, f"{what} {exc.problem}", "fix the choice") from None
    if kind == "str":
        if not isinstance(value, str):
            raise where.error(name, f"{what} {value!r} is not a string", 'use activation names like "relu"')
        try:
            TrainConfig(ruleset=ruleset, layers=f"fc:4:{value}")
        except ConfigError as exc:
            raise where.error(
                name, f"{what} {value!r} is not accepted ({_one_line(str(exc))})", "fix the choice"
            ) from None
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise where.error(name, f"{what} must be a number, got {value!r}", "write a plain number")
    if kind == "int":
        if isinstance(value, float):
            if not value.is_integer():
                raise where.error(
                    name, f"{what} {value!r} is not an integer", f"use {math.floor(value)} or {math.ceil(value)}"
                )
            value = int(value)
    else:
        value = float(value)
    accepted = f"{lo:g}–{hi:g}" if hi is not None else f"≥ {lo:g}"
    if value < lo:
        raise where.error(
            name, f"{what} {value!r} is below what deepqlearn accepts ({accepted})", f"raise it to {lo:g}"
        )
    if hi is not None and value > hi:
        raise where.error(
            name, f"{what} {value!r} is above what deepqlearn accepts ({accepted})", f"lower it to {hi:g}"
        )
    if name == "other_agents":
        try:
            check_other_agents(ruleset, value)
        except ConfigError:
            raise where.error(name, f"{what} {value!r}: {V1_NO_AGENTS}", 'remove it or use ruleset "v2"') from None
    return value


def _check_balance(spec: StudySpec) -> None:
    """[study] balance names categorical, non-layout [space] parameters (or integer ones — the layer count, the
    view's lanes_side — with the values given a floor in balance_values), every one of whose floored values exists
    and can get the share."""
    st = spec.study
    where = _Where(spec.source, "study")
    if st.balance and st.sampler not in BALANCEABLE_SAMPLERS:
        raise where.error("balance", f"needs a sampler whose model is its trial history; '{st.sampler}' is not",
                          'use sampler = "tpe" (or "random"), or remove balance')  # fmt: skip
    dims = spec.dimensions
    categorical = [n for n, d in dims.items() if d.kind == "categorical" and n not in LAYOUT]
    integers = [n for n, d in dims.items() if d.kind == "int" and n not in LAYOUT[1:]]
    valid = categorical + integers
    given = dict(st.balance_values)
    for name in st.balance:
        d = dims.get(name)
        if d is None or name not in valid:
            what = "is not in [space]" if d is None else "is not a categorical or integer [space] parameter of its own"
            named = ", ".join(valid) or "none (the space has no such parameter)"
            raise where.error("balance", f"{name!r} {what}{_hint(name, valid)}", f"name one of: {named}")
        if d.kind != "categorical" and name not in given:
            raise where.error("balance", f"{name} is an integer: name the values to keep a share of the draws",
                              f"add balance_values = {{ {name} = [1] }}")  # fmt: skip
        floored = given.get(name, d.choices)
        for v in floored:
            inside = v in d.choices if d.kind == "categorical" else (
                isinstance(v, int) and not isinstance(v, bool) and d.low is not None and d.high is not None
                and d.low <= v <= d.high)  # fmt: skip
            if not inside:
                span = list(d.choices) if d.kind == "categorical" else f"integers {d.low:g}–{d.high:g}"
                raise where.error("balance_values", f"{name} value {v!r} is not in [space] {name}",
                                  f"use values of {span}")  # fmt: skip
        if st.balance_min_share * len(floored) > 1.0 + 1e-12:
            raise where.error("balance_min_share", f"{st.balance_min_share} × the {len(floored)} values of "
                              f"{name} is over 1", f"use at most {1 / len(floored):.4g}")  # fmt: skip


def _check_twins(spec: StudySpec) -> None:
    """[study] linear_twins needs a space that searches the layer count (0 included), the trainer method (each named
    one among its choices) and the learning rate per input (each rate inside its range)."""
    twins = spec.study.linear_twins
    if not twins:
        return
    where = _Where(spec.source, "study")
    dims = spec.dimensions
    layers = dims.get("n_layers")
    if layers is None or layers.low is None or layers.low > 0:
        raise where.error("linear_twins", "retries configurations with no hidden layer, but [space] n_layers does not "
                          "reach 0", "search n_layers = { low = 0, high = … }, or remove linear_twins")  # fmt: skip
    method = dims.get("method")
    if method is None or method.kind != "categorical":
        raise where.error("linear_twins", "sets the twins' trainer method, but [space] does not search method",
                          'add method = { choices = ["sgd", "adagrad"] }, or remove linear_twins')  # fmt: skip
    rate = dims.get(LR_X_INPUTS)
    if rate is None or rate.low is None or rate.high is None:
        raise where.error("linear_twins", f"its rates are per input, but [space] does not search {LR_X_INPUTS}",
                          f"search {LR_X_INPUTS} (not learning_rate), or remove linear_twins")  # fmt: skip
    for name, rates in twins:
        if name not in method.choices:
            raise where.error("linear_twins", f"{name!r} is not among [space] method's choices"
                              f"{_hint(name, [str(c) for c in method.choices])}",
                              f"use one of {list(method.choices)}")  # fmt: skip
        for r in rates:
            if not rate.low <= r <= rate.high:
                raise where.error("linear_twins", f"{name} rate {r:g} is outside [space] {LR_X_INPUTS} "
                                  f"({rate.low:g}–{rate.high:g})", "use rates inside its range")  # fmt: skip


def _check_combination(spec: StudySpec) -> None:
    """Cross-table rules: nothing both fixed and searched, a complete layout, a threshold below the experience."""
    src = spec.source
    where = _Where(src, "space")
    fixed = spec.fixed_values
    dims = spec.dimensions
    if "learning_rate" in dims and LR_X_INPUTS in dims:
        raise where.error(LR_X_INPUTS, "is searched and so is learning_rate (both set the learning rate)",
                          "keep one of them in [space]")  # fmt: skip
    for d in spec.space:
        field = _FIELD_OF.get(d.name, d.name)
        if field in fixed:
            raise where.error(
                d.name,
                f"is searched but [fixed] also sets {field}",
                f"remove {field} from [fixed] or {d.name} from [space]",
            )
    present = [n for n in LAYOUT if n in dims]
    if present and len(present) < len(LAYOUT):
        missing = next(n for n in LAYOUT if n not in dims)
        raise where.error(missing, f"missing: the layout is searched ({', '.join(present)}) but {missing} is not",
                          f"add {missing} = {_LAYOUT_EXAMPLE[missing]}")  # fmt: skip
    if "activation" in dims and dims["activation"].kind != "categorical":  # pragma: no cover - rejected per entry
        raise where.error("activation", "needs choices", 'write activation = { choices = ["relu", "tanh"] }')
    if spec.ladder:
        for name in ("train_iterations", "learning_steps_burnin", "learning_steps_total"):
            if name in dims or (name == "train_iterations" and name in fixed):
                fix = ("remove it: each rung trains for its budget" if name == "train_iterations"
                       else f"search {name}_fraction (a fraction of the rung's budget) instead")  # fmt: skip
                table = "space" if name in dims else "fixed"
                raise _Where(src, table).error(name, "a ladder study sets the training length per rung", fix)
    else:
        for name in FRACTIONS:
            if name in dims:
                raise where.error(name, "fractions of the budget need a [ladder]",
                                  "add [ladder] rungs = [...] or search learning_steps_* directly")  # fmt: skip
    if spec.ladder_epsilon_grid:
        for name in ("epsilon_test_time", EPSILON_TEST_SHIFTED):
            if name in dims or name in fixed:
                table = "space" if name in dims else "fixed"
                raise _Where(src, table).error(
                    name,
                    "is set, but [ladder] epsilon_test_grid chooses ε_test per net",
                    f"remove {name} from [{table}] or epsilon_test_grid from [ladder]",
                )
    _check_balance(spec)
    _check_twins(spec)
    exp = dims.get("experience_size")
    if "start_learn_threshold" in fixed and exp is not None:
        smallest = min(exp.choices) if exp.kind == "categorical" else exp.low
        if fixed["start_learn_threshold"] >= smallest:
            raise where.error("experience_size", f"can be {smallest} ≤ [fixed] start_learn_threshold "
                              f"{fixed['start_learn_threshold']}, so learning would never start",
                              f"raise experience_size.low above {fixed['start_learn_threshold']}")  # fmt: skip


_LAYOUT_EXAMPLE = {
    "n_layers": "{ low = 1, high = 3 }",
    "neurons": "{ low = 8, high = 512, log = true }",
    "activation": '{ choices = ["relu", "tanh"] }',
}


# --------------------------------------------------------------------------------------------
# building a TrainConfig ([fixed] here, every trial's in space.to_config)
# --------------------------------------------------------------------------------------------

_TRAIN_DEFAULTS = {f.name: f.default for f in dataclasses.fields(TrainConfig)}


def build_config(ruleset: str, values: Mapping[str, Any], *, cap_start: bool) -> TrainConfig:
    """TrainConfig from real field values; with ``cap_start`` the threshold is capped at experience_size − 1."""
    merged = {"ruleset": ruleset, **values}
    if cap_start:
        exp = merged.get("experience_size", _TRAIN_DEFAULTS["experience_size"])
        start = merged.get("start_learn_threshold", _TRAIN_DEFAULTS["start_learn_threshold"])
        if isinstance(exp, int) and isinstance(start, int) and not isinstance(start, bool) and start >= exp:
            merged["start_learn_threshold"] = max(0, exp - 1)
    return TrainConfig.from_mapping(merged)


# --------------------------------------------------------------------------------------------
# small checks
# --------------------------------------------------------------------------------------------


class _Where:
    """A table of one file, for ``file: [table] key: problem; fix`` messages."""

    def __init__(self, source: str, table: str) -> None:
        self.source = source
        self.table = table

    def error(self, key: str, problem: str, fix: str) -> SpecError:
        return SpecError(_one_line(f"{self.source}: [{self.table}] {key}: {problem}; {fix}"))


def _check_keys(table: Mapping[str, Any], section: str, src: str) -> None:
    valid = _SECTION_KEYS[section]
    for key in table:
        if key not in valid:
            raise SpecError(f"{src}: [{section}] {key}: unknown key{_hint(key, valid)} (valid: {', '.join(valid)})")


def _hint(key: str, valid: tuple[str, ...] | list[str]) -> str:
    return did_you_mean(key, valid)


def _one_line(text: str) -> str:
    return " ".join(text.split())


def _flag(table: Mapping[str, Any], key: str, default: bool, where: _Where) -> bool:
    """[study] ``key``, a true/false switch (``default`` when absent)."""
    value = table.get(key, default)
    if not isinstance(value, bool):
        raise where.error(key, f"must be true or false, got {value!r}", f"e.g. {key} = true")
    return value


def _int(value: Any, what: str, lo: int, hi: int) -> int:
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise SpecError(f"{what}: must be an integer in {lo}–{hi:,}, got {value!r}; write a whole number")
    if not lo <= value <= hi:
        raise SpecError(f"{what}: {value} is out of range; use {lo}–{hi:,}")
    return value


def _pos_int(value: Any, what: str) -> int:
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise SpecError(f"{what}: must be a positive integer, got {value!r}; e.g. 2")
    return value


def _float(value: Any, what: str, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SpecError(f"{what}: must be a number in [{lo:g}, {hi:g}], got {value!r}; write a plain number")
    if not lo <= value <= hi:
        raise SpecError(f"{what}: {value!r} is out of range; use [{lo:g}, {hi:g}]")
    return float(value)


def _pos_float(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise SpecError(f"{what}: must be a positive number of seconds, got {value!r}; e.g. 600")
    return float(value)


def _check_name(value: Any, what: str) -> str:
    if not isinstance(value, str) or not _NAME_RE.match(value):
        raise SpecError(
            f"{what}: {value!r} is not a usable study name; "
            "use letters, digits, '.', '_' or '-' (it names runs/<name>/)"
        )
    return value


def _check_str(value: Any, what: str) -> str:
    if not isinstance(value, str):
        raise SpecError(f'{what}: must be a string, got {value!r}; e.g. "" (embedded) or "postgresql://host/db"')
    return value


def _toml_error(source: str, text: str, exc: tomllib.TOMLDecodeError) -> str:
    """``file: [table] (line L, column C): invalid TOML: reason; fix the syntax there``."""
    msg = str(exc)
    m = re.search(r"\(at line (\d+), column (\d+)\)", msg)
    reason = msg[: m.start()].strip() if m else msg
    if not m:
        return _one_line(f"{source}: invalid TOML: {reason}; fix the syntax")
    line, col = int(m.group(1)), int(m.group(2))
    table = ""
    for raw in text.splitlines()[: line - 1]:
        header = re.match(r"^\s*\[\s*([^\[\]]+?)\s*\]", raw)
        if header:
            table = f"[{header.group(1)}] "
    return _one_line(f"{source}: {table}(line {line}, column {col}): invalid TOML: {reason}; fix the syntax there")
