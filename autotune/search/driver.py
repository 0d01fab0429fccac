"""The Optuna driver: owns the study (ask/tell), feeds trials to the worker pool, answers prune or go on.

Optuna decides, Ray executes: the driver asks the sampler for a trial, decodes it into a
TrainConfig (``space.sample`` / ``to_config``), hands the plain task to an idle worker, reports
each quick score the worker streams back (``trial.report(score, step=k)``) and answers the
pruner's verdict; at the end it stores the trial's record (user attrs of the contract's "Trial
records", net.json and net.js as Optuna artifacts) and tells Optuna the state.

States: COMPLETE (value = official score); PRUNED (pruner, divergence or the per-trial wall-time
limit; user attr ``cause``); FAIL with ``cause`` (never a silent zero). A trial whose worker died
or whose driver died is FAIL with ``retryable`` and is retried with the same params and seed
(``retry_of``), at most ``max_retries`` times along one chain; a retry does not use budget:
``n_trials`` counts the study's original trials, so a resumed study runs only what is left.

Resuming (rerun the same ``autotune launch``): every trial records its driver (host, pid, start
time) as a system attr and the driver writes heartbeats for its RUNNING trials (Optuna's own for a
heartbeat-enabled RDB storage, a ``autotune:heartbeat`` system attr otherwise). A new driver fails
the RUNNING trials whose driver is dead (same host: by pid; another host: heartbeat older than
the grace period) and retries them; nothing a dead driver finished is touched.

Budget ladder (a spec with [ladder]): a trial climbs rungs of fresh, complete trainings
(``autotune.search.ladder``), each scored officially and reported at step B_r/B_0; its top rung is
the highest whose predicted cost fits the study's cap and time left (``autotune.search.cost``). Draws
whose ladder up to ``[ladder] min_top`` (the whole ladder without it) is over the cap are refused and
redrawn inside the sampler (``autotune.search.gate``): they never become trials. The study's deadline
travels with every task, so at ``timeout_s`` running trials stop (PRUNED, the finished rungs kept) and
``launch`` exits.

Warm start: the crowd prior (``warm_configs``, enqueued once, every one trained and measured) and
another study's measured trials copied into the sampler's history. Seed race: the last
``race_fraction`` of ``timeout_s`` retrains the best configurations with fresh seeds
(``autotune.search.racing``), then its winner while that winner's runs reach the study's best net, each run an
ordinary trial with ``race_of`` / ``race_seed``. Before the race, ``intensify_share`` of the workers retrain
the incumbent on the race's seeds while its runs reach the study's best net (``_launch_incumbent``).
Refinement: ``refine_share`` of the workers (outside the race's rounds) train on from the study's best single
net (``autotune.search.refine``), each run an ordinary trial with ``refine_of``; on the same workers, fresh seeds
of linear configurations near the best for their seed soups (``autotune.search.ensemble``), every other one the
leader's by mean over its fresh seeds with ``seed_soup_leader``. Linear twins: each new best configuration's
``linear_twins`` are enqueued (``autotune.search.twins``), each one unpruned training at its parent's budget,
``twin_of`` its parent; likewise the ``linear_neighbours`` of the linear configuration of the best net (its own or
its seed soup), and of the linear leader by mean, ``neighbour_of`` it; with ``side_share`` they wait in a plan,
released newest parent first.

Enqueued full configs (``autotune crowd replay``): a trial enqueued with a ``config`` user attr
(``TrainConfig.to_mapping()``) trains exactly that config — settings the [space] cannot express
(trainer method, l1 decay, …) included — and is scored with the official protocol of that
config's ruleset (v2-official / v1-original), so one study can mix engines. Its params still go
through ``space.sample`` (the enqueued values, for the dashboard). A retry carries the user attrs
its trial was enqueued with.
"""

from __future__ import annotations

import collections
import dataclasses
import importlib.util
import math
import os
import socket
import tempfile
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import optuna
from optuna.storages import BaseStorage
from optuna.trial import FrozenTrial, Trial, TrialState

from autotune import TrainConfig
from autotune.convnet import stack, widen
from autotune.convnet.netjson import dumps_net, loads_net
from autotune.learner.config import parse_layers
from autotune.search import ensemble, keys, prior, racing, refine, soup, space, twins
from autotune.search.balance import ApartPruner, BalancedSampler, conditional_startup
from autotune.search.cost import (
    CostModel,
    Observation,
    Plan,
    default_memory_cap,
    features,
    plan,
    plan_one,
    rung_memory_bytes,
)
from autotune.search.denoise import DenoisedSampler
from autotune.search.gate import CostGatedSampler, distributions
from autotune.search.ladder import Ladder, trained_rung_config
from autotune.search.objective import (
    COMPLETE,
    FAILED,
    PRUNED,
    TrialOutcome,
    TrialTask,
    process_alive,
    process_start,
)
from autotune.search.prior import PriorFreePruner, PriorFreeSampler
from autotune.search.records import RecordError, net_rank, net_text, scored_nets
from autotune.search.seeds import derived_seed
from autotune.search.spec import SEED_RUN_REACH, SEED_SOUP_REACH, SpecError, StudySpec
from autotune.search.storage import GRACE_PERIOD_S, HEARTBEAT_INTERVAL_S, Storages
from sim.config import ConfigError

__all__ = [
    "Driver", "Progress", "StudyCounts", "make_sampler", "make_pruner", "trial_seed", "WarmConfig", "clip_params",
    "OFFICIAL_SCORE_METRIC", "race_entry",
]  # fmt: skip

OFFICIAL_SCORE_METRIC = (
    "official score [mph], measured: the trial's trained net in the exact engine, site median of its engine's "
    "official protocol"
)  # the study's metric name


@dataclasses.dataclass(frozen=True)
class WarmConfig:
    """A configuration of the crowd prior: where it comes from and the settings to map into the space."""

    source: str
    """Its provenance (``crowd:<submission id>``)."""
    config: TrainConfig
    """Its full settings (trainIterations picks its top rung)."""


@dataclasses.dataclass
class StudyCounts:
    """Where a study stands, for the progress bar and the final summary."""

    budget: int | None
    """n_trials (original trials; retries excluded); None when only timeout_s bounds the study."""
    started: int = 0
    """Original trials asked so far (this run and earlier ones)."""
    complete: int = 0
    pruned: int = 0
    failed: int = 0
    running: int = 0
    retries: int = 0
    """Retries (``retry_of``, any state): trials that use no budget."""
    race_runs: int = 0
    """Seed-race runs (``race_of``, any state): trials that use no budget either."""
    refine_runs: int = 0
    """Refinement runs (``refine_of``, any state; ``[study] refine_share``): no budget either."""
    best_value: float | None = None
    best_number: int | None = None
    elapsed_s: float = 0.0

    @property
    def finished(self) -> int:
        """Original trials whose chain has ended: budget units used up."""
        return self.complete + self.pruned + self.failed - self.retries - self.race_runs - self.refine_runs

    @property
    def reruns(self) -> str:
        """'N retries' and, when the study raced or refined, ', M race runs', ', K refinement runs' (none uses
        budget): summary lines."""
        return (f"{self.retries} retries" + (f", {self.race_runs} race runs" if self.race_runs else "")
                + (f", {self.refine_runs} refinement runs" if self.refine_runs else ""))  # fmt: skip


Progress = Callable[[StudyCounts], None]
"""Called after every change of the counts (and about once a second while trials run)."""


RACE_MARGIN = 1.25
"""A race run is planned where its predicted seconds × this fit the time left: the cost model's median error is
10–35 % in the benchmark studies, and a race run the deadline stops scores nothing."""

SEED_SOUP_MIN_LEFT_S = 20.0
"""No seed soup starts with fewer seconds left: its official evaluation takes 2–10 s on one core."""


def trial_seed(study_seed: int, number: int) -> int:
    """A trial's training seed: independent per (study seed, trial number), stored with the trial."""
    return derived_seed(study_seed, number)


def make_sampler(
    spec: StudySpec,
    seed: int,
    price: Callable[[dict[str, Any]], float | None] | None = None,
    cap: Callable[[], float] | None = None,
) -> optuna.samplers.BaseSampler:
    """The spec's sampler, seeded, its startup count ``[study] sampler_startup_trials``; TPE multivariate with
    constant liar in parallel; behind ``balance.BalancedSampler`` when ``[study] balance`` names parameters
    (its conditional sampler seeded ``seed + 1``, its startup split between the values); behind
    ``denoise.DenoisedSampler`` (forest seeded ``seed``) with ``[study] denoise``. With ``price``
    it sits behind the cost gate (``gate.CostGatedSampler``), whose
    cap is ``cap()`` when given (the driver's: the study's cost cap or the time left, whichever is less)."""
    name = spec.study.sampler
    needs = {"cmaes": "cmaes", "gp": "scipy"}.get(name)
    if needs is not None and importlib.util.find_spec(needs) is None:
        raise ConfigError(f"{spec.source}: [study] sampler: '{name}' needs the '{needs}' package; pip install {needs}")
    base = _modelled(spec, seed, name)
    if spec.study.prior_free_share > 0.0:  # a share of the draws from a sampler that sees only its own draws
        base = PriorFreeSampler(base, _modelled(spec, seed + 2, name), spec.study.prior_free_share)
    if price is None:
        return base
    return CostGatedSampler(base, spec, price, cap if cap is not None else spec.study.cost_cap_s, seed)


def _modelled(spec: StudySpec, seed: int, name: str) -> optuna.samplers.BaseSampler:
    """The spec's sampler behind its balance and denoise wrappers (``make_sampler``), seeded ``seed``."""
    base = _base_sampler(spec, seed, name)
    if spec.study.balance:  # each value of a balanced parameter keeps its share (``balance.BalancedSampler``)
        floors = _floors(spec, spec.study.balance)
        per_value = conditional_startup(spec.study.sampler_startup_trials, max(len(c) for c in floors.values()))
        conditional = _base_sampler(spec, seed + 1, name, startup=per_value)
        dists = distributions(spec)
        base = BalancedSampler(base, conditional, floors, spec.study.balance_min_share,
                               distributions={n: dists[n] for n in floors},
                               every_draw=spec.study.balance_every_draw)  # fmt: skip
    if spec.study.denoise:  # the history at a forest's estimate of each trial, not its own noisy score
        base = DenoisedSampler(base, denoise_reference_step(spec), seed, quantile=spec.study.denoise_quantile)
    return base


def _floors(spec: StudySpec, names: Sequence[str]) -> dict[str, tuple[Any, ...]]:
    """The values with a floor of each balanced parameter in ``names``: its ``balance_values``, else its choices."""
    dims, given = spec.dimensions, dict(spec.study.balance_values)
    return {n: tuple(given.get(n, dims[n].choices)) for n in names}


def denoise_reference_step(spec: StudySpec) -> int:
    """The report step at which ``[study] denoise`` values every trial: the ladder's gated top (``min_top``, which
    every sampled draw affords), else the last report point."""
    if spec.ladder:
        return Ladder(spec.ladder).steps[spec.gated_rungs - 1]
    return max(1, spec.evaluation.report_points - 1)


def _base_sampler(spec: StudySpec, seed: int, name: str, startup: int | None = None) -> optuna.samplers.BaseSampler:
    s = optuna.samplers
    startup = spec.study.sampler_startup_trials if startup is None else startup
    if name == "tpe":
        return s.TPESampler(
            seed=seed, n_startup_trials=startup, multivariate=True, group=True,
            constant_liar=spec.resources.workers > 1,
        )  # fmt: skip
    if name == "cmaes":
        return s.CmaEsSampler(seed=seed, n_startup_trials=startup, warn_independent_sampling=False)
    if name == "gp":
        return s.GPSampler(seed=seed, n_startup_trials=startup, warn_independent_sampling=False)
    if name == "random":
        return s.RandomSampler(seed=seed)
    if name == "qmc":
        return s.QMCSampler(seed=seed, scramble=True, warn_independent_sampling=False, warn_asynchronous_seeding=False)
    raise ValueError(f"sampler: unknown {name!r}")  # the spec rejected it already


def make_pruner(spec: StudySpec) -> optuna.pruners.BasePruner:
    """The spec's pruner over the report schedule (steps 0 … report_points − 1), tuned by [evaluation]; with
    ``[study] prior_free_share``, the prior-free draws are pruned among their own kind (``prior.PriorFreePruner``),
    and with ``[study] balance_prune_apart`` the balanced values' trials (``balance.ApartPruner``)."""
    base = _base_pruner(spec)
    if spec.study.balance_prune_apart:  # a balanced value's draws halved among their own kind
        base = ApartPruner(base, _floors(spec, spec.study.balance_prune_apart))
    return PriorFreePruner(base) if spec.study.prior_free_share > 0.0 else base


def _base_pruner(spec: StudySpec) -> optuna.pruners.BasePruner:
    e = spec.evaluation
    p = optuna.pruners
    name = spec.study.pruner
    if spec.ladder:  # reports at steps B_r / B_0: successive halving promotes exactly at the ladder
        ladder = Ladder(spec.ladder)
        eta = ladder.reduction_factor
        if name == "median":
            return p.MedianPruner(n_startup_trials=e.n_startup_trials, n_warmup_steps=0)
        if name == "hyperband":
            return p.HyperbandPruner(min_resource=1, max_resource=ladder.steps[-1], reduction_factor=eta)
        if name == "sha":
            return p.SuccessiveHalvingPruner(min_resource=1, reduction_factor=eta, min_early_stopping_rate=0)
        if name == "none":
            return p.NopPruner()
        raise ConfigError(f"{spec.source}: [study] pruner: '{name}' does not fit a budget ladder; use sha, "
                          "hyperband, median or none")  # fmt: skip
    if name == "median":
        return p.MedianPruner(n_startup_trials=e.n_startup_trials, n_warmup_steps=e.n_warmup_steps)
    if name == "hyperband":
        return p.HyperbandPruner(min_resource=e.n_warmup_steps + 1, max_resource=e.report_points, reduction_factor=3)
    if name == "sha":
        return p.SuccessiveHalvingPruner(min_resource=e.n_warmup_steps + 1, reduction_factor=3)
    if name == "wilcoxon":
        return p.WilcoxonPruner(p_threshold=0.1, n_startup_steps=e.n_warmup_steps)
    if name == "none":
        return p.NopPruner()
    raise ValueError(f"pruner: unknown {name!r}")


def _owner() -> dict[str, Any]:
    return {"host": socket.gethostname(), "pid": os.getpid(), "start": process_start(os.getpid())}


def _owner_alive(owner: dict[str, Any]) -> bool:
    try:
        return process_alive(int(owner["pid"]), owner.get("start"))
    except (KeyError, TypeError, ValueError):
        return False


def _heartbeat_enabled(storage: BaseStorage) -> bool:
    """True for a storage with Optuna's heartbeats on (an ``RDBStorage`` given a heartbeat interval)."""
    interval = getattr(storage, "get_heartbeat_interval", None)  # public on the storages that have heartbeats
    return callable(interval) and interval() is not None


@dataclasses.dataclass
class _Running:
    trial: Trial
    trial_id: int
    """The storage's id of the trial (its system attrs and heartbeats are written by id)."""
    slot: int
    task: TrialTask
    started: float = dataclasses.field(default_factory=time.perf_counter)
    killed: str = ""
    """Why the driver killed the worker (a trial past its wall-time limit that stopped answering)."""
    silent: bool = False
    """A race run or a linear twin: its score is not reported to the pruner (it is not a rung of the ladder; a
    twin's one training is at its parent's budget)."""
    sampled: bool = False
    """Drawn by the sampler (not enqueued: no crowd setting, race run or retry)."""
    incumbent: bool = False
    """A race run the search started before the race (``_launch_incumbent``)."""
    refine: bool = False
    """A refinement run (``_launch_refine``)."""
    ensemble: bool = False
    """A fresh seed of a linear configuration for its seed soups (``_launch_seed_run``), on a refinement worker."""


class Driver:
    """Runs one study to its budget on a ``WorkerPool`` (``autotune launch`` is a thin shell around it)."""

    def __init__(
        self,
        spec: StudySpec,
        storages: Storages,
        *,
        address: str | None = None,
        progress: Progress | None = None,
        state_dir: Path | None = None,
        warm_configs: tuple[WarmConfig, ...] = (),
    ) -> None:
        self.spec = spec
        self.warm_configs = warm_configs
        self.cost_model = self._prior_model()
        self._fitted_on = -1
        self._observed: dict[int, list[Observation]] = {}
        self._race_over = False
        self._cheapest_gated_s = 0.0
        """Fewest wall seconds a sampled trial took through the gated rungs (``_gated_seconds``; 0 before any)."""
        self._wall0 = 0.0
        self.warm_notes: list[str] = []
        """What the warm start did (crowd settings enqueued, clipped or skipped; trials copied)."""
        self.on_warm_start: Callable[[list[str]], None] | None = None
        """Called with ``warm_notes`` once the warm start is done (the CLI prints them)."""
        self.storages = storages
        self.address = address
        self.progress = progress
        self.state_dir = state_dir if state_dir is not None else storages.artifact_dir.parent
        self.owner = _owner()
        self.study: optuna.Study | None = None
        self.study_id: int | None = None
        """The storage's id of the study (set by ``open_study``)."""
        self.counts = StudyCounts(budget=spec.study.n_trials)
        self.pool: Any = None
        self._running: dict[int, _Running] = {}  # slot -> trial
        self._t0 = 0.0
        self._last_beat = 0.0
        self.startup_seconds = 0.0
        """Seconds from ``run`` until every worker was warm (Ray start + worker warm-up)."""
        self.recovered: list[int] = []
        """Trial numbers of a dead driver failed on resume."""

    # -- the study ------------------------------------------------------------------------
    def open_study(self) -> optuna.Study:
        """Create the study or load it (same name), store the spec, fail the orphans of dead drivers."""
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
        # this driver records the heartbeats of its trials itself (``_heartbeat``), without Study.optimize
        warnings.filterwarnings("ignore", message="Heartbeat of storage is supposed to be used with Study.optimize")
        storage = self.storages.storage
        name = self.spec.study.name
        previous = [s for s in storage.get_all_studies() if s.study_name == name]
        n_before = 0
        if previous:
            n_before = len(storage.get_all_trials(storage.get_study_id_from_name(name), deepcopy=False))
            self._refuse_changed_space(previous[0].user_attrs.get(keys.STUDY_SPEC))
        study = optuna.create_study(
            study_name=name,
            storage=storage,
            # a resumed run draws anew
            sampler=make_sampler(self.spec, self.spec.study.seed + n_before, self._price, self._draw_cap),
            pruner=make_pruner(self.spec),
            direction="maximize",
            load_if_exists=True,
        )
        study.set_user_attr(keys.STUDY_SPEC, self.spec.to_dict())
        if study.metric_names is None:  # what the value is (optuna-dashboard shows it); a replay study names its own
            study.set_metric_names([OFFICIAL_SCORE_METRIC])
        self.study = study
        self.study_id = storage.get_study_id_from_name(name)
        self.recovered = self._fail_orphans(study)
        self._refresh_counts()
        return study

    def _refuse_changed_space(self, stored: Any) -> None:
        """A study resumed with another space (or ladder) would mix incomparable trials: one line, no change."""
        if not isinstance(stored, dict):
            return
        new = self.spec.to_dict()
        for key, label in (("space", "[space]"), ("ladder", "[ladder]")):
            old_t, new_t = stored.get(key) or {}, new.get(key) or {}
            if key == "ladder":  # how many runs choose ε_test changes no value's meaning (the official score)
                old_t, new_t = ({k: v for k, v in t.items() if k not in _RESUMABLE_LADDER} for t in (old_t, new_t))
            if old_t == new_t:
                continue
            names = sorted(set(old_t) | set(new_t))
            first = next(n for n in names if old_t.get(n) != new_t.get(n))
            raise SpecError(
                f"{self.spec.source}: {label} {first}: the study '{self.spec.study.name}' was created with "
                f"{old_t.get(first, 'no such entry')!r}, the spec now says {new_t.get(first, 'nothing')!r}; "
                "resume it with its original spec or start a new study with --study-name"
            )

    # -- cost ------------------------------------------------------------------------------
    def _rung_configs(self, params: dict[str, Any]) -> list[TrainConfig]:
        """The configuration of every rung of the ladder (one element without a ladder)."""
        if not self.spec.ladder:
            return [space.to_config(self.spec, params)]
        return [space.to_config(self.spec, params, budget=b) for b in self.spec.ladder]

    def _price(self, params: dict[str, Any]) -> float | None:
        """Predicted seconds of a draw climbing the ladder up to ``min_top`` (the cost gate's question; the whole
        ladder without it); None: not buildable.

        Not its cheapest rung: a draw that can only afford 10k or 30k iterations would spend its cost on a
        value that is not comparable with the others' (a 10k score ranked beside 90k scores misleads the
        sampler and the pruner), and such draws were the costliest rung-0 trainings (60–180 s for one 10k
        score). Refusing them keeps every sampled trial's value at ``min_top`` or above; rungs above it are
        climbed where the cap allows (``plan``), so cheap configurations train longer instead of being
        refused for a rung only the cheapest could afford."""
        try:
            configs = self._rung_configs(params)
        except ConfigError:
            return None
        gated = configs[: self.spec.gated_rungs]
        if len(self._held(gated)) < len(gated):  # more memory than a worker may hold: refused whatever its time
            return None
        model = self._model()
        return sum(model.predict(c) for c in gated)

    def _model(self) -> CostModel:
        """The cost model refitted to the study's finished rungs (when their number changed)."""
        if self.study is None:
            return self.cost_model
        trials = self.study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED))
        if len(trials) == self._fitted_on:
            return self.cost_model
        obs = []
        for t in trials:
            if t.number not in self._observed:
                self._observed[t.number] = _observations(t)
            obs.extend(self._observed[t.number])
        self.cost_model = self._prior_model().fit(obs)
        self._fitted_on = len(trials)
        return self.cost_model

    def _prior_model(self) -> CostModel:
        """The prior cost model, pricing each sampled rung's ε_test screens where the spec has a grid."""
        model = CostModel.prior()
        if self.spec.ladder_epsilon_grid:
            model = model.screening(self.spec.ladder_epsilon_grid, self.spec.ladder_epsilon_screen_share,
                                    self.spec.ladder_epsilon_carried_share)  # fmt: skip
        return model

    # -- warm start ------------------------------------------------------------------------
    def _warm_start(self) -> None:
        """Enqueue the crowd prior and copy another study's measured trials, once per study."""
        assert self.study is not None
        attrs = self.study.user_attrs
        crowd_done = f"{keys.WARM_STARTED}crowd"
        if self.spec.warm_start.crowd and self.warm_configs and crowd_done not in attrs:
            n = 0
            ladder = Ladder(self.spec.ladder) if self.spec.ladder else None
            for w in self.warm_configs:
                lost = space.unencodable(w.config)
                if lost:  # the layout would not train this setting
                    self.warm_notes.append(f"{w.source}: skipped ({'; '.join(lost)})")
                    continue
                params = space.encode(self.spec, w.config)
                params, clipped = clip_params(self.spec, params)
                user: dict[str, Any] = {keys.WARM_START: w.source}
                if clipped:
                    user[keys.WARM_START_CLIPPED] = clipped
                    self.warm_notes.append(f"{w.source}: clipped into the space: {'; '.join(clipped)}")
                if ladder is not None:
                    user[keys.LADDER_TOP] = ladder.top_for(w.config.train_iterations)
                self.study.enqueue_trial(params, user_attrs=user, skip_if_exists=True)
                n += 1
            self.study.set_user_attr(crowd_done, n)
            self.warm_notes.insert(0, f"crowd prior: {n} settings enqueued (each trained and measured)")
        source = self.spec.warm_start.study
        if source and f"{keys.WARM_STARTED}{source}" not in attrs:
            copied = self._copy_trials(source)
            self.study.set_user_attr(f"{keys.WARM_STARTED}{source}", copied)
            self.warm_notes.append(f"{source}: {copied} measured trials copied into the sampler's history")

    def _copy_trials(self, source: str) -> int:
        """Add ``source``'s COMPLETE trials whose params fit this space as history (no retraining).

        A trial sampled in other coordinates (say ``epsilon_test_time`` where this space searches
        ``epsilon_test_time_shifted``, or ``learning_rate`` where it searches the rate per input) enters with its
        stored configuration encoded into this space's, when that fits."""
        assert self.study is not None
        try:
            other = optuna.load_study(study_name=source, storage=self.storages.storage)
        except KeyError:
            raise SpecError(f"--warm-start {source}: no such study in this storage; check the name "
                            "(autotune status lists them)") from None  # fmt: skip
        dists = distributions(self.spec)
        copied = 0
        for t in other.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)):
            if keys.REFINE_OF in t.user_attrs:
                continue  # its value is its parent net's training on, not a measure of its configuration
            params = dict(t.params) if set(t.params) == set(dists) else self._encoded(t)
            if params is None or set(params) != set(dists) or t.value is None:
                continue
            if clip_params(self.spec, params)[1]:
                continue  # outside this space: not this space's history
            user = {k: v for k, v in t.user_attrs.items() if k in (keys.CONFIG, keys.SEED, keys.RUNGS)}
            user[keys.COPIED_FROM] = f"{source}:{t.number}"
            self.study.add_trial(optuna.trial.create_trial(
                params=params, distributions=dists, value=t.value, user_attrs=user,
                intermediate_values=dict(t.intermediate_values),
            ))  # fmt: skip
            copied += 1
        return copied

    def _encoded(self, trial: FrozenTrial) -> dict[str, Any] | None:
        """``trial``'s stored configuration in this space's coordinates, or None (no valid configuration stored)."""
        config = trial.user_attrs.get(keys.CONFIG)
        if not isinstance(config, Mapping):
            return None
        try:
            return space.encode(self.spec, TrainConfig.from_mapping(config))
        except (ConfigError, TypeError, ValueError):
            return None

    # -- the seed race ----------------------------------------------------------------------
    def _race_window(self) -> bool:
        """True once the study is in its racing part (last race_fraction of timeout_s, or the budget spent)."""
        st = self.spec.study
        if self._race_over or st.timeout_s is None or st.race_fraction <= 0:
            return False
        elapsed = time.perf_counter() - self._t0
        if elapsed >= (1.0 - st.race_fraction) * st.timeout_s or not self._worth_starting():
            return True  # its part of the time, or no draw could reach a value before the deadline
        self._refresh_counts()
        return st.n_trials is not None and self.counts.started >= st.n_trials

    def _race_state(self) -> tuple[list[int], dict[tuple[int, int], float | None], set[tuple[int, int]]]:
        assert self.study is not None
        field = self.study.user_attrs.get(keys.RACE_FIELD)
        if field is None:
            field, budgets = self._race_field()
            raced_at = {str(n): budgets[n] for n in field if budgets[n] is not None}
            if raced_at:  # stored before the field: a driver that resumes the race finds both
                self.study.set_user_attr(keys.RACE_BUDGETS, raced_at)
            self.study.set_user_attr(keys.RACE_FIELD, field)
        results, launched = self._race_results()
        return list(field), results, launched

    def _race_results(self) -> tuple[dict[tuple[int, int], float | None], set[tuple[int, int]]]:
        """(results, launched) of every race run so far, the incumbent's before the race included: (race_of, seed
        index) → score of the finished ones (``racing.run_result``), and those finished or under way."""
        assert self.study is not None
        results: dict[tuple[int, int], float | None] = {}
        launched: set[tuple[int, int]] = set()
        for t in self.study.get_trials(deepcopy=False):
            if keys.RACE_OF not in t.user_attrs:
                continue
            key = (int(t.user_attrs[keys.RACE_OF]), int(t.user_attrs[keys.RACE_SEED]))
            is_result, score = racing.run_result(
                t.state.name, t.value, t.user_attrs.get(keys.CAUSE), bool(t.user_attrs.get(keys.RETRYABLE))
            )
            if is_result:
                results[key] = score
            if is_result or t.state in (TrialState.RUNNING, TrialState.WAITING):
                launched.add(key)  # a failed run's retry (same race_of / race_seed) or a resumed race reruns the rest
        return results, launched

    def _race_field(self) -> tuple[list[int], dict[int, int | None]]:
        """The race's entrants (best first) and the budget each races at (None: its trial's own top).

        Planned so that the first round finishes: an entrant whose run, padded by ``RACE_MARGIN``, would not fit
        the time left races at the highest lower rung (``race_min_budget`` or above) that does, or not at all;
        and entrants join in ``racing.field_order`` (the leader by mean over fresh seeds first, the best unmeasured
        configuration second, then by their fresh mean or their selecting score less the study's optimism) while
        the round's runs not yet launched, spread over the workers, fit the time left — a
        run the deadline stops scores nothing after taking a worker (measured: a 10-minute study's only entrant
        raced at 810k, predicted just under the 143 s left, took 147 s, and both its runs were lost). The leader's
        seed runs are the round's first seeds, so it usually adds nothing: counted in full, an 810k leader of the
        crowd twin's view (223–226 s a run in a 30-minute crowd-prior study, 2 seeds) leaves no room in that study's
        7.5-minute race on 2 workers for a second such entrant ((450 + 450) / 2 × 1.25 = 563 s of 450), and cheap
        90k entrants take its place."""
        assert self.study is not None
        left = self._time_left()
        results, launched = self._race_results()
        ran = {n for (n, _s) in launched}  # the incumbent's runs: at its entry's own budget
        candidates, budgets, costs = [], {}, {}
        for t in self.study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED)):
            entry = race_entry(t, self.spec.race_min_budget) if _original(t) else None
            fit = self._race_fit(entry, t.user_attrs, left, down=t.number not in ran) if entry is not None else None
            if entry is not None and fit is not None:
                candidates.append((t.number, entry[0], fit[1]))
                budgets[t.number], costs[t.number] = fit[0], fit[2]
        seeds, workers = self.spec.study.race_seeds, max(1, self.spec.resources.workers)
        field: list[int] = []
        load = 0.0  # worker-seconds of the first round so far
        for e in racing.field_order(candidates, results):
            need = costs[e.number] * sum((e.number, s) not in launched for s in range(seeds))
            if field and (load + need) / workers * RACE_MARGIN > left:
                continue  # a cheaper entrant further down may still fit
            field.append(e.number)
            load += need
            if len(field) == self.spec.study.race_configs:
                break
        return field, budgets

    def _race_fit(
        self, entry: tuple[float, int | None, dict[str, Any]], trial_attrs: Mapping[str, Any], left: float, down: bool
    ) -> tuple[int | None, dict[str, Any], float] | None:
        """(budget, config, predicted seconds) of the highest budget, down from the entry's own, whose one run
        (× ``RACE_MARGIN``) fits ``left``; None when no rung at ``race_min_budget`` or above does. A lower rung's
        config is what that rung of the trial (``trial_attrs``) trained (``trained_rung_config``), as
        ``_raced_config`` rebuilds it. ``down=False``: the entry's own budget or None (an entrant whose fresh
        seeds ran at it already: its race compares one budget)."""
        _score, budget, config = entry
        cost = self._race_cost(config)
        if cost * RACE_MARGIN <= left:
            return budget, config, cost
        if not down:
            return None
        try:
            top = TrainConfig.from_mapping(trial_attrs[keys.CONFIG])
        except (ConfigError, TypeError, ValueError):
            return None
        below = TrainConfig.from_mapping(config).train_iterations
        for b in sorted(self.spec.ladder, reverse=True):
            if b >= below or b < self.spec.race_min_budget:
                continue
            lower = trained_rung_config(top, b, trial_attrs.get(keys.RUNGS)).to_mapping()
            cost = self._race_cost(lower)
            if cost * RACE_MARGIN <= left:
                return b, lower, cost
        return None

    def _memory_cap(self) -> int:
        """Bytes one rung may allocate (``[study] max_trial_memory_gb``, else ``cost.default_memory_cap``)."""
        gb = self.spec.study.max_trial_memory_gb
        return int(gb * 1e9) if gb is not None else default_memory_cap(self.spec.resources.workers)

    def _held(self, configs: list[TrainConfig]) -> list[TrainConfig]:
        """The rungs from the first up to the last whose memory fits the cap (the ladder stops below the first that
        does not: a worker the machine cannot hold is killed, and its trial's finished rungs with it)."""
        cap = self._memory_cap()
        held: list[TrainConfig] = []
        for config in configs:
            if rung_memory_bytes(config) > cap:
                break
            held.append(config)
        return held

    def _over_memory(self, config: TrainConfig) -> str:
        need, cap = rung_memory_bytes(config) / 1e9, self._memory_cap() / 1e9
        return (f"refused: its {config.train_iterations:,}-iteration rung needs {need:,.1f} GB (replay memory "
                f"{config.replay_rows:,} × {config.net_inputs:,} inputs), over the memory cap of {cap:,.1f} GB "
                f"([study] max_trial_memory_gb)")  # fmt: skip

    def _draw_cap(self, side: bool = False) -> float:
        """The gate's cap for the next draw: the study's cost cap (``side``: a twin's or neighbour's one training,
        ``max_side_cost_s``), or the time left if less (a ladder the deadline would stop is refused: its finished
        rungs are no value, and its worker's time is lost)."""
        return min(self.spec.study.cap_s(side), self._time_left())

    def _worth_starting(self) -> bool:
        """False once the time left is below the cheapest ladder up to the gated rungs (``min_top``) this study has
        run: no draw would reach a value, so the time left goes to the seed race (``_race_window``), or the study
        ends when its running trials do instead of starting trials the deadline stops."""
        return self._time_left() >= self._cheapest_gated_s

    def _gated_seconds(self, outcome: TrialOutcome) -> float | None:
        """Seconds a sampled trial took through the rungs the gate prices (its whole run without a ladder); None
        when it stopped before them.

        Not its whole ladder: a cheap configuration climbs on to 810k, and a study whose only complete trial did
        so (200 s) once ended 195 s early, before its race, though 90k draws cost 20 s."""
        if not self.spec.ladder:
            return outcome.wall_seconds if outcome.state == COMPLETE and outcome.wall_seconds > 0 else None
        rungs = outcome.attrs.get(keys.RUNGS) or []
        need = self.spec.gated_rungs
        if len(rungs) < need:
            return None
        seconds = sum(float(r.get(keys.SECONDS) or 0.0) for r in rungs[:need])
        return seconds if seconds > 0 else None

    def _time_left(self) -> float:
        """Seconds until the study's deadline (inf without ``timeout_s``)."""
        limit = self.spec.study.timeout_s
        return math.inf if limit is None else limit - (time.perf_counter() - self._t0)

    def _race_cost(self, config: Any) -> float:
        """Predicted seconds of one race run of a trial's ``config`` mapping (inf: not buildable).

        The race's field is drawn from the configurations one run of which fits the time left: a run the
        deadline stops scores nothing, so such an entrant would only rank last after taking a worker."""
        try:
            return self._model().predict(TrainConfig.from_mapping(config), screened=False)  # at its own ε_test
        except (ConfigError, TypeError, ValueError):
            return math.inf

    def _raced_config(self, source: FrozenTrial) -> dict[str, Any]:
        """The configuration an entrant races with: its trial's, at the kept rung it entered with, if any."""
        assert self.study is not None
        config: dict[str, Any] = source.user_attrs[keys.CONFIG]
        budget = (self.study.user_attrs.get(keys.RACE_BUDGETS) or {}).get(str(source.number))
        if budget is None:
            return config
        rungs = source.user_attrs.get(keys.RUNGS)
        return trained_rung_config(TrainConfig.from_mapping(config), int(budget), rungs).to_mapping()

    def _race_runs(self) -> tuple[list[racing.RaceRun], bool]:
        """(race runs to launch now, is the race over?): the halving's next runs, then the winner's tail.

        The race is over once a round's next runs would not all fit the time left (each padded by ``RACE_MARGIN``):
        a round the deadline cuts ranks no one (a stopped run is no result), and its workers go back to the search
        and the seed soups. Measured: a 30-minute crowd-prior study (seed 0) started its second round's two 810k runs
        (~145 s each) with ~100 s left; the deadline stopped both with nothing scored, where in the minutes before
        its seed soups had made its best nets.
        Once the halving leaves one configuration, the winner takes the next fresh seed while its best run
        reaches the study's best single net (``racing.tail_reaches``), one run of it fits the time left (padded by
        ``RACE_MARGIN``) and the trial budget is not spent (a study that ends by ``n_trials`` ends after its race)."""
        field, results, launched = self._race_state()
        seeds = self.spec.study.race_seeds
        runs, over = racing.next_runs(field, results, launched, seeds)
        assert self.study is not None
        trials = self.study.get_trials(deepcopy=False)
        if not over:
            left = self._time_left()
            if any(self._race_cost(self._raced_config(trials[r.race_of])) * RACE_MARGIN > left for r in runs):
                return [], True  # the round would not finish: its runs would score nothing (the deadline stops
                # them) after taking the workers, and the winner is decided on the rounds finished
            return runs, False
        tail = racing.tail_run(field, results, launched, seeds)
        if tail is None:
            return [], True
        scores = [v for (n, _s), v in results.items() if n == tail.race_of]
        self._refresh_counts()
        budget = self.spec.study.n_trials
        if (
            not racing.tail_reaches(scores, _best_score(trials))
            or self._race_cost(self._raced_config(trials[tail.race_of])) * RACE_MARGIN > self._time_left()
            or (budget is not None and self.counts.started >= budget)
        ):
            return [], True
        return [tail], False

    def _race_slot(self, slot: int) -> bool:
        """In the race window: whether ``slot`` is taken by the race or kept for it — a race run started, else the
        oldest enqueued trial (``_launch_waiting``), else kept while a round is still under way; False once the race
        is over (the slot goes back to the search)."""
        return self._launch_race(slot) or self._launch_waiting(slot) or not self._race_over

    def _launch_waiting(self, slot: int) -> bool:
        """Start the oldest enqueued trial on ``slot``; False when none waits. Why: Optuna's queue pops the oldest
        waiting trial, so a race run enqueued behind linear neighbours (enqueued just before the race window, while
        both workers were busy) had a neighbour start in its place, and then counted as launched while it waited: no
        race run was left to start, and the race kept both slots for it. A crowd-prior hour (study seed 2) sat idle
        from minute 45 to its end that way, four neighbours and two race runs waiting."""
        assert self.study is not None
        if not self.study.get_trials(deepcopy=False, states=(TrialState.WAITING,)):
            return False
        return self._launch_next(slot)

    def _launch_race(self, slot: int) -> bool:
        """Start the next race run on ``slot``; False when none can start now (round running, or race over)."""
        assert self.study is not None
        runs, over = self._race_runs()
        if over:
            self._race_over = True
            return False
        if not runs:
            return False
        trials = self.study.get_trials(deepcopy=False)
        # longest first: a round ends with its cheap runs, not with one long run on one worker
        run = max(runs, key=lambda r: self._race_cost(self._raced_config(trials[r.race_of])))
        source = trials[run.race_of]
        seed = racing.race_seed(self.spec.study.seed, run.seed_index)
        self.study.enqueue_trial(dict(source.params), user_attrs={
            keys.CONFIG: self._raced_config(source), keys.SEED: seed, keys.RACE_OF: run.race_of,
            keys.RACE_SEED: run.seed_index,
        })  # fmt: skip
        return self._launch_next(slot)

    def _launch_incumbent(self, slot: int) -> bool:
        """Before the race, start the incumbent's next fresh seed on ``slot`` (``racing.incumbent_run``; SMAC's
        intensification); False when none starts: ``intensify_share`` is 0, its share of the workers (at least one,
        never all) is busy with such runs, the queue (crowd settings, retries) or the trial budget comes first, no
        configuration reaches the study's best single net (or every one that does has had ``intensify_runs``
        runs), or one run of the incumbent (× ``RACE_MARGIN``) would not fit the time left.

        Each run is a race run (``race_of`` / ``race_seed``, the race's own seeds), marked ``incumbent_run``: a
        configuration that enters the race has run those seeds already, and one found early gets many fresh
        trainings at the study's top (a 30-minute crowd-prior study's best, 75.37, was the 10th tail run of a
        configuration found at 8 minutes). Off in ``paper.toml``: measured on one crowd-prior hour it led at 10 and
        30 minutes and tied at 60, one configuration holding its worker from minute 7 to the race (README)."""
        assert self.study is not None
        st = self.spec.study
        share = st.intensify_share
        if share <= 0.0 or not self.spec.ladder or self._race_over or self._race_window():
            return False  # before the race only: once it is over the time left is the search's
        if not self._side_slot_free(share, sum(r.incumbent for r in self._running.values())):
            return False
        trials = self.study.get_trials(deepcopy=False)
        results, launched = self._race_results()
        best = _best_score(trials)
        ran = {n for (n, _s) in launched}
        entries = {}
        for t in trials:
            if not _original(t) or t.state not in (TrialState.COMPLETE, TrialState.PRUNED):
                continue
            nets = [s for s, _b in scored_nets(t.user_attrs, t.value, t.state == TrialState.COMPLETE)]
            if t.number not in ran and best is not None and not racing.tail_reaches(nets, best):
                continue  # no net of it reaches the best: not a candidate (and its configuration is not rebuilt)
            entry = race_entry(t, self.spec.race_min_budget)
            if entry is not None:
                entries[t.number] = entry
        candidates = racing.entrants([(n, e[0], e[2]) for n, e in entries.items()], len(entries))
        run = racing.incumbent_run(candidates, results, launched, best, max_runs=st.intensify_runs)
        return run is not None and self._launch_race_run(slot, trials, entries[run.race_of][2], run, keys.INCUMBENT_RUN)

    def _launch_race_run(
        self, slot: int, trials: list[FrozenTrial], config: dict[str, Any], run: racing.RaceRun, *flags: str
    ) -> bool:
        """Enqueue and start ``run`` (a race seed of a configuration, ``config`` its race entry's) before the race,
        marked ``flags`` (an incumbent run, a seed soup's seed, the leader's); False when it would not finish before
        the deadline."""
        assert self.study is not None
        if self._race_cost(config) * RACE_MARGIN > self._time_left():
            return False
        self.study.enqueue_trial(dict(trials[run.race_of].params), user_attrs={
            keys.CONFIG: config, keys.SEED: racing.race_seed(self.spec.study.seed, run.seed_index),
            keys.RACE_OF: run.race_of, keys.RACE_SEED: run.seed_index, **dict.fromkeys(flags, True),
        })  # fmt: skip
        return self._launch_next(slot)

    def _side_slot_free(self, share: float, busy: int) -> bool:
        """Whether a worker may start one more run of a side task (incumbent, refinement) that ``busy`` workers run
        now: under ``share`` of the workers (at least one, never all: the search always goes on), nothing waiting in
        the queue (crowd settings, retries come first), and the trial budget not spent."""
        assert self.study is not None
        workers = self.spec.resources.workers
        if busy >= min(max(1, int(share * workers)), workers - 1):
            return False
        if self.study.get_trials(deepcopy=False, states=(TrialState.WAITING,)):
            return False
        self._refresh_counts()
        budget = self.spec.study.n_trials
        return budget is None or self.counts.started < budget

    def _launch_refine(self, slot: int) -> bool:
        """Start a refinement run of the study's best single net on ``slot`` (``autotune.search.refine``); False when
        none starts: ``refine_share`` is 0, its share of the workers (at least one, never all) is busy with such
        runs, the seed race is running its rounds, the queue (crowd settings, retries) or the trial budget comes
        first, the search has not had its ``refine_start`` yet, no net is stored yet, the nets near the best had
        their ``refine_runs``, or one run (× ``RACE_MARGIN``) would not fit the time left.

        The parent is chosen when the run starts, over every net stored by then, refinement runs included
        (``refine.choose_parent``): a run that beat its parent is the next one's (the runs climb); once the best
        had its runs, the next best within ``refine.PARENT_SPAN`` mph has them. Its seed is the study's refinement
        seed number k, k = the refinement runs started before it.

        With ``[study] seed_soup_leader`` the configuration that leads by mean over its fresh seeds takes every other
        run (``_leader_turn``): on a crowd-prior hour (seed 2) the stream of neighbours' 4 probe seeds held the
        worker until the race, so no configuration had more than 4 seeds before it, and the race winner (75.22 over
        22 seeds, souped to 75.61) got its seeds only in the last quarter. With ``[study] seed_soup_best`` those
        turns go to the configurations whose nets make the best net (``ensemble.best_net_configs``) first."""
        assert self.study is not None
        st = self.spec.study
        if st.refine_share <= 0.0 or (self._race_window() and not self._race_over):
            return False
        if not self._side_slot_free(st.refine_share, sum(r.refine or r.ensemble for r in self._running.values())):
            return False
        if not self._refine_open():
            return False
        if not (st.seed_soup_leader or st.seed_soup_best):
            return self._launch_refine_run(slot)
        leader_first = self._leader_turn()  # the leader and the rest take turns; either takes the other's idle run
        if leader_first and self._launch_leader_seed(slot):
            return True
        return self._launch_refine_run(slot) or (not leader_first and self._launch_leader_seed(slot))

    def _launch_refine_run(self, slot: int) -> bool:
        """``_launch_refine``'s run other than the leader's seeds: a linear configuration's probe seeds, seeds near
        the best net, a soup of the parent's runs, or a refinement run, in that order."""
        assert self.study is not None
        st = self.spec.study
        if st.seed_soup_runs and (self._launch_seed_run(slot, st.seed_soup_reach, ensemble.PROBE_SEEDS, own=True)
                                  or self._launch_seed_run(slot, SEED_RUN_REACH)):  # fmt: skip
            return True  # a configuration in reach first gets its probe seeds; one near the best, all its seeds
        trials = self.study.get_trials(deepcopy=False)
        refine_ofs = [  # the training runs: a soup trains nothing, and uses neither a net's runs nor a seed
            t.user_attrs.get(keys.REFINE_OF) if not {keys.RETRY_OF, keys.SOUP_OF} & t.user_attrs.keys() else None
            for t in trials
        ]  # fmt: skip
        wide = st.seed_soup_runs > 0 and st.seed_soup_reach > SEED_RUN_REACH
        seeds = sum(1 for t in trials if t.user_attrs.get(keys.SEED_SOUP_RUN) and not t.user_attrs.keys() & {
            keys.RETRY_OF, keys.SEED_LEADER_RUN})  # fmt: skip
        if wide and seeds <= sum(r is not None for r in refine_ofs) and self._launch_seed_run(slot, st.seed_soup_reach):
            return True  # a linear configuration further below the best: every other run of this worker
        parent = refine.choose_parent(
            ((t.number, t.user_attrs, t.value, t.state == TrialState.COMPLETE) for t in trials), refine_ofs,
            st.refine_runs, self.spec.race_min_budget,
        )  # fmt: skip
        if parent is None:  # no net yet, or the nets near the best had their runs: seeds, else back to the search
            return wide and self._launch_seed_run(slot, st.seed_soup_reach)
        source = trials[parent.trial]
        if st.refine_soups and self._launch_soup(slot, trials, parent):
            return True
        top = TrainConfig.from_mapping(source.user_attrs[keys.CONFIG])
        rungs = source.user_attrs.get(keys.RUNGS)
        trained = top if parent.budget is None else trained_rung_config(top, parent.budget, rungs)
        # a refinement run's config already has the scaled rate: its children keep it (× 0.1 a generation froze
        # the climbs of a cold study: 1.9e-9 → 1.9e-11 in two steps)
        # (a seed soup's config is its best ingredient's, a fresh training's: its children take the scaled rate)
        scaled = refine.is_refinement(source.user_attrs) and keys.SEED_SOUP_OF not in source.user_attrs
        rate = 1.0 if scaled else st.refine_learning_rate
        config = refine.refine_config(trained, st.refine_iterations, rate).to_mapping()
        if self._race_cost(config) * RACE_MARGIN > self._time_left():
            return False
        index = sum(1 for r in refine_ofs if r is not None)
        self.study.enqueue_trial(dict(source.params), user_attrs={
            keys.CONFIG: config, keys.SEED: refine.refine_seed(st.seed, index), keys.REFINE_OF: parent.to_attr(),
        })  # fmt: skip
        return self._launch_next(slot)

    def _launch_soup(self, slot: int, trials: list[FrozenTrial], parent: refine.Parent) -> bool:
        """Score the next weight soup of ``parent``'s finished refinement runs on ``slot`` (``soup.next_soup`` over
        ``[study] refine_soups``, runs within ``refine_soup_span`` of the parent); False when every size's best set
        had its soup."""
        assert self.study is not None
        mine = parent.to_attr()
        runs, tried = [], []
        for t in trials:
            of = t.user_attrs.get(keys.REFINE_OF)
            if of is None or keys.RETRY_OF in t.user_attrs or (of.get("trial"), of.get("budget")) != (
                    mine["trial"], mine["budget"]):  # fmt: skip
                continue
            if keys.SOUP_OF in t.user_attrs:
                tried.append(t.user_attrs[keys.SOUP_OF])
            elif t.state == TrialState.COMPLETE and t.value is not None and t.user_attrs.get(keys.ARTIFACT_NET_JSON):
                runs.append((t.number, float(t.value)))
        st = self.spec.study
        ingredients = soup.next_soup(runs, st.refine_soups, tried, parent.score - st.refine_soup_span)
        if ingredients is None:
            return False
        first = trials[ingredients[0]]
        self.study.enqueue_trial(dict(first.params), user_attrs={
            keys.CONFIG: first.user_attrs[keys.CONFIG], keys.REFINE_OF: mine, keys.SOUP_OF: list(ingredients),
        })  # fmt: skip
        return self._launch_next(slot)

    def _launch_seed_soup(self, slot: int) -> bool:
        """Score the next seed soup of a linear configuration on ``slot`` (``ensemble.next_seed_soup`` over ``[study]
        seed_soups``, then its greedy soup with ``seed_soup_greedy``: its nets within ``refine_soup_span`` of its
        best, configurations within ``SEED_SOUP_REACH``, or ``seed_soup_reach`` when wider, of the study's best net);
        False when there is none, the queue comes first, or the deadline is near.

        The soup is a refinement trial of its configuration's best net (``refine_of``: a soup that beats it is a
        parent like any refinement run that did), with ``soup_of`` its ingredients and ``seed_soup_of`` the
        configuration's selecting trial."""
        assert self.study is not None
        st = self.spec.study
        if not st.seed_soups or self._time_left() < SEED_SOUP_MIN_LEFT_S:
            return False
        if self.study.get_trials(deepcopy=False, states=(TrialState.WAITING,)):
            return False
        trials = self.study.get_trials(deepcopy=False)
        rows = [(t.number, t.user_attrs, t.value, t.state == TrialState.COMPLETE) for t in trials]
        groups, family = ensemble.seed_groups(rows, st.seed_soup_families, st.seed_ensembles, st.seed_soup_views)
        if not any(len(nets) > 1 for nets in groups.values()):
            return False
        if not st.seed_soup_families:
            family = {}
        tried: dict[int, list[list[int]]] = {}
        scored: dict[int, list[tuple[list[int], float]]] = {}
        for t in trials:
            owner = t.user_attrs.get(keys.SEED_SOUP_OF)
            if owner is not None and keys.RETRY_OF not in t.user_attrs:
                owner = family.get(int(owner), int(owner))  # a soup scored before an earlier twin joined its family
                soup_of = list(t.user_attrs.get(keys.SOUP_OF) or ())
                tried.setdefault(owner, []).append(soup_of)
                if t.state == TrialState.COMPLETE and t.value is not None:
                    scored.setdefault(owner, []).append((soup_of, float(t.value)))
        most = {}  # a stack is k times as wide as its members; one that cannot stack (odd maxout, LRN) has none
        for owner in groups:
            hidden = parse_layers(trials[owner].user_attrs[keys.CONFIG].get("layers", ""))
            widest = stack.widest_hidden(hidden)
            if widest:
                most[owner] = max(1, ensemble.MAX_STACK_NEURONS // widest) if stack.stackable(hidden) else 1
        pick = ensemble.next_seed_soup(
            groups, tried, st.seed_soups, st.refine_soup_span, _best_score(trials),
            max(SEED_SOUP_REACH, st.seed_soup_reach),
            scored if st.seed_soup_greedy else None, most, st.seed_soup_swap_span,
        )  # fmt: skip
        if pick is None:
            return False
        owner, ingredients = pick
        number, score = max(groups[owner], key=lambda r: (r[1], -r[0]))
        best = trials[number]
        config = TrainConfig.from_mapping(best.user_attrs[keys.CONFIG])
        if config.layers:  # a stack of k: its config has every hidden width × k, so it refines as it is stored
            config = config.replace(layers=stack.stacked_hidden(config.layers, len(ingredients)))
        else:  # nets of several views (seed_soup_views) are souped on the union of their views (``_soup_net``)
            wide = widen.union(ensemble.view_of(trials[n].user_attrs[keys.CONFIG]) for n in ingredients)
            config = config.replace(**dict(zip(ensemble.VIEW_FIELDS, wide, strict=True)))
        self.study.enqueue_trial(dict(best.params), user_attrs={
            keys.CONFIG: config.to_mapping(), keys.REFINE_OF: refine.Parent(number, None, score).to_attr(),
            keys.SOUP_OF: list(ingredients), keys.SEED_SOUP_OF: owner,
        })  # fmt: skip
        return self._launch_next(slot)

    def _launch_seed_run(self, slot: int, reach: float, runs: int | None = None, own: bool = False) -> bool:
        """Start a fresh seed of a linear configuration within ``reach`` mph of the study's best net on ``slot``, for
        its seed soups (``ensemble.next_seed_run``, up to ``runs`` or ``[study] seed_soup_runs`` seeds, the fewer):
        a race run before the race, on the race's seeds, so the race counts it. With ``[study] seed_ensembles`` a
        configuration with hidden layers too, only within ``SEED_RUN_REACH`` (of the best net, or its own net of
        the best fresh training's) and up to ``ensemble.STACK_SEED_RUNS`` seeds (one trains for longer: no probe
        seeds further below). The caller (``_launch_refine``) has checked the
        refinement's share.

        A configuration's level is its best net or seed soup, a family's soup counting for each of its members; with
        ``own`` (the probe seeds, ``ensemble.PROBE_SEEDS``) its own nets alone: a probe measures a configuration, and
        by the family's level the best family's members took every probe. A crowd-prior hour (seed 0, 3065400) gave
        its probes to the family of the crowd twin's soups (75.48–75.68): to gsurma's adadelta twin (its own best
        71.97; its probes 72.36, 58.85, 60.66, 37.69) and a view neighbour (73.74), while the twin's γ neighbour
        (74.91 on its one seed, in another family by its ε_test) had none; retrained offline it scored 75.37–75.67
        on 4 seeds, where the twin's runs averaged 74.77 without its two collapses. With own levels the same hour
        (030ceb1) probed it from minute 18.5 (75.47–75.49) and reached 75.91, its pick 75.44 on fresh seeds."""
        assert self.study is not None
        st = self.spec.study
        trials = self.study.get_trials(deepcopy=False)
        entries = {}
        for t in trials:
            if not _original(t) or t.state not in (TrialState.COMPLETE, TrialState.PRUNED):
                continue
            entry = race_entry(t, self.spec.race_min_budget)
            if entry is not None and (ensemble.is_linear(entry[2]) or (
                    st.seed_ensembles and reach <= SEED_RUN_REACH
                    and stack.stackable(parse_layers(entry[2].get("layers", ""))))):  # fmt: skip
                entries[t.number] = entry  # one with hidden layers: only near the best (no probe seeds), if it stacks
        if not entries:
            return False
        candidates = racing.entrants([(n, e[0], e[2]) for n, e in entries.items()], len(entries))
        level: dict[int, float] = {}
        rows = [(t.number, t.user_attrs, t.value, t.state == TrialState.COMPLETE) for t in trials]
        groups, family = ensemble.seed_groups(rows, hidden=st.seed_ensembles, views=st.seed_soup_views)
        for owner, nets in groups.items():
            level[owner] = max(s for _, s in nets)
        if not own:  # a probe's level is its own nets; otherwise its seed soups count, a family's for each member
            if not st.seed_soup_families:
                family = {}
            members: dict[int, list[int]] = {}
            for owner, head in family.items():
                members.setdefault(head, []).append(owner)
            for t in trials:
                of = t.user_attrs.get(keys.SEED_SOUP_OF)
                if of is not None and t.state == TrialState.COMPLETE and t.value is not None:
                    for owner in members.get(family.get(int(of), int(of)), [int(of)]):
                        level[owner] = max(level.get(owner, -math.inf), float(t.value))
        _results, launched = self._race_results()
        hidden = {n: ensemble.STACK_SEED_RUNS for n, e in entries.items() if not ensemble.is_linear(e[2])}
        run = ensemble.next_seed_run(
            candidates, launched, level, _best_score(trials), reach, min(runs or st.seed_soup_runs, st.seed_soup_runs),
            hidden, _best_score(trials, fresh=True),
        )  # fmt: skip
        return run is not None and self._launch_race_run(slot, trials, entries[run.race_of][2], run, keys.SEED_SOUP_RUN)

    def _leader_turn(self) -> bool:
        """Whether the refinement's next run is the leader's seed (``[study] seed_soup_leader``): the last of its
        training runs (seed runs, refinement runs; retries aside) was not one (``keys.SEED_LEADER_RUN``)."""
        assert self.study is not None
        last: Mapping[str, Any] = {}
        for t in self.study.get_trials(deepcopy=False):
            a = t.user_attrs
            if keys.RETRY_OF not in a and (a.get(keys.SEED_SOUP_RUN) or (
                    keys.REFINE_OF in a and keys.SOUP_OF not in a)):  # fmt: skip
                last = a
        return not last.get(keys.SEED_LEADER_RUN)

    def _seed_leader(self) -> tuple[racing.RaceRun, dict[str, Any]] | None:
        """(its next seed run, its race entry's config) of the best configuration by mean over its fresh seeds
        (``racing.provisional_standings``) that may take more (``_launch_seed_run``'s kinds, under their cap:
        ``seed_soup_runs``, or ``ensemble.STACK_SEED_RUNS`` with hidden layers; ``ensemble.next_seed_run`` ranked by
        that mean, with no reach), or None. With ``[study] seed_soup_best`` the best net's configurations first
        (``_best_net_seed``), and only they unless ``seed_soup_leader`` is on too."""
        assert self.study is not None
        st = self.spec.study
        trials = self.study.get_trials(deepcopy=False)
        results, launched = self._race_results()
        if st.seed_soup_best:
            mine = self._best_net_seed(trials, results, launched)
            if mine is not None or not st.seed_soup_leader:
                return mine
        means = {s.number: s.mean for s in racing.provisional_standings(results)}
        return self._next_seed_of(trials, list(means), lambda number, _score: means[number], launched)

    def _next_seed_of(
        self,
        trials: list[FrozenTrial],
        numbers: Sequence[int],
        mean: Callable[[int, float], float],
        launched: set[tuple[int, int]],
    ) -> tuple[racing.RaceRun, dict[str, Any]] | None:
        """(next seed run, race entry's config) of the configurations ``numbers`` (selecting trials), the best first
        by ``mean`` (number, race entry's score → mean), the first that may take more seeds: a linear one, or with
        ``[study] seed_ensembles`` one whose hidden layers stack, under ``seed_soup_runs`` (``ensemble.
        STACK_SEED_RUNS`` with hidden layers; ``ensemble.next_seed_run`` with no reach); or None."""
        st = self.spec.study
        candidates, configs, most = [], {}, {}
        for number in numbers:
            entry = race_entry(trials[number], self.spec.race_min_budget)
            if entry is None:
                continue
            config = configs[number] = entry[2]
            if not ensemble.is_linear(config):
                if not (st.seed_ensembles and stack.stackable(parse_layers(config.get("layers", "")))):
                    continue
                most[number] = ensemble.STACK_SEED_RUNS
            candidates.append(racing.Entrant(number, mean(number, entry[0]), racing.config_key(config)))
        run = ensemble.next_seed_run(candidates, launched, {}, None, 0.0, st.seed_soup_runs, most)
        return None if run is None else (run, configs[run.race_of])

    def _best_net_seed(
        self, trials: list[FrozenTrial], results: Mapping[tuple[int, int], float | None], launched: set[tuple[int, int]]
    ) -> tuple[racing.RaceRun, dict[str, Any]] | None:
        """``_seed_leader`` with ``[study] seed_soup_best``: the next seed run of the configurations whose nets make
        the study's best net (``ensemble.best_net_configs``; those ``_launch_seed_run`` may seed, under the same
        caps), the best first by mean over its race entry's score and its fresh seeds' (``results``), or None."""
        best = _best_net(trials)
        if best is None:
            return None
        number = best[1]

        def mean(owner: int, score: float) -> float:
            scores = [score, *(s for (n, _i), s in results.items() if n == owner and s is not None)]
            return sum(scores) / len(scores)

        attrs = [t.user_attrs for t in trials]
        owners = ensemble.best_net_configs(number, attrs)
        span = self.spec.study.seed_soup_best_span
        if span <= 0.0:
            return self._next_seed_of(trials, owners, mean, launched)
        values = [t.value if t.state == TrialState.COMPLETE else None for t in trials]
        seeds = collections.Counter(n for n, _i in launched)
        others = ensemble.contender_configs(
            attrs, values, best[0] - span, seeds, skip=owners, views=self.spec.study.seed_soup_views
        )
        last = _last_turn_of(trials)
        order = [*others, owners] if last is not None and last in owners else [owners, *others]
        for group in order:  # the best net's family and the others take turns, the others fewest seeds first
            run = self._next_seed_of(trials, group, mean, launched)
            if run is not None:
                return run
        return None

    def _launch_leader_seed(self, slot: int) -> bool:
        """Start the next fresh seed of ``_seed_leader`` on ``slot``, a seed run like ``_launch_seed_run``'s; False
        when there is no such configuration or the run would not fit the time left."""
        leader = self._seed_leader()
        if leader is None:
            return False
        assert self.study is not None
        run, config = leader
        trials = self.study.get_trials(deepcopy=False)
        return self._launch_race_run(slot, trials, config, run, keys.SEED_SOUP_RUN, keys.SEED_LEADER_RUN)

    def _soup_net(self, ingredients: list[int], stacked: bool = False, config: TrainConfig | None = None) -> str:
        """The convnetjs Net JSON of the weight soup of ``ingredients``' stored nets; ``stacked`` (a seed soup): their
        ensemble (``stack.stack_nets``: the mean of their weights without hidden layers, else side by side). Given
        the soup's ``config`` without hidden layers, each net is first moved onto its view (``widen.widen_linear``;
        the union of theirs with ``seed_soup_views``, a net of that view itself)."""
        assert self.study is not None
        texts = [(int(n), self._parent_net(refine.Parent(int(n), None, 0.0))) for n in ingredients]
        combine = stack.stack_nets if stacked else soup.average_nets
        try:
            nets = [loads_net(text, where=f"trial {n}") for n, text in texts]
            if stacked and config is not None and not config.layers:
                trials = self.study.get_trials(deepcopy=False)
                views = [ensemble.view_of(trials[n].user_attrs[keys.CONFIG]) for n, _ in texts]
                wide = ensemble.view_of(config)
                nets = [widen.widen_linear(net, view, wide, config.temporal_window)
                        for net, view in zip(nets, views, strict=True)]  # fmt: skip
            return dumps_net(combine(nets))
        except ConfigError as exc:
            raise _Refused(f"weight soup: {exc}") from None

    def _refine_open(self) -> bool:
        """Whether the search has had its ``refine_start`` share of the study's budget: of ``timeout_s`` (this run's
        time), else of ``n_trials`` (trials started), else none to wait for. A crowd-prior study opens as soon as
        its crowd settings are enqueued (``_side_slot_free`` then waits until each has started): its first nets at
        the race's floor are the crowd's best settings, not a cold search's first draws. Waiting the quarter hour
        of a 60-minute study left gsurma's 74.95 net, scored at minute 2, unrefined until minute 15."""
        assert self.study is not None
        st = self.spec.study
        if st.refine_start <= 0.0 or self.study.user_attrs.get(f"{keys.WARM_STARTED}crowd"):
            return True
        if st.timeout_s is not None:
            return time.perf_counter() - self._t0 >= st.refine_start * st.timeout_s
        if st.n_trials is not None:
            self._refresh_counts()
            return self.counts.started >= st.refine_start * st.n_trials
        return True

    def _parent_net(self, parent: refine.Parent) -> str:
        """The convnetjs Net JSON of ``parent`` (a trial's net, or its kept rung's) from the artifact store."""
        assert self.study is not None
        attrs = self.study.get_trials(deepcopy=False)[parent.trial].user_attrs
        try:
            return net_text(self.storages, parent.trial, attrs, parent.budget)
        except RecordError as exc:
            raise _Refused(f"refinement: {exc}") from None

    def _fail_orphans(self, study: optuna.Study) -> list[int]:
        storage = self.storages.storage
        if _heartbeat_enabled(storage):
            optuna.storages.fail_stale_trials(study)  # other hosts' dead drivers (RDB heartbeats)
        failed = []
        now = time.time()
        for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
            owner = t.system_attrs.get(keys.DRIVER)
            if isinstance(owner, dict) and owner.get("host") == self.owner["host"]:
                dead = not _owner_alive(owner)
            else:  # another host, or no owner: only a silent heartbeat proves it dead
                beat = t.system_attrs.get(keys.HEARTBEAT)
                dead = beat is not None and now - float(beat) > GRACE_PERIOD_S
                if beat is None and not _heartbeat_enabled(storage) and t.datetime_start is not None:
                    dead = time.mktime(t.datetime_start.timetuple()) < now - GRACE_PERIOD_S
            if not dead:
                continue
            who = f"{owner.get('host')}:{owner.get('pid')}" if isinstance(owner, dict) else "unknown"
            trial_id = self._trial_id(t.number)
            storage.set_trial_user_attr(trial_id, keys.CAUSE, f"driver lost: driver {who} stopped while the trial ran")
            storage.set_trial_user_attr(trial_id, keys.RETRYABLE, True)
            try:
                storage.set_trial_state_values(trial_id, TrialState.FAIL)
                failed.append(t.number)
            except optuna.exceptions.UpdateFinishedTrialError:  # another driver got there first
                pass
        return failed

    def _trial_id(self, number: int) -> int:
        """The storage's id of trial ``number`` of this study (Optuna's public storage API)."""
        assert self.study_id is not None
        return self.storages.storage.get_trial_id_from_study_id_trial_number(self.study_id, number)

    def _enqueue_retries(self) -> None:
        """Enqueue one retry for every retryable failure that has none yet (and retries left)."""
        assert self.study is not None
        trials = self.study.get_trials(deepcopy=False)
        by_number = {t.number: t for t in trials}
        retried = {t.user_attrs.get(keys.RETRY_OF) for t in trials}
        for t in trials:
            if t.state != TrialState.FAIL or t.number in retried or not self._retryable(t):
                continue
            depth, cur = 0, t
            while keys.RETRY_OF in cur.user_attrs and cur.user_attrs[keys.RETRY_OF] in by_number:
                depth += 1
                cur = by_number[cur.user_attrs[keys.RETRY_OF]]
            if depth >= self.spec.study.max_retries:
                continue
            seed = t.user_attrs.get(keys.SEED, trial_seed(self.spec.study.seed, cur.number))
            given = {k: t.user_attrs[k] for k in t.system_attrs.get(keys.ENQUEUED, ()) if k in t.user_attrs}
            self.study.enqueue_trial(t.params, user_attrs={**given, keys.RETRY_OF: t.number, keys.SEED: seed})

    @staticmethod
    def _retryable(t: FrozenTrial) -> bool:
        # ours say so; a FAIL with no cause was failed by Optuna's heartbeat check (a dead driver)
        return bool(t.user_attrs.get(keys.RETRYABLE)) or keys.CAUSE not in t.user_attrs

    def _refresh_counts(self) -> None:
        assert self.study is not None
        c = self.counts
        trials = [t for t in self.study.get_trials(deepcopy=False) if keys.COPIED_FROM not in t.user_attrs]
        c.started = sum(1 for t in trials if _original(t) and t.state != TrialState.WAITING)
        c.retries = sum(1 for t in trials if keys.RETRY_OF in t.user_attrs and not _rerun(t))
        c.race_runs = sum(1 for t in trials if keys.RACE_OF in t.user_attrs)
        c.refine_runs = sum(1 for t in trials if keys.REFINE_OF in t.user_attrs)
        c.complete = sum(1 for t in trials if t.state == TrialState.COMPLETE)
        c.pruned = sum(1 for t in trials if t.state == TrialState.PRUNED)
        c.failed = sum(1 for t in trials if t.state == TrialState.FAIL)
        c.running = len(self._running)
        done = [t for t in trials if t.state == TrialState.COMPLETE and t.value is not None]
        if done:
            best = max(done, key=lambda t: (t.value, -t.number))
            c.best_value, c.best_number = float(best.value), best.number  # type: ignore[arg-type]
        c.elapsed_s = time.perf_counter() - self._t0 if self._t0 else 0.0

    def _notify(self) -> None:
        self._refresh_counts()
        if self.progress is not None:
            self.progress(self.counts)

    # -- the loop ---------------------------------------------------------------------------
    def run(self) -> StudyCounts:
        """Run the study until its budget (n_trials / timeout_s) is spent; returns the final counts."""
        from autotune.search.workers import WorkerPool

        if self.study is None:
            self.open_study()
        self._t0 = time.perf_counter()
        self._wall0 = time.time()
        self._warm_start()
        if self.warm_notes and self.on_warm_start is not None:
            self.on_warm_start(self.warm_notes)
        self._enqueue_retries()
        if not self._launch_possible():  # the budget is spent already: no Ray at all
            self._notify()
            return self.counts
        r = self.spec.resources
        self.pool = WorkerPool(
            r.workers, cpus_per_trial=r.cpus_per_trial, gpus_per_trial=r.gpus_per_trial,
            address=self.address, state_dir=self.state_dir,
        )  # fmt: skip
        try:
            self.pool.start()
            self.startup_seconds = time.perf_counter() - self._t0
            self._notify()
            self._loop()
        finally:
            try:
                self._abandon_running("driver stopped before the trial ended")
            finally:
                self.pool.close()
        self._notify()
        return self.counts

    def _out_of_time(self) -> bool:
        limit = self.spec.study.timeout_s
        return limit is not None and time.perf_counter() - self._t0 >= limit

    def _loop(self) -> None:
        assert self.study is not None
        last_note = time.perf_counter()
        while True:
            if not self._out_of_time():
                for slot in self.pool.idle_slots(set(self._running)):
                    self._release_side()
                    if self._launch_seed_soup(slot):
                        continue  # seconds of evaluation: before the race's runs and the search's
                    if self._race_window() and self._race_slot(slot):
                        continue  # started a race run, or a round is still running: keep the slot for it
                    if not (self._launch_refine(slot) or self._launch_incumbent(slot) or self._launch_next(slot)):
                        break
            if not self._running:
                if self._out_of_time() or not self._launch_possible():
                    return
                if not self._worth_starting() and not self.study.get_trials(
                    deepcopy=False, states=(TrialState.WAITING,)
                ):
                    return  # no sampled trial could finish before the deadline, and nothing is queued
            for event in self.pool.poll(timeout=1.0):
                self._handle(event)
            now = time.perf_counter()
            if now - self._last_beat >= HEARTBEAT_INTERVAL_S:
                self._heartbeat()
                self._kill_hung(now)
            if now - last_note >= 1.0:
                last_note = now
                self._notify()

    def _kill_hung(self, now: float) -> None:
        """Backstop of the per-trial limit: a worker silent well past it (stuck in native code) is killed.

        The objective enforces ``trial_timeout_s`` itself at ~1 % steps of training and before the
        official evaluation; only a worker that cannot get there is killed, and its trial fails
        without a retry (the same params would hang again).
        """
        limit = self.spec.study.trial_timeout_s
        for run in self._running.values():
            if not run.killed and now - run.started > 2 * limit + HEARTBEAT_INTERVAL_S:
                run.killed = (
                    f"timeout: worker killed, no answer {now - run.started:.0f} s into a trial limited to {limit:g} s"
                )
                self.pool.kill(run.slot)

    def _launch_possible(self) -> bool:
        """True while a retry waits or the budget allows another original trial."""
        assert self.study is not None
        if self.study.get_trials(deepcopy=False, states=(TrialState.WAITING,)):
            return True
        if self._race_window():
            if not self._race_runs()[1]:
                return True
            self._race_over = True
        self._refresh_counts()
        budget = self.spec.study.n_trials
        return budget is None or self.counts.started < budget

    def _launch_next(self, slot: int) -> bool:
        """Ask for a trial (a waiting retry first) and start it on ``slot``; False when the budget is spent or
        the time left is too short for any sampled trial to finish (``_worth_starting``)."""
        assert self.study is not None
        waiting = self.study.get_trials(deepcopy=False, states=(TrialState.WAITING,))
        if not waiting:
            self._refresh_counts()
            budget = self.spec.study.n_trials
            if budget is not None and self.counts.started >= budget:
                return False
            if not self._worth_starting():
                return False
        trial = self.study.ask()
        trial_id = self._trial_id(trial.number)
        storage = self.storages.storage
        given = sorted(k for k in trial.user_attrs if k != keys.RETRY_OF)  # what it was enqueued with
        if given:
            storage.set_trial_system_attr(trial_id, keys.ENQUEUED, given)
        storage.set_trial_system_attr(trial_id, keys.DRIVER, self.owner)
        self._beat(trial_id)
        seed = trial.user_attrs.get(keys.SEED)
        if seed is None:
            seed = trial_seed(self.spec.study.seed, trial.number)
            trial.set_user_attr(keys.SEED, seed)
        full = trial.user_attrs.get(keys.CONFIG)  # an enqueued full config (crowd replay) wins over the params
        refine_of = trial.user_attrs.get(keys.REFINE_OF)
        race = keys.RACE_OF in trial.user_attrs or refine_of is not None  # one training of a stored config
        twin = keys.TWIN_OF in trial.user_attrs or keys.NEIGHBOUR_OF in trial.user_attrs  # a linear twin or
        # neighbour: measured at its parent's budget, never pruned
        init_net: str | None = None
        try:
            params = space.sample(trial, self.spec)
            if full is not None:
                config = TrainConfig.from_mapping(full)
                if not self._held([config]):
                    raise _Refused(self._over_memory(config))
                rungs: tuple[int, ...] = (config.train_iterations,) if race and self.spec.ladder else ()
                ingredients = trial.user_attrs.get(keys.SOUP_OF)
                if ingredients is not None:
                    init_net = self._soup_net(ingredients, keys.SEED_SOUP_OF in trial.user_attrs, config)
                elif refine_of is not None:
                    init_net = self._parent_net(refine.Parent.from_attr(refine_of))
                cost = self._model().predict(config, screened=False)  # measured with its own ε_test
                predicted: Plan | None = Plan((config.train_iterations,), (cost,))
            else:
                every = self._rung_configs(params)
                configs = self._held(every)  # never a rung the worker cannot hold
                if not configs:
                    raise _Refused(self._over_memory(every[0]))
                top = trial.user_attrs.get(keys.LADDER_TOP)
                # the top: the highest rung that fits the cap and the time left (a rung the deadline would stop
                # is never started); at least the rungs the gate priced when the deadline is far
                alone = twin and bool(self.spec.ladder)  # one training at its parent's budget: no screening
                # rung prunes it, and no ladder below it is paid for ([study] max_side_cost_s)
                cap = self._draw_cap(alone)
                predicted = (plan_one if alone else plan)(configs, self._model(), cap, top)
                if predicted is None:
                    cheapest = self._model().predict(configs[0])
                    if cap >= self.spec.study.cap_s(alone):
                        raise _Refused(f"refused: its cheapest rung is predicted to take {cheapest:,.0f} s, over "
                                       f"the study's cost cap of {cap:,.0f} s ([study] "
                                       f"{self.spec.study.cap_key(alone)})")  # fmt: skip
                    # the deadline came nearer while the draw was made: stopped by it before training, like a
                    # running trial it stops (PRUNED with a 'deadline' cause), not a failure
                    raise _Refused(f"deadline: the study's time budget ended (before training: its cheapest rung "
                                   f"is predicted to take {cheapest:,.0f} s, {max(cap, 0.0):,.0f} s were left)",
                                   TrialState.PRUNED)  # fmt: skip
                config = next(c for c in configs if c.train_iterations == predicted.budgets[-1])
                rungs = predicted.budgets if self.spec.ladder else ()
        except Exception as exc:  # a combination deepqlearn rejects: a failed trial, not a crashed study
            cause = str(exc) if isinstance(exc, _Refused) else f"invalid configuration: {exc}"
            trial.set_user_attr(keys.CAUSE, cause)
            self.study.tell(trial, state=exc.state if isinstance(exc, _Refused) else TrialState.FAIL)
            self._notify()
            return True
        assert predicted is not None
        soup_of = keys.SOUP_OF in trial.user_attrs
        if not soup_of:  # the model prices trainings; a soup's one evaluation takes seconds
            trial.set_user_attr(keys.PREDICTED_COST, predicted.total_s)
            trial.set_user_attr(keys.PREDICTED_RUNG_COSTS, list(predicted.costs))
        if isinstance(self.study.sampler, CostGatedSampler):
            trial.set_user_attr(keys.REFUSED_DRAWS, self.study.sampler.refused(trial.number))
            balanced = self.study.sampler.base
            if isinstance(balanced, PriorFreeSampler):
                drew = balanced.drew(trial.number)
                if drew:
                    trial.set_user_attr(keys.PRIOR_FREE, True)
                balanced = balanced.own if drew else balanced.base
            if isinstance(balanced, DenoisedSampler):
                balanced = balanced.base
            if isinstance(balanced, BalancedSampler):
                forced = balanced.forced(trial.number)
                pairs = ((forced,) if forced is not None else ()) + balanced.forced_within(trial.number)
                if pairs:
                    trial.set_user_attr(keys.BALANCED, ",".join(f"{name}={value}" for name, value in pairs))
        e = self.spec.evaluation
        st = self.spec.study
        task = TrialTask(
            number=trial.number, config=config.to_mapping(), seed=int(seed), report_points=e.report_points,
            quick_runs=e.quick_runs, quick_frames=e.quick_frames,
            final_protocol="" if full is not None and not race else e.final_protocol,  # '': its ruleset's official
            timeout_s=st.trial_timeout_s, rungs=rungs, reseed_rungs=self.spec.ladder_reseed,
            prune_static=self.spec.ladder_prune_static and not race,  # a race run's score counts, whatever it is
            min_weight_change=0.0 if race else self.spec.ladder_min_weight_change,
            epsilon_test_grid=self.spec.ladder_epsilon_grid if full is None and rungs else (),
            epsilon_test_screen_runs=self.spec.ladder_epsilon_screen_runs,
            deadline=self._wall0 + st.timeout_s if st.timeout_s is not None and self._wall0 else None,
            init_net=init_net,
            evaluate_only=soup_of,
        )  # fmt: skip
        trial.set_user_attr(keys.WORKER, self.pool.worker_of(slot))
        trial.set_user_attr(keys.RAY_NODE, self.pool.node_of(slot))
        self._running[slot] = _Running(trial, trial_id, slot, task, silent=race or twin, sampled=not given,
                                       incumbent=bool(trial.user_attrs.get(keys.INCUMBENT_RUN)),
                                       refine=refine_of is not None,
                                       ensemble=bool(trial.user_attrs.get(keys.SEED_SOUP_RUN)))  # fmt: skip
        self.pool.submit(slot, task)
        self._notify()
        return True

    def _handle(self, event: Any) -> None:
        assert self.study is not None
        run = self._running.get(event.slot)
        if event.kind == "ready" or run is None:
            return
        if event.kind == "report":
            if run.silent:
                self.pool.answer(event.slot, False)
                return
            run.trial.report(event.score, step=event.step)
            prune = run.trial.should_prune()
            self.pool.answer(event.slot, prune)
            return
        del self._running[event.slot]
        if event.kind == "done" and run.sampled:
            wall = self._gated_seconds(event.outcome)
            if wall is not None:
                self._cheapest_gated_s = wall if self._cheapest_gated_s == 0.0 else min(self._cheapest_gated_s, wall)
        if (event.kind == "done" and not self._out_of_time() and not self._race_window() and not run.incumbent
                and not run.refine and not run.ensemble):  # fmt: skip
            # the worker starts its next trial before this one's storage writes (in the race window the loop
            # starts race runs instead, once this trial's result is stored: it may be an entrant; after an
            # incumbent's or a refinement run too: its score decides the next one)
            self._release_side()
            if not self._launch_refine(event.slot) and not self._launch_incumbent(event.slot):
                self._launch_next(event.slot)
        if event.kind == "lost":
            self._fail(run.trial, run.killed or event.cause, retryable=not run.killed and event.retry)
            self._enqueue_retries()
        else:
            self._finish(run.trial, event.outcome)
        self._notify()

    def _finish(self, trial: Trial, outcome: TrialOutcome) -> None:
        assert self.study is not None
        for key, value in outcome.attrs.items():
            trial.set_user_attr(key, _jsonable(value))
        if _never_learned(outcome.attrs):  # a told constraint: TPE ranks infeasible trials last
            trial.set_constraint(keys.POLICY_LEARNS, 1.0)
        if outcome.rung_nets:  # every finished rung's net, pruned trials included
            ids = {}
            with tempfile.TemporaryDirectory() as tmp:
                for budget, net_text in sorted(outcome.rung_nets.items()):
                    path = Path(tmp) / f"net_rung_{budget}.json"
                    path.write_text(net_text)
                    ids[str(budget)] = optuna.artifacts.upload_artifact(
                        artifact_store=self.storages.artifacts, file_path=str(path), study_or_trial=trial,
                        mimetype="application/json",
                    )  # fmt: skip
            trial.set_user_attr(keys.ARTIFACT_RUNG_NETS, ids)
        if outcome.state == COMPLETE:
            with tempfile.TemporaryDirectory() as tmp:
                for key, name, text in ((keys.ARTIFACT_NET_JSON, "net.json", outcome.net_json),
                                        (keys.ARTIFACT_NET_JS, "net.js", outcome.net_js)):  # fmt: skip
                    if text is None:
                        continue
                    path = Path(tmp) / name
                    path.write_text(text)
                    artifact_id = optuna.artifacts.upload_artifact(
                        artifact_store=self.storages.artifacts, file_path=str(path), study_or_trial=trial,
                        mimetype="application/json" if name.endswith(".json") else "text/javascript",
                    )  # fmt: skip
                    trial.set_user_attr(key, artifact_id)
            self.study.tell(trial, outcome.value)
        elif outcome.state == PRUNED:
            self.study.tell(trial, state=TrialState.PRUNED)
        else:
            assert outcome.state == FAILED
            self.study.tell(trial, state=TrialState.FAIL)
        self._enqueue_twins()
        self._enqueue_neighbours()

    def _twin_score(self, t: FrozenTrial) -> float | None:
        """A trial's score as a parent of linear twins: its seed-race entry's (its best net at min_top or above)."""
        entry = race_entry(t, self.spec.race_min_budget)
        return None if entry is None else entry[0]

    def _enqueue_twins(self) -> None:
        """Enqueue the linear twins (``[study] linear_twins``) of the study's best configuration, and of each within
        ``linear_twin_span`` of it, once per parent (``twins.parents``; a resumed study sees the twins it stored),
        before the sampler's next draw. A twin trains once, at the budget of its parent's best net
        (``keys.LADDER_TOP``), unpruned: on the ladder its 10k screen (sd ~10 mph) pruned the twins of gsurma's
        setting at 62–72, where the same twin at 90k scored 73.7–74.4. With ``[warm_start] crowd_twins`` each crowd
        setting without hidden layers is a parent too, once started, whatever it scored, its twins at the ladder's
        top (``_crowd_linear``)."""
        assert self.study is not None
        st = self.spec.study
        if not st.linear_twins or self._out_of_time() or self._race_window():
            return
        trials = self.study.get_trials(deepcopy=False)
        done = {t.user_attrs.get(keys.TWIN_OF) for t in trials} | self._planned(keys.TWIN_OF)
        sources = twins.parents(trials, self._twin_score, st.linear_twin_span)
        own = self._prior_free(trials)
        if own is not None:  # and the prior-free sampler's best (``[study] prior_free_share``)
            sources += twins.parents(own, self._twin_score, 0.0)
        tops: list[tuple[FrozenTrial, int | None]] = []
        for source in sources:
            entry = race_entry(source, self.spec.race_min_budget)
            budget = None if entry is None else entry[1] if entry[1] is not None else entry[2].get("train_iterations")
            tops.append((source, budget))  # its twins train as long as its best net did
        if self.spec.warm_start.crowd_twins:  # at the ladder's top: the cost cap picks the rung (``plan_one``)
            top = self.spec.ladder[-1] if self.spec.ladder else None
            tops += [(source, top) for source in self._crowd_linear(trials)]
        for source, budget in tops:
            if source.number in done:
                continue
            done.add(source.number)
            user: dict[str, Any] = {keys.TWIN_OF: source.number}
            if self.spec.ladder and budget in self.spec.ladder:
                user[keys.LADDER_TOP] = self.spec.ladder.index(budget)
            for params in twins.twins(source.params, st.linear_twins):
                self._plan_side(params, user)

    @staticmethod
    def _crowd_linear(trials: Sequence[FrozenTrial]) -> list[FrozenTrial]:
        """The crowd prior's settings without hidden layers that have started (``[warm_start] crowd_twins``).

        Why their twins, whatever their own score: the crowd's linear nets were trained on loaded weights.
        jnorthrup-v05 (the best v2 human net, 75.80 in this engine: 6 lanes a side, 52 patches ahead, adagrad at
        1e-8, 50k iterations) fine-tuned the weights of its 500k-iteration version; from a fresh start its rate
        learns nothing. Its view as a linear adagrad net at 8 per input scored 75.22, 75.37, 75.22, 74.84 at 810k
        (seeds 11-14; its 4 seeds souped at 75.60), at 3 per input 75.09 and 74.27: one of the strongest families
        measured, which the crowd-prior hours, starting from gsurma's narrow view, never reached."""
        return [t for t in trials if keys.WARM_START in t.user_attrs and t.state != TrialState.WAITING
                and t.params.get("n_layers") == 0]  # fmt: skip

    def _enqueue_neighbours(self) -> None:
        """Enqueue the neighbours (``[study] linear_neighbours``, ``twins.neighbours``) of two linear configurations,
        each once (a resumed study sees the neighbours it stored), each neighbour trained like a linear twin: once,
        at its parent's budget, unpruned. The first is the configuration of the study's best net when linear
        (``_best_linear_configuration``: its own training, or its seed soup's best ingredient's); the second the linear
        configuration with the best mean over its fresh seed runs (``racing.provisional_standings``), so that a
        neighbour whose seeds beat its parent's carries the climb on. Measured in a crowd-prior hour (seed 1): the
        family soups of one configuration's neighbours went 75.40 → 75.62, and its neighbour with a lane a side
        fewer averaged 75.02 over 61 seeds (the parent 74.53 over 4), but got no neighbours of its own: its soups
        were not the best net."""
        assert self.study is not None
        if not self.spec.study.linear_neighbours or self._out_of_time() or self._race_window():
            return
        trials = self.study.get_trials(deepcopy=False)
        done = {t.user_attrs.get(keys.NEIGHBOUR_OF) for t in trials} | self._planned(keys.NEIGHBOUR_OF)
        for owner, params, budget in self._neighbour_parents(trials):
            if owner in done:
                continue
            done.add(owner)
            user: dict[str, Any] = {keys.NEIGHBOUR_OF: owner}
            if self.spec.ladder and budget in self.spec.ladder:  # its neighbours train as long as its nets did
                user[keys.LADDER_TOP] = self.spec.ladder.index(budget)
            for moved in twins.neighbours(params, self.spec.space):
                self._plan_side(moved, user)

    def _plan_side(self, params: dict[str, Any], user: dict[str, Any]) -> None:
        """Enqueue a linear twin or neighbour now, or with ``[study] side_share`` < 1 add it to the study's side plan
        (``keys.SIDE_PLAN``), which ``_release_side`` enqueues from while their share of the time allows."""
        assert self.study is not None
        if self.spec.study.side_share >= 1.0:
            self.study.enqueue_trial(params, user_attrs=user, skip_if_exists=True)
            return
        plan = list(self.study.user_attrs.get(keys.SIDE_PLAN) or [])
        if all(e["params"] != params for e in plan):
            self.study.set_user_attr(keys.SIDE_PLAN, [*plan, {"params": params, "user_attrs": user, "released": False}])

    def _planned(self, key: str) -> set[Any]:
        """The parents (``key``: ``twin_of`` or ``neighbour_of``) of the side plan's entries: planned is done."""
        assert self.study is not None
        return {e["user_attrs"].get(key) for e in self.study.user_attrs.get(keys.SIDE_PLAN) or []}

    def _release_side(self) -> None:
        """Enqueue the side plan's next entry (``next_side_entry``: the newest parent's first), while nothing else
        waits and the twins and neighbours have taken at most ``[study] side_share`` of the workers' time so far
        (their finished trials' wall seconds and the running ones' so far, against every trial's); before the race
        only.

        Why: each is one unpruned training at its parent's budget, and each new best or leader enqueues 3–10 of
        them. A cold hour (study seed 1) whose early best was a linear net at 810k (73.18; its seeds 67.7 and 73.7)
        spent 58 % of its first 30 minutes on 8 twins and 10 neighbours (~150 s each, none above 73.92), the search
        33 %, and stood at 73.92 / 74.30 at 30 / 60 minutes; capped at a third, the same seed's search found a
        linear family at 14.9 min whose soups reached 74.88 / 75.02. The crowd-prior hours gave them 9–27 % of the
        first 30 minutes (each ~10–40 s), under that cap."""
        assert self.study is not None
        share = self.spec.study.side_share
        if share >= 1.0 or self._out_of_time() or self._race_window():
            return
        plan = self.study.user_attrs.get(keys.SIDE_PLAN) or []
        if not plan:
            return
        trials = self.study.get_trials(deepcopy=False)
        if any(t.state == TrialState.WAITING for t in trials):
            return
        side = total = 0.0
        for t in trials:
            if t.state == TrialState.RUNNING:
                continue
            seconds = float(t.user_attrs.get(keys.TRIAL_WALL_SECONDS) or 0.0)
            total += seconds
            side += seconds if _side(t.user_attrs) else 0.0
        now = time.perf_counter()
        for run in self._running.values():
            total += now - run.started
            side += now - run.started if _side(run.trial.user_attrs) else 0.0
        if side > share * total:
            return
        i = next_side_entry(plan)
        if i is not None:
            entry = plan[i]
            self.study.enqueue_trial(entry["params"], user_attrs=entry["user_attrs"], skip_if_exists=True)
            self.study.set_user_attr(keys.SIDE_PLAN, [*plan[:i], {**entry, "released": True}, *plan[i + 1 :]])

    def _prior_free(self, trials: Sequence[FrozenTrial]) -> list[FrozenTrial] | None:
        """With ``[study] prior_free_share``: the prior-free sampler's draws and the trials made from them
        (``prior.prior_free``), whose best gets twins and neighbours as the study's does; else None."""
        return prior.prior_free(trials) if self.spec.study.prior_free_share > 0.0 else None

    def _neighbour_parents(self, trials: Sequence[FrozenTrial]) -> list[tuple[int, dict[str, Any], Any]]:
        """(configuration, parameters to move, budget) of ``_enqueue_neighbours``'s parents: the linear configuration
        of the best net (``_best_linear_configuration``), that of the prior-free sampler's draws and what was made
        from them (``[study] prior_free_share``), then the linear leader by mean over its fresh seeds."""
        parents: list[tuple[int, dict[str, Any], Any]] = []
        own = self._prior_free(trials)
        for pool in (trials,) if own is None else (trials, own):
            found = _best_linear_configuration(pool, self.spec.race_min_budget)
            if found is not None:
                parents.append(found)
        seed_configs: dict[int, Mapping[str, Any]] = {}  # a configuration's seed runs' config (their budget)
        for t in trials:
            if keys.RACE_OF in t.user_attrs and t.state == TrialState.COMPLETE and keys.CONFIG in t.user_attrs:
                seed_configs[int(t.user_attrs[keys.RACE_OF])] = t.user_attrs[keys.CONFIG]
        for standing in racing.provisional_standings(self._race_results()[0]):
            config = seed_configs.get(standing.number)
            if config is not None and ensemble.is_linear(config):
                parents.append((standing.number, dict(trials[standing.number].params), config.get("train_iterations")))
                break
        return parents

    def _fail(self, trial: Trial, cause: str, *, retryable: bool) -> None:
        assert self.study is not None
        trial.set_user_attr(keys.CAUSE, cause)
        trial.set_user_attr(keys.RETRYABLE, retryable)
        self.study.tell(trial, state=TrialState.FAIL)

    def _abandon_running(self, cause: str) -> None:
        """Fail (retryable) the trials still running when the driver leaves, so none stays RUNNING."""
        for run in list(self._running.values()):
            try:
                self._fail(run.trial, cause, retryable=True)
            except Exception:  # noqa: S110 - the storage itself may be what failed; a resume cleans up
                pass
        self._running.clear()

    # -- heartbeats -------------------------------------------------------------------------
    def _beat(self, trial_id: int) -> None:
        storage = self.storages.storage
        if _heartbeat_enabled(storage):
            storage.record_heartbeat(trial_id)  # type: ignore[attr-defined]
        else:
            storage.set_trial_system_attr(trial_id, keys.HEARTBEAT, time.time())

    def _heartbeat(self) -> None:
        self._last_beat = time.perf_counter()
        for run in self._running.values():
            self._beat(run.trial_id)


def _observations(t: FrozenTrial) -> list[Observation]:
    """A finished trial's rungs as cost observations (work terms, wall seconds); a single training as one."""
    cfg = t.user_attrs.get(keys.CONFIG)
    if not isinstance(cfg, dict) or keys.COPIED_FROM in t.user_attrs or keys.SOUP_OF in t.user_attrs:
        return []  # copied (timed elsewhere) or a soup (an evaluation, no training)
    try:
        top = TrainConfig.from_mapping(cfg)
    except ConfigError:
        return []
    out = []
    rungs = t.user_attrs.get(keys.RUNGS) or ()
    share, runs = _screen_share_of(t)
    for rung in rungs:
        seconds = rung.get(keys.SECONDS)
        if isinstance(seconds, (int, float)):
            config = trained_rung_config(top, int(rung[keys.BUDGET]), rungs)
            screens = rung.get(keys.EPSILON_SCREEN) or ()
            screen = [float(s[0]) for s in screens]
            shares = [float(s[3]) / runs if len(s) > 3 and runs else share for s in screens]  # a halving's own runs
            if rung.get(keys.SCORE, 0.0) is None:  # not scored officially: its training, and any screens it ran
                x = features(config, evaluated=bool(screens), screen=screen, screen_share=shares, carried=1.0)
            else:
                x = features(config, screen=screen, screen_share=shares)
            out.append(Observation(tuple(x), float(seconds)))
    if not t.user_attrs.get(keys.RUNGS) and t.state == TrialState.COMPLETE:
        wall = t.user_attrs.get(keys.TRIAL_WALL_SECONDS)
        if isinstance(wall, (int, float)):
            out.append(Observation(tuple(features(top)), float(wall)))
    return out


def _screen_share_of(t: FrozenTrial) -> tuple[float, int]:
    """The share of its protocol's runs a finished trial's ε_test screens evaluated (0: none stored; a record from
    before the halving, one for all of them; since, each screen stores its own runs, the finalists this share),
    and the protocol's runs (0: unknown)."""
    from sim.protocols import PROTOCOLS

    proto = PROTOCOLS.get(str(t.user_attrs.get(keys.OFFICIAL_PROTOCOL)))
    runs = t.user_attrs.get(keys.EPSILON_SCREEN_RUNS)
    if proto is None:
        return 0.0, 0
    return (float(runs) / proto.runs if isinstance(runs, int) else 0.0), proto.runs


_RESUMABLE_LADDER = frozenset({"epsilon_test_screen_runs"})
"""[ladder] keys a study may resume with changed: the ε_test screens' runs choose among the same grid values, and
every trial's value stays the official score at its choice (a study from before the halving resumes with it)."""


class _Refused(Exception):
    """A configuration the driver does not train: its cheapest rung is over the cost cap (FAIL), or over the time
    left once the deadline overtook its draw (PRUNED, a 'deadline' cause). The message is the trial's cause."""

    def __init__(self, cause: str, state: TrialState = TrialState.FAIL) -> None:
        super().__init__(cause)
        self.state = state


def _never_learned(attrs: Mapping[str, Any]) -> bool:
    """True for a trial pruned as a static policy or as a net that does not learn (``keys.POLICY_LEARNS``)."""
    return bool(attrs.get(keys.STATIC_POLICY) or attrs.get(keys.DOES_NOT_LEARN))


def race_entry(t: FrozenTrial, min_budget: int = 0) -> tuple[float, int | None, dict[str, Any]] | None:
    """(score, budget, config) a trial enters the seed race with, or None: its best scored net (``net_rank``
    over its value and its kept rungs) among those trained for ``min_budget`` iterations or more
    (``StudySpec.race_min_budget``), and the configuration that trained it — at a kept rung, ``trained_rung_config`` at
    that budget, exactly what the rung trained.

    A rung at or above ``min_budget`` that beat its trial's top is raced at its own budget: the cold studies' top
    rungs at 270k–810k often score below their 90k nets. Rungs below it never enter: their scores are screening
    draws whose seed spread (sd ~10 mph at 10k, 1–3 at 90k) makes the best of a study's dozens a lucky seed — the
    10k and 30k nets that led the benchmark's races averaged 61 mph over fresh seeds. A trial pruned as a static
    policy or as one that does not learn does not enter (its net never learned to steer).
    """
    config = t.user_attrs.get(keys.CONFIG)
    if not isinstance(config, dict) or _never_learned(t.user_attrs):
        return None
    top = config.get("train_iterations")
    reached = min_budget <= 0 or (isinstance(top, int) and top >= min_budget)  # the value's own budget
    found = [(score, budget) for score, budget in scored_nets(t.user_attrs, t.value, t.state == TrialState.COMPLETE)
             if math.isfinite(score) and (reached if budget is None else budget >= min_budget)]  # fmt: skip
    if not found:
        return None
    score, budget = max(found, key=lambda f: net_rank(f[0], f[1], t.number))
    if budget is None:
        return score, None, config
    try:
        return score, budget, trained_rung_config(TrainConfig.from_mapping(config), budget,
                                                  t.user_attrs.get(keys.RUNGS)).to_mapping()  # fmt: skip
    except (ConfigError, TypeError, ValueError):
        return None


def _best_net(trials: Sequence[FrozenTrial], fresh: bool = False) -> tuple[float, int] | None:
    """(score, trial number) of the study's best single net (``records.best_net``'s, over ``scored_nets``, ranked
    by ``net_rank``); None before any. ``fresh``: of fresh trainings only (no refinement run, soup or stack: nothing
    trained on or from other nets)."""
    found = [(net_rank(score, budget, t.number), t.number) for t in trials
             if not (fresh and keys.REFINE_OF in t.user_attrs)
             for score, budget in scored_nets(t.user_attrs, t.value, t.state == TrialState.COMPLETE)
             if math.isfinite(score)]  # fmt: skip
    if not found:
        return None
    rank, number = max(found)
    return rank[0], number


def _last_turn_of(trials: Sequence[FrozenTrial]) -> int | None:
    """The configuration (``race_of``) of the refinement's last seed turn (``keys.SEED_LEADER_RUN``), or None."""
    turns = [t.user_attrs.get(keys.RACE_OF) for t in trials
             if t.user_attrs.get(keys.SEED_LEADER_RUN) and keys.RETRY_OF not in t.user_attrs]  # fmt: skip
    return None if not turns or turns[-1] is None else int(turns[-1])


def _best_score(trials: Sequence[FrozenTrial], fresh: bool = False) -> float | None:
    """The study's best single net's score (``_best_net``); None before any."""
    best = _best_net(trials, fresh)
    return None if best is None else best[0]


def _best_linear_configuration(trials: Sequence[FrozenTrial], floor: int = 0) -> tuple[int, dict[str, Any], Any] | None:
    """(configuration, parameters, budget) of the best net's configuration when it has no hidden layers: a seed
    soup's (``seed_soup_of``, moved from its best ingredient's parameters), a fresh seed run's (``race_of``), or the
    trial's own when the best net is its first training (a sampled trial's rung, a twin, a neighbour) of ``floor``
    iterations or more (the seed race's, ``min_top``); None before any, with hidden layers, below the floor, or when
    the best net was refined or copied (no first measure of a configuration).

    Why a single net too, not only a soup: a crowd-prior hour's best net was the crowd twin of jnorthrup-v05 (75.39)
    from minute 6, but its soups became the best net only at minute 18 (seed 3) and later, so its neighbours were
    planned too late to train before the race (seed 3) or until minute 29 (seed 2), where the one with 1 - γ
    doubled scored 75.85 at minute 33 (its 9 seeds at 810k: median 75.72). Why the floor: a cold hour's first best
    nets are 10k rungs (60 mph), and without it (seed 3) neighbours of neighbours of them took 27 of its first 50
    trials at 10k, and its best stood at 70.1 at minute 17 (with soup parents only: 73.8 at minute 15)."""
    best = _best_net(trials)
    if best is None:
        return None
    t = next(t for t in trials if t.number == best[1])
    attrs = t.user_attrs
    config = attrs.get(keys.CONFIG)
    if not ensemble.is_linear(config) or keys.COPIED_FROM in attrs:
        return None
    assert isinstance(config, Mapping)
    if keys.SEED_SOUP_OF in attrs:
        return int(attrs[keys.SEED_SOUP_OF]), dict(t.params), config.get("train_iterations")
    if keys.SOUP_OF in attrs or keys.REFINE_OF in attrs:
        return None
    budget = next(b for s, b in scored_nets(attrs, t.value, t.state == TrialState.COMPLETE) if s == best[0])
    budget = config.get("train_iterations") if budget is None else budget
    if not isinstance(budget, int) or budget < floor:
        return None
    return int(attrs.get(keys.RACE_OF, t.number)), dict(t.params), budget


def next_side_entry(plan: Sequence[Mapping[str, Any]]) -> int | None:
    """The index of the side plan's (``keys.SIDE_PLAN``) next entry to release: the first entry not yet released of
    the newest parent (its ``twin_of`` or ``neighbour_of``, in the order parents were first planned) that has one;
    None when all are released.

    Why newest first: a parent's entries are planned when it becomes the best (or the linear leader), so the newest
    is the study's current best and an older parent's were planned for a best since overtaken. Oldest first, a
    crowd-prior hour (seed 2) trained the crowd setting's sgd and adadelta twins (73.15-74.64, 4 minutes each) and
    gsurma's twins from minute 12 to 25 while the neighbours of its best net (75.39 since minute 6) waited; their
    second scored 75.85 at minute 33."""
    order: list[tuple[str, Any]] = []
    for entry in plan:
        parent = _side_parent(entry["user_attrs"])
        if parent not in order:
            order.append(parent)
    for parent in reversed(order):
        for i, entry in enumerate(plan):
            if not entry.get("released") and _side_parent(entry["user_attrs"]) == parent:
                return i
    return None


def _side_parent(attrs: Mapping[str, Any]) -> tuple[str, Any]:
    """A side plan entry's parent: (``twin_of`` or ``neighbour_of``, its trial number)."""
    key = keys.TWIN_OF if keys.TWIN_OF in attrs else keys.NEIGHBOUR_OF
    return key, attrs.get(key)


def _side(attrs: Mapping[str, Any]) -> bool:
    """Whether a trial's user attrs mark a linear twin or neighbour (``[study] side_share``)."""
    return keys.TWIN_OF in attrs or keys.NEIGHBOUR_OF in attrs


def _original(t: FrozenTrial) -> bool:
    """A trial that uses budget: not a retry, not a race or refinement run, not copied history."""
    return not any(k in t.user_attrs for k in (keys.RETRY_OF, keys.RACE_OF, keys.REFINE_OF, keys.COPIED_FROM))


def _rerun(t: FrozenTrial) -> bool:
    """A race or refinement run: trains a stored configuration again (never a draw of the sampler's)."""
    return keys.RACE_OF in t.user_attrs or keys.REFINE_OF in t.user_attrs


def clip_params(spec: StudySpec, params: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """``params`` moved inside the space's ranges and choices, and one line per value that moved."""
    out = dict(params)
    notes = []
    for name, d in space.dimensions(spec).items():
        if name not in out:
            continue
        v = out[name]
        if d.kind == "categorical":
            if v not in d.choices:
                out[name] = d.choices[0]
                notes.append(f"{name} {v!r} → {d.choices[0]!r} (not among the choices)")
            continue
        assert d.low is not None and d.high is not None
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            c: Any = min(max(v, d.low), d.high)
            if d.kind == "int":
                c = int(round(c))
            elif d.step:
                c = d.low + round((c - d.low) / d.step) * d.step
            if c != v:
                out[name] = c
                notes.append(f"{name} {v!r} → {c!r}")
    return out, notes


def _jsonable(x: Any) -> Any:
    """User attrs are JSON: NaN/inf become None, tuples lists."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    return x
