"""Search quality: what each way of searching finds in the same wall time on the same cores.

    python bench/search_quality.py --minutes 10,30,60 --calibration 0     # every arm on paper.toml: 4 h + reseeding
    python bench/search_quality.py --minutes 10 --arms plain,cold --study-seeds 0,1,2 --calibration 0
    python bench/search_quality.py --arms none --calibration 30            # the rung calibration alone
    python bench/search_quality.py --minutes 0.5 --arms plain,random --space smoke --reference none   # plumbing

The arms run one after another, each with ``--workers`` processes (one core each) for the longest
of ``--minutes``, timed from the arm's first command (process start, compilation and Ray start count):

* ``plain``  — the loop a user writes in ten minutes: Optuna's default TPE + MedianPruner around
  ``autotune.learner.train`` (the quick scores its reporter gives, at the spec's [evaluation]
  report_points / quick_runs / quick_frames — train's own defaults in paper.toml), define-by-run over
  the spec's [space] (``n_layers``, then ``neurons_i`` / ``activation_i`` for i < n_layers; in a ladder
  spec train_iterations log-uniform over the ladder's range up to min_top, ``*_fraction`` settings × that
  length, the threshold capped only below the replay memory), scored with ``evaluate_official``; ``--workers``
  processes share a JournalStorage study; a trial past the spec's ``trial_timeout_s`` is stopped through
  ``train``'s progress hook and pruned (cause ``timeout: …``), one still running at the arm's end too;
* ``random`` — the same loop with RandomSampler, no pruner and no quick scores;
* ``cold``   — ``autotune launch SPEC`` (the service, no crowd knowledge);
* ``warm``   — ``autotune launch SPEC --warm-start crowd`` (skipped, saying so, where launch lacks it).

``--study-seeds`` repeats ``plain`` and ``cold`` once per study seed (the checkpoint figures are then
medians over the runs); ``random`` and ``warm`` use the first seed. At every checkpoint: the best
single net (max official score of the nets stored by then — COMPLETE trials' values and the kept rungs
of finished ladder trials, as ``autotune best`` ranks them), the configuration the arm would pick
(the best trial's; where seed-race trials (``race_of``) have finished, the race winner as
``autotune best`` ranks it: ``racing.standings``) retrained with ``--reseeds`` fresh seeds — the
same seeds for every arm, after the arm's budget, timed apart — and for ``warm`` the best trial that
was not enqueued (no ``warm_start``). ``--reference`` (a crowd submission id, default gsurma's, the
best v2 crowd setting our sgd learner replays) is retrained with the same seeds.

``--held-out`` (default ``1000000,2000000``; ``none`` skips): each checkpoint's best single net is scored again
on runs the official protocol never plays, because the best net is a best-of-many over one fixed set of 500
official runs (seeded 1…500): the ``v2-heldout`` protocol, the site's evaluation worker itself (one world, the
runs coupled through ``reset()``, every temporal window carried from run to run) on ``--held-out-runs`` (500)
runs from each given seed (run k ↦ Park–Miller seed s + k + 1); a v1 study's nets, on the ``custom`` protocol.
Until 2026-12-06 the ``custom`` protocol scored them, whose fresh world per run scores a net with a temporal
window apart from the same runs played officially: a cold hour's best nets (windows 7–8) scored 1.7–12 mph
lower there on the official runs' own seeds, and within 0.3 of their official scores on the held-out runs of
``v2-heldout``. Arms whose studies store no nets (the plain loop, random) have none to score.

Per run, from the trial records: the cost model's median |actual − predicted| / actual over the
COMPLETE trials that stored ``predicted_cost_s`` before training; the share of worker time (workers ×
the arm's wall) spent in trials stopped by a limit (cause ``timeout…``); the worst trial wall time /
``trial_timeout_s``; the share of sampler draws refused (``refused_draws``), where stored; the pruned
trials by cause (the pruner, not learning, static, diverged, a limit); and at each checkpoint the share of the
workers' time each kind of trial took (the search's draws, warm-start settings, twins and neighbours, seed runs,
the race, refinement runs, soups: ``time_shares``).

``--calibration N`` (a spec with a [ladder]): N configurations drawn from the service's own space
(``space.sample`` with a seeded RandomSampler, ``space.to_config`` per rung, as the driver builds
them), each with the rungs whose cumulative cost the prior cost model (``cost.plan``) puts under the
cap (``--calibration-cap``, default the spec's max_trial_cost_s, else trial_timeout_s) — a draw with
fewer than two such rungs is refused before any training — then trained through all of them unpruned
by ``run_trial`` (rung r a fresh complete training at B_r from the configuration's seed, officially
scored). Reported: the Spearman rank correlation of each rung's score with the top rung's, and the
prior cost model's median error on those rungs.

Output in ``--out``/<time>/: the studies (journal per run), ``result.json`` (rewritten after every
stage), ``search_quality.html`` (running best vs wall minutes, self-contained); on stdout a table
(arm × checkpoint) and one JSON line (prefix ``JSON``), with the load average at each arm's start/end.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import json
import math
import os
import queue
import signal
import statistics
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from autotune.search.spec import Dimension

ROOT = Path(__file__).resolve().parents[1]
THIS = Path(__file__).resolve()
sys.path.insert(0, str(ROOT))

ARMS = ("plain", "random", "cold", "warm")
SEEDED_ARMS = ("plain", "cold")  # --study-seeds repeats these; the others run with the first seed
FRESH_SEED0 = 900_001  # fresh seeds FRESH_SEED0 + i, the same for every arm (no study draws them)
HELD_OUT_SEEDS = (1_000_000, 2_000_000)  # `v2-heldout` seeds: runs seeded s + 1 … s + runs, never official ones
HELD_OUT_RUNS = 500  # runs per held-out set: the official protocol's number
REFERENCE_ID = "dt-gsurma-deep-traffic-v00"
LAYOUT = ("n_layers", "neurons", "activation")
# train length the plain loop searches when the spec has neither it nor a [ladder] (paper.toml's old range)
FALLBACK_ITERATIONS = {"low": 5_000, "high": 1_000_000, "log": True}
FRACTION = "_fraction"  # [space] names <setting>_fraction: that setting as a fraction of train_iterations
LR_X_INPUTS = "learning_rate_x_inputs"  # the service's learning rate per input; the plain loop samples the rate
PLAIN_LEARNING_RATE = {"low": 1e-8, "high": 1e-2, "log": True}  # itself, over the crowd's range (the issue's loop)
PLAIN_EPSILON_TEST = {"low": 0.0, "high": 0.9}  # ε_test where the spec chooses it per net: paper.toml's old range
FINISHED = ("COMPLETE", "PRUNED", "FAIL")
LIMIT_CAUSE = "timeout"  # causes of trials stopped by a wall-time limit start with this
PRUNE_CAUSES = (  # (how the objective's cause starts, its label in the figures), first match wins
    ("pruned after rung", "by the pruner"), ("does not learn", "not learning"), ("static policy", "static"),
    ("diverged", "diverged"), (LIMIT_CAUSE, "trial limit"), ("deadline", "deadline"),
)  # fmt: skip
DEADLINE_CAUSE = "deadline: the arm's wall budget ended"


class BenchError(Exception):
    """Bad input (option, spec): one line, exit 2."""


# ---------------------------------------------------------------------------------------------
# a study spec copy, written back as TOML
# ---------------------------------------------------------------------------------------------


def _toml_key(key: str) -> str:
    return key if key and all(c.isalnum() or c in "_-" for c in key) else json.dumps(key)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # JSON's escapes are TOML basic-string escapes
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items()) + " }"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"toml: cannot write {type(value).__name__} {value!r}")


def toml_dumps(data: Mapping[str, Mapping[str, Any]]) -> str:
    """A study spec's tables as TOML (nested values inline); ``tomllib.loads`` gives ``data`` back."""
    lines: list[str] = []
    for table, body in data.items():
        if not isinstance(body, Mapping):
            raise TypeError(f"toml: top-level {table!r} is not a table")
        lines.append(f"[{_toml_key(table)}]")
        lines += [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in body.items()]
        lines.append("")
    return "\n".join(lines)


def study_copy(data: Mapping[str, Any], name: str, seed: int, timeout_s: float) -> dict[str, Any]:
    """The spec with [study] name, seed and timeout_s set: the wall budget alone ends an arm (no n_trials)."""
    out = {k: dict(v) if isinstance(v, Mapping) else v for k, v in data.items()}
    study = out.setdefault("study", {})
    study.update(name=name, seed=int(seed), storage="", timeout_s=float(timeout_s))
    study.pop("n_trials", None)
    return out


# ---------------------------------------------------------------------------------------------
# the plain loop's own space: define-by-run over the spec's [space]
# ---------------------------------------------------------------------------------------------


def plain_space(spec: Any) -> tuple[tuple[Dimension, ...], tuple[str, ...]]:
    """The [space] entries that are training settings, their ``_fraction`` forms or the layout, plus the train
    length (a ladder study's: searched over the ladder's range up to ``min_top``), and notes on what was left out
    or added."""
    from autotune import TrainConfig
    from autotune.search.spec import EPSILON_TEST_SHIFTED, Dimension, unshift_epsilon

    settings = {f.name for f in dataclasses.fields(TrainConfig)}
    dims: list[Dimension] = []
    notes: list[str] = []
    for d in spec.space:
        base = d.name.removesuffix(FRACTION)
        if base in settings or d.name in LAYOUT or d.name == "one_minus_gamma":
            dims.append(d)
        elif d.name == EPSILON_TEST_SHIFTED and d.low is not None and d.high is not None:
            # a user's loop draws ε_test itself, uniformly over the same range
            lo, hi = unshift_epsilon(d.low), unshift_epsilon(d.high)
            dims.append(Dimension("epsilon_test_time", "float", lo, hi))
            notes.append(f"plain loop: [space] {EPSILON_TEST_SHIFTED} sampled as epsilon_test_time, uniform on "
                         f"{lo:g}–{hi:g}")  # fmt: skip
        elif d.name == LR_X_INPUTS and "learning_rate" not in spec.fixed_values:
            dims.append(Dimension("learning_rate", "float", **PLAIN_LEARNING_RATE))  # type: ignore[arg-type]
            notes.append(f"plain loop: [space] {LR_X_INPUTS} sampled as learning_rate over the crowd's range "
                         f"{PLAIN_LEARNING_RATE['low']:g}–{PLAIN_LEARNING_RATE['high']:g} (log)")  # fmt: skip
        else:
            notes.append(f"plain loop: [space] {d.name} is not a training setting; not sampled")
    names = {d.name for d in dims}
    grid = tuple(getattr(spec, "ladder_epsilon_grid", ()) or ())
    if grid and "epsilon_test_time" not in names and "epsilon_test_time" not in spec.fixed_values:
        # the service chooses ε_test per net from the grid; a user's loop draws it, over the paper's range
        lo, hi = PLAIN_EPSILON_TEST["low"], PLAIN_EPSILON_TEST["high"]
        dims.append(Dimension("epsilon_test_time", "float", lo, hi))
        notes.append(f"plain loop: ε_test (the service's [ladder] epsilon_test_grid) sampled as epsilon_test_time, "
                     f"uniform on {lo:g}–{hi:g}")  # fmt: skip
    if "train_iterations" not in names and "train_iterations" not in spec.fixed_values:
        ladder = tuple(getattr(spec, "ladder", ()) or ())  # a spec-like without a ladder too
        # up to min_top (every sampled trial's top or above): paper.toml's 10k–90k, the issue's "10k–100k" loop
        rng = {"low": ladder[0], "high": ladder[spec.gated_rungs - 1], "log": True} if ladder else FALLBACK_ITERATIONS
        dims.insert(0, Dimension("train_iterations", "int", **rng))  # type: ignore[arg-type]
        where = "the [ladder]'s range up to min_top" if ladder else "paper.toml's pre-ladder range"
        notes.append(f"plain loop: train_iterations sampled from {where} {rng['low']:,}–{rng['high']:,} (log)")
    return tuple(dims), tuple(notes)


def _suggest(trial: Any, d: Dimension, name: str) -> Any:
    if d.kind == "categorical":
        return trial.suggest_categorical(name, list(d.choices))
    assert d.low is not None and d.high is not None
    if d.kind == "int":
        return trial.suggest_int(name, int(d.low), int(d.high), step=int(d.step or 1), log=d.log)
    return trial.suggest_float(name, float(d.low), float(d.high), step=d.step, log=d.log)


def sample_plain(trial: Any, dims: Sequence[Dimension]) -> dict[str, Any]:
    """Define-by-run: each setting, then n_layers and neurons_i / activation_i for i < n_layers."""
    by_name = {d.name: d for d in dims}
    params: dict[str, Any] = {}
    for d in dims:
        if d.name == "n_layers":
            n = params["n_layers"] = _suggest(trial, d, "n_layers")
            for i in range(n):
                params[f"neurons_{i}"] = _suggest(trial, by_name["neurons"], f"neurons_{i}")
                params[f"activation_{i}"] = _suggest(trial, by_name["activation"], f"activation_{i}")
        elif d.name not in LAYOUT:
            params[d.name] = _suggest(trial, d, d.name)
    return params


def decode_plain(spec: Any, params: Mapping[str, Any]) -> Any:
    """The TrainConfig of plain-loop params: [fixed] ∪ params, ``<setting>_fraction`` × train_iterations, the
    threshold capped below the replay memory only (a user's loop knows nothing of the ladder's cap)."""
    from autotune import TrainConfig

    values = dict(spec.fixed_values)
    fractions = {}
    for name, value in params.items():
        if name == "one_minus_gamma":
            values["gamma"] = float(f"{1.0 - value:.15g}")
        elif name.endswith(FRACTION):
            fractions[name.removesuffix(FRACTION)] = float(value)
        elif name != "n_layers" and not name.startswith(("neurons_", "activation_")):
            values[name] = value
    length = values.get("train_iterations", TrainConfig().train_iterations)
    for name, fraction in fractions.items():
        values[name] = max(0, round(fraction * length))
    if "n_layers" in params:
        n = params["n_layers"]
        values["layers"] = "|".join(f"fc:{params[f'neurons_{i}']}:{params[f'activation_{i}']}" for i in range(n))
    if "start_learn_threshold" not in spec.fixed_values:
        base = TrainConfig.from_mapping({"ruleset": spec.ruleset})
        exp = values.get("experience_size", base.experience_size)
        if values.get("start_learn_threshold", base.start_learn_threshold) >= exp:
            values["start_learn_threshold"] = max(0, exp - 1)
    return TrainConfig.from_mapping({"ruleset": spec.ruleset, **values})


def _seed(*entropy: int) -> int:
    import numpy as np

    return int(np.random.SeedSequence([int(e) for e in entropy]).generate_state(1, np.uint32)[0] >> 1)


class _Limit(Exception):
    """Raised from ``train``'s progress hook when a trial's limit or the arm's deadline has passed."""


def plain_objective(
    trial: Any, spec: Any, dims: Sequence[Dimension], *, prune: bool, deadline: float, study_seed: int
) -> float:
    """One plain-loop trial: sample, train (reporting quick scores when pruning), score officially."""
    import optuna

    from autotune import evaluate_official, official_protocol
    from autotune.learner import train

    t0 = time.time()
    timeout = float(spec.study.trial_timeout_s)
    stop_at = min(t0 + timeout, deadline)
    ev = spec.evaluation

    def done(cause: str | None) -> None:
        trial.set_user_attr("trial_wall_seconds", time.time() - t0)
        if cause is not None:
            trial.set_user_attr("cause", cause)

    try:
        config = decode_plain(spec, sample_plain(trial, dims))
    except Exception as exc:  # deepqlearn rejects the draw: FAIL with its cause
        done(f"config: {exc}")
        raise
    seed = _seed(study_seed, trial.number)
    trial.set_user_attr("config", config.to_mapping())
    trial.set_user_attr("seed", seed)

    def reporter(k: int, frames: int, quick_score: float) -> bool:
        trial.report(float(quick_score), k)
        return bool(trial.should_prune())

    def progress(frames: int, total: int) -> None:
        now = time.time()
        if now > deadline:
            raise _Limit(f"{DEADLINE_CAUSE} (training at {frames:,} of {total:,} frames)")
        if now > stop_at:
            raise _Limit(f"timeout: trial wall time exceeded trial_timeout_s = {timeout:g} s ({frames:,} frames)")

    try:
        result = train(
            config,
            seed,
            reporter if prune else None,
            report_points=ev.report_points,
            quick_eval=prune,
            quick_eval_runs=ev.quick_runs,
            quick_eval_frames=ev.quick_frames,
            progress=progress,
        )
    except _Limit as exc:
        done(str(exc))
        raise optuna.TrialPruned(str(exc)) from None
    except Exception as exc:
        done(f"{type(exc).__name__}: {exc}")
        raise
    if result.diverged:
        done(f"diverged: {result.diverged_reason}")
        raise optuna.TrialPruned("diverged")
    if result.stopped:
        done(f"pruned by the pruner ({result.stop_reason})")
        raise optuna.TrialPruned(result.stop_reason)
    value = float(evaluate_official(result.convnet(), config, protocol=official_protocol(config)).median_site)
    done(None)
    return value


def loop_job(job: Mapping[str, Any]) -> dict[str, Any]:
    """One plain-loop worker: its own sampler on the shared journal study until the deadline (or n_trials)."""
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    from autotune.search.spec import load_spec

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    spec = load_spec(job["space"])
    dims, _ = plain_space(spec)
    seed = _seed(job["study_seed"], 1_000 + job["worker"])
    prune = bool(job["prune"])
    sampler = optuna.samplers.TPESampler(seed=seed) if prune else optuna.samplers.RandomSampler(seed=seed)
    pruner = optuna.pruners.MedianPruner() if prune else optuna.pruners.NopPruner()
    storage = JournalStorage(JournalFileBackend(str(Path(job["storage"]).absolute())))  # lock links resolve
    study = optuna.load_study(study_name=job["study"], storage=storage, sampler=sampler, pruner=pruner)
    deadline = float(job["deadline"])
    ran = 0

    def objective(trial: Any) -> float:
        nonlocal ran
        ran += 1
        return plain_objective(trial, spec, dims, prune=prune, deadline=deadline, study_seed=job["study_seed"])

    left = deadline - time.time()
    if left > 0:
        study.optimize(objective, n_trials=job.get("n_trials"), timeout=left, catch=(Exception,))
    return {"worker": job["worker"], "trials": ran}


# ---------------------------------------------------------------------------------------------
# training jobs: reseeding and calibration
# ---------------------------------------------------------------------------------------------


def _stages(runs: Any) -> tuple[int, ...]:
    """A job's ``epsilon_test_screen_runs``: a number (a job written before the halving) or its stages."""
    return (int(runs),) if isinstance(runs, (int, float)) else tuple(int(r) for r in runs)


def train_job(job: Mapping[str, Any]) -> dict[str, Any]:
    """Train + score one config from one seed through the service's objective (``run_trial``)."""
    from autotune.search.objective import TrialTask, run_trial

    rungs = tuple(int(b) for b in job.get("rungs", ()))
    task = TrialTask(
        number=int(job.get("number", 0)),
        config=dict(job["config"]),
        seed=int(job["seed"]),
        report_points=1,
        quick_runs=1,
        quick_frames=200,
        timeout_s=job.get("timeout_s"),
        rungs=rungs,  # a ladder: every rung trained and scored, never pruned
        reseed_rungs=bool(job.get("reseed", False)),  # each rung below the top from its own seed, as the study's
        epsilon_test_grid=tuple(float(e) for e in job.get("epsilon_test_grid", ())),  # ε_test per net, as the study's
        epsilon_test_screen_runs=_stages(job.get("epsilon_test_screen_runs", [50, 100])),
    )
    out = run_trial(task, lambda k, frames, score: False)
    return {
        "state": out.state,
        "value": out.value,
        "cause": out.cause,
        "seconds": out.wall_seconds,
        "rungs": out.attrs.get("rungs"),
    }


def run_job(job: Mapping[str, Any]) -> dict[str, Any]:
    """A job in a worker process: 'loop', 'train' or 'echo'."""
    kind = job["kind"]
    if kind == "loop":
        return loop_job(job)
    if kind == "train":
        return train_job(job)
    if kind == "echo":  # the pool's own check: a round trip, optionally slow (sleep_s) to test the deadline
        time.sleep(float(job.get("sleep_s", 0.0)))
        return {"echo": job.get("payload"), "pid": os.getpid()}
    raise ValueError(f"unknown job kind {kind!r}")


def serve() -> int:
    """Worker process: one JSON job per stdin line → one JSON result per stdout line (all else to stderr)."""
    import traceback

    out = sys.stdout
    sys.stdout = sys.stderr
    configured = False
    for line in sys.stdin:
        job = json.loads(line)
        if not configured and job["kind"] != "echo":
            from autotune import configure_process

            configure_process(1, numba_threads=1)  # one core per worker, like the service's workers
            configured = True
        try:
            result = run_job(job)
        except Exception as exc:
            result = {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc(limit=6)}
        out.write(json.dumps(result) + "\n")
        out.flush()
    return 0


class Pool:
    """``workers`` long-lived worker processes (``THIS --serve``), each running one job at a time."""

    def __init__(self, workers: int) -> None:
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
        self.procs = [
            subprocess.Popen(
                [sys.executable, str(THIS), "--serve"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
                env=env,
                cwd=ROOT,
                start_new_session=True,
            )
            for _ in range(workers)
        ]

    def run(self, jobs: Sequence[Mapping[str, Any]], *, deadline: float | None = None) -> list[dict[str, Any]]:
        """Each job's result, in order; at ``deadline`` (epoch s) the workers still busy are killed."""
        results: list[dict[str, Any]] = [{"error": "not run"} for _ in jobs]
        todo: queue.SimpleQueue[int] = queue.SimpleQueue()
        for i in range(len(jobs)):
            todo.put(i)

        def feed(proc: subprocess.Popen[str]) -> None:
            assert proc.stdin is not None and proc.stdout is not None
            while True:
                try:
                    i = todo.get_nowait()
                except queue.Empty:
                    return
                try:
                    proc.stdin.write(json.dumps(jobs[i]) + "\n")
                    proc.stdin.flush()
                    line = proc.stdout.readline()
                except OSError:
                    line = ""
                if not line:
                    results[i] = {"error": "the worker process ended (killed at the deadline, or it crashed)"}
                    return
                results[i] = json.loads(line)

        threads = [threading.Thread(target=feed, args=(p,), daemon=True) for p in self.procs]
        for t in threads:
            t.start()
        for t in threads:
            t.join(None if deadline is None else max(0.0, deadline - time.time()))
        if any(t.is_alive() for t in threads):
            self.kill()
            for t in threads:
                t.join()
        return results

    def kill(self) -> None:
        """Kill the worker processes (each leads its own session: only what this pool started)."""
        for p in self.procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
        for p in self.procs:
            p.wait()

    def close(self) -> None:
        for p in self.procs:
            if p.stdin is not None and not p.stdin.closed:
                try:
                    p.stdin.close()
                except OSError:
                    pass
        for p in self.procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()

    def __enter__(self) -> Pool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---------------------------------------------------------------------------------------------
# trial records → the figures of one run (plain data; tested as data)
# ---------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class TrialRow:
    """What the benchmark reads of one trial (any arm); times in seconds since the arm started."""

    number: int
    state: str
    """Optuna state name: COMPLETE, PRUNED, FAIL, RUNNING, WAITING."""
    value: float | None
    """Official score [mph] (COMPLETE)."""
    end_s: float | None
    """datetime_complete − arm start [s]; None while unfinished."""
    wall_s: float | None = None
    """trial_wall_seconds: the trial's own busy time [s]."""
    config: dict[str, Any] | None = None
    seed: int | None = None
    warm_start: str | None = None
    race_of: int | None = None
    race_seed: int | None = None
    """Fresh seed index of a race run (with ``race_of``)."""
    incumbent: bool = False
    """A race run the search started before the race (``incumbent_run``: ``[study] intensify_share``)."""
    seed_run: bool = False
    """A race run started before the race for a linear configuration's seed soups (``seed_soup_run``)."""
    refine_of: int | None = None
    """A refinement run (``[study] refine_share``): the trial whose net it trained on from."""
    soup: bool = False
    """A weight soup (``[study] refine_soups``): a refinement trial that averaged runs' weights, training nothing."""
    side: bool = False
    """A linear twin or neighbour (``twin_of`` / ``neighbour_of``: ``[study] linear_twins``, ``linear_neighbours``)."""
    predicted_cost_s: float | None = None
    cause: str | None = None
    retryable: bool = False
    """A failed trial whose retry was queued (its retry stands for it)."""
    refused_draws: int | None = None
    rung_scores: tuple[tuple[int, float], ...] = ()
    """(budget, official score) of each rung whose net was kept (ladder trials, pruned ones too)."""


def rows_from_trials(trials: Iterable[Any], t0: float) -> list[TrialRow]:
    """TrialRows of Optuna FrozenTrials, times relative to ``t0`` (epoch seconds)."""
    from autotune.search.records import kept_rungs

    rows = []
    for t in trials:
        a = t.user_attrs
        end = t.datetime_complete.timestamp() - t0 if t.datetime_complete is not None else None
        rows.append(
            TrialRow(
                number=t.number,
                state=t.state.name,
                value=t.value if t.state.name == "COMPLETE" else None,
                end_s=end,
                wall_s=a.get("trial_wall_seconds"),
                config=a.get("config"),
                seed=a.get("seed"),
                warm_start=a.get("warm_start"),
                race_of=a.get("race_of"),
                race_seed=a.get("race_seed"),
                incumbent=bool(a.get("incumbent_run")),
                seed_run=bool(a.get("seed_soup_run")),
                refine_of=(a.get("refine_of") or {}).get("trial"),
                soup="soup_of" in a,
                side="twin_of" in a or "neighbour_of" in a,
                predicted_cost_s=a.get("predicted_cost_s"),
                cause=a.get("cause"),
                retryable=bool(a.get("retryable")),
                refused_draws=a.get("refused_draws"),
                rung_scores=tuple(kept_rungs(a)),
            )
        )
    return rows


def _stored_study(journal: Path, study_name: str) -> Any:
    """The Optuna study ``study_name`` in a journal file; None when it was never created."""
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    if not journal.exists():
        return None
    storage = JournalStorage(JournalFileBackend(str(journal.absolute())))
    if study_name not in [s.study_name for s in storage.get_all_studies()]:
        return None
    return optuna.load_study(study_name=study_name, storage=storage)


def read_rows(journal: Path, study_name: str, t0: float) -> list[TrialRow]:
    """The rows of a study in a journal file (empty when the study was never created)."""
    study = _stored_study(journal, study_name)
    return [] if study is None else rows_from_trials(study.get_trials(deepcopy=False), t0)


def read_race(journal: Path, study_name: str) -> tuple[list[int], int]:
    """The study's stored seed race: its field and fresh seeds per round (``records.race_setup``)."""
    from autotune.search.records import race_setup

    study = _stored_study(journal, study_name)
    return race_setup({} if study is None else study.user_attrs)


def _complete_by(rows: Iterable[TrialRow], t_s: float) -> list[TrialRow]:
    return [r for r in rows if r.state == "COMPLETE" and r.value is not None and r.end_s is not None and r.end_s <= t_s]


def best_single(rows: Iterable[TrialRow], t_s: float, *, enqueued: bool = True) -> TrialRow | None:
    """The best COMPLETE trial finished by ``t_s`` (ties: the earlier) that is a configuration's own training (no
    refinement run: its config trains on from its parent's net); ``enqueued=False`` skips warm-start trials."""
    done = [r for r in _complete_by(rows, t_s) if r.refine_of is None and (enqueued or r.warm_start is None)]
    return max(done, key=lambda r: (r.value, -(r.end_s or 0.0)), default=None)


@dataclasses.dataclass(frozen=True)
class Net:
    """A scored net: a COMPLETE trial's (``budget`` None) or a kept rung's (``autotune best``'s best single net)."""

    score: float
    number: int
    budget: int | None


def best_net(rows: Iterable[TrialRow], t_s: float, *, enqueued: bool = True) -> Net | None:
    """The best net stored by ``t_s`` (a trial's value or a kept rung of any finished trial, refinement runs
    included, ranked as ``autotune best`` ranks them: ``records.net_rank``); ``enqueued=False`` skips warm-start
    trials and the refinement runs that descend from one (``lineage_root``)."""
    from autotune.search.records import net_rank

    rows = list(rows)
    by_number = {r.number: r for r in rows}
    best: tuple[tuple[float, int, int], Net] | None = None
    for r in rows:
        if r.end_s is None or r.end_s > t_s or r.state not in FINISHED:
            continue
        if not enqueued and lineage_root(r, by_number).warm_start is not None:
            continue
        nets = [Net(float(r.value), r.number, None)] if r.state == "COMPLETE" and r.value is not None else []
        nets += [Net(score, r.number, budget) for budget, score in r.rung_scores]
        for n in nets:
            rank = net_rank(n.score, n.budget, n.number)
            if best is None or rank > best[0]:
                best = (rank, n)
    return None if best is None else best[1]


def lineage_root(row: TrialRow, by_number: Mapping[int, TrialRow]) -> TrialRow:
    """The fresh training a refinement run descends from (``refine_of`` followed to its end); ``row`` itself when it
    is none."""
    seen = {row.number}
    while row.refine_of is not None and row.refine_of in by_number and row.refine_of not in seen:
        row = by_number[row.refine_of]
        seen.add(row.number)
    return row


def chosen_trial(rows: Sequence[TrialRow], t_s: float, race: tuple[Sequence[int], int] = ((), 1)) -> TrialRow | None:
    """The trial whose configuration the arm would pick at ``t_s``, as ``autotune best`` ranks it: the race winner
    (``racing.standings`` on the race runs finished by ``t_s``; ``race``: the study's stored field and seeds per
    round, ``read_race``) once a race run of the race itself has finished; before, the provisional standing's
    first (``racing.provisional_standings``: the best mean over a configuration's fresh seed runs, once it has
    ``racing.PROVISIONAL_SEEDS``), else the best trial. Race runs started before the race (seed runs, the
    incumbent's) count in both; the field the study stored at the race's start did not exist before it."""
    from autotune.search import racing

    field, seeds_per_round = race
    results: dict[tuple[int, int], float | None] = {}
    for r in rows:
        if r.race_of is None or r.race_seed is None:
            continue
        state = r.state if r.end_s is not None and r.end_s <= t_s else "RUNNING"
        is_result, score = racing.run_result(state, r.value, r.cause, r.retryable)
        if is_result:
            results[(r.race_of, r.race_seed)] = score
    racing_now = any(
        r.race_of is not None and not (r.seed_run or r.incumbent) and r.end_s is not None and r.end_s <= t_s
        for r in rows
    )
    if not racing_now or not field or not any(v is not None for v in results.values()):
        # before the race (its field was stored later): the provisional standing ``autotune best`` shows
        provisional = racing.provisional_standings(results)
        if not provisional:
            return best_single(rows, t_s)
        root = provisional[0].number
    else:
        root = racing.standings(field, results, seeds_per_round)[0].number
    by_number = {r.number: r for r in rows}
    runs = [r for r in _complete_by(rows, t_s) if r.race_of == root]
    raced = next((r.config for r in runs if r.config is not None), None)  # a kept rung's budget, if it entered so
    if root in by_number and by_number[root].config is not None:
        return dataclasses.replace(by_number[root], config=raced or by_number[root].config)
    return runs[0] if runs else None


def running_best(rows: Iterable[TrialRow]) -> list[tuple[float, float]]:
    """(minutes since the arm started, best single net so far — ``best_net``) at each improvement."""
    rows = list(rows)
    points: list[tuple[float, float]] = []
    for end in sorted({r.end_s for r in rows if r.end_s is not None and r.state in FINISHED}):
        net = best_net(rows, end)
        if net is not None and (not points or net.score > points[-1][1]):
            points.append((end / 60.0, net.score))
    return points


def median(values: Iterable[float | None]) -> float | None:
    """Median of the values present (None when there are none)."""
    present = [float(v) for v in values if v is not None]
    return statistics.median(present) if present else None


def cost_model_error(rows: Iterable[TrialRow]) -> tuple[float | None, int]:
    """Median |actual − predicted| / actual over COMPLETE trials with a stored prediction, and their count."""
    errors = [
        abs(r.wall_s - r.predicted_cost_s) / r.wall_s
        for r in rows
        if r.state == "COMPLETE" and r.predicted_cost_s is not None and r.wall_s
    ]
    return median(errors), len(errors)


def limit_share(rows: Iterable[TrialRow], worker_seconds: float) -> float:
    """Share of the workers' time spent in trials stopped by a wall-time limit (cause ``timeout…``)."""
    stopped = sum(r.wall_s or 0.0 for r in rows if (r.cause or "").startswith(LIMIT_CAUSE))
    return stopped / worker_seconds if worker_seconds > 0 else 0.0


def refused_share(rows: Iterable[TrialRow]) -> float | None:
    """Refused draws / all draws of the sampler (enqueued and race trials are not draws); None if not stored."""
    drawn = [r for r in rows if r.warm_start is None and r.race_of is None]
    refused = [r.refused_draws for r in drawn if r.refused_draws is not None]
    if not refused:
        return None
    return sum(refused) / (sum(refused) + len(drawn))


def pruned_by(rows: Iterable[TrialRow]) -> dict[str, int]:
    """PRUNED trials counted by cause (``PRUNE_CAUSES``' labels, the rest as "other"), most frequent first."""
    counts: dict[str, int] = {}
    for r in rows:
        if r.state == "PRUNED":
            cause = r.cause or ""
            label = next((name for start, name in PRUNE_CAUSES if cause.startswith(start)), "other")
            counts[label] = counts.get(label, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def worst_overrun(rows: Iterable[TrialRow], limit_s: float) -> float | None:
    """The largest trial wall time / the per-trial limit (1.1 = 10 % past it)."""
    walls = [r.wall_s for r in rows if r.wall_s is not None]
    return max(walls) / limit_s if walls and limit_s > 0 else None


def config_key(config: Mapping[str, Any]) -> str:
    return json.dumps(config, sort_keys=True)


def checkpoint_picks(
    rows: Sequence[TrialRow], minutes: Sequence[float], race: tuple[Sequence[int], int] = ((), 1)
) -> list[dict[str, Any]]:
    """Per checkpoint: the best single net, the best not enqueued, and the configuration picked for reseeding
    (``race``: the study's stored seed race, ``read_race``)."""
    out = []
    for m in minutes:
        t = m * 60.0
        best, free = best_net(rows, t), best_net(rows, t, enqueued=False)
        chosen = chosen_trial(rows, t, race)
        out.append(
            {
                "minutes": m,
                "finished": sum(1 for r in rows if r.state in FINISHED and r.end_s is not None and r.end_s <= t),
                "best": best.score if best else None,
                "best_trial": best.number if best else None,
                "best_rung": best.budget if best else None,
                "best_not_enqueued": free.score if free else None,
                "chosen_trial": chosen.number if chosen else None,
                "chosen_config": chosen.config if chosen else None,
            }
        )
    return out


def mean_sd(scores: Sequence[float]) -> tuple[float | None, float | None]:
    if not scores:
        return None, None
    return statistics.fmean(scores), (statistics.stdev(scores) if len(scores) > 1 else None)


def _causes(counts: Mapping[str, int] | None) -> str:
    """': 40 by the pruner, 9 not learning, …' for a run's summary line ('' when none were pruned)."""
    return ": " + ", ".join(f"{n} {label}" for label, n in counts.items()) if counts else ""


def run_figures(rows: Sequence[TrialRow], wall_s: float, workers: int, limit_s: float) -> dict[str, Any]:
    """The per-run figures of the module doc (counts, cost-model error, limit/refused shares, overrun)."""
    err, n_err = cost_model_error(rows)
    states = {s: sum(1 for r in rows if r.state == s) for s in ("COMPLETE", "PRUNED", "FAIL", "RUNNING")}
    return {
        "trials": len(rows),
        "states": states,
        "pruned_by": pruned_by(rows),
        "cost_model_median_error": err,
        "cost_model_n": n_err,
        "limit_share": limit_share(rows, workers * wall_s),
        "refused_share": refused_share(rows),
        "worst_overrun": worst_overrun(rows, limit_s),
        "running_best": running_best(rows),
        **incumbent_figures(rows, workers * wall_s),
        **refine_figures(rows, workers * wall_s),
    }


SHARE_KINDS = ("search", "warm start", "twins and neighbours", "seed runs", "incumbent runs", "race", "refinement",
               "soups")  # fmt: skip
"""What a trial spent worker time on (``trial_kind``), in the order the shares are printed."""


def trial_kind(r: TrialRow) -> str:
    """The ``SHARE_KINDS`` entry of a trial: a weight soup, another refinement run, a twin or neighbour, a race run
    (a seed-soup run or an incumbent run started before the race apart), an enqueued warm-start setting, else a
    sampler draw (the search)."""
    if r.soup:
        return "soups"
    if r.refine_of is not None:
        return "refinement"
    if r.side:
        return "twins and neighbours"
    if r.seed_run:
        return "seed runs"
    if r.incumbent:
        return "incumbent runs"
    if r.race_of is not None:
        return "race"
    if r.warm_start is not None:
        return "warm start"
    return "search"


def time_shares(rows: Iterable[TrialRow], until_s: float, workers: int) -> dict[str, float]:
    """Share of the workers' time up to ``until_s`` (``workers`` × ``until_s``) that each kind of trial took
    (``trial_kind``; kinds that took none left out): a finished trial's busy time (``wall_s``, ending at ``end_s``)
    counted where it falls before ``until_s``. What the shares leave to 1 is time outside trials (start-up, the
    driver's turns, idle workers). Why: how an hour is spent (the search against twins, seed runs, soups and the
    race) is what the study's time keys (``side_share``, ``refine_share``, ``race_fraction``) trade."""
    total = workers * until_s
    busy: dict[str, float] = {}
    for r in rows:
        if r.end_s is None or not r.wall_s:
            continue
        overlap = min(r.end_s, until_s) - max(r.end_s - r.wall_s, 0.0)
        if overlap > 0:
            kind = trial_kind(r)
            busy[kind] = busy.get(kind, 0.0) + overlap
    return {k: busy[k] / total for k in SHARE_KINDS if k in busy and total > 0}


def incumbent_figures(rows: Sequence[TrialRow], worker_s: float) -> dict[str, Any]:
    """The incumbent's runs before the race: how many, their share of the worker time, their best score."""
    runs = [r for r in rows if r.incumbent]
    scores = [r.value for r in runs if r.state == "COMPLETE" and r.value is not None]
    busy = sum(r.wall_s or 0.0 for r in runs)
    return {"incumbent_runs": len(runs), "incumbent_share": busy / worker_s if worker_s > 0 else None,
            "incumbent_best": max(scores) if scores else None}  # fmt: skip


def arm_checkpoints(runs: Sequence[Mapping[str, Any]], minutes: Sequence[float]) -> list[dict[str, Any]]:
    """Per checkpoint, medians over an arm's runs (study seeds) of its best, reseed mean and best not enqueued."""
    out = []
    for i, m in enumerate(minutes):
        cps = [r["checkpoints"][i] for r in runs]
        out.append(
            {
                "minutes": m,
                "runs": len(cps),
                "best_median": median(c["best"] for c in cps),
                "best_runs": [c["best"] for c in cps],
                "reseed_mean_median": median(c.get("reseed_mean") for c in cps),
                "reseed_means": [c.get("reseed_mean") for c in cps],
                "best_not_enqueued_median": median(c["best_not_enqueued"] for c in cps),
                "best_held_out": [c.get("best_held_out") for c in cps],
            }
        )
    return out


def _held_out_text(scores: Any) -> str:
    """A best net's held-out scores for the table: " (held out a / b)", why none could be read, or nothing."""
    if isinstance(scores, list) and scores:
        return " (held out " + " / ".join(_f(x) for x in scores) + ")"
    return f" (held out: {scores})" if isinstance(scores, str) else ""


def rung_correlations(configs: Sequence[Sequence[Mapping[str, Any]]]) -> list[dict[str, Any]]:
    """Per budget: Spearman ρ of that rung's score with the configuration's top rung's, over the configurations
    that have both (each configuration's top is its highest scored rung)."""
    from scipy import stats

    pairs: dict[int, list[tuple[float, float]]] = {}
    for rungs in configs:
        scored = [r for r in rungs if r.get("score") is not None]
        if len(scored) < 2:
            continue
        top = max(scored, key=lambda r: r["budget"])
        for r in scored:
            if r["budget"] < top["budget"]:
                pairs.setdefault(int(r["budget"]), []).append((float(r["score"]), float(top["score"])))
    out = []
    for budget in sorted(pairs):
        xs, ys = zip(*pairs[budget], strict=True)
        rho = None
        if len(xs) >= 3 and len(set(xs)) > 1 and len(set(ys)) > 1:
            rho = float(stats.spearmanr(xs, ys).statistic)
        out.append({"budget": budget, "n": len(xs), "spearman": rho})
    return out


# ---------------------------------------------------------------------------------------------
# the plot: data first, then the figure
# ---------------------------------------------------------------------------------------------

COLORS = {"plain": "#7f7f7f", "random": "#bcbd22", "cold": "#1f77b4", "warm": "#d62728"}


def plot_data(result: Mapping[str, Any]) -> dict[str, Any]:
    """One step line per run (running best vs wall minutes, held to the arm's end) and the checkpoints."""
    traces = []
    for arm, body in result["arms"].items():
        for run in body.get("runs", []):
            pts = run["running_best"]
            if not pts:
                continue
            end = max(run["wall_s"] / 60.0, pts[-1][0])
            traces.append(
                {
                    "arm": arm,
                    "name": f"{arm} (study seed {run['study_seed']})",
                    "x": [p[0] for p in pts] + [end],
                    "y": [p[1] for p in pts] + [pts[-1][1]],
                }
            )
    ref = result.get("reference") or {}
    reference = {"id": ref["id"], "mean": ref["reseed_mean"]} if ref.get("reseed_mean") is not None else None
    return {"traces": traces, "checkpoints": list(result["minutes"]), "reference": reference}


def draw(data: Mapping[str, Any]) -> Any:
    """The plotly figure of ``plot_data``."""
    import plotly.graph_objects as go

    fig = go.Figure()
    for tr in data["traces"]:
        fig.add_trace(
            go.Scatter(
                x=tr["x"],
                y=tr["y"],
                name=tr["name"],
                mode="lines+markers",
                line_shape="hv",
                line={"color": COLORS.get(tr["arm"])},
                legendgroup=tr["arm"],
            )
        )
    for m in data["checkpoints"]:
        fig.add_vline(x=m, line_dash="dot", line_color="#999")
    ref = data.get("reference")
    if ref is not None:
        fig.add_hline(
            y=ref["mean"], line_dash="dash", line_color="#2ca02c", annotation_text=f"{ref['id']}: mean over fresh seeds"
        )
    fig.update_layout(
        template="plotly_white",
        title="Running best official score vs wall time, per arm",
        xaxis_title="wall minutes since the arm started",
        yaxis_title="best official score [mph]",
    )
    return fig


# ---------------------------------------------------------------------------------------------
# running the arms
# ---------------------------------------------------------------------------------------------


def _load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}


_HELP: dict[str, str] = {}


def launch_help() -> str:
    """``autotune launch --help`` of this checkout (to see which contract options it has)."""
    if "text" not in _HELP:
        done = subprocess.run(
            [sys.executable, "-m", "autotune.cli", "launch", "--help"],
            capture_output=True,
            text=True,
            env=_env(),
            cwd=ROOT,
            check=False,
        )
        _HELP["text"] = done.stdout
    return _HELP["text"]


def run_plain(
    arm: str, seed: int, space: Path, run_dir: Path, duration_s: float, workers: int, grace_s: float
) -> dict[str, Any]:
    """The plain (TPE + median) or random loop: ``workers`` processes on one journal study for ``duration_s``."""
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    journal, name = run_dir / "journal.log", f"sq-{arm}-s{seed}"
    storage = JournalStorage(JournalFileBackend(str(journal.absolute())))
    optuna.create_study(study_name=name, storage=storage, direction="maximize")
    t0 = time.time()
    deadline = t0 + duration_s
    jobs = [
        {
            "kind": "loop",
            "space": str(space),
            "storage": str(journal),
            "study": name,
            "study_seed": seed,
            "worker": w,
            "prune": arm == "plain",
            "deadline": deadline,
        }
        for w in range(workers)
    ]
    with Pool(workers) as pool:
        results = pool.run(jobs, deadline=deadline + grace_s)
    errors = [r["error"] for r in results if "error" in r]
    return {"journal": journal, "study": name, "t0": t0, "wall_s": time.time() - t0, "errors": errors}


def run_service(
    arm: str, seed: int, data: Mapping[str, Any], run_dir: Path, duration_s: float, workers: int, grace_s: float
) -> dict[str, Any]:
    """``autotune launch`` on a copy of the spec (study seed and name set); Ctrl-C'd ``grace_s`` past the budget."""
    journal, name = run_dir / "journal.log", f"sq-{arm}-s{seed}"
    spec_path = run_dir / "study.toml"
    spec_path.write_text(toml_dumps(study_copy(data, name, seed, duration_s)), encoding="utf-8")
    cmd = [
        sys.executable,
        "-m",
        "autotune.cli",
        "launch",
        str(spec_path),
        "--study-name",
        name,
        "--storage",
        str(journal),
        "--workers",
        str(workers),
        "--timeout",
        f"{duration_s:g}",
        "--quiet",
    ]
    if arm == "warm":
        cmd += ["--warm-start", "crowd"]
    errors: list[str] = []
    t0 = time.time()
    with open(run_dir / "launch.log", "w", encoding="utf-8") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=_env(), cwd=ROOT, start_new_session=True)
        try:
            rc = proc.wait(timeout=duration_s + grace_s)
        except subprocess.TimeoutExpired:
            errors.append(f"launch still running {grace_s:g} s past its --timeout: interrupted")
            os.killpg(proc.pid, signal.SIGINT)
            try:
                rc = proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                rc = proc.wait()
    wall = time.time() - t0
    if rc not in (0, 130, -signal.SIGINT):
        tail = (run_dir / "launch.log").read_text(encoding="utf-8", errors="replace").strip().splitlines()[-1:]
        errors.append(f"launch exited {rc}: {tail[0] if tail else '(no output)'} (see {run_dir / 'launch.log'})")
    return {"journal": journal, "study": name, "t0": t0, "wall_s": wall, "errors": errors, "command": cmd}


def reseed(
    configs: Mapping[str, Mapping[str, Any]],
    seeds: Sequence[int],
    cache: dict[str, dict[str, Any]],
    workers: int,
) -> float:
    """Train every (config, seed) not in ``cache`` (key ``config_key|seed``); returns the wall seconds it took."""
    todo = [(key, s) for key in configs for s in seeds if f"{key}|{s}" not in cache]
    if not todo:
        return 0.0
    t0 = time.time()
    jobs = [{"kind": "train", "config": dict(configs[key]), "seed": s} for key, s in todo]
    with Pool(min(workers, len(jobs))) as pool:
        for (key, s), res in zip(todo, pool.run(jobs), strict=True):
            cache[f"{key}|{s}"] = res
    return time.time() - t0


def reseed_scores(key: str, seeds: Sequence[int], cache: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """Mean ± sd of a config's fresh-seed scores, with the runs that did not score and why."""
    results = [cache[f"{key}|{s}"] for s in seeds if f"{key}|{s}" in cache]
    scores = [float(r["value"]) for r in results if r.get("state") == "complete" and r.get("value") is not None]
    mean, sd = mean_sd(scores)
    causes = [r.get("cause") or r.get("error") for r in results if r.get("state") != "complete"]
    return {
        "reseed_mean": mean,
        "reseed_sd": sd,
        "reseed_n": len(scores),
        "reseed_scores": scores,
        "reseed_train_s": sum(float(r.get("seconds") or 0.0) for r in results),
        "reseed_unscored": causes,
    }


def held_out_scores(
    journal: Path, study_name: str, nets: Iterable[tuple[int, int | None]], seeds: Sequence[int], runs: int
) -> dict[tuple[int, int | None], list[float] | str]:
    """Per (trial, kept rung or None) of ``nets``: its stored net's site median on ``runs`` runs of the
    ``held_out_protocol`` from each of ``seeds``, scored as the study scored it (``records.stored_net``: a rung's
    own ε_test); where the study or the net cannot be read, why (one line): an arm's figures are never lost to this
    score."""
    from autotune.learner.official import evaluate_official
    from autotune.search.records import read_study, stored_net
    from autotune.search.storage import open_storage
    from sim.config import ConfigError

    picks = list(dict.fromkeys(nets))
    try:
        storages = open_storage(str(journal), study_name, heartbeat=False, read_only=True)
        study = read_study(storages, study_name)
    except ConfigError as exc:
        return dict.fromkeys(picks, str(exc).splitlines()[0])
    out: dict[tuple[int, int | None], list[float] | str] = {}
    for number, budget in picks:
        try:
            net, config = stored_net(storages, study.trials[number], budget)
        except ConfigError as exc:  # not stored, or stored damaged
            out[(number, budget)] = str(exc).splitlines()[0]
            continue
        protocol = held_out_protocol(config.ruleset)
        out[(number, budget)] = [
            float(evaluate_official(net, config, seed=s, protocol=protocol, runs=runs).median_site) for s in seeds
        ]
    return out


def held_out_protocol(ruleset: str) -> str:
    """The protocol of the held-out scores: v2's official harness on other runs (``v2-heldout``), so a net is
    scored as the site scored it, its temporal window carried from run to run; v1 nets on ``custom``."""
    from sim.protocols import CUSTOM, V2_HELDOUT

    return V2_HELDOUT if ruleset == "v2" else CUSTOM


def add_held_out(run: dict[str, Any], seeds: Sequence[int], runs: int) -> None:
    """Each checkpoint of a service arm's ``run`` gets ``best_held_out`` (``held_out_scores`` of its best net)."""
    picks = [(c["best_trial"], c["best_rung"]) for c in run["checkpoints"] if c.get("best_trial") is not None]
    if not seeds or not picks:
        return
    scores = held_out_scores(Path(run["storage"]), run["study"], picks, seeds, runs)
    for c in run["checkpoints"]:
        if c.get("best_trial") is not None:
            c["best_held_out"] = scores[(c["best_trial"], c["best_rung"])]


def run_arm(arm: str, seed: int, args: argparse.Namespace, ctx: dict[str, Any]) -> dict[str, Any]:
    """One run of one arm: start it, wait out its budget, read its study back."""
    run_dir = ctx["out"] / f"{arm}-s{seed}"
    run_dir.mkdir(parents=True, exist_ok=True)
    duration_s = max(ctx["minutes"]) * 60.0
    load_start = _load()
    print(
        f"[{dt.datetime.now():%H:%M:%S}] {arm} (study seed {seed}): {duration_s / 60:g} min, load {load_start}",
        file=sys.stderr,
    )
    if arm in ("plain", "random"):
        info = run_plain(arm, seed, ctx["space"], run_dir, duration_s, args.workers, args.grace)
    else:
        info = run_service(arm, seed, ctx["data"], run_dir, duration_s, args.workers, args.grace)
    load_end = _load()
    rows = read_rows(info["journal"], info["study"], info["t0"])
    race = read_race(info["journal"], info["study"])
    run = {
        "study_seed": seed,
        "study": info["study"],
        "storage": str(info["journal"]),
        "wall_s": info["wall_s"],
        "load_start": load_start,
        "load_end": load_end,
        "errors": info["errors"],
        **run_figures(rows, info["wall_s"], args.workers, float(ctx["spec"].study.trial_timeout_s)),
        "checkpoints": checkpoint_picks(rows, ctx["minutes"], race),
        "time_shares": [{"minutes": m, "shares": time_shares(rows, m * 60.0, args.workers)} for m in ctx["minutes"]],
    }
    for e in info["errors"]:
        print(f"  {arm} s{seed}: {e}", file=sys.stderr)
    return run


def calibration_draws(
    spec: Any, n: int, seed: int, cap_s: float, workers: int = 2
) -> tuple[list[dict[str, Any]], list[str], int]:
    """Up to ``n`` affordable draws of the service's space: (jobs with each draw's top config, planned rungs and
    their prior-predicted seconds; the refusals' causes; draws made). No training: the prior prices them, and as
    in a study no rung needs more memory than a worker may hold (``[study] max_trial_memory_gb`` or its default
    for ``workers``)."""
    import optuna

    from autotune.search import space
    from autotune.search.cost import CostModel, default_memory_cap, plan, rung_memory_bytes

    gb = spec.study.max_trial_memory_gb
    memory = int(gb * 1e9) if gb is not None else default_memory_cap(workers)

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    draws = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=seed))
    model = CostModel.prior()
    if spec.ladder_epsilon_grid:  # each rung screens its net at the grid, as the study's trials do
        model = model.screening(spec.ladder_epsilon_grid, spec.ladder_epsilon_screen_share,
                                spec.ladder_epsilon_carried_share)  # fmt: skip
    jobs: list[dict[str, Any]] = []
    refused: list[str] = []
    drawn = 0
    while len(jobs) < n and drawn < 100 * n:
        params = space.sample(draws.ask(), spec)
        drawn += 1
        try:
            configs = [space.to_config(spec, params, budget=b) for b in spec.ladder]
        except Exception as exc:  # a combination deepqlearn rejects (the driver fails such a trial)
            refused.append(f"invalid: {str(exc).splitlines()[0]}")
            continue
        held = next((i for i, c in enumerate(configs) if rung_memory_bytes(c) > memory), len(configs))
        if held < 2:
            refused.append(f"rung {held} over the memory cap ({rung_memory_bytes(configs[held]) / 1e9:,.1f} GB)")
            continue
        p = plan(configs[:held], model, cap_s)
        if p is None or len(p.budgets) < 2:
            first = model.predict(configs[0])
            refused.append(f"{'rung 0' if p is None else 'rung 1'} over the cap (rung 0 predicted {first:,.0f} s)")
            continue
        top = configs[len(p.budgets) - 1]
        jobs.append({"kind": "train", "config": top.to_mapping(), "seed": _seed(seed, drawn), "rungs": list(p.budgets),
                     "reseed": spec.ladder_reseed, "epsilon_test_grid": list(spec.ladder_epsilon_grid),
                     "epsilon_test_screen_runs": list(spec.ladder_epsilon_screen_runs),
                     "predicted_s": list(p.costs), "timeout_s": float(spec.study.trial_timeout_s)})  # fmt: skip
    return jobs, refused, drawn


def run_calibration(n: int, args: argparse.Namespace, ctx: dict[str, Any]) -> dict[str, Any]:
    """The calibration set (module doc); {"skipped": why} when there is nothing to calibrate."""
    spec = ctx["spec"]
    if n <= 0:
        return {"skipped": "--calibration 0"}
    if not tuple(getattr(spec, "ladder", ()) or ()):
        return {"skipped": f"{ctx['space']} has no [ladder]: no rungs to calibrate"}
    cap = args.calibration_cap or float(spec.study.cost_cap_s)
    t0 = time.time()
    jobs, refused, drawn = calibration_draws(spec, n, args.calibration_seed, cap, args.workers)
    with Pool(min(args.workers, max(1, len(jobs)))) as pool:
        results = pool.run(jobs)
    sets, unfinished, errors = [], [], []
    for job, res in zip(jobs, results, strict=True):
        rungs = res.get("rungs") or []
        for rung, predicted in zip(rungs, job["predicted_s"], strict=False):
            if rung.get("seconds"):
                errors.append(abs(rung["seconds"] - predicted) / rung["seconds"])
        entry = {"config": job["config"], "seed": job["seed"], "rungs": rungs, "predicted_s": job["predicted_s"]}
        if res.get("state") == "complete":
            sets.append(entry)
        else:
            unfinished.append({**entry, "cause": res.get("cause") or res.get("error")})
    return {
        "ladder": list(spec.ladder),
        "cap_s": cap,
        "configs": len(sets),
        "unfinished": unfinished,
        "draws": drawn,
        "refused": len(refused),
        "refused_causes": refused[:20],
        "prior_cost_median_error": median(errors),
        "prior_cost_rungs": len(errors),
        "seconds": time.time() - t0,
        "correlations": rung_correlations([c["rungs"] for c in sets]),
        "sets": sets,
    }


def reference_config(crowd_id: str) -> dict[str, Any]:
    """The TrainConfig mapping of a crowd submission (BenchError naming the id if unknown)."""
    from dashboards.crowd_data import load_submissions, train_config

    for sub in load_submissions():
        if sub.id == crowd_id:
            return dict(train_config(sub).to_mapping())
    raise BenchError(f"--reference {crowd_id}: no such crowd submission id (see dashboards/data/crowd/submissions.csv)")


# ---------------------------------------------------------------------------------------------
# output
# ---------------------------------------------------------------------------------------------


def _f(x: float | None, fmt: str = ".2f") -> str:
    return "–" if x is None else format(x, fmt)


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:.1f} %"


def refine_figures(rows: Sequence[TrialRow], worker_s: float) -> dict[str, Any]:
    """The refinement runs: how many (weight soups among them), their share of the worker time, their best score,
    and the lineage of the best one (its fresh root's trial number)."""
    runs = [r for r in rows if r.refine_of is not None]
    scores = [r.value for r in runs if r.state == "COMPLETE" and r.value is not None]
    busy = sum(r.wall_s or 0.0 for r in runs)
    best = max((r for r in runs if r.state == "COMPLETE" and r.value is not None), key=lambda r: r.value or 0.0,
               default=None)  # fmt: skip
    by_number = {r.number: r for r in rows}
    return {"refine_runs": len(runs), "refine_soups": sum(r.soup for r in runs),
            "refine_share": busy / worker_s if worker_s > 0 else None,
            "refine_best": max(scores) if scores else None,
            "refine_root": lineage_root(best, by_number).number if best is not None else None}  # fmt: skip


def format_table(result: Mapping[str, Any]) -> list[str]:
    """The arm × checkpoint table, then one line of per-run figures per arm."""
    head = f"{'arm':<7} {'runs':>4} {'min':>5} {'best':>7} {'reseed mean':>12} {'not enqueued':>13}  per run (best)"
    lines = [head, "-" * len(head)]
    for arm, body in result["arms"].items():
        if "skipped" in body:
            lines.append(f"{arm:<7} skipped: {body['skipped']}")
            continue
        for cp in body["checkpoints"]:
            held = cp.get("best_held_out") or [None] * len(cp["best_runs"])
            per_run = ", ".join(_f(b) + _held_out_text(h) for b, h in zip(cp["best_runs"], held, strict=True))
            lines.append(
                f"{arm:<7} {cp['runs']:>4} {cp['minutes']:>5g} {_f(cp['best_median']):>7} "
                f"{_f(cp['reseed_mean_median']):>12} {_f(cp['best_not_enqueued_median']):>13}  {per_run}"
            )
    lines += ["", *result.get("notes", [])]
    for arm, body in result["arms"].items():
        for run in body.get("runs", []):
            st = run["states"]
            lines.append(
                f"{arm} s{run['study_seed']}: {run['trials']} trials ({st['COMPLETE']} complete, "
                f"{st['PRUNED']} pruned{_causes(run.get('pruned_by'))}, {st['FAIL']} failed), cost model error "
                f"{_pct(run['cost_model_median_error'])} "
                f"(n={run['cost_model_n']}), limit-stopped {_pct(run['limit_share'])} of worker time, refused draws "
                f"{_pct(run['refused_share'])}, worst trial {_f(run['worst_overrun'])}× its limit, "
                f"{run.get('incumbent_runs', 0)} incumbent runs ({_pct(run.get('incumbent_share'))} of worker time, "
                f"best {_f(run.get('incumbent_best'))}), {run.get('refine_runs', 0)} refinement runs "
                f"({run.get('refine_soups', 0)} of them weight soups) "
                f"({_pct(run.get('refine_share'))} of worker time, best {_f(run.get('refine_best'))}, from trial "
                f"{run.get('refine_root')}), reseeding "
                f"{_f(run.get('reseed_wall_s'), '.0f')} s, load {run['load_start']} → {run['load_end']}"
            )
            for ts in run.get("time_shares", []):
                shares = ", ".join(f"{k} {_pct(v)}" for k, v in ts["shares"].items()) or "none"
                lines.append(f"  {arm} s{run['study_seed']}: worker time to {ts['minutes']:g} min: {shares}")
    ref = result.get("reference") or {}
    if ref.get("id"):
        lines.append(
            f"reference {ref['id']}: mean {_f(ref.get('reseed_mean'))} ± {_f(ref.get('reseed_sd'))} "
            f"over seeds {result['fresh_seeds']} (n={ref.get('reseed_n')})"
        )
    cal = result.get("calibration") or {}
    if "skipped" in cal:
        lines.append(f"calibration skipped: {cal['skipped']}")
    elif cal:
        rhos = ", ".join(f"{c['budget']:,}: ρ={_f(c['spearman'])} (n={c['n']})" for c in cal["correlations"])
        lines.append(
            f"calibration: {cal['configs']} configs + {len(cal['unfinished'])} unfinished ({cal['refused']} of "
            f"{cal['draws']} draws refused, cap {cal['cap_s']:g} s, {cal['seconds']:.0f} s); prior cost model error "
            f"{_pct(cal['prior_cost_median_error'])} over {cal['prior_cost_rungs']} rungs; rung vs top: {rhos}"
        )
    return lines


def compact(result: Mapping[str, Any]) -> dict[str, Any]:
    """The result for the JSON line: no calibration sets, no reference settings (result.json has them)."""
    out = dict(result)
    if isinstance(out.get("calibration"), Mapping):
        out["calibration"] = {k: v for k, v in out["calibration"].items() if k != "sets"}
    if isinstance(out.get("reference"), Mapping):
        out["reference"] = {k: v for k, v in out["reference"].items() if k != "config"}
    return out


def _save(result: Mapping[str, Any], out: Path) -> None:
    (out / "result.json").write_text(json.dumps(result, indent=1, default=str), encoding="utf-8")


def _space_path(text: str) -> Path:
    path = Path(text)
    if path.suffix != ".toml":
        path = ROOT / "study_configs" / f"{text}.toml"
    if not path.is_file():
        raise BenchError(f"--space {text}: no such spec ({path}); give a study_configs name (paper, smoke) or a path")
    return path


def _floats(text: str, what: str) -> list[float]:
    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise BenchError(f"{what} {text}: expected comma-separated numbers, e.g. 10,30,60") from None
    if not values or any(not (v > 0 and math.isfinite(v)) for v in values):
        raise BenchError(f"{what} {text}: expected positive numbers, e.g. 10,30,60")
    return values


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--space", default="paper", help="study spec: a study_configs name (paper, smoke) or a TOML path")
    p.add_argument(
        "--arms",
        default=",".join(ARMS),
        help=f"arms to run, in order (default {','.join(ARMS)}; none: calibration only)",
    )
    p.add_argument("--minutes", default="10,30,60", help="checkpoints [min]; the longest is each arm's budget")
    p.add_argument("--study-seeds", default="0", help="study seeds of the plain and cold arms (e.g. 0,1,2)")
    p.add_argument("--workers", type=int, default=2, help="processes per arm, one core each (default 2)")
    p.add_argument("--reseeds", type=int, default=3, help="fresh seeds per picked configuration (0: no reseeding)")
    p.add_argument(
        "--reference", default=REFERENCE_ID, help="crowd submission retrained on the fresh seeds ('none' to skip)"
    )
    p.add_argument(
        "--held-out",
        default=",".join(str(s) for s in HELD_OUT_SEEDS),
        help="v2-heldout seeds (v1: custom) on which each checkpoint's best net is scored again ('none' to skip)",
    )
    p.add_argument("--held-out-runs", type=int, default=HELD_OUT_RUNS, help="runs per held-out seed (default 500)")
    p.add_argument("--calibration", type=int, default=30, help="configurations in the calibration set (0: none)")
    p.add_argument("--calibration-cap", type=float, default=None, metavar="S", help="trial cost cap of the set [s]")
    p.add_argument("--calibration-seed", type=int, default=14)
    p.add_argument(
        "--grace",
        type=float,
        default=120.0,
        metavar="S",
        help="seconds past an arm's budget before its processes are stopped",
    )
    p.add_argument("--out", default=str(ROOT / "runs" / "search_quality"), help="output folder")
    args = p.parse_args(argv)
    args.arm_list = [] if args.arms == "none" else [a.strip() for a in args.arms.split(",") if a.strip()]
    bad = [a for a in args.arm_list if a not in ARMS]
    if bad or (not args.arm_list and args.arms != "none"):
        raise BenchError(
            f"--arms {args.arms}: unknown arm {bad[0] if bad else '(none)'}; use {', '.join(ARMS)} or none"
        )
    args.minute_list = sorted(set(_floats(args.minutes, "--minutes")))
    try:
        args.seed_list = [int(x) for x in args.study_seeds.split(",") if x.strip()]
    except ValueError:
        raise BenchError(f"--study-seeds {args.study_seeds}: expected comma-separated integers, e.g. 0,1,2") from None
    if not args.seed_list:
        raise BenchError("--study-seeds: give at least one seed, e.g. 0")
    if args.workers < 1 or args.reseeds < 0 or args.calibration < 0:
        raise BenchError("--workers must be ≥ 1, --reseeds and --calibration ≥ 0")
    try:
        args.held_out_seeds = [] if args.held_out == "none" else [int(x) for x in args.held_out.split(",") if x.strip()]
    except ValueError:
        raise BenchError(f"--held-out {args.held_out}: expected comma-separated integers, e.g. 1000000,2000000, "
                         "or none") from None  # fmt: skip
    if any(s < 0 for s in args.held_out_seeds) or args.held_out_runs < 1:
        raise BenchError("--held-out seeds must be ≥ 0 and --held-out-runs ≥ 1")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv == ["--serve"]:
        return serve()
    from autotune.search.spec import load_spec
    from sim.config import ConfigError

    try:
        args = parse_args(argv)
        space = _space_path(args.space)
        spec = load_spec(space)
        data = tomllib.loads(space.read_text(encoding="utf-8"))
        ref_config = reference_config(args.reference) if args.reference != "none" and args.reseeds else None
    except (BenchError, ConfigError) as exc:
        print(str(exc).splitlines()[0], file=sys.stderr)
        return 2
    out = Path(args.out) / dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    out.mkdir(parents=True, exist_ok=True)
    ctx = {"out": out, "space": space, "spec": spec, "data": data, "minutes": args.minute_list}
    fresh = [FRESH_SEED0 + i for i in range(args.reseeds)]
    result: dict[str, Any] = {
        "space": str(space),
        "workers": args.workers,
        "minutes": args.minute_list,
        "fresh_seeds": fresh,
        "cpus": os.cpu_count(),
        "out": str(out),
        "arms": {},
        "notes": list(plain_space(spec)[1]),
    }
    cache: dict[str, dict[str, Any]] = {}
    for arm in args.arm_list:
        if arm == "warm" and "--warm-start" not in launch_help():
            result["arms"][arm] = {"skipped": "autotune launch has no --warm-start yet (issue 14, deliverable 4)"}
            print(f"warm: skipped: {result['arms'][arm]['skipped']}", file=sys.stderr)
            continue
        seeds = args.seed_list if arm in SEEDED_ARMS else args.seed_list[:1]
        runs = [run_arm(arm, s, args, ctx) for s in seeds]
        for run in runs:
            configs = {
                config_key(c["chosen_config"]): c["chosen_config"]
                for c in run["checkpoints"]
                if c["chosen_config"] is not None
            }
            run["reseed_wall_s"] = reseed(configs, fresh, cache, args.workers) if fresh else 0.0
            if arm not in ("plain", "random"):  # the service stores every scored net
                add_held_out(run, args.held_out_seeds, args.held_out_runs)
            for c in run["checkpoints"]:
                config = c.pop("chosen_config")
                if config is not None and fresh:
                    c.update(reseed_scores(config_key(config), fresh, cache))
        result["arms"][arm] = {"runs": runs, "checkpoints": arm_checkpoints(runs, args.minute_list)}
        _save(result, out)
    if ref_config is not None:
        key = config_key(ref_config)
        wall = reseed({key: ref_config}, fresh, cache, args.workers)
        result["reference"] = {
            "id": args.reference,
            "config": ref_config,
            "wall_s": wall,
            **reseed_scores(key, fresh, cache),
        }
        _save(result, out)
    result["calibration"] = run_calibration(args.calibration, args, ctx)
    fig_path = out / "search_quality.html"
    draw(plot_data(result)).write_html(str(fig_path), include_plotlyjs=True, full_html=True)
    result["figure"] = str(fig_path)
    _save(result, out)
    for line in format_table(result):
        print(line)
    print(f"figure: {fig_path}; studies and result.json in {out}")
    print("JSON " + json.dumps(compact(result), default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
