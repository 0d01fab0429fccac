"""Compile the numba kernels into numba's on-disk cache once, before anything needs them.

    python tools/warm_compile.py          # both engines (~65–80 s on a cold cache, a few s warm)
    python tools/warm_compile.py --ruleset v2

Why: every kernel is cached on disk (``cache=True``), keyed on the compiled sources (``sim.numba_cache_key``);
on a cold cache the first caller compiles it. CI starts each run from an empty ``NUMBA_CACHE_DIR`` (no stale
machine code), and three test modules (the JS learner, the golden traces, the simulator's API) spent about
100 of their 150 s compiling there. ``.ci/run`` runs this on the second core while the linters run on the
first, so the tests, the study workers and the CLI commands they start load the kernels instead.

What it runs, short and small, for each engine: the simulator stepped directly, the built-in policies
through every protocol of the engine (compiled twins and a Python policy), a torch training (float32 and float64,
both draw streams) with its quick scores, the official evaluation of its net (greedy and at ε_test > 0), the
exact replica of the original learner, and a net evaluated by protocol name. Nothing is written but the cache.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RULESETS = ("v2", "v1")


def warm(ruleset: str) -> None:
    """Run each compiled path of ``ruleset``'s engine and learner once, at toy sizes."""
    from autotune.learner.brain_policy import evaluate_net
    from autotune.learner.config import preset
    from autotune.learner.js_learner import train_exact
    from autotune.learner.official import evaluate_official
    from autotune.learner.training import train
    from sim.config import EngineConfig
    from sim.policies import BUILTINS
    from sim.protocols import OFFICIAL, PROTOCOLS, evaluate
    from sim.simulator import Simulator

    agents = 2 if ruleset == "v2" else 0
    engine = EngineConfig(ruleset=ruleset, other_agents=agents, lanes_side=1, patches_ahead=4)
    for policy in (lambda obs: np.zeros(len(obs), dtype=int), BUILTINS["heuristic_a"].bind(engine)):
        for seed in (1, 7):  # stepped from Python: the actions' dtype and a seed's size (int64 or uint64) both
            sim = Simulator(engine, 2, 60, 2)  # pick a specialization
            sim.seed_independent(seed)
            obs = sim.start()
            while obs is not None:
                obs = sim.step(policy(obs))
    single = Simulator(engine, n_worlds=1, frames_per_run=60)
    single.seed_independent(1)
    car = single.start_single()
    while car >= 0:
        car = single.step_single(1)
    single = Simulator(engine, n_worlds=1, frames_per_run=60)
    single.seed_independent(1)
    car, pos = single.start_single(), 0
    while car >= 0:
        car, pos = single.step_single_agents(1, np.ones(3, dtype=np.int64), pos) if car == 0 else (
            single.step_single(2), pos)  # fmt: skip
    for builtin in BUILTINS.values():  # each compiled twin is its own specialization of the drivers
        bound = builtin.bind(engine)
        batch = Simulator(engine, 2, 60, 2)
        batch.seed_independent(1)
        bound.run(batch, 0, 2)
        for name, protocol in PROTOCOLS.items():
            if protocol.ruleset in (None, ruleset):
                evaluate(engine, bound, name, runs=2, frames=200)
    python = BUILTINS["accelerate"].bind(engine)
    evaluate(engine, lambda obs: python(obs), OFFICIAL[ruleset], runs=2)  # a Python policy: no compiled twin

    small = {"train_iterations": 400, "experience_size": 2_000, "start_learn_threshold": 100,
             "learning_steps_burnin": 50, "learning_steps_total": 300}  # fmt: skip
    config = preset("network_basic_" + ruleset, **small)
    result = train(config, 1, report_points=1, quick_eval_runs=2, quick_eval_frames=200)
    train(preset("network_basic_" + ruleset, dtype="float64", **small), 1, quick_eval=False, stream="original")
    net = result.convnet()
    evaluate_official(net, config, runs=2)
    evaluate_official(net, config.replace(epsilon_test_time=0.05), runs=2)
    exact = train_exact(config, 1)
    evaluate_net(exact.convnet, config.settings, OFFICIAL[ruleset], seed=1, runs=2)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ruleset", choices=RULESETS, action="append", help="an engine (default: both)")
    args = p.parse_args(argv)
    for ruleset in args.ruleset or RULESETS:
        t0 = time.perf_counter()
        warm(ruleset)
        print(f"{ruleset}: compiled or loaded in {time.perf_counter() - t0:.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
