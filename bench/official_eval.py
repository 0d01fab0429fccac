"""Official evaluation speed: seconds of one v2-official scoring (500 runs × 2,000 frames) of real crowd nets.

Every rung of a study is scored with it, and a wide view costs more than a wide net there: each greedy decision
allocates convnetjs's input ``Vol``, whose discarded Gaussians the exact evaluation must still draw from
``Math.random`` (``autotune.convnet.random.gauss_skip``). The nets span input sizes from a few dozen to a few
thousand; each is scored at ε_test 0 (every decision greedy: the most Gaussians) with 10 other agents (the
paper's setting, 11 red cars), and with the net's own settings. Compilation is excluded (one warm-up scoring of a
tiny net first); each figure is the median of ``--repeats`` scorings on one thread. Prints a table and one JSON
line; the scores are printed too, so a run on another commit shows it scores the same nets the same.

    python bench/official_eval.py [--repeats 3] [--nets DIR]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

NETS = (
    "dt-gsurma-deep-traffic-v00",
    "dt-jnorthrup-deeptraffic-v05",
    "dt-huaweiren-deeptraffic-v02",
    "dt-jordanott-deep-traffic-v03",
)
"""Crowd nets of different input sizes (``../shared/crowd/nets``)."""


def main() -> None:
    from autotune import load_net_and_settings
    from autotune.learner.brain_policy import evaluate_net

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="scorings per net and setting (median reported)")
    ap.add_argument("--nets", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "crowd" / "nets",
                    help="the crowd's nets (default ../shared/crowd/nets)")  # fmt: skip
    args = ap.parse_args()
    warm_net, warm_settings = load_net_and_settings(args.nets / f"{NETS[0]}.json")
    evaluate_net(warm_net, warm_settings, runs=2, frames=200, protocol="custom", other_agents=10, epsilon=0.0,
                 threads=1)  # fmt: skip
    rows = []
    print(f"{'net':34s} {'inputs':>7s} {'params':>8s} {'ε_test':>6s} {'agents':>6s} {'score':>6s} {'seconds':>8s}")
    for name in NETS:
        net, settings = load_net_and_settings(args.nets / f"{name}.json")
        inputs, params = net.input_size, sum(w.size + b.size for w, b in net.params)
        for epsilon, agents in ((0.0, 10), (None, None)):
            times, score = [], None
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                ev = evaluate_net(net, settings, epsilon=epsilon, other_agents=agents, threads=1)
                times.append(time.perf_counter() - t0)
                score = float(ev.median_site)
            eps = settings.filled().epsilon_test_time if epsilon is None else epsilon
            k = (settings.other_agents or 0) if agents is None else agents
            row = {"net": name, "inputs": inputs, "params": params, "epsilon_test": eps, "other_agents": k,
                   "score": score, "seconds": statistics.median(times), "spread": [min(times), max(times)]}  # fmt: skip
            rows.append(row)
            print(f"{name[3:37]:34s} {inputs:7d} {params:8d} {eps:6.2f} {k:6d} {score:6.2f} {row['seconds']:8.2f}")
    print(json.dumps({"bench": "official_eval", "rows": rows}))


if __name__ == "__main__":
    main()
