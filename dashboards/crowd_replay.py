"""Retrain crowd configurations into the shipped replay table (``data/crowd/replay.json``).

Each selected configuration (``measured.replay_selection``: the best-claimed ones of each engine,
identical settings once) is trained by our learner from K seeds — the same training seeds and the
same trial objective (``autotune.search.objective.run_trial``: full training, five quick scores,
the official protocol of its engine) as ``autotune crowd replay``, so a row here and a trial there
agree — in a pool of worker processes, without a study or Ray. Every finished (configuration,
seed) is written at once to ``work_dir`` as one JSON file, so an interrupted run resumes where it
stopped. ``max_iterations`` caps training (tests and rehearsals only; the table records the cap).
Training imports torch; it is only imported here, inside the functions that train.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import json
import multiprocessing
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from dashboards import crowd_data as cd
from dashboards import measured
from sim.config import ConfigError
from sim.protocols import OFFICIAL

__all__ = ["ReplayTask", "replay_seed", "replay_tasks", "run_task", "run_replay"]

REPORT_POINTS, QUICK_RUNS, QUICK_FRAMES = 5, 10, 2000  # as autotune crowd replay (crowd_cli.replay_spec)


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


def run_task(task: ReplayTask) -> measured.ReplayRun:
    """Train and score one task with the trial objective (in this process)."""
    from autotune.runtime import configure_process, process_configured
    from autotune.search.objective import COMPLETE, TrialTask, run_trial

    if not process_configured():
        configure_process(1, numba_threads=1)
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
        with concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
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
