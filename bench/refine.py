"""Refinement: does training on from the best net (``[study] refine_share``) raise the policy, or the 500 runs' luck?

    python bench/refine.py                                               # gsurma's setting: 8 steps of 8 runs
    python bench/refine.py --config runs/paper/journal.log:211 --steps 6 --runs 8 --learning-rate 0.1
    python bench/refine.py --steps 1 --runs 10 --learning-rate 1.0 --own-schedule   # the net's own ε schedule
    python bench/refine.py --soups 2,4                                   # with weight soups ([study] refine_soups)

Why: a study's refinement runs select, among nets trained on from its best one, those that score best with the
official protocol — 500 fixed runs (v2-official: run k ↦ Park–Miller seed k + 1). A gain found that way could be
the 500 runs' luck. This climbs the same way outside a study and scores every step's best net also on runs the
official protocol never plays: ``--heldout`` sets of 500 runs of the ``custom`` protocol (independent worlds,
seeds 10⁶·k + i). If the held-out scores rise with the official ones, the gain is the policy's.

The parent: ``--config`` (as ``bench/ceiling.py`` reads it: a crowd id, ``JOURNAL:N`` or a TOML) trained once
from ``--seed`` at its own length, scored officially at its own ε_test. Each step trains ``--runs`` refinement
runs from the current best net (``refine.refine_config`` at ``--iterations`` and ``--learning-rate``; with
``--own-schedule`` the net's own ε schedule and threshold instead, only the length and the rate changed), seeds
``refine.refine_seed(--seed, k)``, through the service's own learner and scoring; with ``--soups K,…`` each step
also scores the weight soup of its best K runs for each K (``soup.average_nets``, as ``[study] refine_soups``);
the best net of the step — run or soup — becomes the parent when it beats it. ``--workers`` processes, one core
each.

Printed per step: the parent's official and held-out scores, the runs' official scores (median, best), the best
run's held-out scores, and the wall time; then one JSON line (prefix ``JSON``) with the same figures and the load
average.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
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

HELDOUT_RUNS = 500
HELDOUT_SEED = 1_000_000


def _ceiling() -> Any:
    """``bench/ceiling.py`` (its ``load_config`` and ``BenchError``), loaded once."""
    module = sys.modules.get("bench_ceiling")
    if module is None:
        spec = importlib.util.spec_from_file_location("bench_ceiling", ROOT / "bench" / "ceiling.py")
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules["bench_ceiling"] = module
        spec.loader.exec_module(module)
    return module


def _setup() -> None:
    from autotune.runtime import configure_process

    configure_process(1, numba_threads=1)


def train_and_score(job: tuple[dict[str, Any], int, str | None]) -> tuple[float, str, float]:
    """(official score, the net's JSON, seconds) of one training of ``config`` from ``seed`` (on from ``parent``)."""
    from autotune.convnet.netjson import dumps_net, loads_net
    from autotune.learner.config import TrainConfig
    from autotune.learner.official import evaluate_official
    from autotune.learner.training import train

    config_map, seed, parent = job
    t0 = time.perf_counter()
    config = TrainConfig.from_mapping(config_map)
    result = train(config, seed, quick_eval=False, init_net=None if parent is None else loads_net(parent))
    net = result.convnet()
    score = float(evaluate_official(net, config).median_site)
    return score, dumps_net(net), time.perf_counter() - t0


def score_net(job: tuple[dict[str, Any], str]) -> float:
    """The official score of a net (a weight soup) at ``config``'s ε_test."""
    from autotune.convnet.netjson import loads_net
    from autotune.learner.config import TrainConfig
    from autotune.learner.official import evaluate_official

    config_map, net = job
    return float(evaluate_official(loads_net(net), TrainConfig.from_mapping(config_map)).median_site)


def soups(runs: Sequence[tuple[float, str, float]], sizes: Sequence[int]) -> list[tuple[int, str]]:
    """(K, Net JSON) of the weight soup of the best K of ``runs`` for each K in ``sizes`` that many runs allow."""
    from autotune.convnet.netjson import dumps_net, loads_net
    from autotune.search.soup import average_nets

    ranked = sorted(runs, key=lambda r: -r[0])
    return [(k, dumps_net(average_nets([loads_net(r[1]) for r in ranked[:k]]))) for k in sizes if len(ranked) >= k]


def heldout(job: tuple[dict[str, Any], str, int]) -> float:
    """The site's median of the net on 500 ``custom`` runs from ``seed`` (runs the official protocol never plays)."""
    from autotune.convnet.netjson import loads_net
    from autotune.learner.config import TrainConfig
    from autotune.learner.official import evaluate_official

    config_map, net, seed = job
    config = TrainConfig.from_mapping(config_map)
    return float(evaluate_official(loads_net(net), config, protocol="custom", seed=seed, runs=HELDOUT_RUNS).median_site)


class _InProcess:
    """``Pool``'s ``map`` in this process (one worker: no child to start, nothing to pickle); the process's settings
    are left as they are (``train`` sets one thread and denormal flushing for its own call only)."""

    def map(self, fn: Any, jobs: Sequence[Any]) -> list[Any]:
        return [fn(job) for job in jobs]

    def __enter__(self) -> _InProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


def _pool(workers: int) -> Any:
    """``workers`` spawned processes, one core each (``--workers 1``: this process)."""
    return _InProcess() if workers == 1 else mp.get_context("spawn").Pool(workers, initializer=_setup)


def child_config(parent: Any, args: argparse.Namespace) -> Any:
    from autotune.search.refine import refine_config

    if args.own_schedule:
        return parent.replace(train_iterations=args.iterations, learning_rate=parent.learning_rate * args.learning_rate)
    return refine_config(parent, args.iterations, args.learning_rate)


def run(args: argparse.Namespace) -> dict[str, Any]:
    from autotune.learner.config import TrainConfig
    from autotune.search.refine import refine_seed

    base = TrainConfig.from_mapping(_ceiling().load_config(args.config))
    child = child_config(base, args).to_mapping()
    seeds = [HELDOUT_SEED * (k + 1) for k in range(args.heldout)]
    t0 = time.perf_counter()
    steps = []
    with _pool(args.workers) as pool:
        score, net, _s = pool.map(train_and_score, [(base.to_mapping(), args.seed, None)])[0]
        held = pool.map(heldout, [(base.to_mapping(), net, s) for s in seeds])
        print(f"parent: {args.config} from seed {args.seed}: {score:.2f} official, held-out {held}", flush=True)
        k = 0
        for step in range(args.steps):
            jobs = [(child, refine_seed(args.seed, k + i), net) for i in range(args.runs)]
            k += args.runs
            runs = pool.map(train_and_score, jobs)
            mixed = soups(runs, args.soups)
            soup_scores = pool.map(score_net, [(child, text) for _, text in mixed])
            candidates = [*runs, *((sc, text, 0.0) for sc, (_, text) in zip(soup_scores, mixed, strict=True))]
            best = max(candidates, key=lambda r: r[0])
            best_held = pool.map(heldout, [(child, best[1], s) for s in seeds])
            row = {
                "step": step, "parent": score, "parent_heldout": held, "runs": [r[0] for r in runs],
                "median": statistics.median(r[0] for r in runs), "best_run": max(r[0] for r in runs),
                "soups": {str(k): sc for (k, _), sc in zip(mixed, soup_scores, strict=True)},
                "best": best[0], "best_heldout": best_held,
                "seconds": time.perf_counter() - t0,
            }  # fmt: skip
            steps.append(row)
            print(
                f"step {step}: parent {score:.2f} (held-out {', '.join(f'{h:.2f}' for h in held)}) | runs median "
                f"{row['median']:.2f}, best {row['best_run']:.2f}"
                + "".join(f", soup of {k} {sc:.2f}" for (k, _), sc in zip(mixed, soup_scores, strict=True))
                + f" | best {best[0]:.2f} (held-out {', '.join(f'{h:.2f}' for h in best_held)}) | "
                f"{row['seconds']:.0f} s",
                flush=True,
            )
            if best[0] > score:
                score, net, held = best[0], best[1], best_held
    return {
        "config": args.config, "seed": args.seed, "iterations": args.iterations, "learning_rate": args.learning_rate,
        "own_schedule": args.own_schedule, "soups": list(args.soups), "runs_per_step": args.runs,
        "workers": args.workers,
        "heldout_seeds": seeds, "steps": steps, "final": score, "final_heldout": held, "load": os.getloadavg(),
    }  # fmt: skip


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0], formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--config", default="dt-gsurma-deep-traffic-v00", help="crowd id, JOURNAL:N or a TOML file")
    p.add_argument("--seed", type=int, default=1735130437, help="the parent's training seed (default: a 74.39 net)")
    p.add_argument("--steps", type=int, default=8)
    p.add_argument("--runs", type=int, default=8, help="refinement runs per step")
    p.add_argument("--iterations", type=int, default=20_000, help="one run's length ([study] refine_iterations)")
    p.add_argument("--learning-rate", type=float, default=0.1, help="× the parent's ([study] refine_learning_rate)")
    p.add_argument("--own-schedule", action="store_true", help="keep the net's own ε schedule and threshold")
    p.add_argument("--soups", default="", help="soup sizes K scored each step, e.g. 2,4 (default: none)")
    p.add_argument("--heldout", type=int, default=2, help="held-out sets of 500 custom runs")
    p.add_argument("--workers", type=int, default=2)
    args = p.parse_args(argv)
    for name in ("steps", "runs", "iterations", "workers"):
        if getattr(args, name) < 1:
            p.error(f"--{name}: must be ≥ 1, got {getattr(args, name)}")
    try:
        args.soups = tuple(int(k) for k in args.soups.split(",") if k.strip())
    except ValueError:
        p.error(f"--soups: sizes as integers, e.g. 2,4; got {args.soups!r}")
    if any(k < 2 for k in args.soups):
        p.error(f"--soups: each size must be ≥ 2, got {args.soups!r}")
    if args.learning_rate <= 0 or args.heldout < 0:
        p.error("--learning-rate must be > 0 and --heldout ≥ 0")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        result = run(args)
    except _ceiling().BenchError as exc:
        print(exc, file=sys.stderr)
        return 2
    print("JSON " + json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
