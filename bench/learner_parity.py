"""Learner parity with the original JS deepqlearn: network_basic, 8 seeds per engine.

    python bench/learner_parity.py                     # v1 and v2, seeds 1…8, 2 processes
    python bench/learner_parity.py --rulesets v2 --seeds 1 2 3 --jobs 1

Each seed s trains ``network_basic`` with the training protocol (v1: train.js; v2: the training web
worker, otherAgents 0) and evaluates the trained net exactly as the reference data did
(learner_scores.json / learner_scores_v2.json): ``Math.random := mulberry32(100 + s)``, a fresh
brain built (its weight-init draws consumed), the trained weights loaded after the JSON round
trip; v1: evaluate.js (10 × 100,000 frames, lexicographic ``sorted[5]``), v2: the official worker
(500 × 2,000 frames, ``sorted[250]``). The learner cannot match the JS runs draw for draw (spec
§10.6), so the comparison is statistical: the median over seeds of the per-seed scores against
the original's (v1 70.41, v2 66.30), and the number of collapsed seeds (score < 60 mph; the
original had 1 of 8 in v1 at 51.96, none in v2).

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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

REFERENCE = {
    "v1": {"medians": [71.32, 70.7, 69.14, 69.46, 70.92, 71.22, 70.13, 51.96], "median_of_medians": 70.415},
    "v2": {"medians": [66.15, 66.51, 67.04, 66.45, 65.81, 66.08, 66.04, 66.58], "median_of_medians": 66.30},
}
COLLAPSE_MPH = 60.0


def run_one(args: tuple[str, int, dict]) -> dict:
    ruleset, seed, overrides = args
    import torch

    torch.set_num_threads(1)
    from autotune.config import preset
    from autotune.learner import train
    from autotune.train import evaluate_official

    config = preset("network_basic", ruleset=ruleset, **overrides)
    t = time.perf_counter()
    result = train(config, seed, quick_eval=False)
    train_s = time.perf_counter() - t
    t = time.perf_counter()
    ev = evaluate_official(result.convnet(), config, seed=100 + seed)
    return {
        "ruleset": ruleset,
        "seed": seed,
        "eval_seed": 100 + seed,
        "score": ev.median_site,
        "mean": ev.mean,
        "train_seconds": train_s,
        "it_per_s": result.iterations_per_second,
        "eval_seconds": time.perf_counter() - t,
        "diverged": result.diverged,
        "training_run_scores": result.training_run_scores,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rulesets", nargs="+", default=["v1", "v2"], choices=["v1", "v2"])
    parser.add_argument("--seeds", nargs="+", type=int, default=list(range(1, 9)))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a setting")
    args = parser.parse_args()
    overrides = {}
    for item in args.set:
        key, value = item.split("=", 1)
        overrides[key] = json.loads(value) if value[:1].isdigit() or value[:1] in "-[{" else value
    tasks = [(r, s, overrides) for r in args.rulesets for s in args.seeds]
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
        }
        print(f"{ruleset}: seeds {args.seeds}")
        for r in mine:
            print(f"  seed {r['seed']}: {r['score']:.2f} mph (mean {r['mean']:.2f}; train {r['train_seconds']:.1f} s "
                  f"at {r['it_per_s']:,.0f} it/s, eval {r['eval_seconds']:.1f} s)")  # fmt: skip
        s = summary[ruleset]
        print(f"  median {s['median_of_seed_scores']:.2f} vs original {s['reference_median']:.2f} "
              f"(Δ {s['difference']:+.2f}, {'within' if s['within_1_mph'] else 'NOT within'} 1 mph); "
              f"collapsed (< {COLLAPSE_MPH:.0f} mph): {s['collapsed']} of {len(scores)} "
              f"(original {s['reference_collapsed']} of 8)")  # fmt: skip
    print("JSON " + json.dumps({"summary": summary, "runs": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
