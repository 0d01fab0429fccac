"""Learner parity with the original JS deepqlearn: network_basic, 8 seeds per engine.

    python bench/learner_parity.py                                  # v1 and v2, seeds 1…8, 2 processes
    python bench/learner_parity.py --dtype float64                  # the original's runs, decision for decision
    python bench/learner_parity.py --learner exact                  # the float64 numba replica (js_learner)
    python bench/learner_parity.py --stream independent --seeds $(seq 1 48)

Each seed s trains ``network_basic`` with the training protocol (v1: train.js; v2: the training web
worker, otherAgents 0) and evaluates the trained net as the reference data did (learner_scores.json /
learner_scores_v2.json): ``Math.random := mulberry32(100 + s)``, a fresh brain built, the trained
weights loaded after the JSON round trip; v1: evaluate.js's 10 × 100,000 frames (lexicographic
``sorted[5]``) with the reference harness's seeding — no engine-load draws, the Gaussian cache flag
inherited from the training (``--stream original``; 0 otherwise); v2: the official worker (500 × 2,000
frames, ``sorted[250]``).

Randomness (``--stream``): ``original`` (default) is the original harness's ``mulberry32(s)`` stream
for every learner draw (shared with the traffic in v1, feeding the training-mode seeds in v2), so a
float64 run is the original's run and the per-seed scores can be compared digit for digit (``same
run as the original``: the training-run scores equal the reference's); ``independent`` seeds
everything from ``SeedSequence(s)`` and the comparison is statistical. The summary: the median over
seeds against the original's (v1 70.41, v2 66.30) and the number of collapsed seeds (score < 60 mph;
the original: 1 of 8 in v1 at 51.96, none in v2).

Prints a table and one JSON line (prefix ``JSON``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

REFERENCE_FILES = {"v1": "learner_scores.json", "v2": "learner_scores_v2.json"}
REFERENCE: dict[str, dict[str, Any]] = {
    "v1": {"medians": [71.32, 70.7, 69.14, 69.46, 70.92, 71.22, 70.13, 51.96], "median_of_medians": 70.415},
    "v2": {"medians": [66.15, 66.51, 67.04, 66.45, 65.81, 66.08, 66.04, 66.58], "median_of_medians": 66.30},
}
COLLAPSE_MPH = 60.0


def _reference_runs(ruleset: str) -> dict[int, list[float]]:
    """Sorted training-run scores of the reference's network_basic seeds (empty if the data is absent)."""
    path = ROOT.parent / "shared" / "reference" / REFERENCE_FILES[ruleset]
    if not path.exists():
        return {}
    data = json.loads(path.read_text())
    return {
        r["train"]["seed"]: r["train"]["training_run_mph_sorted"]
        for r in data["runs"]
        if r["config_file"] == "network_basic.json"
    }


def run_one(args: tuple[str, int, dict, str, str]) -> dict:
    ruleset, seed, overrides, learner, stream = args
    import torch

    torch.set_num_threads(1)
    from autotune.learner.config import preset
    from autotune.learner.official import evaluate_official

    config = preset("network_basic", ruleset=ruleset, **overrides)
    t = time.perf_counter()
    if learner == "exact":
        from autotune.learner.js_learner import train_exact

        exact = train_exact(config, seed)
        net, runs, cache = exact.convnet, exact.training_run_scores, exact.final_gauss_cache
        it_s, diverged = None, False
    else:
        from autotune.learner.training import train

        result = train(config, seed, quick_eval=False, stream=stream)
        net, runs, cache = result.convnet(), result.training_run_scores, result.final_gauss_cache or 0
        it_s, diverged = result.iterations_per_second, result.diverged
    train_s = time.perf_counter() - t
    t = time.perf_counter()
    reference_harness = ruleset == "v1"
    ev = evaluate_official(
        net, config, seed=100 + seed, engine_load=not reference_harness, gauss_cache=cache if reference_harness else 0
    )
    ref_runs = _reference_runs(ruleset).get(seed)
    return {
        "ruleset": ruleset,
        "seed": seed,
        "eval_seed": 100 + seed,
        "score": ev.median_site,
        "mean": ev.mean,
        "train_seconds": train_s,
        "it_per_s": it_s if it_s is not None else config.train_iterations / train_s,
        "eval_seconds": time.perf_counter() - t,
        "diverged": diverged,
        "training_run_scores": runs,
        "same_run": None if ref_runs is None else sorted(runs) == ref_runs,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rulesets", nargs="+", default=["v1", "v2"], choices=["v1", "v2"])
    parser.add_argument("--seeds", nargs="+", type=int, default=list(range(1, 9)))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a setting")
    parser.add_argument("--learner", choices=["torch", "exact"], default="torch", help="torch (default) or the replica")
    parser.add_argument("--stream", choices=["original", "independent"], default="original",
                        help="randomness: original (default) or independent")  # fmt: skip
    parser.add_argument("--dtype", choices=["float32", "float64"], default=None, help="torch learner precision")
    args = parser.parse_args()
    overrides = {}
    for item in args.set:
        key, value = item.split("=", 1)
        overrides[key] = json.loads(value) if value[:1].isdigit() or value[:1] in "-[{" else value
    if args.dtype:
        overrides["dtype"] = args.dtype
    stream = args.stream
    tasks = [(r, s, overrides, args.learner, stream) for r in args.rulesets for s in args.seeds]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        rows = list(pool.map(run_one, tasks))
    summary = {}
    for ruleset in args.rulesets:
        mine = [r for r in rows if r["ruleset"] == ruleset]
        scores = [r["score"] for r in mine]
        ref = REFERENCE[ruleset]
        med = statistics.median(scores)
        summary[ruleset] = {
            "scores": scores,
            "median_of_seed_scores": med,
            "mean_of_seed_scores": statistics.mean(scores),
            "collapsed": sum(s < COLLAPSE_MPH for s in scores),
            "reference_median": ref["median_of_medians"],
            "reference_collapsed": sum(s < COLLAPSE_MPH for s in ref["medians"]),
            "difference": med - ref["median_of_medians"],
            "within_1_mph": abs(med - ref["median_of_medians"]) <= 1.0,
            "same_runs": sum(bool(r["same_run"]) for r in mine),
            "learner": args.learner,
            "stream": stream,
            "dtype": overrides.get("dtype", "float32"),
        }
        print(f"{ruleset}: seeds {args.seeds} ({args.learner} learner, {summary[ruleset]['stream']} stream)")
        for r in mine:
            same = {True: "same run as the original", False: "different run", None: ""}[r["same_run"]]
            print(f"  seed {r['seed']}: {r['score']:.2f} mph (mean {r['mean']:.2f}; train {r['train_seconds']:.1f} s "
                  f"at {r['it_per_s']:,.0f} it/s, eval {r['eval_seconds']:.1f} s) {same}")  # fmt: skip
        s = summary[ruleset]
        print(f"  median {s['median_of_seed_scores']:.2f} vs original {s['reference_median']:.2f} "
              f"(Δ {s['difference']:+.2f}, {'within' if s['within_1_mph'] else 'NOT within'} 1 mph); "
              f"collapsed (< {COLLAPSE_MPH:.0f} mph): {s['collapsed']} of {len(scores)} "
              f"(original {s['reference_collapsed']} of 8)")  # fmt: skip
    print("JSON " + json.dumps({"summary": summary, "runs": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
