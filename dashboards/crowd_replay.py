"""The crowd's settings retrained by our learner: the shipped replay table, and the replay study.

Both train a crowd configuration from K seeds fixed by (crowd id, seed index) — ``replay_seed``, the
same in the table and in every study — with the trial objective (``autotune.search.objective``:
full training, five quick scores, the official protocol of its engine), so a row of the table and a
trial of a replay study agree.

* The replay table (``data/crowd/replay.json``, ``run_replay``): each selected configuration
  (``measured.replay_selection``: the best-claimed ones of each engine, identical settings once) in
  a pool of worker processes, without a study or Ray. Every finished (configuration, seed) is
  written at once to ``work_dir`` as one JSON file, so an interrupted run resumes where it stopped.
  ``max_iterations`` caps training (tests and rehearsals only; the table records the cap).
* The replay study (``autotune crowd replay``): ``enqueue_replay`` enqueues each selected
  submission's K seeds as trials (``autotune.search.enqueue``: its settings as the search's
  parameters, its full config — the trainer method and l1 decay included — in the ``config`` user
  attr), ``run_replay_study`` trains the waiting ones with the search driver on Ray workers, and
  ``replay_table`` reads self-reported against replayed. Enqueuing again adds only missing (setting,
  seed) pairs; running again runs only waiting trials.

Training imports torch; it is only imported inside the functions that train.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import json
import multiprocessing
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from autotune.learner.config import TrainConfig
from autotune.search import keys
from autotune.search.cost import CostModel
from autotune.search.driver import Progress, StudyCounts
from autotune.search.enqueue import ConfigTrial, enqueue_configs, replay_spec, run_enqueued
from autotune.search.records import StudyRecord, read_study_if_present
from autotune.search.storage import Storages
from dashboards import crowd, measured
from dashboards import crowd_data as cd
from sim.config import ConfigError
from sim.protocols import OFFICIAL

__all__ = [
    "ReplayTask", "replay_seed", "replay_tasks", "run_task", "run_replay", "ReplayRow", "enqueue_replay",
    "run_replay_study", "replay_table", "format_replay_table",
]  # fmt: skip

REPORT_POINTS, QUICK_RUNS, QUICK_FRAMES = 5, 10, 2000  # as autotune crowd replay (autotune.search.enqueue.replay_spec)


def replay_seed(crowd_id: str, seed_index: int) -> int:
    """The training seed of seed index k of a crowd setting: the same in every replay (this table, any replay study)."""
    import zlib

    import numpy as np

    state = np.random.SeedSequence([zlib.crc32(crowd_id.encode()), int(seed_index)]).generate_state(1, np.uint32)
    return int(state[0] >> 1)


@dataclasses.dataclass(frozen=True)
class ReplayTask:
    """One (configuration, seed) to train: plain data, it crosses a process boundary."""

    crowd_id: str
    seed_index: int
    seed: int
    config: dict[str, Any]
    """``TrainConfig.to_mapping()`` of the row (iterations capped when asked)."""

    def cache_name(self) -> str:
        """File name of its result in the work directory (the config is part of it: a cap is another run)."""
        import hashlib

        digest = hashlib.sha1(json.dumps(self.config, sort_keys=True).encode()).hexdigest()[:10]
        return f"{self.crowd_id}.seed{self.seed_index}.{digest}.json"


def replay_tasks(
    groups: Sequence[Sequence[cd.Submission]], seeds: int, max_iterations: int | None = None
) -> list[ReplayTask]:
    """The tasks of ``groups`` (each: a configuration's rows, the first is trained) × ``seeds`` seeds."""
    if seeds < 1:
        raise ConfigError(f"seeds: must be ≥ 1, got {seeds}")
    if max_iterations is not None and max_iterations < 1:
        raise ConfigError(f"max_iterations: must be ≥ 1, got {max_iterations}")
    tasks = []
    for rows in groups:
        sub = rows[0]
        config = cd.train_config(sub)
        if max_iterations is not None and config.train_iterations > max_iterations:
            config = config.replace(train_iterations=max_iterations)
        mapping = config.to_mapping()
        tasks += [ReplayTask(sub.id, k, replay_seed(sub.id, k), mapping) for k in range(seeds)]
    return tasks


def _configure_worker() -> None:
    """A pool worker owns its process: one torch and one numba thread, denormals flushed (set once)."""
    from autotune.runtime import configure_process

    configure_process(1, numba_threads=1)


def run_task(task: ReplayTask) -> measured.ReplayRun:
    """Train and score one task with the trial objective (in this process, whose settings its owner set)."""
    from autotune.search.objective import COMPLETE, TrialTask, run_trial

    outcome = run_trial(
        TrialTask(
            number=task.seed_index, config=task.config, seed=task.seed, report_points=REPORT_POINTS,
            quick_runs=QUICK_RUNS, quick_frames=QUICK_FRAMES,
        ),
        lambda _k, _frames, _score: False,  # no pruning: a replay trains to the end
    )  # fmt: skip
    return measured.ReplayRun(
        seed_index=task.seed_index,
        seed=task.seed,
        state=outcome.state,
        score=outcome.value if outcome.state == COMPLETE else None,
        seconds=round(outcome.wall_seconds, 2),
        cause=None if outcome.cause is None else outcome.cause.splitlines()[0],
    )


def _cached(path: Path) -> measured.ReplayRun | None:
    try:
        return measured.ReplayRun(**json.loads(path.read_text()))
    except (OSError, ValueError, TypeError):
        return None


def run_replay(
    groups: Sequence[Sequence[cd.Submission]],
    seeds: int,
    *,
    work_dir: Path,
    workers: int = 1,
    max_iterations: int | None = None,
    command: str = measured.REPLAY_COMMAND,
    progress: Callable[[ReplayTask, measured.ReplayRun, bool], None] | None = None,
) -> measured.ReplayTable:
    """Train every task not yet in ``work_dir`` on ``workers`` processes and assemble the table.

    ``progress(task, run, cached)`` is called for each task as its result is known.
    """
    if workers < 1:
        raise ConfigError(f"workers: must be ≥ 1, got {workers}")
    tasks = replay_tasks(groups, seeds, max_iterations)
    work_dir.mkdir(parents=True, exist_ok=True)
    results: dict[str, measured.ReplayRun] = {}  # by cache name
    todo = []
    for task in tasks:
        run = _cached(work_dir / task.cache_name())
        if run is not None:
            results[task.cache_name()] = run
            if progress is not None:
                progress(task, run, True)
        else:
            todo.append(task)
    # longest first (the prior cost model's prediction): the pool's last task is then a short one
    prior = CostModel.prior()
    todo.sort(key=lambda t: -prior.predict(TrainConfig.from_mapping(t.config)))

    def keep(task: ReplayTask, run: measured.ReplayRun) -> None:
        path = work_dir / task.cache_name()
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(dataclasses.asdict(run)))
        tmp.replace(path)
        results[task.cache_name()] = run
        if progress is not None:
            progress(task, run, False)

    if todo and workers == 1:
        for task in todo:
            keep(task, run_task(task))
    elif todo:
        context = multiprocessing.get_context("spawn")  # a fresh interpreter per worker: no inherited threads
        with concurrent.futures.ProcessPoolExecutor(
            max_workers=workers, mp_context=context, initializer=_configure_worker
        ) as pool:
            futures = {pool.submit(run_task, task): task for task in todo}
            for future in concurrent.futures.as_completed(futures):
                keep(futures[future], future.result())
    entries = []
    for rows in groups:
        sub = rows[0]
        mine = [t for t in tasks if t.crowd_id == sub.id]
        config = mine[0].config
        assert sub.reported_score_mph is not None and sub.score_kind is not None and sub.score_confidence is not None
        entries.append(
            measured.ReplayEntry(
                crowd_id=sub.id,
                config_hash=sub.config_hash,
                rows=tuple(r.id for r in rows),
                engine=sub.engine_version,
                other_agents=sub.other_agents if sub.engine_version == "v2" else None,
                protocol=OFFICIAL[sub.engine_version],
                train_iterations=int(config["train_iterations"]),
                claimed=sub.reported_score_mph,
                claim_kind=sub.score_kind,
                claim_confidence=sub.score_confidence,
                runs=tuple(results[t.cache_name()] for t in mine),
            )
        )
    return measured.ReplayTable(command, seeds, max_iterations, tuple(entries))


# -- the replay study (autotune crowd replay) ---------------------------------------------------------
def enqueue_replay(
    storages: Storages, study_name: str, subs: Sequence[cd.Submission], seeds: int
) -> tuple[int, int, dict[str, str]]:
    """Enqueue ``seeds`` trials per submission (skipping pairs already in the study); (added, present, skipped).

    ``skipped``: {id: why} for submissions whose settings our learner refuses.
    """
    before = read_study_if_present(storages, study_name)
    present = {
        (t.user_attrs.get(keys.CROWD_ID), t.user_attrs.get(keys.SEED_INDEX))
        for t in (before.trials if before is not None else ())
        if t.user_attrs.get(keys.CROWD_ID) is not None
    }
    existing = 0
    todo: list[ConfigTrial] = []
    skipped: dict[str, str] = {}
    for sub in subs:
        try:
            config = cd.train_config(sub)
        except cd.CrowdDataError as exc:
            skipped[sub.id] = str(exc)
            continue
        params = crowd.crowd_params(config)
        for k in range(seeds):
            if (sub.id, k) in present:
                existing += 1
                continue
            provenance = {
                keys.SOURCE: keys.SOURCE_CROWD_REPLAY,
                keys.CROWD_ID: sub.id,
                keys.SEED_INDEX: k,
                keys.REPORTED_SCORE: sub.reported_score_mph,
                keys.ENGINE_VERSION: sub.engine_version,
            }
            todo.append(ConfigTrial(params, config.to_mapping(), replay_seed(sub.id, k), provenance))
    added = enqueue_configs(
        storages, study_name, todo, {keys.SOURCE: keys.SOURCE_CROWD_REPLAY}, metric_name=crowd.REPLAY_METRIC
    )
    return added, existing, skipped


def run_replay_study(
    storages: Storages, study: StudyRecord, *, storage: str, workers: int, progress: Progress | None = None
) -> StudyCounts:
    """Train the replay study's waiting trials on ``workers`` Ray workers; the driver's final counts.

    ``storage`` is the ``--storage`` the study was opened with (the spec records it). Nothing
    waiting starts no Ray; Ctrl-C propagates once the running trials are failed (retryable).
    """
    spec = replay_spec(
        study.name, storage=storage, workers=workers,
        n_trials=sum(1 for t in study.trials if keys.RETRY_OF not in t.user_attrs),  # exactly the enqueued ones
        params=[crowd.crowd_params(TrainConfig.from_mapping(t.user_attrs[keys.CONFIG]))
                for t in study.trials if keys.CONFIG in t.user_attrs],
        activations=crowd.ACTIVATION_CHOICES,
    )  # fmt: skip
    return run_enqueued(storages, spec, progress)


@dataclasses.dataclass(frozen=True)
class ReplayRow:
    """One replayed crowd setting: its self-reported score beside our seeds' official scores."""

    crowd_id: str
    engine: str
    """Engine of the submission ('v1' or 'v2'); its official protocol scored the replay."""
    reported: float | None
    """Self-reported score [mph] (None: the submission reported none)."""
    scores: tuple[float, ...]
    """Official score of each complete seed [mph]."""
    unfinished: int
    """Seeds of this setting not complete (waiting, running, failed or pruned)."""

    @property
    def mean(self) -> float | None:
        """Mean over the complete seeds [mph]."""
        return sum(self.scores) / len(self.scores) if self.scores else None


def replay_table(study: StudyRecord, subs: Sequence[cd.Submission]) -> list[ReplayRow]:
    """Per submission of ``subs`` (in that order): the complete replay scores in ``study``."""
    rows = []
    for sub in subs:
        mine = [t for t in study.trials if t.user_attrs.get(keys.CROWD_ID) == sub.id]
        if not mine:
            continue
        latest = {}  # seed index -> its last attempt (a retry supersedes the failure it retries)
        for t in mine:
            latest[t.user_attrs.get(keys.SEED_INDEX)] = t
        done = tuple(float(t.value) for t in latest.values() if t.state == "COMPLETE" and t.value is not None)
        rows.append(ReplayRow(sub.id, sub.engine_version, sub.reported_score_mph, done, len(latest) - len(done)))
    return rows


def format_replay_table(rows: Sequence[ReplayRow]) -> str:
    """The rows as an aligned text table (crowd id, engine, self-reported, replayed mean ± sd over seeds)."""

    def num(x: float | None) -> str:
        return "—" if x is None else f"{x:.2f}"

    head = ("crowd id", "engine", "self-reported", "replayed mean", "sd", "seeds")
    body = []
    for r in rows:
        sd = None
        if len(r.scores) > 1:
            m = r.mean or 0.0
            sd = (sum((x - m) ** 2 for x in r.scores) / (len(r.scores) - 1)) ** 0.5
        seeds = f"{len(r.scores)}" + (f" (+{r.unfinished} not complete)" if r.unfinished else "")
        body.append((r.crowd_id, r.engine, num(r.reported), num(r.mean), num(sd), seeds))
    widths = [max(len(row[i]) for row in (head, *body)) for i in range(len(head))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip() for row in (head, *body))
