"""Training throughput (trainIterations per second) of the torch learner vs the original JS.

    python bench/train_throughput.py                 # default_v1, network_basic, strong; 3 seeds each
    python bench/train_throughput.py --repeats 1 --configs network_basic --no-eval
    python bench/train_throughput.py --stream original --dtype float64 --no-eval   # the original's own runs
    python bench/train_throughput.py --learner exact --no-eval                      # the numba replica
    python bench/train_throughput.py --configs network_basic --other-agents 10 --no-eval   # v2 with 10 agents

For each reference config (settings and JS wall times from learner_scores.json) the full training
protocol runs ``--repeats`` times (seeds 1, 2, …; no quick evaluations, as train.js has none) in
this single process with one torch thread. Reported per config: the median over repeats of
iterations/s by wall clock and by process CPU time (the CPU figure is robust to other jobs on the
machine), and the speed-up over the JS (its fastest seed: iterations / train_wall_seconds, i.e.
≈1,370 it/s default_v1, 515 network_basic, 125 strong; those jobs ran two at a time, one per core,
on the 2-core reference VM).

Unless ``--no-eval``: a network_basic net trained in v2 is evaluated with the exact official v2
protocol (``autotune.learner.brain_policy``: 500 runs × 2,000 frames) with 0 and 10 agents; the first call
includes numba compilation, so a second, warm call is timed too.

Prints a table and one JSON line (prefix ``JSON``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from autotune.learner.config import preset  # noqa: E402
from autotune.learner.training import train  # noqa: E402

REFERENCE = ROOT.parent / "shared" / "reference"
CONFIGS = {"default_v1": "default_v1.json", "network_basic": "network_basic.json", "strong": "strong.json"}
# Fallback JS figures (learner_scores.json, fastest seed) if the reference folder is not beside the checkout.
JS_FALLBACK = {"default_v1": 1367.5, "network_basic": 514.8, "strong": 125.1}
TARGETS = {"network_basic": 10.0, "strong": 20.0}


def js_iterations_per_second() -> dict[str, float]:
    path = REFERENCE / "learner_scores.json"
    if not path.exists():
        return dict(JS_FALLBACK)
    data = json.loads(path.read_text())
    out = {}
    for name, file in CONFIGS.items():
        runs = [r for r in data["runs"] if r["config_file"] == file]
        rates = [r["train"]["trainIterations"] / r["train"]["wall_seconds"] for r in runs]
        out[name] = max(rates)  # the JS's best run: the conservative comparison
    return out


def _exact(config, seed: int):  # noqa: ANN001, ANN202
    """The replica timed like ``train`` (first call per config compiles: one untimed warm-up)."""
    from autotune.learner.js_learner import train_exact

    t, c = time.perf_counter(), time.process_time()
    r = train_exact(config, seed)
    return r.forward_passes, time.perf_counter() - t, time.process_time() - c, r.updates, r.training_run_scores


def bench_training(
    names: list[str],
    repeats: int,
    iterations: int | None,
    learner: str,
    stream: str,
    dtype: str | None,
    other_agents: int | None = None,
) -> dict[str, dict]:
    js = js_iterations_per_second()
    results = {}
    for name in names:
        overrides: dict[str, object] = {"dtype": dtype} if dtype else {}
        if iterations is not None:
            overrides["train_iterations"] = iterations
        if other_agents is not None:
            overrides["other_agents"] = other_agents
        config = preset(name, **overrides)
        wall, cpu, runs = [], [], []
        if learner == "exact":
            train_exact_warm = preset(name, train_iterations=100)
            _exact(train_exact_warm, 1)
        for seed in range(1, repeats + 1):
            if learner == "exact":
                decisions, seconds, cpu_s, updates, scores = _exact(config, seed)
                diverged = False
            else:
                r = train(config, seed, quick_eval=False, stream=stream)
                decisions, seconds, cpu_s, updates = r.decisions, r.train_seconds, r.train_cpu_seconds, r.updates
                scores, diverged = r.training_run_scores, r.diverged
            wall.append(decisions / seconds)
            cpu.append(decisions / cpu_s)
            runs.append({"seed": seed, "seconds": seconds, "cpu_seconds": cpu_s, "updates": updates,
                         "diverged": diverged, "training_run_scores": scores})  # fmt: skip
        med_wall, med_cpu = statistics.median(wall), statistics.median(cpu)
        ref = js[name] if other_agents is None else None  # the JS ran each config with its own agents only
        results[name] = {
            "ruleset": config.ruleset,
            "other_agents": config.other_agents,
            "train_iterations": config.train_iterations,
            "it_per_s_wall": med_wall,
            "it_per_s_cpu": med_cpu,
            "js_it_per_s": ref,
            "speedup_wall": med_wall / ref if ref else None,
            "speedup_cpu": med_cpu / ref if ref else None,
            "target_speedup": TARGETS.get(name) if ref else None,
            "learner": learner,
            "stream": stream,
            "dtype": "float64" if learner == "exact" else config.dtype,
            "runs": runs,
        }
    return results


def bench_eval() -> dict[str, dict]:
    from autotune.learner.official import evaluate_official

    config = preset("network_basic")  # v2
    net = train(config, 1, quick_eval=False).convnet()
    out = {}
    for other_agents in (0, 10):
        times = []
        for _ in range(2):
            t = time.perf_counter()
            ev = evaluate_official(net, config, other_agents=other_agents)
            times.append(time.perf_counter() - t)
        out[f"agents_{other_agents}"] = {
            "cold_seconds": times[0], "warm_seconds": times[1], "median_site": ev.median_site, "mean": ev.mean,
            "target_seconds": 2.0 if other_agents == 10 else None,
        }  # fmt: skip
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--iterations", type=int, default=None, help="override trainIterations (default: the config's)")
    parser.add_argument("--no-eval", action="store_true")
    parser.add_argument("--learner", choices=["torch", "exact"], default="torch", help="torch (default) or the replica")
    parser.add_argument("--stream", choices=["independent", "original"], default="independent")
    parser.add_argument("--dtype", choices=["float32", "float64"], default=None, help="torch learner precision")
    parser.add_argument(
        "--other-agents",
        type=int,
        default=None,
        metavar="N",
        help="override otherAgents (v2 configs only; the JS figures are for the config's own)",
    )
    args = parser.parse_args()
    if args.learner == "exact":
        if args.stream == "independent" and "--stream" in sys.argv:
            parser.error("--learner exact always draws from the original stream; drop --stream independent")
        args.stream = "original"  # the replica has no other stream
    if args.other_agents is not None and not all(preset(n).ruleset == "v2" for n in args.configs):
        parser.error("--other-agents: only the v2 configs have other agents; e.g. --configs network_basic")
    training = bench_training(args.configs, args.repeats, args.iterations, args.learner, args.stream, args.dtype,
                              args.other_agents)  # fmt: skip
    print(f"learner {args.learner}, stream {args.stream}")
    print(f"{'config':<14} {'ruleset':<7} {'agents':>6} {'iterations':>10} {'it/s wall':>10} {'it/s cpu':>9} "
          f"{'JS it/s':>8} {'× wall':>7} {'× cpu':>6} {'target':>7}")  # fmt: skip
    for name, r in training.items():
        target = f"≥{r['target_speedup']:.0f}×" if r["target_speedup"] else "-"
        js_s, xw, xc = ((f"{r['js_it_per_s']:,.0f}", f"{r['speedup_wall']:.1f}×", f"{r['speedup_cpu']:.1f}×")
                        if r["js_it_per_s"] else ("-", "-", "-"))  # fmt: skip
        rates = f"{r['it_per_s_wall']:>10,.0f} {r['it_per_s_cpu']:>9,.0f}"
        print(f"{name:<14} {r['ruleset']:<7} {r['other_agents']:>6} {r['train_iterations']:>10,} "
              f"{rates} {js_s:>8} {xw:>7} {xc:>6} {target:>7}")  # fmt: skip
    out = {"training": training}
    if not args.no_eval:
        ev = bench_eval()
        out["v2_official_eval_network_basic"] = ev
        for key, r in ev.items():
            print(f"v2-official eval, {key.replace('_', ' ')}: {r['warm_seconds']:.2f} s warm "
                  f"({r['cold_seconds']:.2f} s cold), median {r['median_site']}")  # fmt: skip
    print("JSON " + json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
