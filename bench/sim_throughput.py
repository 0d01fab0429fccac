"""Simulator throughput: frames/s with the noop policy, for every way a policy drives the engine.

Grid: rulesets v1, v2 (0 agents), v2 (10 agents) × batch 1, 64, 4096 worlds × threads 1, 2, for
two drivers:

* ``python`` — a plain Python function policy, called once per batch of pending decisions
  (``Simulator.start``/``step``): what a user's NumPy or torch policy gets;
* ``compiled`` — the built-in ``noop`` run inside the compiled, parallel per-world loop
  (``BoundPolicy.run``): what ``python -m sim.evaluate --policy noop`` uses;

plus a single world stepped decision by decision through the lean ``start_single``/``step_single``
path that training uses, sequential official evaluations with a compiled policy, and (unless
``--no-cli``) the issue's end-to-end figure: ``python -m sim.evaluate --protocol custom --runs 4096
--frames 2000 --policy noop`` as a subprocess, its own reported frames/s and the process's wall time.
Compilation is excluded from the in-process figures (one warm-up pass per shape). Prints a table
and one JSON line.

    python bench/sim_throughput.py [--quick] [--no-cli]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

import numba
import numpy as np

from sim.config import EngineConfig
from sim.policies import BUILTINS
from sim.protocols import evaluate
from sim.simulator import Simulator

CASES = (("v1", 0), ("v2", 0), ("v2", 10))


def _noop(obs):  # noqa: ANN001, ANN202
    return np.zeros(len(obs), dtype=np.int64)


def batch_fps(ruleset: str, other_agents: int, worlds: int, frames: int, driver: str) -> float:
    config = EngineConfig(ruleset=ruleset, other_agents=other_agents)
    sim = Simulator(config, worlds, frames)
    sim.seed_independent(1)
    start = time.perf_counter()
    if driver == "compiled":
        BUILTINS["noop"].bind(config).run(sim)
    else:
        obs = sim.start()
        while obs is not None:
            obs = sim.step(_noop(obs))
    return worlds * frames / (time.perf_counter() - start)


def single_fps(ruleset: str, other_agents: int, frames: int) -> float:
    config = EngineConfig(ruleset=ruleset, other_agents=other_agents)
    sim = Simulator(config, 1, frames)
    sim.seed_independent(1)
    start = time.perf_counter()
    car = sim.start_single()
    while car >= 0:
        car = sim.step_single(0)
    return frames / (time.perf_counter() - start)


def official_seconds(other_agents: int) -> float:
    config = EngineConfig(ruleset="v2", lanes_side=1, patches_ahead=10, other_agents=other_agents)
    policy = BUILTINS["heuristic_a"].bind(config)
    return evaluate(config, policy, "v2-official").wall_seconds


def cli_row(ruleset: str, threads: int) -> dict:
    """``python -m sim.evaluate`` end to end: its reported frames/s and the whole process's wall time."""
    cmd = [
        sys.executable, "-m", "sim.evaluate", "--ruleset", ruleset, "--protocol", "custom", "--runs", "4096",
        "--frames", "2000", "--policy", "noop", "--lanes-side", "1", "--patches-ahead", "10",
        "--patches-behind", "0", "--threads", str(threads), "--json",
    ]  # fmt: skip
    start = time.perf_counter()
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    process = time.perf_counter() - start
    result = json.loads(out.strip().splitlines()[-1])
    return {
        "ruleset": ruleset,
        "agents": 0,
        "batch": 4096,
        "threads": threads,
        "driver": "cli",
        "fps": result["frames_per_second"],
        "process_seconds": process,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller runs (noisier)")
    ap.add_argument("--no-cli", action="store_true", help="skip the end-to-end sim.evaluate subprocesses")
    args = ap.parse_args()
    scale = 0.25 if args.quick else 1.0
    total = int(8_000_000 * scale)
    rows = []
    if not args.no_cli:  # first, so the subprocesses also compile anything not yet cached
        for ruleset in ("v1", "v2"):
            cli_row(ruleset, 2)  # warm the on-disk compilation cache
            for threads in (1, 2):
                rows.append(cli_row(ruleset, threads))
    for ruleset, other_agents in CASES:  # warm-up: compile every shape once
        for driver in ("python", "compiled"):
            batch_fps(ruleset, other_agents, 2, 60, driver)
        single_fps(ruleset, other_agents, 60)
    official_seconds(10)
    for ruleset, other_agents in CASES:
        for threads in (1, 2):
            numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
            for driver in ("python", "compiled"):
                for worlds in (1, 64, 4096):
                    frames = max(2000, total // worlds) if worlds > 1 else int(1_000_000 * scale)
                    fps = batch_fps(ruleset, other_agents, worlds, frames, driver)
                    rows.append(
                        {
                            "ruleset": ruleset,
                            "agents": other_agents,
                            "batch": worlds,
                            "threads": threads,
                            "driver": driver,
                            "fps": fps,
                        }
                    )
        numba.set_num_threads(1)
        rows.append(
            {
                "ruleset": ruleset,
                "agents": other_agents,
                "batch": "single-step",
                "threads": 1,
                "driver": "python",
                "fps": single_fps(ruleset, other_agents, int(2_000_000 * scale)),
            }
        )
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    official = {f"v2_official_heuristic_a_agents{a}_s": official_seconds(a) for a in (0, 10)}

    print(f"{'ruleset':8} {'agents':>6} {'batch':>12} {'threads':>7} {'driver':>9} {'frames/s':>14}")
    for r in rows:
        extra = f"   (process {r['process_seconds']:.2f} s)" if "process_seconds" in r else ""
        print(
            f"{r['ruleset']:8} {r['agents']:>6} {r['batch']!s:>12} {r['threads']:>7} {r['driver']:>9} "
            f"{r['fps']:>14,.0f}{extra}"
        )
    for k, v in official.items():
        print(f"{k}: {v:.3f}")
    print(json.dumps({"bench": "sim_throughput", "rows": rows, **official}))


if __name__ == "__main__":
    main()
