"""What one training reaches: a configuration's official score over many fresh seeds, per budget.

    python bench/ceiling.py                                            # gsurma's crowd setting, 90k/270k/810k, 6 seeds
    python bench/ceiling.py --config dt-gsurma-deep-traffic-v00 --budgets 90000 --seeds 24
    python bench/ceiling.py --config runs/paper/journal.log:212 --budgets 270000,810000
    python bench/ceiling.py --config my_setting.toml --budgets 30000 --seeds 4 --workers 2
    python bench/ceiling.py --config runs/paper/journal.log:160 --budgets 10000 --seeds 60 --space none

Why: a study's best single net (the leaderboard's number) is the best of many trainings, so what it can
reach is bounded by the upper tail of one configuration's scores over seeds. This measures that tail
for named configurations, so a target above it can be judged from data rather than from how long a
search ran.

A ``--config`` is a crowd submission id (``dashboards/data/crowd/submissions.csv``; its settings as
the crowd prior enqueues them), ``JOURNAL:N`` (trial N's ``config`` user attribute in a study's
journal file), or a TrainConfig TOML file. Each (configuration, budget, seed) is one fresh, complete
training at that budget, the length-bound settings scaled to it exactly as a ladder rung
(``ladder.rung_config``), trained and officially scored through the service's own ``run_trial``
(v2-official for a v2 configuration: 500 runs × 2,000 frames, the site's median), and scored as a study
of ``--space`` scores its rungs (default ``paper``): where its ``[ladder] epsilon_test_grid`` chooses ε_test
per trained net, each training is screened at the grid's values and scored at the best, as a rung is;
``--space none`` scores at the configuration's own ``epsilon_test_time``. Seeds are
``--seed-start`` + 0 … ``--seeds`` − 1, the same for every configuration and budget. ``--workers``
processes, one core each (torch and numba single-threaded).

Printed per configuration and budget: the scores, n, mean ± sd, median, min, max, the share at or
above 74, 75 and 75.5 mph, and the expected best of k trainings for k = 10, 30 and 100 under the
measured distribution (draws with replacement from the n scores: an estimate that cannot exceed the
measured maximum); then one JSON line (prefix ``JSON``) with the same figures and the load average.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import statistics
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

DEFAULT_CONFIG = "dt-gsurma-deep-traffic-v00"
THRESHOLDS = (74.0, 75.0, 75.5)
BEST_OF = (10, 30, 100)


class BenchError(Exception):
    """A bad argument: one line naming it and the fix."""


def load_config(source: str) -> dict[str, Any]:
    """The TrainConfig mapping ``source`` names (module docstring); BenchError when it names nothing."""
    from autotune.learner.config import TrainConfig, load_toml

    path, _, number = source.rpartition(":")
    if path and number.isdigit() and Path(path).is_file():
        return dict(TrainConfig.from_mapping(_trial_config(Path(path), int(number))).to_mapping())
    if Path(source).is_file():
        return dict(load_toml(source).to_mapping())
    from dashboards.crowd_data import load_submissions, train_config

    subs = {s.id: s for s in load_submissions()}
    if source in subs:
        return dict(train_config(subs[source]).to_mapping())
    raise BenchError(
        f"--config {source}: neither a crowd submission id, a JOURNAL:N trial nor a TOML file; "
        f"e.g. --config {DEFAULT_CONFIG} or --config runs/paper/journal.log:12"
    )


def _trial_config(journal: Path, number: int) -> dict[str, Any]:
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = JournalStorage(JournalFileBackend(str(journal)))
    study = optuna.load_study(study_name=None, storage=storage)
    trials = study.get_trials(deepcopy=False)
    if not 0 <= number < len(trials) or "config" not in trials[number].user_attrs:
        raise BenchError(f"--config {journal}:{number}: the study has no trial {number} with a stored config "
                         f"(it has {len(trials)} trials)")  # fmt: skip
    return dict(trials[number].user_attrs["config"])


Scoring = tuple[tuple[float, ...], tuple[int, ...]]
"""(ε_test grid, its screens' run counts) a training is scored with; an empty grid: the config's own ε_test."""


def scoring(space: str) -> Scoring:
    """How a study of ``space`` (a study_configs name or a TOML path; 'none': no grid) scores a rung's net."""
    if space == "none":
        return (), ()
    from autotune.search.spec import SpecError, load_spec

    path = Path(space) if space.endswith(".toml") else ROOT / "study_configs" / f"{space}.toml"
    if not path.is_file():
        raise BenchError(f"--space {space}: no such spec ({path}); give a study_configs name (paper), a TOML "
                         f"path or none (the configuration's own epsilon_test_time)")  # fmt: skip
    try:
        spec = load_spec(path)
    except SpecError as exc:
        raise BenchError(f"--space: {exc}") from None  # the spec error names the file, table and key
    return tuple(spec.ladder_epsilon_grid), tuple(spec.ladder_epsilon_screen_runs)


def job(args: tuple[dict[str, Any], int, int, Scoring]) -> dict[str, Any]:
    """One fresh training of ``config`` at ``budget`` from ``seed``, officially scored (a worker process)."""
    config, budget, seed, (grid, screens) = args
    from autotune.learner.config import TrainConfig
    from autotune.search.ladder import rung_config
    from autotune.search.objective import TrialTask, run_trial

    at_budget = rung_config(TrainConfig.from_mapping(config), budget)
    # a grid acts on ladder trials: a one-rung ladder at the budget is this training, its ε_test chosen as a rung's
    task = TrialTask(number=0, config=at_budget.to_mapping(), seed=seed, report_points=1, quick_runs=1,
                     quick_frames=200, timeout_s=None, rungs=(budget,) if grid else (), epsilon_test_grid=grid,
                     epsilon_test_screen_runs=screens or TrialTask.epsilon_test_screen_runs)  # fmt: skip
    t0 = time.time()
    out = run_trial(task, lambda _k, _frames, _score: False)
    rungs = out.attrs.get("rungs") or [{}]
    return {"budget": budget, "seed": seed, "state": out.state, "score": out.value, "cause": out.cause,
            "epsilon_test": rungs[-1].get("chosen_epsilon_test"), "seconds": time.time() - t0}  # fmt: skip


def _init_worker() -> None:
    from autotune import configure_process

    configure_process(1, numba_threads=1)


def expected_best_of(scores: Sequence[float], k: int) -> float:
    """E[max of k draws with replacement from ``scores``]: Σ x_(i) · ((i/n)^k − ((i−1)/n)^k), sorted ascending."""
    xs = sorted(scores)
    n = len(xs)
    return sum(x * ((i / n) ** k - ((i - 1) / n) ** k) for i, x in enumerate(xs, start=1))


def summary(scores: Sequence[float]) -> dict[str, Any]:
    """The figures printed per configuration and budget (module docstring)."""
    if not scores:
        return {"n": 0}
    return {
        "n": len(scores),
        "scores": list(scores),
        "mean": statistics.fmean(scores),
        "sd": statistics.stdev(scores) if len(scores) > 1 else 0.0,
        "median": statistics.median(scores),
        "min": min(scores),
        "max": max(scores),
        "share_at_or_above": {f"{t:g}": sum(s >= t for s in scores) / len(scores) for t in THRESHOLDS},
        "expected_best_of": {str(k): expected_best_of(scores, k) for k in BEST_OF},
    }


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--config", action="append", default=None,
                   help=f"crowd id, JOURNAL:N or TOML (repeatable; default {DEFAULT_CONFIG})")  # fmt: skip
    p.add_argument("--budgets", default="90000,270000,810000", help="training iterations, comma-separated")
    p.add_argument("--seeds", type=int, default=6, help="fresh seeds per configuration and budget")
    p.add_argument("--seed-start", type=int, default=8_100_001, help="the first seed")
    p.add_argument("--workers", type=int, default=2, help="processes, one core each")
    p.add_argument(
        "--space",
        default="paper",
        help="score as this spec's rungs ([ladder] epsilon_test_grid); none: the config's ε_test",
    )
    args = p.parse_args(argv)
    try:
        args.budget_list = [int(b) for b in args.budgets.split(",") if b.strip()]
    except ValueError:
        p.error(f"--budgets {args.budgets!r}: write whole iteration counts, e.g. 90000,270000")
    if not args.budget_list or min(args.budget_list) < 1:
        p.error("--budgets: at least one positive iteration count, e.g. 90000")
    if args.seeds < 1 or args.workers < 1:
        p.error("--seeds and --workers must be ≥ 1")
    args.config = args.config or [DEFAULT_CONFIG]
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        configs = {source: load_config(source) for source in args.config}
        scored = scoring(args.space)
    except BenchError as exc:
        print(f"ceiling: {exc}", file=sys.stderr)
        return 2
    seeds = [args.seed_start + i for i in range(args.seeds)]
    todo = [(source, b, s) for source in configs for b in args.budget_list for s in seeds]
    load_start = os.getloadavg()
    t0 = time.time()
    results: dict[tuple[str, int], list[dict[str, Any]]] = {}
    with mp.get_context("spawn").Pool(args.workers, initializer=_init_worker) as pool:
        outs = pool.imap(job, [(configs[src], b, s, scored) for src, b, s in todo])
        for (source, budget, seed), out in zip(todo, outs, strict=True):
            results.setdefault((source, budget), []).append(out)
            shown = f"{out['score']:.2f}" if out["score"] is not None else f"{out['state']} ({out['cause']})"
            if out.get("epsilon_test") is not None:
                shown += f" at ε_test {out['epsilon_test']:g}"
            print(f"[{time.time() - t0:7.0f} s] {source} at {budget:,}, seed {seed}: {shown} ({out['seconds']:.0f} s)",
                  file=sys.stderr)  # fmt: skip
    report = []
    print(f"\n{'configuration':44} {'budget':>8} {'n':>3} {'mean ± sd':>13} {'median':>7} {'min':>6} {'max':>6} "
          f"{'≥74':>5} {'≥75':>5} {'≥75.5':>5} {'best of 10/30/100':>19}")  # fmt: skip
    for (source, budget), runs in results.items():
        scores = [float(o["score"]) for o in runs if o["score"] is not None and math.isfinite(o["score"])]
        row = {"config": source, "budget": budget, "seeds": [o["seed"] for o in runs], **summary(scores),
               "unscored": [o["cause"] for o in runs if o["score"] is None],
               "train_s": sum(o["seconds"] for o in runs)}  # fmt: skip
        report.append(row)
        if not scores:
            print(f"{source[:44]:44} {budget:>8,} {0:>3}  (no run scored: {row['unscored'][:1]})")
            continue
        share = row["share_at_or_above"]
        best = row["expected_best_of"]
        print(f"{source[:44]:44} {budget:>8,} {row['n']:>3} {row['mean']:>6.2f} ± {row['sd']:<4.2f} "
              f"{row['median']:>7.2f} {row['min']:>6.2f} {row['max']:>6.2f} {share['74']:>5.0%} {share['75']:>5.0%} "
              f"{share['75.5']:>5.0%} {best['10']:>6.2f} {best['30']:>6.2f} {best['100']:>6.2f}")  # fmt: skip
    print("JSON " + json.dumps({"rows": report, "wall_s": time.time() - t0, "workers": args.workers,
                                "epsilon_test_grid": list(scored[0]), "space": args.space,
                                "load_start": load_start, "load_end": os.getloadavg()}))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
