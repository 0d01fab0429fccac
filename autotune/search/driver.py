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

Enqueued full configs (``autotune crowd replay``): a trial enqueued with a ``config`` user attr
(``TrainConfig.to_mapping()``) trains exactly that config — settings the [space] cannot express
(trainer method, l1 decay, …) included — and is scored with the official protocol of that
config's ruleset (v2-official / v1-original), so one study can mix engines. Its params still go
through ``space.sample`` (the enqueued values, for the dashboard). A retry carries the user attrs
its trial was enqueued with.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import os
import socket
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import optuna
from optuna.storages import BaseStorage
from optuna.trial import FrozenTrial, Trial, TrialState

from autotune import TrainConfig
from autotune.search import space
from autotune.search.objective import (
    COMPLETE,
    FAILED,
    PRUNED,
    TrialOutcome,
    TrialTask,
    process_alive,
    process_start,
)
from autotune.search.spec import StudySpec
from autotune.search.storage import GRACE_PERIOD_S, HEARTBEAT_INTERVAL_S, Storages
from sim.config import ConfigError

__all__ = [
    "Driver", "Progress", "StudyCounts", "make_sampler", "make_pruner", "trial_seed", "OWNER_ATTR", "CONFIG_ATTR",
]  # fmt: skip

OWNER_ATTR = "autotune:driver"  # system attr: {"host", "pid", "start"} of the driver running the trial
BEAT_ATTR = "autotune:heartbeat"  # system attr: time.time() of the driver's latest heartbeat for the trial
CONFIG_ATTR = "config"  # user attr an enqueued trial may carry: the full TrainConfig mapping it trains
ENQUEUED_ATTR = "autotune:enqueued"  # system attr: the user attr keys a trial was enqueued with (kept by retries)


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
    """Retries (trials with ``retry_of``, any state): each stands for a failed trial whose chain goes on."""
    best_value: float | None = None
    best_number: int | None = None
    elapsed_s: float = 0.0

    @property
    def finished(self) -> int:
        """Original trials whose chain has ended: budget units used up."""
        return self.complete + self.pruned + self.failed - self.retries


Progress = Callable[[StudyCounts], None]
"""Called after every change of the counts (and about once a second while trials run)."""


def trial_seed(study_seed: int, number: int) -> int:
    """A trial's training seed: independent per (study seed, trial number), stored with the trial."""
    return int(np.random.SeedSequence([int(study_seed), int(number)]).generate_state(1, np.uint32)[0] >> 1)


def make_sampler(spec: StudySpec, seed: int) -> optuna.samplers.BaseSampler:
    """The spec's sampler, seeded; TPE multivariate, grouped (define-by-run layout), constant liar in parallel."""
    name = spec.study.sampler
    needs = {"cmaes": "cmaes", "gp": "scipy"}.get(name)
    if needs is not None and importlib.util.find_spec(needs) is None:
        raise ConfigError(f"{spec.source}: [study] sampler: '{name}' needs the '{needs}' package; pip install {needs}")
    s = optuna.samplers
    if name == "tpe":
        return s.TPESampler(
            seed=seed, multivariate=True, group=True, constant_liar=spec.resources.workers > 1
        )  # fmt: skip
    if name == "cmaes":
        return s.CmaEsSampler(seed=seed, warn_independent_sampling=False)
    if name == "gp":
        return s.GPSampler(seed=seed, warn_independent_sampling=False)
    if name == "random":
        return s.RandomSampler(seed=seed)
    if name == "qmc":
        return s.QMCSampler(seed=seed, scramble=True, warn_independent_sampling=False, warn_asynchronous_seeding=False)
    raise ValueError(f"sampler: unknown {name!r}")  # the spec rejected it already


def make_pruner(spec: StudySpec) -> optuna.pruners.BasePruner:
    """The spec's pruner over the report schedule (steps 0 … report_points − 1), tuned by [evaluation]."""
    e = spec.evaluation
    p = optuna.pruners
    name = spec.study.pruner
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
    from optuna.storages._heartbeat import is_heartbeat_enabled

    return is_heartbeat_enabled(storage)


@dataclasses.dataclass
class _Running:
    trial: Trial
    slot: int
    task: TrialTask
    started: float = dataclasses.field(default_factory=time.perf_counter)
    killed: str = ""
    """Why the driver killed the worker (a trial past its wall-time limit that stopped answering)."""


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
    ) -> None:
        self.spec = spec
        self.storages = storages
        self.address = address
        self.progress = progress
        self.state_dir = state_dir if state_dir is not None else storages.artifact_dir.parent
        self.owner = _owner()
        self.study: optuna.Study | None = None
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
            n_before = len(storage.get_all_trials(previous[0]._study_id, deepcopy=False))
        study = optuna.create_study(
            study_name=name,
            storage=storage,
            sampler=make_sampler(self.spec, self.spec.study.seed + n_before),  # a resumed run draws anew
            pruner=make_pruner(self.spec),
            direction="maximize",
            load_if_exists=True,
        )
        study.set_user_attr("spec", self.spec.to_dict())
        self.study = study
        self.recovered = self._fail_orphans(study)
        self._refresh_counts()
        return study

    def _fail_orphans(self, study: optuna.Study) -> list[int]:
        storage = self.storages.storage
        if _heartbeat_enabled(storage):
            optuna.storages.fail_stale_trials(study)  # other hosts' dead drivers (RDB heartbeats)
        failed = []
        now = time.time()
        for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
            owner = t.system_attrs.get(OWNER_ATTR)
            if isinstance(owner, dict) and owner.get("host") == self.owner["host"]:
                dead = not _owner_alive(owner)
            else:  # another host, or no owner: only a silent heartbeat proves it dead
                beat = t.system_attrs.get(BEAT_ATTR)
                dead = beat is not None and now - float(beat) > GRACE_PERIOD_S
                if beat is None and not _heartbeat_enabled(storage) and t.datetime_start is not None:
                    dead = time.mktime(t.datetime_start.timetuple()) < now - GRACE_PERIOD_S
            if not dead:
                continue
            who = f"{owner.get('host')}:{owner.get('pid')}" if isinstance(owner, dict) else "unknown"
            storage.set_trial_user_attr(t._trial_id, "cause", f"driver lost: driver {who} stopped while the trial ran")
            storage.set_trial_user_attr(t._trial_id, "retryable", True)
            try:
                storage.set_trial_state_values(t._trial_id, TrialState.FAIL)
                failed.append(t.number)
            except optuna.exceptions.UpdateFinishedTrialError:  # another driver got there first
                pass
        return failed

    def _enqueue_retries(self) -> None:
        """Enqueue one retry for every retryable failure that has none yet (and retries left)."""
        assert self.study is not None
        trials = self.study.get_trials(deepcopy=False)
        by_number = {t.number: t for t in trials}
        retried = {t.user_attrs.get("retry_of") for t in trials}
        for t in trials:
            if t.state != TrialState.FAIL or t.number in retried or not self._retryable(t):
                continue
            depth, cur = 0, t
            while "retry_of" in cur.user_attrs and cur.user_attrs["retry_of"] in by_number:
                depth += 1
                cur = by_number[cur.user_attrs["retry_of"]]
            if depth >= self.spec.study.max_retries:
                continue
            seed = t.user_attrs.get("seed", trial_seed(self.spec.study.seed, cur.number))
            given = {k: t.user_attrs[k] for k in t.system_attrs.get(ENQUEUED_ATTR, ()) if k in t.user_attrs}
            self.study.enqueue_trial(t.params, user_attrs={**given, "retry_of": t.number, "seed": seed})

    @staticmethod
    def _retryable(t: FrozenTrial) -> bool:
        # ours say so; a FAIL with no cause was failed by Optuna's heartbeat check (a dead driver)
        return bool(t.user_attrs.get("retryable")) or "cause" not in t.user_attrs

    def _refresh_counts(self) -> None:
        assert self.study is not None
        c = self.counts
        trials = self.study.get_trials(deepcopy=False)
        c.started = sum(1 for t in trials if "retry_of" not in t.user_attrs and t.state != TrialState.WAITING)
        c.retries = sum(1 for t in trials if "retry_of" in t.user_attrs)
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
                    if not self._launch_next(slot):
                        break
            if not self._running:
                if self._out_of_time() or not self._launch_possible():
                    return
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
        self._refresh_counts()
        budget = self.spec.study.n_trials
        return budget is None or self.counts.started < budget

    def _launch_next(self, slot: int) -> bool:
        """Ask for a trial (a waiting retry first) and start it on ``slot``; False when the budget is spent."""
        assert self.study is not None
        waiting = self.study.get_trials(deepcopy=False, states=(TrialState.WAITING,))
        if not waiting:
            self._refresh_counts()
            budget = self.spec.study.n_trials
            if budget is not None and self.counts.started >= budget:
                return False
        trial = self.study.ask()
        storage = self.storages.storage
        given = sorted(k for k in trial.user_attrs if k != "retry_of")  # what it was enqueued with
        if given:
            storage.set_trial_system_attr(trial._trial_id, ENQUEUED_ATTR, given)
        storage.set_trial_system_attr(trial._trial_id, OWNER_ATTR, self.owner)
        self._beat(trial)
        seed = trial.user_attrs.get("seed")
        if seed is None:
            seed = trial_seed(self.spec.study.seed, trial.number)
            trial.set_user_attr("seed", seed)
        full = trial.user_attrs.get(CONFIG_ATTR)  # an enqueued full config (crowd replay) wins over the params
        try:
            params = space.sample(trial, self.spec)
            config = TrainConfig.from_mapping(full) if full is not None else space.to_config(self.spec, params)
        except Exception as exc:  # a combination deepqlearn rejects: a failed trial, not a crashed study
            trial.set_user_attr("cause", f"invalid configuration: {exc}")
            self.study.tell(trial, state=TrialState.FAIL)
            self._notify()
            return True
        e = self.spec.evaluation
        task = TrialTask(
            number=trial.number, config=config.to_mapping(), seed=int(seed), report_points=e.report_points,
            quick_runs=e.quick_runs, quick_frames=e.quick_frames,
            final_protocol="" if full is not None else e.final_protocol,  # '': the config's ruleset's official
            timeout_s=self.spec.study.trial_timeout_s,
        )  # fmt: skip
        trial.set_user_attr("worker", self.pool.worker_of(slot))
        trial.set_user_attr("ray_node", self.pool.node_of(slot))
        self._running[slot] = _Running(trial, slot, task)
        self.pool.submit(slot, task)
        self._notify()
        return True

    def _handle(self, event: Any) -> None:
        assert self.study is not None
        run = self._running.get(event.slot)
        if event.kind == "ready" or run is None:
            return
        if event.kind == "report":
            run.trial.report(event.score, step=event.step)
            prune = run.trial.should_prune()
            self.pool.answer(event.slot, prune)
            return
        del self._running[event.slot]
        if event.kind == "done" and not self._out_of_time():
            self._launch_next(event.slot)  # the worker starts its next trial before this one's storage writes
        if event.kind == "lost":
            self._fail(run.trial, run.killed or event.cause, retryable=not run.killed)
            self._enqueue_retries()
        else:
            self._finish(run.trial, event.outcome)
        self._notify()

    def _finish(self, trial: Trial, outcome: TrialOutcome) -> None:
        assert self.study is not None
        for key, value in outcome.attrs.items():
            trial.set_user_attr(key, _jsonable(value))
        if outcome.state == COMPLETE:
            with tempfile.TemporaryDirectory() as tmp:
                for key, name, text in (("artifact_net_json", "net.json", outcome.net_json),
                                        ("artifact_net_js", "net.js", outcome.net_js)):  # fmt: skip
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

    def _fail(self, trial: Trial, cause: str, *, retryable: bool) -> None:
        assert self.study is not None
        trial.set_user_attr("cause", cause)
        trial.set_user_attr("retryable", retryable)
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
    def _beat(self, trial: Trial) -> None:
        storage = self.storages.storage
        if _heartbeat_enabled(storage):
            storage.record_heartbeat(trial._trial_id)  # type: ignore[attr-defined]
        else:
            storage.set_trial_system_attr(trial._trial_id, BEAT_ATTR, time.time())

    def _heartbeat(self) -> None:
        self._last_beat = time.perf_counter()
        for run in self._running.values():
            self._beat(run.trial)


def _jsonable(x: Any) -> Any:
    """User attrs are JSON: NaN/inf become None, tuples lists."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    return x
